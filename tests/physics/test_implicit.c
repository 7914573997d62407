/* test_implicit.c - integrator implicit_euler against values that do not come from its code:
 * backward Euler's closed form for one spring, free fall, a hanging column's extension
 * sum (N - j) m g / k, energy that never grows without damping, momentum kept between rock and cloth,
 * a rock that slides then rolls at 5/7 of its speed under Coulomb friction with the cloth, a pile of
 * stones that the solve does not press into each other, stiff and scrambled states that stay
 * finite, and the same bits for any thread count. */
#include "testkit.h"

/* The scene of these tests: vertical (hanging in the xz-plane), pinned along its top row, no
 * ground, and only the structural springs (shear and bending off), so that a column moves as a
 * chain of structural springs along z. */
static void column(cs_scene *sc, cs_params *p, int nx, int ny)
{
    cs_scene_default(sc);
    cs_params_default(p);
    sc->nx = nx, sc->ny = ny;
    sc->orientation = CS_VERTICAL;
    sc->pins = CS_PINS_TOP_EDGE;
    sc->size_x = 0.02f, sc->size_y = 2.0f, sc->height = 2.0f;
    p->k_shear = 0.0f, p->k_bend = 0.0f;
    p->ground = 0;
    p->integrator = CS_IMPLICIT_EULER;
}

/* One substep of a vertex hanging by one spring from a pinned one, moving along the spring: the
 * problem is linear along z, and backward Euler's step has the closed form
 *   v1 (m/h + k h + m drag) = m v0 / h + k (z_top - z0 - L0) - m g,  z1 = z0 + h v1. */
static void test_one_spring_step_is_backward_euler(void **unused)
{
    (void)unused;
    cs_scene sc;
    cs_params p;
    column(&sc, &p, 2, 2);
    p.solver_tolerance = 1e-7f;
    p.c_spring = 0.0f, p.drag = 0.3f; /* spring damping would act along the diagonals too */
    cs_sim *sim = tk_sim_serial(&sc, &p);
    cs_info info;
    cs_sim_info(sim, &info);
    const double h = info.dt, m = sim->model.phys.mass, k = p.k_structural, g = 9.81;
    const double L0 = sc.size_y, z_top = sc.height + sc.size_y / 2;
    /* both bottom vertices 3 cm below rest, moving down at 0.4 m/s: the spring between them stays
     * horizontal and unstretched */
    const double z0 = z_top - L0 - 0.03, v0 = -0.4;
    for (int32_t v = 0; v < 2; v++) {
        const float x[3] = {sim->state.x[v], 0.0f, (float)z0}, vel[3] = {0.0f, 0.0f, (float)v0};
        tk_set_vertex(sim, v, x, vel);
    }
    tk_step(sim, 1);
    const double v1 = (m * v0 / h + k * (z_top - z0 - L0) - m * g) / (m / h + k * h + m * p.drag);
    const double z1 = z0 + h * v1;
    for (int32_t v = 0; v < 2; v++) {
        tk_assert_near(sim->state.vz[v], v1, 1e-4 * fabs(v1) + 1e-5);
        tk_assert_near(sim->state.z[v], z1, 1e-6);
        tk_assert_near(sim->state.x[v], v == 0 ? -0.01 : 0.01, 1e-6);
    }
    assert_true(sim->solver.newton >= 1 && sim->solver.cg >= 1);
    cs_sim_destroy(sim);
}

/* A free cloth without air falls as backward Euler says: after N substeps v = -N h g and the drop
 * is h^2 g N (N + 1) / 2; its springs never stretch. */
