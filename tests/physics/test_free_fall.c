/* test_free_fall.c - a rock falling under gravity alone, against z0 - g t^2/2.
 *
 * With constant acceleration velocity Verlet is exact: kick-drift-kick gives
 * x_n = x0 + v0 t + a t^2/2 for every n, so what remains is float rounding. Symplectic Euler
 * (v first, then x with the new v) gives x_n = x0 + v0 t + a t^2/2 + a t dt/2 exactly: with
 * a = -g it sits g t dt/2 below the parabola. Both are checked at every frame of one second,
 * for a rock (ground off, the cloth far away and pinned) and, for Verlet, for a free flat cloth
 * whose springs stay exactly at rest while it falls. */
#include "testkit.h"

#define G 9.81
#define Z0 0.0f     /* start at 0, so |z| stays small and its rounding too */
#define FRAMES 60   /* one second at the default 60 frames per second */

/* Float rounding allowed in z after one second (m). Rounding is systematic here: v = v + h a
 * adds the same float each substep, so within a binade of v every addition rounds the same way
 * and the velocity error grows linearly, its integral quadratically. The worst case over
 * N = 1800 substeps (|v| <= 9.81, ulp 9.5e-7, |z| <= 4.9, ulp 4.8e-7) is
 * N ulp(v) N dt / 2 + N ulp(z) / 2 = 8.6e-4 + 4.3e-4 m. The sequence is deterministic
 * (-ffp-contract=off), and measured: Verlet 1.7e-5 m (rock and cloth alike), symplectic Euler
 * 5.4e-5 m (one kick of dt a a step rounds differently from two of dt/2 a). Bounds: 5e-5 m for
 * Verlet (3x) and 2e-4 m for Euler (4x), both well below the Euler offset it must tell apart,
 * g t dt/2 = 2.7e-3 m at 1 s. */
#define VERLET_ROUNDING 5e-5
#define EULER_ROUNDING 2e-4

static cs_sim *falling(int integrator, uint32_t *rock)
{
    cs_scene sc;
    cs_params p;
    tk_quiet(&sc, &p);
    p.gravity[2] = (float)-G;
    p.integrator = integrator;
    sc.nx = sc.ny = 4;
    sc.pins = CS_PINS_EDGES; /* every vertex of a 4 x 4 grid but 4 is pinned; none moves far */
    sc.height = 50.0f;
    cs_sim *sim = tk_sim_serial(&sc, &p);
    *rock = tk_add_rock(sim, 20.0f, -10.0f, Z0, 0.1f, 300.0f);
    return sim;
}

