/* test_momentum.c - a fast rock hitting a free cloth: total linear momentum is conserved.
 *
 * Nothing external acts (no gravity, drag, pins or ground), so cloth + rock momentum must stay
 * what the rock brought in. Every contact force on a vertex is applied negated to the rock in
 * the same force pass (and springs pull both ends with exactly opposite forces), so the only
 * loss left is float rounding. The check is meaningful only if the rock really pushed the
 * cloth: the cloth must end up with a good share of the momentum. Run for both integrators and
 * both friction models. */
#include "testkit.h"

#define FRAMES 60 /* 1 s */
#define PI 3.14159265358979323846

/* Relative bound on |P(t) - P0| / |P0| at every frame: 1e-5. Measured at most 1.8e-6 (about
 * 1.2e-5 kg m/s of 6.4 kg m/s), i.e. float rounding over ~2000 substeps of a 256-vertex sum. */
#define REL_BOUND 1e-5

static double norm3(const double v[3]) { return sqrt(v[0] * v[0] + v[1] * v[1] + v[2] * v[2]); }

static void check(int integrator, int friction)
{
    cs_scene sc;
    cs_params p;
    tk_quiet(&sc, &p); /* gravity, drag, damping, ground: off */
    sc.nx = sc.ny = 16;
    sc.size_x = sc.size_y = 1.0f; /* 1 kg of cloth, vertex mass 1/256 kg */
    sc.height = 0.0f;
    sc.pins = CS_PINS_NONE;
    p.integrator = integrator;
    p.friction_model = friction;
    p.c_contact = 0.05f; /* the default normal damping: dissipative, still action = reaction */
    cs_sim *sim = tk_sim_serial(&sc, &p);
    /* A 1.26 kg rock coming down at 5 m/s, a little off centre, sliding sideways and spinning,
     * so friction and torque take part. */
    cs_rock_def d;
    cs_rock_def_default(&d);
    d.position[0] = 0.02f;
    d.position[2] = 0.3f;
    d.velocity[0] = 1.0f;
    d.velocity[2] = -5.0f;
    d.angular_velocity[1] = 5.0f;
    d.radius = 0.1f;
    d.density = 300.0f;
    uint32_t id;
    assert_int_equal(cs_rock_add(sim, &d, &id), CS_OK);
    cs_info info;
    cs_sim_info(sim, &info);
    double P0[3], P[3];
    tk_momentum(sim, P0);
    const cs_rock r0 = tk_rock(sim, id);
    /* What the rock brought: M v with M = 300 x 4/3 pi 0.1^3 = 1.2566 kg. */
    assert_float_equal(P0[2], -5.0 * 300.0 * 4.0 / 3.0 * PI * 1e-3, 1e-5);
    assert_float_equal(P0[0], 1.0 * r0.mass, 1e-6);
    double worst = 0, cloth_best = 0;
    for (int f = 1; f <= FRAMES; f++) {
        tk_step(sim, info.substeps);
        tk_momentum(sim, P);
        const double dP[3] = {P[0] - P0[0], P[1] - P0[1], P[2] - P0[2]};
        const double rel = norm3(dP) / norm3(P0);
        if (rel > worst) worst = rel;
        if (rel > REL_BOUND)
            fail_msg("frame %d: momentum (%.8f, %.8f, %.8f), started (%.8f, %.8f, %.8f): relative change %.3g", f,
                     P[0], P[1], P[2], P0[0], P0[1], P0[2], rel);
        const cs_rock r = tk_rock(sim, id);
        const double Pc[3] = {P[0] - (double)r.mass * r.def.velocity[0], P[1] - (double)r.mass * r.def.velocity[1],
                              P[2] - (double)r.mass * r.def.velocity[2]};
        if (norm3(Pc) > cloth_best) cloth_best = norm3(Pc);
    }
    print_message("%s, %s: max |dP|/|P0| = %.2e (bound %.0e); cloth momentum up to %.3f of |P0| = %.3f kg m/s\n",
                  integrator == CS_VELOCITY_VERLET ? "verlet" : "euler", friction ? "resultant" : "coulomb_viscous",
                  worst, REL_BOUND, cloth_best / norm3(P0), norm3(P0));
    /* The rock did push the cloth (measured: 0.30 to 0.52 of the momentum moved to it). */
    assert_true(cloth_best > 0.15 * norm3(P0));
    cs_sim_destroy(sim);
}

static void test_verlet_coulomb_viscous(void **unused)
{
    (void)unused;
    check(CS_VELOCITY_VERLET, CS_FRICTION_COULOMB_VISCOUS);
}

static void test_verlet_resultant(void **unused)
{
    (void)unused;
    check(CS_VELOCITY_VERLET, CS_FRICTION_RESULTANT);
}

static void test_euler_coulomb_viscous(void **unused)
{
    (void)unused;
    check(CS_SYMPLECTIC_EULER, CS_FRICTION_COULOMB_VISCOUS);
}

static void test_euler_resultant(void **unused)
{
    (void)unused;
    check(CS_SYMPLECTIC_EULER, CS_FRICTION_RESULTANT);
}

int main(void)
{
    const struct CMUnitTest tests[] = {
        cmocka_unit_test(test_verlet_coulomb_viscous),
        cmocka_unit_test(test_verlet_resultant),
        cmocka_unit_test(test_euler_coulomb_viscous),
        cmocka_unit_test(test_euler_resultant),
    };
    return cmocka_run_group_tests(tests, NULL, NULL);
}