static void test_free_fall(void **unused)
{
    (void)unused;
    cs_scene sc;
    cs_params p;
    cs_scene_default(&sc);
    cs_params_default(&p);
    sc.nx = sc.ny = 12;
    sc.pins = CS_PINS_NONE;
    p.drag = 0.0f, p.ground = 0;
    p.integrator = CS_IMPLICIT_EULER;
    cs_sim *sim = tk_sim_serial(&sc, &p);
    cs_info info;
    cs_sim_info(sim, &info);
    const int N = 30;
    tk_step(sim, N);
    const double h = info.dt, g = 9.81;
    for (int32_t v = 0; v < sim->state.n; v += 7) {
        tk_assert_near(sim->state.vz[v], -N * h * g, 2e-4);
        tk_assert_near(sim->state.z[v], sc.height - h * h * g * N * (N + 1) / 2.0, 2e-5);
    }
    cs_sim_destroy(sim);
}

/* A column of N vertices hanging from its top: the link below row j carries the j vertices
 * under it, so the column stretches by m g / k (1 + 2 + ... + (N - 1)) = m g N (N - 1) / (2 k) -
 * the stiffness the explicit integrators need 270 substeps a frame for, here in one. */
static void test_hanging_column_extension(void **unused)
{
    (void)unused;
    cs_scene sc;
    cs_params p;
    const int N = 128;
    column(&sc, &p, 2, N);
    cs_sim *sim = tk_sim_serial(&sc, &p);
    cs_info info;
    cs_sim_info(sim, &info);
    assert_int_equal(info.substeps, p.implicit_substeps);
    assert_int_equal(cs_sim_step_frames(sim, 180), CS_OK); /* 3 s */
    const double m = sim->model.phys.mass, g = 9.81, k = p.k_structural;
    const double want = m * g * N * (N - 1) / (2 * k);
    const double z_top = sc.height + sc.size_y / 2, rest = sc.size_y;
    const double got = (z_top - sim->state.z[0]) - rest;
    print_message("column of %d: extension %.6f m, closed form %.6f m (%.2f%%)\n", N, got, want,
                  100 * (got - want) / want);
    tk_assert_near(got, want, 0.01 * want);
    cs_sim_destroy(sim);
}

/* Without spring damping or drag every force is elastic or gravity, and backward Euler only takes
 * energy away: the total never rises above its start (a cloth dropped flat from its corners). */
static void test_energy_never_grows(void **unused)
{
    (void)unused;
    cs_scene sc;
    cs_params p;
    cs_scene_default(&sc);
    cs_params_default(&p);
    sc.nx = sc.ny = 24;
    sc.pins = CS_PINS_CORNERS;
    p.c_spring = 0.0f, p.drag = 0.0f, p.ground = 0;
    p.integrator = CS_IMPLICIT_EULER;
    cs_sim *sim = tk_sim_serial(&sc, &p);
    cs_energy e;
    assert_int_equal(cs_energy_get(sim, &e), CS_OK);
    const double e0 = e.total;
    double prev = e0;
    for (int f = 0; f < 90; f++) {
        assert_int_equal(cs_sim_step_frames(sim, 1), CS_OK);
        assert_int_equal(cs_energy_get(sim, &e), CS_OK);
        /* float rounding of a sum of about 1 J */
        if (e.total > prev + 1e-5) fail_msg("frame %d: energy rose from %.9f to %.9f J", f, prev, e.total);
        prev = e.total;
    }
    assert_true(prev < e0); /* it fell and swings, losing energy to the method's damping */
    cs_sim_destroy(sim);
}

/* A rock thrown at a free cloth in empty space (no gravity, pins, ground or drag): the carried
 * mass and the push only pass momentum between rock and cloth, so the total stays what it was
 * (to the solver's tolerance), while the rock is slowed by the cloth and the cloth set moving;
 * and the switch to implicit_euler with a rock there, and a rock added under it, are taken. */