static void check_fall(int integrator)
{
    uint32_t id;
    cs_sim *sim = falling(integrator, &id);
    cs_info info;
    cs_sim_info(sim, &info);
    assert_int_equal(info.substeps, 30); /* the guard had no reason to raise it */
    const double dt = info.dt;
    double worst = 0, worst_offset_err = 0;
    for (int f = 1; f <= FRAMES; f++) {
        tk_step(sim, info.substeps);
        cs_sim_info(sim, &info);
        const double t = info.time;
        const cs_rock r = tk_rock(sim, id);
        const double z = r.def.position[2];
        const double parabola = Z0 - 0.5 * G * t * t;
        /* Nothing but gravity acts: x and y stay exactly where they were, no spin appears. */
        assert_true(r.def.position[0] == 20.0f && r.def.position[1] == -10.0f);
        assert_true(r.def.angular_velocity[0] == 0.0f && r.def.angular_velocity[1] == 0.0f &&
                    r.def.angular_velocity[2] == 0.0f);
        if (integrator == CS_VELOCITY_VERLET) {
            const double err = fabs(z - parabola);
            if (err > worst) worst = err;
            if (err > VERLET_ROUNDING) fail_msg("verlet: t = %.4f s: z = %.9g, parabola %.9g (error %.3g m)", t, z, parabola, err);
            /* v = -g t as well (velocity Verlet's v is exact too); measured 1.3e-4 m/s at most. */
            const double verr = fabs(r.def.velocity[2] + G * t);
            if (verr > 5e-4) fail_msg("verlet: t = %.4f s: vz = %.9g, expected %.9g", t, r.def.velocity[2], -G * t);
        } else {
            /* Symplectic Euler: exactly g t dt/2 below the parabola, up to the same rounding. */
            const double offset = 0.5 * G * t * dt;
            const double err = fabs(z - parabola);
            if (err > offset + EULER_ROUNDING)
                fail_msg("euler: t = %.4f s: z = %.9g, parabola %.9g: off by %.3g m, more than g t dt/2 = %.3g m", t,
                         z, parabola, err, offset);
            const double e2 = fabs(z - (parabola - offset));
            if (e2 > worst_offset_err) worst_offset_err = e2;
            if (e2 > EULER_ROUNDING)
                fail_msg("euler: t = %.4f s: z = %.9g, expected parabola - g t dt/2 = %.9g", t, z, parabola - offset);
        }
    }
    if (integrator == CS_VELOCITY_VERLET)
        print_message("verlet: largest |z - (z0 - g t^2/2)| over 1 s: %.3g m (bound %.3g)\n", worst, VERLET_ROUNDING);
    else
        print_message("euler: largest |z - (z0 - g t^2/2 - g t dt/2)| over 1 s: %.3g m (bound %.3g; offset at 1 s %.3g)\n",
                      worst_offset_err, EULER_ROUNDING, 0.5 * G * dt);
    cs_sim_destroy(sim);
}

static void test_rock_verlet(void **unused)
{
    (void)unused;
    check_fall(CS_VELOCITY_VERLET);
}

static void test_rock_symplectic_euler(void **unused)
{
    (void)unused;
    check_fall(CS_SYMPLECTIC_EULER);
}

/* A free horizontal cloth falls as one body: all its vertices share z, so every spring keeps
 * exactly its rest length and pulls with exactly zero force; each vertex follows the parabola. */
static void test_cloth_verlet(void **unused)
{
    (void)unused;
    cs_scene sc;
    cs_params p;
    tk_quiet(&sc, &p);
    p.integrator = CS_VELOCITY_VERLET;
    p.gravity[2] = (float)-G;
    sc.nx = sc.ny = 8;
    sc.pins = CS_PINS_NONE;
    sc.height = Z0;
    cs_sim *sim = tk_sim_serial(&sc, &p);
    cs_info info;
    cs_sim_info(sim, &info);
    const int32_t n = info.n_vertices;
    float *x0 = tk_positions(sim);
    double worst = 0;
    for (int f = 1; f <= FRAMES; f++) {
        tk_step(sim, info.substeps);
        cs_sim_info(sim, &info);
        const double parabola = Z0 - 0.5 * G * info.time * info.time;
        float *x = tk_positions(sim);
        for (int32_t v = 0; v < n; v++) {
            assert_true(x[3 * v] == x0[3 * v] && x[3 * v + 1] == x0[3 * v + 1]);
            const double err = fabs(x[3 * v + 2] - parabola);
            if (err > worst) worst = err;
            if (err > VERLET_ROUNDING) fail_msg("vertex %d at t = %.4f s: z = %.9g, parabola %.9g", (int)v, info.time,
                                         (double)x[3 * v + 2], parabola);
        }
        free(x);
    }
    print_message("cloth: largest |z - (z0 - g t^2/2)| over 1 s: %.3g m\n", worst);
    free(x0);
    cs_sim_destroy(sim);
}

int main(void)
{
    const struct CMUnitTest tests[] = {
        cmocka_unit_test(test_rock_verlet),
        cmocka_unit_test(test_rock_symplectic_euler),
        cmocka_unit_test(test_cloth_verlet),
    };
    return cmocka_run_group_tests(tests, NULL, NULL);
}
