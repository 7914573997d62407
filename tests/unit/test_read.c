/* test_read.c - reading the state: arrays, torn springs, energy on hand-computed cases, the
 * FNV-1a hash against its published test vectors. */
#include "testkit.h"

static void test_fnv1a_vectors(void **unused)
{
    (void)unused;
    /* From the FNV reference (draft-eastlake-fnv): FNV-1a 64 of "", "a", "foobar". */
    assert_true(cs_fnv1a(CS_FNV_OFFSET, "", 0) == 0xcbf29ce484222325ull);
    assert_true(cs_fnv1a(CS_FNV_OFFSET, "a", 1) == 0xaf63dc4c8601ec8cull);
    assert_true(cs_fnv1a(CS_FNV_OFFSET, "foobar", 6) == 0x85944171f73967e8ull);
    char hex[17];
    cs_hash_hex(0x0123456789abcdefull, hex);
    assert_string_equal(hex, "0123456789abcdef");
    cs_hash_hex(0, hex);
    assert_string_equal(hex, "0000000000000000");
}

/* The state hash covers positions, velocities, accelerations, rest lengths and rocks. */
static void test_hash_sees_every_part_of_the_state(void **unused)
{
    (void)unused;
    cs_sim *sim = tk_sim(NULL, NULL);
    tk_add_rock(sim, 0, 0, 3, 0.1f, 300);
    uint64_t seen[8];
    int k = 0;
    seen[k++] = cs_state_hash(sim);
    assert_true(cs_state_hash(sim) == seen[0]);
    float *fields[] = {&sim->state.y[10], &sim->state.vz[11], &sim->state.ax[12], &sim->state.L0[3 * 4096 + 13],
                       &sim->state.rocks[0].w.y, &sim->state.rocks[0].alpha.z, &sim->state.rocks[0].q[1]};
    for (size_t f = 0; f < sizeof fields / sizeof fields[0]; f++) {
        *fields[f] += 0.5f;
        seen[k] = cs_state_hash(sim);
        for (int o = 0; o < k; o++) assert_true(seen[k] != seen[o]);
        k++;
    }
    cs_sim_destroy(sim);
}

static void test_read_arrays_and_buffer_checks(void **unused)
{
    (void)unused;
    cs_scene sc;
    cs_params p;
    tk_quiet(&sc, &p);
    sc.nx = 3, sc.ny = 2;
    cs_sim *sim = tk_sim(&sc, &p);
    float xyz[18], small[17];
    const float vel[3] = {1, 2, 3};
    tk_set_vertex(sim, 4, NULL, vel);
    assert_int_equal(cs_read_velocities(sim, xyz, 18), CS_OK);
    assert_true(xyz[12] == 1 && xyz[13] == 2 && xyz[14] == 3 && xyz[0] == 0);
    assert_int_equal(cs_read_positions(sim, small, 17), CS_E_INVALID);
    assert_int_equal(cs_read_velocities(sim, NULL, 18), CS_E_INVALID);
    float L[36];
    assert_int_equal(cs_read_rest_lengths(sim, L, 35), CS_E_INVALID);
    assert_int_equal(cs_read_rest_lengths(sim, L, 36), CS_OK);
    cs_sim_destroy(sim);
}

static void test_torn_list(void **unused)
{
    (void)unused;
    cs_scene sc;
    cs_params p;
    tk_quiet(&sc, &p);
    sc.nx = sc.ny = 2;
    cs_sim *sim = tk_sim(&sc, &p);
    assert_int_equal(cs_read_torn(sim, NULL, 0), 0);
    sim->state.L0[CS_SX * 4 + 0] = CS_TORN; /* (0,0)-(1,0) */
    sim->state.L0[CS_SY * 4 + 1] = CS_TORN; /* (1,0)-(1,1) */
    uint32_t ids[4] = {0};
    assert_int_equal(cs_read_torn(sim, ids, 4), 2);
    assert_int_equal(ids[0], 0);
    assert_int_equal(ids[1], 5);
    assert_int_equal(cs_read_torn(sim, ids, 1), 2);
    cs_sim_destroy(sim);
}

/* Strain on a 3 x 2 grid of 1 m spacing: vertex 1 moved 0.5 m along +x stretches (0,0)-(1,0) to
 * 1.5 m (strain 0.5) and compresses (1,0)-(2,0) to 0.5 m; (1,0)-(1,1) becomes sqrt(1.25). Each
 * vertex gets the largest stretch of the structural springs it ends; a torn one counts for none. */