static void test_rock_momentum(void **unused)
{
    (void)unused;
    cs_scene sc;
    cs_params p;
    cs_scene_default(&sc);
    cs_params_default(&p);
    sc.nx = sc.ny = 16;
    sc.pins = CS_PINS_NONE;
    p.gravity[0] = p.gravity[1] = p.gravity[2] = 0.0f;
    p.ground = 0;
    p.drag = 0.0f;
    cs_sim *sim = tk_sim_serial(&sc, &p);
    cs_rock_def d;
    cs_rock_def_default(&d);
    d.radius = 0.15f;
    d.density = 1000.0f; /* 14 kg against the cloth's 1.2 kg */
    d.position[2] = sc.height + p.contact_offset + d.radius + 0.05f;
    d.velocity[0] = 2.0f; /* obliquely: friction takes part */
    d.velocity[2] = -3.0f;
    uint32_t id;
    assert_int_equal(cs_rock_add(sim, &d, &id), CS_OK);
    cs_params q = sim->model.params;
    q.integrator = CS_IMPLICIT_EULER;
    assert_int_equal(cs_sim_set_params(sim, &q), CS_OK);
    double m0[3], m1[3];
    tk_momentum(sim, m0);
    cs_info info;
    cs_sim_info(sim, &info);
    tk_step(sim, 30 * (int64_t)info.substeps); /* half a second: through the impact */
    tk_momentum(sim, m1);
    const double scale = sqrt(m0[0] * m0[0] + m0[2] * m0[2]);
    /* what the solve leaves unbalanced, at solver_tolerance 1e-3 (measured: 0.08 %) */
    for (int k = 0; k < 3; k++) assert_true(fabs(m1[k] - m0[k]) <= 2e-3 * scale);
    const cs_rock_state *r = &sim->state.rocks[0];
    assert_true(r->v.z > -3.0f + 0.05f); /* slowed */
    assert_true(r->v.x < 2.0f - 0.05f);  /* dragged back by friction */
    /* a second rock under implicit_euler is taken */
    tk_add_rock(sim, 0.6f, 0.6f, sc.height + 1.0f, 0.1f, 2500);
    assert_int_equal(cs_rock_count(sim), 2);
    cs_sim_destroy(sim);
}

/* Coulomb friction between rock and cloth: a sphere launched sliding without spin at V0 on a flat
 * cloth whose every vertex is pinned (a rigid floor made of cloth) slides with dv/dt = -mu g while
 * R w grows at 5/2 mu g (the friction mu M g at its contact point, I = 2/5 M R^2), until its
 * contact point stops slipping at t = 2 V0 / (7 mu g); from there it rolls at 5/7 V0 with R w = v
 * (I w + M R v about the contact point is kept). With mu 0 it slides on without spin. */
static cs_sim *rock_on_rigid_cloth(float mu, uint32_t *id)
{
    cs_scene sc;
    cs_params p;
    cs_scene_default(&sc);
    cs_params_default(&p);
    sc.nx = sc.ny = 32;
    p.integrator = CS_IMPLICIT_EULER;
    p.mu = mu;
    cs_sim *sim = tk_sim_serial(&sc, &p);
    int32_t all[32 * 32];
    for (int32_t v = 0; v < 32 * 32; v++) all[v] = v;
    assert_int_equal(cs_pin(sim, all, 32 * 32, true), CS_OK);
    cs_rock_def d;
    cs_rock_def_default(&d);
    d.radius = 0.1f;
    d.density = 300.0f;
    d.position[0] = -0.3f;
    d.position[2] = sc.height + p.contact_offset + d.radius;
    d.velocity[0] = 3.0f;
    assert_int_equal(cs_rock_add(sim, &d, id), CS_OK);
    return sim;
}

