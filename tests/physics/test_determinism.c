/* test_determinism.c - same scene and commands at the same steps give bitwise the same state
 * whatever the thread count; a different script gives another; and the hash a fixed script ends
 * at is the one pinned here.
 *
 * The script exercises what could break it: rocks added at given frames (dynamic and kinematic),
 * a grab that pulls hard enough to tear, pins, parameter changes mid-run (stiffness, wind, both
 * integrators), plasticity with a finite rate, tearing, resultant friction and the ground. */
#include "testkit.h"

/* The state hash the script below ends at (on two threads, as the test runs it), pinned as Box2D
 * pins its own, so that any change that alters results - on purpose or not - is noticed here.
 * NULL: not pinned yet; the test prints the hash it got and skips the comparison. When a change
 * alters results on purpose (new physics, new defaults), regenerate it: run
 *   build/tests/physics_determinism
 * and put the hash its first test prints ("hash <16 hex digits> after ...") here. */
static const char *const pinned_hash = NULL;

typedef struct script {
    int threads;       /* cs_sim_set_threads */
    float rock_dx;     /* shift of the first rock's x (m) */
} script;

typedef struct outcome {
    uint64_t hash;
    int64_t torn;
    int32_t grown;     /* rest lengths grown by plasticity */
    uint64_t step;
    int32_t rocks;
} outcome;

static void run_script(const script *scr, outcome *out)
{
    cs_scene sc;
    cs_params p;
    cs_scene_default(&sc);
    cs_params_default(&p);
    sc.nx = 18;
    sc.ny = 15;
    sc.size_x = 1.2f;
    sc.size_y = 1.0f;
    sc.height = 0.5f;
    sc.pins = CS_PINS_CORNERS;
    p.plastic_yield = 0.02f;
    p.plastic_rate = 40.0f;
    p.tear_strain = 0.12f;
    p.friction_model = CS_FRICTION_RESULTANT;
    p.integrator = CS_VELOCITY_VERLET;
    p.ground = 1;
    p.ground_z = 0.0f;
    cs_sim *sim = tk_sim(&sc, &p);
    assert_int_equal(cs_sim_set_threads(sim, scr->threads), CS_OK);
    float *L_start = malloc(sizeof(float) * (size_t)sim->state.n * CS_NTYPES);
    assert_non_null(L_start);
    assert_int_equal(cs_read_rest_lengths(sim, L_start, (size_t)sim->state.n * CS_NTYPES), CS_OK);

    uint32_t rock_b = 0;
    for (int frame = 0; frame < 90; frame++) {
        switch (frame) {
        case 0: /* a dynamic rock dropped near the centre */
            tk_add_rock(sim, 0.1f + scr->rock_dx, -0.05f, 0.9f, 0.12f, 400.0f);
            break;
        case 6: { /* a kinematic rock sweeping through the cloth */
            cs_rock_def d;
            cs_rock_def_default(&d);
            d.position[0] = -0.4f, d.position[1] = 0.2f, d.position[2] = 0.35f;
            d.velocity[0] = 0.6f, d.velocity[2] = 0.2f;
            d.angular_velocity[1] = 2.0f;
            d.radius = 0.1f;
            d.kinematic = true;
            assert_int_equal(cs_rock_add(sim, &d, &rock_b), CS_OK);
            break;
        }
        case 12: { /* grab a vertex and pull it hard, far up */
            const float target[3] = {0.3f, 0.3f, 1.6f};
            assert_int_equal(cs_grab(sim, 7 * sc.nx + 12, target), CS_OK);
            break;
        }
        case 24: /* stiffer, wind, the other integrator */
            p.k_structural = 700.0f;
            p.wind[0] = 2.0f;
            p.integrator = CS_SYMPLECTIC_EULER;
            assert_int_equal(cs_sim_set_params(sim, &p), CS_OK);
            break;
        case 36: { /* pins, and the grab let go */
            const int32_t pins[3] = {3, 4 * sc.nx, 10 * sc.nx + 17};
            assert_int_equal(cs_pin(sim, pins, 3, true), CS_OK);
            assert_int_equal(cs_release(sim), CS_OK);
            break;
        }
        case 45: /* another rock, the sweeping one removed, back to velocity Verlet */
            tk_add_rock(sim, -0.2f, -0.2f, 1.0f, 0.08f, 900.0f);
            assert_int_equal(cs_rock_remove(sim, rock_b), CS_OK);
            p.integrator = CS_VELOCITY_VERLET;
            p.wind[0] = 0.0f;
            p.wind[1] = -1.0f;
            assert_int_equal(cs_sim_set_params(sim, &p), CS_OK);
            break;
        case 60: { /* a second grab, then on to the end */
            const float target[3] = {-0.5f, 0.6f, 1.0f};
            assert_int_equal(cs_grab(sim, 2 * sc.nx + 2, target), CS_OK);
            break;
        }
        default: break;
        }
        assert_int_equal(cs_sim_step_frames(sim, 1), CS_OK);
    }
    out->hash = cs_state_hash(sim);
    cs_info info;
    cs_sim_info(sim, &info);
    out->torn = info.n_torn;
    out->step = info.step;
    out->rocks = info.n_rocks;
    float *L = malloc(sizeof(float) * (size_t)sim->state.n * CS_NTYPES);
    assert_non_null(L);
    assert_int_equal(cs_read_rest_lengths(sim, L, (size_t)sim->state.n * CS_NTYPES), CS_OK);
    out->grown = 0;
    for (size_t k = 0; k < (size_t)sim->state.n * CS_NTYPES; k++) out->grown += L[k] > 0 && L[k] > L_start[k];
    free(L);
    free(L_start);
    cs_sim_destroy(sim);
}

