/* test_rolling.c - a sphere launched sliding on the ground without spin ends up rolling at 5/7
 * of its launch speed, with omega = v/R.
 *
 * Friction acts at the contact point, arm (0, 0, -R) from the centre, so it has no moment about
 * that point: I w_y + M R v_x is conserved (torque T = arm x F gives T_y = -R F_x, and
 * M dv_x/dt = F_x). It starts at M R v0 and ends, once the contact point no longer slips
 * (v = R w_y), at (2/5 + 1) M R v: v = 5/7 v0, whatever the friction law. Motion along +x
 * rolls with w_y = +v/R, motion along +y with w_x = -v/R (w x arm must cancel v).
 *
 * Rock-ground friction is coulomb_viscous: F_t = min(mu_rock |F_n|, c_tangent |v_t|). Two
 * regimes are checked, each against its own analytic start:
 *   - Coulomb sliding first: c_tangent = 50 N s/m, v0 = 3 m/s: c_tangent v0 = 150 N far above
 *     mu_rock M g = 6.2 N, so the rock slides with dv/dt = -mu g and dw/dt = 5 mu g/(2 R) until
 *     the slip 3.5 mu g t catches v0 at t = 2 v0/(7 mu g) = 0.175 s (the viscous branch only
 *     takes over for the last 0.12 m/s of slip, and removes it in ~7 ms).
 *   - viscous from the start (the default c_tangent 0.5): 0.5 x 3 = 1.5 N < 6.2 N, so
 *     the slip decays as exp(-3.5 c_tangent t/M) (time constant 0.72 s); after 5 s it is 1e-3
 *     of v0.
 * The cloth hangs pinned by its edges 5 m up, far from the rock. */
#include "testkit.h"

#define PI 3.14159265358979323846
#define G 9.81
#define R 0.1
#define RHO 300.0
#define V0 3.0

typedef struct roll {
    cs_sim *sim;
    uint32_t id;
    double mass;
} roll;

/* A rock resting on the ground (at the penetration where k_rock delta = M g, so it does not
 * bounce) launched at V0 along +x (dir 0) or +y (dir 1), no spin. */
static roll launch(int dir, float c_tangent, int integrator)
{
    cs_scene sc;
    cs_params p;
    cs_scene_default(&sc);
    cs_params_default(&p);
    sc.nx = sc.ny = 8;
    sc.height = 5.0f;
    sc.pins = CS_PINS_EDGES;
    p.c_tangent = c_tangent;
    p.integrator = integrator;
    roll r;
    r.sim = tk_sim_serial(&sc, &p);
    r.mass = RHO * 4.0 / 3.0 * PI * R * R * R;
    cs_rock_def d;
    cs_rock_def_default(&d);
    d.radius = (float)R;
    d.density = (float)RHO;
    d.position[2] = (float)(R - r.mass * G / p.k_rock);
    d.velocity[dir] = (float)V0;
    assert_int_equal(cs_rock_add(r.sim, &d, &r.id), CS_OK);
    const cs_rock k = tk_rock(r.sim, r.id);
    assert_float_equal(k.mass, r.mass, 1e-6 * r.mass);
    assert_float_equal(k.inertia, 0.4 * r.mass * R * R, 1e-6 * k.inertia);
    return r;
}

static double seconds_to_substeps(cs_sim *sim, double t)
{
    cs_info info;
    cs_sim_info(sim, &info);
    return floor(t / info.dt + 0.5);
}

/* Speed along the launch direction and the matching spin component, signed so that rolling
 * gives spin * R = +speed: w_y for +x, -w_x for +y. */
static void speed_spin(const cs_rock *k, int dir, double *v, double *w)
{
    *v = k->def.velocity[dir];
    *w = dir == 0 ? k->def.angular_velocity[1] : -k->def.angular_velocity[0];
}