static void test_rock_friction_slides_then_rolls(void **unused)
{
    (void)unused;
    const double V0 = 3.0, mu = 0.5, g = 9.81, R = 0.1;
    uint32_t id;
    cs_sim *sim = rock_on_rigid_cloth((float)mu, &id);
    cs_info info;
    cs_sim_info(sim, &info);
    tk_step(sim, 6 * (int64_t)info.substeps); /* 0.1 s: sliding (it rolls from 0.175 s) */
    cs_rock k = tk_rock(sim, id);
    double v = k.def.velocity[0], w = k.def.angular_velocity[1];
    print_message("sliding at 0.1 s: v %.4f (V0 - mu g t %.4f), R w %.4f (5/2 mu g t %.4f)\n", v, V0 - mu * g * 0.1,
                  R * w, 2.5 * mu * g * 0.1);
    /* within 0.2 % of V0 each (measured 1e-5 of it) */
    assert_true(fabs(v - (V0 - mu * g * 0.1)) < 0.002 * V0);
    assert_true(fabs(R * w - 2.5 * mu * g * 0.1) < 0.002 * V0);
    tk_step(sim, 24 * (int64_t)info.substeps); /* 0.5 s: rolling */
    k = tk_rock(sim, id);
    v = k.def.velocity[0], w = k.def.angular_velocity[1];
    print_message("rolling at 0.5 s: v %.5f (5/7 V0 %.5f), R w %.5f\n", v, 5.0 / 7.0 * V0, R * w);
    assert_true(fabs(v - 5.0 / 7.0 * V0) < 0.005 * V0); /* measured 1e-4 */
    assert_true(fabs(R * w - v) < 0.005 * V0);
    print_message("sideways v %.3g, spin about x %.3g\n", k.def.velocity[1], k.def.angular_velocity[0]);
    /* straight on: sideways within 1e-4 of V0 (measured 4e-9) */
    assert_true(fabs(k.def.velocity[1]) < 1e-4 * V0 && fabs(R * k.def.angular_velocity[0]) < 1e-4 * V0);
    cs_sim_destroy(sim);
    /* without friction: no spin, no slowing */
    sim = rock_on_rigid_cloth(0.0f, &id);
    tk_step(sim, 30 * (int64_t)info.substeps);
    k = tk_rock(sim, id);
    assert_true(fabs(k.def.angular_velocity[1]) * R < 1e-3 && fabs(k.def.velocity[0] - V0) < 0.005 * V0);
    cs_sim_destroy(sim);
}

/* The deepest two rocks lie in each other now (m; 0 when none touch). */
static double deepest_overlap(const cs_sim *sim)
{
    double most = 0.0;
    for (int32_t a = 0; a < sim->state.n_rocks; a++)
        for (int32_t b = a + 1; b < sim->state.n_rocks; b++) {
            const cs_rock_state *A = &sim->state.rocks[a], *B = &sim->state.rocks[b];
            const double dx = A->x.x - B->x.x, dy = A->x.y - B->x.y, dz = A->x.z - B->x.z;
            const double o = A->radius + B->radius - sqrt(dx * dx + dy * dy + dz * dz);
            most = o > most ? o : most;
        }
    return most;
}

/* Eight stones (0.05-0.12 m, 2,500 kg/m^3: 1.5 to 18 kg, 72 kg in all) dropped one every half
 * second onto the default 32 x 32 edge-pinned cloth pile up in its sag. The solve moves each with
 * the cloth that carries it and does not see their contacts with one another: it must not drive
 * them into each other. The rock law alone lets a pair meeting at u sink about u / sqrt(k_rock)
 * into each other (1 mm at 1 m/s) and holds one pressed by the pile's whole weight under 0.1 mm;
 * from 8 s on no stone should move at 1 m/s, and no pair lie 2 mm deep. (Without
 * cs_im_rocks_apart the solve presses them 7 mm deep, and the stiff contact throws them apart every
 * part at up to 2.8 m/s: a pile that never comes to rest.) */