/* One thread except where two are the point: under a loaded machine (ctest -j) OpenMP barriers
 * at every substep make two threads on two busy cores very slow, and the thread count does not
 * change the result (checked here). */
static void test_same_script_same_hash(void **unused)
{
    (void)unused;
    const script two = {2, 0.0f}, one = {1, 0.0f}, moved = {1, 0.001f};
    outcome a, b, c, d;
    run_script(&two, &a);
    run_script(&two, &b);
    run_script(&one, &c);
    run_script(&moved, &d);
    char hex[17];
    cs_hash_hex(a.hash, hex);
    print_message("hash %s after %llu substeps: %lld springs torn, %d rest lengths grown, %d rocks\n", hex,
                  (unsigned long long)a.step, (long long)a.torn, (int)a.grown, (int)a.rocks);
    /* The script did exercise tearing and plasticity. */
    assert_true(a.torn > 0);
    assert_true(a.grown > 20);
    assert_int_equal(a.rocks, 2);
    /* Twice the same on 2 threads, and the same on 1 thread. */
    assert_true(a.hash == b.hash);
    assert_int_equal(a.torn, b.torn);
    assert_int_equal(a.grown, b.grown);
    assert_true(a.hash == c.hash);
    /* The first rock 1 mm to the side: another state. */
    assert_true(d.hash != c.hash);
}

/* The script's hash is the pinned one (when one is pinned). */
static void test_pinned_hash(void **unused)
{
    (void)unused;
    const script two = {2, 0.0f};
    outcome a;
    run_script(&two, &a);
    char hex[17];
    cs_hash_hex(a.hash, hex);
    if (!pinned_hash) {
        print_message("no hash is pinned: this build ends the script at %s (test_determinism.c says how to pin it)\n", hex);
        skip();
    }
    assert_string_equal(hex, pinned_hash);
}

/* The hash covers the state: one flipped bit of one velocity changes it, flipping it back
 * restores it. */
static void test_hash_sees_one_bit(void **unused)
{
    (void)unused;
    cs_sim *sim = tk_sim(NULL, NULL);
    const uint64_t h0 = cs_state_hash(sim);
    assert_int_equal(cs_sim_sync(sim, CS_SYNC_ALL), CS_OK);
    uint32_t u;
    memcpy(&u, &sim->state.vz[100], 4);
    u ^= 1u;
    memcpy(&sim->state.vz[100], &u, 4);
    assert_true(cs_state_hash(sim) != h0);
    u ^= 1u;
    memcpy(&sim->state.vz[100], &u, 4);
    assert_true(cs_state_hash(sim) == h0);
    cs_sim_destroy(sim);
}

int main(void)
{
    const struct CMUnitTest tests[] = {
        cmocka_unit_test(test_same_script_same_hash),
        cmocka_unit_test(test_pinned_hash),
        cmocka_unit_test(test_hash_sees_one_bit),
    };
    return cmocka_run_group_tests(tests, NULL, NULL);
}