static void test_strain_hand_computed(void **unused)
{
    (void)unused;
    cs_scene sc;
    cs_params p;
    tk_quiet(&sc, &p);
    sc.nx = 3, sc.ny = 2, sc.size_x = 2, sc.size_y = 1;
    cs_sim *sim = tk_sim(&sc, &p);
    float e[6], small[5];
    assert_int_equal(cs_read_strain(sim, e, 6), CS_OK);
    for (int v = 0; v < 6; v++) tk_assert_near(e[v], 0, 0); /* at rest */
    assert_int_equal(cs_read_strain(sim, small, 5), CS_E_INVALID);
    const float x1[3] = {0.5f, -0.5f, 1.0f}; /* vertex 1 sits at (0, -0.5, 1): +0.5 in x */
    tk_set_vertex(sim, 1, x1, NULL);
    assert_int_equal(cs_read_strain(sim, e, 6), CS_OK);
    const double up = sqrt(1.25) - 1;
    tk_assert_near(e[0], 0.5, 1e-6); /* (0,0)-(1,0) at 1.5 m; (0,0)-(0,1) unchanged */
    tk_assert_near(e[1], 0.5, 1e-6); /* the largest of 0.5, -0.5 and sqrt(1.25) - 1 */
    tk_assert_near(e[2], 0, 0);      /* (1,0)-(2,0) compressed: no stretch */
    tk_assert_near(e[3], 0, 1e-6);
    tk_assert_near(e[4], up, 1e-6);  /* (1,0)-(1,1) */
    tk_assert_near(e[5], 0, 1e-6);
    /* The stretched spring torn: vertex 0 is left with none stretched, vertex 1 with its upper one. */
    sim->state.L0[CS_SX * 6 + 0] = CS_TORN;
    assert_int_equal(cs_read_strain(sim, e, 6), CS_OK);
    tk_assert_near(e[0], 0, 1e-6);
    tk_assert_near(e[1], up, 1e-6);
    cs_sim_destroy(sim);
}

/* A 2 x 2 cloth, 1 m square, 1 kg/m^2 (m = 1/4), at height 2 under g = -10 z. */
static void test_energy_hand_computed(void **unused)
{
    (void)unused;
    cs_scene sc;
    cs_params p;
    tk_quiet(&sc, &p);
    sc.nx = sc.ny = 2, sc.size_x = sc.size_y = 1, sc.areal_density = 1, sc.height = 2;
    p.gravity[2] = -10;
    p.k_structural = 100, p.k_shear = 40;
    cs_sim *sim = tk_sim(&sc, &p);
    cs_energy e;
    assert_int_equal(cs_energy_get(sim, &e), CS_OK);
    tk_assert_near(e.gravity, 4 * 0.25 * 10 * 2, 1e-5);
    tk_assert_near(e.kinetic, 0, 0);
    tk_assert_near(e.spring, 0, 1e-9);
    /* Vertex 0 moving at (1, 2, 2): KE = 1/2 m 9. */
    tk_set_vertex(sim, 0, NULL, (const float[3]){1, 2, 2});
    assert_int_equal(cs_energy_get(sim, &e), CS_OK);
    tk_assert_near(e.kinetic, 0.5 * 0.25 * 9, 1e-6);
    /* Vertex 3 (1, 1) moved 0.5 along x: its springs from 2 (structural, 1 -> 1.5), from 1
     * (structural, 1 -> sqrt(1.25)) and from 0 (shear, sqrt 2 -> sqrt(3.25)). */
    tk_set_vertex(sim, 3, (const float[3]){1.0f, 0.5f, 2}, NULL);
    assert_int_equal(cs_energy_get(sim, &e), CS_OK);
    const double s1 = 0.5, s2 = sqrt(1.25) - 1, s3 = sqrt(3.25) - sqrt(2.0);
    tk_assert_near(e.spring, 0.5 * 100 * (s1 * s1 + s2 * s2) + 0.5 * 40 * s3 * s3, 1e-4);
    tk_assert_near(e.total, e.kinetic + e.spring + e.gravity, 1e-9);
    /* A rock at height 3 moving at 2 m/s and spinning at 3 rad/s. */
    cs_rock_def d;
    cs_rock_def_default(&d);
    d.position[0] = 10, d.position[2] = 3, d.velocity[1] = 2, d.angular_velocity[0] = 3;
    d.radius = 0.5f, d.density = 6; /* M = pi, I = pi / 10 */
    const cs_energy before = e;
    assert_int_equal(cs_rock_add(sim, &d, NULL), CS_OK);
    assert_int_equal(cs_energy_get(sim, &e), CS_OK);
    tk_assert_near(e.kinetic - before.kinetic, 0.5 * TK_PI * 4 + 0.5 * TK_PI / 10 * 9, 1e-5);
    tk_assert_near(e.gravity - before.gravity, TK_PI * 10 * 3, 1e-4);
    cs_sim_destroy(sim);
}

int main(void)
{
    const struct CMUnitTest tests[] = {
        cmocka_unit_test(test_fnv1a_vectors),
        cmocka_unit_test(test_hash_sees_every_part_of_the_state),
        cmocka_unit_test(test_read_arrays_and_buffer_checks),
        cmocka_unit_test(test_torn_list),
        cmocka_unit_test(test_strain_hand_computed),
        cmocka_unit_test(test_energy_hand_computed),
    };
    return cmocka_run_group_tests(tests, NULL, NULL);
}