static void test_pile_of_stones_not_pressed_together(void **unused)
{
    (void)unused;
    static const float drop[8][3] = {{-0.547f, -0.328f, 0.112f}, {0.470f, -0.244f, 0.089f}, {0.411f, -0.152f, 0.107f},
                                     {-0.437f, 0.686f, 0.119f},  {-0.474f, 0.457f, 0.083f},  {-0.234f, 0.225f, 0.076f},
                                     {-0.167f, -0.192f, 0.052f}, {-0.575f, -0.390f, 0.088f}};
    cs_scene sc;
    cs_params p;
    cs_scene_default(&sc);
    cs_params_default(&p);
    sc.nx = sc.ny = 32;
    p.integrator = CS_IMPLICIT_EULER;
    cs_sim *sim = tk_sim_serial(&sc, &p);
    double deepest = 0.0, fastest = 0.0;
    for (int f = 0; f < 16 * 60; f++) {
        if (f % 30 == 0 && f / 30 < 8) {
            const float *d = drop[f / 30];
            tk_add_rock(sim, d[0], d[1], sc.height + 0.8f, d[2], 2500.0f);
        }
        assert_int_equal(cs_sim_step_frames(sim, 1), CS_OK);
        if (f >= 8 * 60) {
            const double o = deepest_overlap(sim);
            deepest = o > deepest ? o : deepest;
            for (int32_t r = 0; r < sim->state.n_rocks; r++) {
                const cs_vec3 v = sim->state.rocks[r].v;
                const double u = sqrt((double)v.x * v.x + (double)v.y * v.y + (double)v.z * v.z);
                fastest = u > fastest ? u : fastest;
            }
        }
    }
    print_message("8 stones on the 32 x 32 cloth, 8-16 s: the deepest two lie in each other %.3f mm, the fastest "
                  "moves at %.3f m/s\n", 1e3 * deepest, fastest);
    assert_int_equal(cs_rock_count(sim), 8);
    assert_true(fastest < 1.0);
    assert_true(deepest < 2e-3);
    cs_sim_destroy(sim);
}

/* k_structural 1e5 and a scrambled state (random positions and velocities) stay finite. */
static void test_stiff_and_scrambled_stay_finite(void **unused)
{
    (void)unused;
    cs_scene sc;
    cs_params p;
    cs_scene_default(&sc);
    cs_params_default(&p);
    sc.nx = sc.ny = 20;
    p.k_structural = 1e5f;
    p.integrator = CS_IMPLICIT_EULER;
    cs_sim *sim = tk_sim_serial(&sc, &p);
    uint32_t seed = 12345;
    for (int32_t v = 0; v < sim->state.n; v++) {
        float x[3], vel[3];
        for (int c = 0; c < 3; c++) {
            seed = seed * 1664525u + 1013904223u;
            x[c] = (float)((seed >> 8) / 16777216.0) * 2.0f - 1.0f + (c == 2 ? 1.0f : 0.0f);
            seed = seed * 1664525u + 1013904223u;
            vel[c] = (float)((seed >> 8) / 16777216.0) * 20.0f - 10.0f;
        }
        tk_set_vertex(sim, v, x, vel);
    }
    assert_int_equal(cs_sim_step_frames(sim, 30), CS_OK);
    /* and flattened: every vertex on one point */
    for (int32_t v = 0; v < sim->state.n; v++) {
        const float x[3] = {0.0f, 0.0f, 1.0f}, vel[3] = {0.0f, 0.0f, 0.0f};
        tk_set_vertex(sim, v, x, vel);
    }
    assert_int_equal(cs_sim_step_frames(sim, 30), CS_OK);
    cs_sim_destroy(sim);
}

/* The same bits on 1 and 2 threads, with the ground, tearing, and switches of integrator mid-run. */
static uint64_t run_hash(int threads)
{
    cs_scene sc;
    cs_params p;
    cs_scene_default(&sc);
    cs_params_default(&p);
    sc.nx = 40, sc.ny = 36;
    p.integrator = CS_IMPLICIT_EULER;
    p.tear_strain = 0.05f;
    sc.height = 0.05f; /* it sags onto the ground */
    cs_sim *sim = tk_sim(&sc, &p);
    assert_int_equal(cs_sim_set_threads(sim, threads), CS_OK);
    assert_int_equal(cs_sim_step_frames(sim, 20), CS_OK);
    cs_params q = sim->model.params;
    q.integrator = CS_VELOCITY_VERLET;
    assert_int_equal(cs_sim_set_params(sim, &q), CS_OK);
    assert_int_equal(cs_sim_step_frames(sim, 2), CS_OK);
    q.integrator = CS_IMPLICIT_EULER;
    assert_int_equal(cs_sim_set_params(sim, &q), CS_OK);
    assert_int_equal(cs_sim_step_frames(sim, 20), CS_OK);
    const uint64_t h = cs_state_hash(sim);
    cs_sim_destroy(sim);
    return h;
}