static void check_rolls(roll *r, int dir, double seconds, const char *what)
{
    tk_step(r->sim, (int64_t)seconds_to_substeps(r->sim, seconds));
    const cs_rock k = tk_rock(r->sim, r->id);
    double v, w;
    speed_spin(&k, dir, &v, &w);
    cs_info info;
    cs_sim_info(r->sim, &info);
    print_message("%s: at %.1f s v = %.6f m/s = %.6f v0 (5/7 = %.6f), R w = %.6f m/s\n", what, info.time, v, v / V0,
                  5.0 / 7.0, R * w);
    /* 5/7 v0 within 2% (measured: 1e-5 after Coulomb sliding, 3.7e-4 in the viscous case, whose
     * slip is still 1e-3 of v0 at 5 s). */
    assert_true(fabs(v / (5.0 / 7.0 * V0) - 1) < 0.02);
    /* Rolling: no slip, R w = v within 0.5% (measured: 2e-6 after Coulomb sliding, 1.3e-3 in the
     * viscous case); the sign is checked too. */
    assert_true(w > 0);
    assert_true(fabs(R * w - v) < 0.005 * v);
    /* Nothing moved it sideways or spun it about other axes; it stays on the ground, and it
     * never came near the cloth. */
    const int other = 1 - dir;
    assert_true(fabs(k.def.velocity[other]) < 1e-6 && fabs(k.def.velocity[2]) < 1e-3);
    assert_true(fabs(k.def.angular_velocity[2]) < 1e-6);
    assert_true(fabs(dir == 0 ? k.def.angular_velocity[0] : k.def.angular_velocity[1]) < 1e-6);
    assert_float_equal(k.def.position[2], R, 1e-3);
    cs_sim_destroy(r->sim);
}

static void coulomb_case(int dir, int integrator)
{
    roll r = launch(dir, 50.0f, integrator);
    /* Sliding phase at t = 0.1 s (before 0.175 s): v = v0 - mu g t, R w = 5/2 mu g t. */
    const double t = 0.1, mu = 0.5;
    tk_step(r.sim, (int64_t)seconds_to_substeps(r.sim, t));
    cs_rock k = tk_rock(r.sim, r.id);
    double v, w;
    speed_spin(&k, dir, &v, &w);
    print_message("sliding, t = %.2f s: v = %.5f (v0 - mu g t = %.5f), R w = %.5f (5/2 mu g t = %.5f)\n", t, v,
                  V0 - mu * G * t, R * w, 2.5 * mu * G * t);
    /* Within 0.5% of each (measured 1e-4): Coulomb friction mu M g at full strength. */
    assert_true(fabs(v - (V0 - mu * G * t)) < 0.005 * V0);
    assert_true(fabs(R * w - 2.5 * mu * G * t) < 0.005 * V0);
    assert_true(v - R * w > 0.3 * V0); /* still sliding */
    check_rolls(&r, dir, 1.0, dir == 0 ? "coulomb, +x" : "coulomb, +y");
}

static void test_slides_then_rolls_along_x(void **unused)
{
    (void)unused;
    coulomb_case(0, CS_VELOCITY_VERLET);
}

static void test_slides_then_rolls_along_y(void **unused)
{
    (void)unused;
    coulomb_case(1, CS_VELOCITY_VERLET);
}

static void test_slides_then_rolls_symplectic_euler(void **unused)
{
    (void)unused;
    coulomb_case(0, CS_SYMPLECTIC_EULER);
}

/* Default c_tangent: viscous from the start, and for the whole run (|F_t| = c_tangent |v_t| <=
 * 1.5 N < mu_rock M g). The slip s = v - R w then obeys ds/dt = -c_tangent (1/M + R^2/I) s =
 * -3.5 c_tangent s / M, and v = v0 (5/7 + 2/7 exp(-3.5 c_tangent t / M)) exactly; checked along
 * the way, then rolling after 5 s. */
static void test_viscous_regime_rolls(void **unused)
{
    (void)unused;
    const double ct = 0.5;
    roll r = launch(0, (float)ct, CS_VELOCITY_VERLET);
    const double times[] = {0.1, 0.5, 1.0, 2.0};
    double done = 0;
    for (size_t i = 0; i < sizeof times / sizeof times[0]; i++) {
        tk_step(r.sim, (int64_t)seconds_to_substeps(r.sim, times[i] - done));
        done = times[i];
        const cs_rock k = tk_rock(r.sim, r.id);
        const double expect = V0 * (5.0 / 7.0 + 2.0 / 7.0 * exp(-3.5 * ct * done / r.mass));
        print_message("viscous, t = %.1f s: v = %.6f m/s, analytic %.6f m/s\n", done, k.def.velocity[0], expect);
        /* Within 1e-3 v0 (measured: 6e-5 v0 at most). */
        assert_true(fabs(k.def.velocity[0] - expect) < 1e-3 * V0);
    }
    check_rolls(&r, 0, 5.0 - done, "viscous, +x");
}

int main(void)
{
    const struct CMUnitTest tests[] = {
        cmocka_unit_test(test_slides_then_rolls_along_x),
        cmocka_unit_test(test_slides_then_rolls_along_y),
        cmocka_unit_test(test_slides_then_rolls_symplectic_euler),
        cmocka_unit_test(test_viscous_regime_rolls),
    };
    return cmocka_run_group_tests(tests, NULL, NULL);
}