static void test_same_bits_for_any_thread_count(void **unused)
{
    (void)unused;
    const uint64_t a = run_hash(1), b = run_hash(2);
    if (a != b) fail_msg("1 thread: %016llx, 2 threads: %016llx", (unsigned long long)a, (unsigned long long)b);
}

/* A snapshot taken mid-run (mid-frame, at an odd substep) and loaded into another simulation
 * goes on bitwise as the original does: nothing of the solver's lives outside the state. */
static void test_snapshot_goes_on_the_same(void **unused)
{
    (void)unused;
    cs_scene sc;
    cs_params p;
    cs_scene_default(&sc);
    cs_params_default(&p);
    sc.nx = 20, sc.ny = 18;
    sc.height = 0.05f; /* it sags onto the ground */
    p.integrator = CS_IMPLICIT_EULER;
    p.tear_strain = 0.05f;
    cs_sim *a = tk_sim_serial(&sc, &p);
    tk_step(a, 7);
    const size_t cap = cs_snapshot_size(a);
    void *buf = malloc(cap);
    size_t len = 0;
    assert_non_null(buf);
    assert_int_equal(cs_snapshot_save(a, buf, cap, &len), CS_OK);
    cs_sim *b = tk_sim_serial(&sc, &p);
    tk_step(b, 3);
    assert_int_equal(cs_snapshot_load(b, buf, len), CS_OK);
    assert_true(cs_state_hash(a) == cs_state_hash(b));
    /* the statistics are the last step's: the loaded state has had none yet, nor a rebuilt one */
    cs_info info;
    cs_sim_info(b, &info);
    assert_true(info.solver.substeps == 0 && info.solver.newton == 0 && info.solver.cg == 0);
    sc.nx = 12;
    assert_int_equal(cs_sim_set_scene(a, &sc), CS_OK);
    cs_sim_info(a, &info);
    assert_true(info.solver.substeps == 0 && info.solver.newton == 0);
    sc.nx = 20;
    assert_int_equal(cs_snapshot_load(a, buf, len), CS_OK);
    tk_step(a, 23);
    tk_step(b, 23);
    assert_true(cs_state_hash(a) == cs_state_hash(b));
    free(buf);
    cs_sim_destroy(a);
    cs_sim_destroy(b);
}

/* The solver's parameters are checked like every other: 0, negative, NaN or past the range. */
static void test_solver_parameters_checked(void **unused)
{
    (void)unused;
    char why[200];
    const char *names[] = {"solver_iterations", "solver_tolerance", "cg_iterations", "implicit_substeps"};
    const double bad[] = {0.0, -1.0, NAN, 1e9};
    for (size_t i = 0; i < 4; i++)
        for (size_t k = 0; k < 4; k++)
            if (cs_param_check(cs_param_find(names[i]), &bad[k], why, sizeof why) == 0)
                fail_msg("%s accepted %g", names[i], bad[k]);
    const double half = 1e-3;
    assert_int_equal(cs_param_check(cs_param_find("solver_tolerance"), &half, why, sizeof why), 0);
}

int main(void)
{
    const struct CMUnitTest tests[] = {
        cmocka_unit_test(test_one_spring_step_is_backward_euler),
        cmocka_unit_test(test_free_fall),
        cmocka_unit_test(test_hanging_column_extension),
        cmocka_unit_test(test_energy_never_grows),
        cmocka_unit_test(test_rock_momentum),
        cmocka_unit_test(test_rock_friction_slides_then_rolls),
        cmocka_unit_test(test_pile_of_stones_not_pressed_together),
        cmocka_unit_test(test_stiff_and_scrambled_stay_finite),
        cmocka_unit_test(test_same_bits_for_any_thread_count),
        cmocka_unit_test(test_snapshot_goes_on_the_same),
        cmocka_unit_test(test_solver_parameters_checked),
    };
    return cmocka_run_group_tests(tests, NULL, NULL);
}
