/* test_sim.c - creating simulations, changing scene and parameters, stepping, pins and grab:
 * every entry point refuses bad input with a code and leaves the state as it was. */
#include "testkit.h"

#include <dirent.h>
#include <pthread.h>

static void small(cs_scene *sc, cs_params *p)
{
    cs_scene_default(sc);
    cs_params_default(p);
    sc->nx = 12, sc->ny = 10;
}

static void test_create_refuses_bad_input(void **unused)
{
    (void)unused;
    cs_scene sc;
    cs_params p;
    cs_sim *sim = (cs_sim *)&sc; /* set to NULL on failure */
    char err[256];
    small(&sc, &p);
    sc.nx = 1;
    assert_int_equal(cs_sim_create(&sc, &p, "cpu", &sim, err, sizeof err), CS_E_RANGE);
    assert_null(sim);
    assert_non_null(strstr(err, "nx"));
    small(&sc, &p);
    sc.ny = 5000;
    assert_int_equal(cs_sim_create(&sc, &p, "cpu", &sim, err, sizeof err), CS_E_RANGE);
    small(&sc, &p);
    sc.size_x = NAN;
    assert_int_equal(cs_sim_create(&sc, &p, "cpu", &sim, err, sizeof err), CS_E_RANGE);
    small(&sc, &p);
    p.drag = INFINITY;
    assert_int_equal(cs_sim_create(&sc, &p, "cpu", &sim, err, sizeof err), CS_E_RANGE);
    assert_non_null(strstr(err, "drag"));
    small(&sc, &p);
    assert_int_equal(cs_sim_create(&sc, &p, "gpu9000", &sim, err, sizeof err), CS_E_INVALID);
    assert_non_null(strstr(err, "gpu9000"));
    assert_int_equal(cs_sim_create(&sc, &p, "cpu", NULL, err, sizeof err), CS_E_INVALID);
    /* NULL scene and params mean the defaults. */
    assert_int_equal(cs_sim_create(NULL, NULL, "cpu", &sim, NULL, 0), CS_OK);
    cs_scene got;
    cs_sim_scene(sim, &got);
    cs_scene_default(&sc);
    assert_memory_equal(&got, &sc, sizeof sc);
    cs_sim_destroy(sim);
    cs_sim_destroy(NULL);
}

static void test_step_advances_counters(void **unused)
{
    (void)unused;
    cs_scene sc;
    cs_params p;
    small(&sc, &p);
    cs_sim *sim = tk_sim(&sc, &p);
    cs_info info;
    cs_sim_info(sim, &info);
    const double dt = 1.0 / (60.0 * info.substeps);
    tk_step(sim, 7);
    assert_int_equal(cs_sim_step_frames(sim, 2), CS_OK);
    cs_sim_info(sim, &info);
    assert_int_equal(info.step, 7 + 2 * info.substeps);
    tk_assert_near(info.time, (7 + 2 * info.substeps) * dt, 1e-12);
    const uint64_t h = cs_state_hash(sim);
    assert_int_equal(cs_sim_step(sim, -1), CS_E_RANGE);
    assert_int_equal(cs_sim_step(sim, 2000000000), CS_E_RANGE);
    assert_int_equal(cs_sim_step_frames(sim, -3), CS_E_RANGE);
    assert_int_equal(cs_sim_step(sim, 0), CS_OK);
    assert_true(cs_state_hash(sim) == h);
    cs_info again;
    cs_sim_info(sim, &again);
    assert_int_equal(again.step, info.step);
    cs_sim_destroy(sim);
}

static void test_set_params_is_all_or_nothing(void **unused)
{
    (void)unused;
    cs_scene sc;
    cs_params p;
    small(&sc, &p);
    cs_sim *sim = tk_sim(&sc, &p);
    tk_step(sim, 10);
    const uint64_t h = cs_state_hash(sim);
    cs_params bad = p;
    bad.k_shear = 55.0f;  /* fine */
    bad.mu = NAN;         /* not */
    assert_int_equal(cs_sim_set_params(sim, &bad), CS_E_RANGE);
    assert_string_equal(cs_sim_error_param(sim), "mu");
    cs_params now;
    cs_sim_params(sim, &now);
    assert_memory_equal(&now, &p, sizeof p);
    assert_true(cs_state_hash(sim) == h);
    bad = p;
    bad.integrator = 3;
    assert_int_equal(cs_sim_set_params(sim, &bad), CS_E_RANGE);
    assert_int_equal(cs_sim_set_params(sim, NULL), CS_E_INVALID);
    /* A good change applies and recomputes accelerations (gravity flipped: a_z flips). */
    cs_params good = p;
    good.gravity[2] = 9.81f;
    assert_int_equal(cs_sim_set_params(sim, &good), CS_OK);
    cs_sim_params(sim, &now);
    assert_true(now.gravity[2] == 9.81f);
    const int32_t centre = 5 * 12 + 6;
    assert_true(sim->state.az[centre] > 0.0f);
    cs_sim_destroy(sim);
}

static void test_set_scene_rebuilds(void **unused)
{
    (void)unused;
    cs_scene sc;
    cs_params p;
    small(&sc, &p);
    cs_sim *sim = tk_sim(&sc, &p);
    tk_add_rock(sim, 0, 0, 2, 0.1f, 300);
    tk_step(sim, 30);
    cs_scene next = sc;
    next.nx = 6;
    next.orientation = CS_VERTICAL;
    assert_int_equal(cs_sim_set_scene(sim, &next), CS_OK);
    cs_info info;
    cs_sim_info(sim, &info);
    assert_int_equal(info.step, 0);
    assert_int_equal(info.n_rocks, 0);
    assert_int_equal(info.n_vertices, 60);
    assert_true(info.time == 0.0);
    cs_scene got;
    cs_sim_scene(sim, &got);
    assert_int_equal(got.nx, 6);
    /* A bad scene changes nothing. */
    const uint64_t h = cs_state_hash(sim);
    next.areal_density = -1;
    assert_int_equal(cs_sim_set_scene(sim, &next), CS_E_RANGE);
    assert_string_equal(cs_sim_error_param(sim), "areal_density");
    cs_sim_scene(sim, &got);
    assert_true(got.areal_density == sc.areal_density);
    assert_true(cs_state_hash(sim) == h);
    /* Reset gives the freshly built state back. */
    const uint64_t fresh = cs_state_hash(sim);
    tk_step(sim, 20);
    assert_true(cs_state_hash(sim) != fresh);
    assert_int_equal(cs_sim_reset(sim), CS_OK);
    assert_true(cs_state_hash(sim) == fresh);
    cs_sim_destroy(sim);
}

static void test_pins_refuse_bad_vertices_and_hold(void **unused)
{
    (void)unused;
    cs_scene sc;
    cs_params p;
    small(&sc, &p);
    sc.pins = CS_PINS_NONE;
    cs_sim *sim = tk_sim(&sc, &p);
    const int32_t bad[] = {3, 4, 120};
    assert_int_equal(cs_pin(sim, bad, 3, true), CS_E_RANGE);
    assert_string_equal(cs_sim_error_param(sim), "vertices");
    assert_false(cs_is_pinned(sim, 3));
    const int32_t neg[] = {-1};
    assert_int_equal(cs_pin(sim, neg, 1, true), CS_E_RANGE);
    assert_int_equal(cs_pin(sim, NULL, 2, true), CS_E_INVALID);
    const int32_t good[] = {3, 4};
    assert_int_equal(cs_pin(sim, good, 2, true), CS_OK);
    assert_true(cs_is_pinned(sim, 3) && cs_is_pinned(sim, 4));
    float before[3] = {sim->state.x[3], sim->state.y[3], sim->state.z[3]};
    tk_step(sim, 200);
    /* A pinned vertex does not move while the rest falls. */
    assert_true(sim->state.x[3] == before[0] && sim->state.y[3] == before[1] && sim->state.z[3] == before[2]);
    assert_true(sim->state.z[60] < before[2] - 0.01f);
    assert_int_equal(cs_pin(sim, good, 1, false), CS_OK);
    assert_false(cs_is_pinned(sim, 3));
    tk_step(sim, 50);
    assert_true(sim->state.z[3] < before[2]);
    cs_sim_destroy(sim);
}

/* The grabbed vertex moves straight toward its target at grab_speed until it gets there. */
static void test_grab_moves_at_grab_speed(void **unused)
{
    (void)unused;
    cs_scene sc;
    cs_params p;
    tk_quiet(&sc, &p);
    sc.nx = sc.ny = 8;
    p.grab_speed = 0.5f;
    cs_sim *sim = tk_sim(&sc, &p);
    const int32_t g = 3 * 8 + 3;
    const float x0[3] = {sim->state.x[g], sim->state.y[g], sim->state.z[g]};
    const float target[3] = {x0[0], x0[1], x0[2] + 0.3f};
    assert_int_equal(cs_grab(sim, g, (const float[3]){0, NAN, 0}), CS_E_INVALID);
    assert_int_equal(cs_grab(sim, 64, target), CS_E_RANGE);
    assert_int_equal(cs_grab(sim, g, (const float[3]){0, 0, 1e9f}), CS_E_RANGE);
    assert_int_equal(cs_grabbed(sim, NULL), -1);
    assert_int_equal(cs_grab(sim, g, target), CS_OK);
    float got[3];
    assert_int_equal(cs_grabbed(sim, got), g);
    assert_true(got[2] == target[2]);
    cs_info info;
    cs_sim_info(sim, &info);
    const int32_t steps = (int32_t)(0.2 / info.dt); /* 0.2 s at 0.5 m/s: 0.1 m */
    tk_step(sim, steps);
    tk_assert_near(sim->state.z[g] - x0[2], 0.5 * steps * info.dt, 1e-4);
    tk_assert_near(sim->state.x[g], x0[0], 1e-6);
    tk_step(sim, steps * 3); /* long enough to arrive */
    tk_assert_near(sim->state.z[g], target[2], 1e-5);
    /* Its neighbours were pulled along. */
    assert_true(sim->state.z[g + 1] > x0[2] + 0.01f);
    assert_int_equal(cs_release(sim), CS_OK);
    assert_int_equal(cs_grabbed(sim, NULL), -1);
    assert_true(sim->state.w[g] == 1.0f);
    cs_sim_destroy(sim);
}

static void test_threads_setting(void **unused)
{
    (void)unused;
    cs_sim *sim = tk_sim(NULL, NULL);
    assert_int_equal(cs_sim_set_threads(sim, -1), CS_E_RANGE);
    assert_int_equal(cs_sim_set_threads(sim, 257), CS_E_RANGE);
    assert_int_equal(cs_sim_set_threads(sim, 2), CS_OK);
    assert_string_equal(cs_sim_backend(sim), "cpu");
    assert_non_null(strstr(cs_sim_device(sim), "cpu"));
    if (strstr(cs_sim_device(sim), "OpenMP")) {
        /* The device names the threads this model runs on, not the machine's count. */
        assert_non_null(strstr(cs_sim_device(sim), "2 threads"));
        assert_int_equal(cs_sim_set_threads(sim, 1), CS_OK);
        assert_non_null(strstr(cs_sim_device(sim), "1 thread)"));
    }
    cs_sim_destroy(sim);
}

/* The threads this process runs now (/proc/self/task). */
static int process_threads(void)
{
    DIR *d = opendir("/proc/self/task");
    if (!d) return -1;
    int n = 0;
    for (struct dirent *e; (e = readdir(d)) != NULL;) n += e->d_name[0] != '.';
    closedir(d);
    return n;
}

/* What outside_steps saw: the process's threads before, after the calls that refresh, after a
 * step; and whether the backend runs OpenMP. */
typedef struct {
    int before, refreshed, stepped, openmp, ok;
} threads_seen;

/* On a thread that has never opened an OpenMP team: a simulation on three threads created,
 * switched between integrators and loaded from its snapshot, then stepped. */
static void *outside_steps(void *arg)
{
    threads_seen *t = arg;
    cs_scene sc;
    cs_params p;
    small(&sc, &p);
    p.integrator = CS_IMPLICIT_EULER;
    t->before = process_threads();
    cs_sim *sim = NULL;
    char err[256];
    if (cs_sim_create(&sc, &p, "cpu", &sim, err, sizeof err) != CS_OK) return NULL;
    size_t len = 0;
    unsigned char *snap = malloc(cs_snapshot_size(sim));
    t->ok = cs_sim_set_threads(sim, 3) == CS_OK && snap &&
            cs_snapshot_save(sim, snap, cs_snapshot_size(sim), &len) == CS_OK;
    p.integrator = CS_VELOCITY_VERLET;
    t->ok = t->ok && cs_sim_set_params(sim, &p) == CS_OK;
    p.integrator = CS_IMPLICIT_EULER;
    t->ok = t->ok && cs_sim_set_params(sim, &p) == CS_OK && cs_snapshot_load(sim, snap, len) == CS_OK;
    t->refreshed = process_threads();
    t->ok = t->ok && cs_sim_step(sim, 1) == CS_OK;
    t->stepped = process_threads();
    t->openmp = strstr(cs_sim_device(sim), "OpenMP") != NULL;
    free(snap);
    cs_sim_destroy(sim);
    return NULL;
}

/* Only a step opens an OpenMP team: creating a simulation, changing its parameters and loading a
 * snapshot compute on the calling thread alone. A thread that opens a team keeps a pool of workers,
 * and once a process holds more pool threads than cores libgomp sleeps at the step's barriers
 * rather than spinning - the daemon creates its first scene on its main thread and steps on its
 * sim thread (docs/developing.md, "The daemon's threads"). The step, on three threads, starts its
 * team: the count below can see one. */
static void test_only_steps_open_teams(void **unused)
{
    (void)unused;
    threads_seen t = {0, 0, 0, 0, 0};
    pthread_t th;
    assert_int_equal(pthread_create(&th, NULL, outside_steps, &t), 0);
    assert_int_equal(pthread_join(th, NULL), 0);
    assert_true(t.ok);
    assert_true(t.before > 0);
    assert_int_equal(t.refreshed, t.before);
    if (t.openmp) assert_true(t.stepped > t.before);
}

/* However a run of substeps is split into calls - a frame stepped in slices by the daemon, a
 * journal replayed in one go - it ends in the same state and on the same clock, bit for bit. */
static void test_split_steps_agree(void **unused)
{
    (void)unused;
    cs_scene sc;
    cs_params p;
    small(&sc, &p);
    cs_sim *whole = tk_sim_serial(&sc, &p), *parts = tk_sim_serial(&sc, &p);
    tk_add_rock(whole, 0.1f, 0.0f, 1.3f, 0.15f, 300.0f);
    tk_add_rock(parts, 0.1f, 0.0f, 1.3f, 0.15f, 300.0f);
    assert_int_equal(cs_sim_step(whole, 300), CS_OK);
    /* 100 single substeps, then 37, then 163 (added up per call, 300 dt would read 1.4e-16 s
     * less than in one call of 300). */
    for (int k = 0; k < 100; k++) assert_int_equal(cs_sim_step(parts, 1), CS_OK);
    assert_int_equal(cs_sim_step(parts, 37), CS_OK);
    assert_int_equal(cs_sim_step(parts, 163), CS_OK);
    cs_info a, b;
    cs_sim_info(whole, &a);
    cs_sim_info(parts, &b);
    assert_true(a.step == 300 && b.step == 300);
    if (a.time != b.time) fail_msg("clock: %.17g in one call, %.17g in parts", a.time, b.time);
    assert_true(cs_state_hash(whole) == cs_state_hash(parts));
    cs_sim_destroy(whole);
    cs_sim_destroy(parts);
}

/* A batch steps each simulation as it would be stepped alone, bit for bit, whatever sits beside
 * it; a bad call runs nothing. */
static void test_batch_steps_like_alone(void **unused)
{
    (void)unused;
    cs_scene sc;
    cs_params p;
    cs_sim *alone[3], *batch[3];
    const int64_t n[3] = {7, 0, 130};
    for (int k = 0; k < 3; k++) {
        small(&sc, &p);
        sc.nx += 3 * k;
        p.wind[0] = 0.5f * (float)k;
        assert_int_equal(cs_sim_create(&sc, &p, "cpu", &alone[k], NULL, 0), CS_OK);
        assert_int_equal(cs_sim_create(&sc, &p, "cpu", &batch[k], NULL, 0), CS_OK);
        assert_int_equal(cs_sim_step(alone[k], n[k]), CS_OK);
    }
    cs_status each[3] = {99, 99, 99};
    cs_sim *twice[2] = {batch[0], batch[0]};
    const int64_t one[2] = {1, 1};
    assert_int_equal(cs_sims_step(twice, 2, one, each), CS_E_INVALID);
    assert_int_equal(each[0], 99);
    const int64_t bad[3] = {1, -1, 1};
    assert_int_equal(cs_sims_step(batch, 3, bad, each), CS_OK);
    assert_int_equal(each[1], CS_E_RANGE);
    assert_int_equal(each[0], CS_OK);
    /* undo the good ones' substep by starting over */
    for (int k = 0; k < 3; k++) {
        cs_sim_destroy(batch[k]);
        small(&sc, &p);
        sc.nx += 3 * k;
        p.wind[0] = 0.5f * (float)k;
        assert_int_equal(cs_sim_create(&sc, &p, "cpu", &batch[k], NULL, 0), CS_OK);
    }
    assert_int_equal(cs_sims_step(batch, 3, n, each), CS_OK);
    for (int k = 0; k < 3; k++) {
        assert_int_equal(each[k], CS_OK);
        cs_info a, b;
        cs_sim_info(alone[k], &a);
        cs_sim_info(batch[k], &b);
        assert_int_equal(a.step, (uint64_t)n[k]);
        assert_int_equal(b.step, a.step);
        assert_true(b.time == a.time);
        assert_int_equal(cs_state_hash(batch[k]), cs_state_hash(alone[k]));
        cs_sim_destroy(alone[k]);
        cs_sim_destroy(batch[k]);
    }
}

int main(void)
{
    const struct CMUnitTest tests[] = {
        cmocka_unit_test(test_create_refuses_bad_input),
        cmocka_unit_test(test_step_advances_counters),
        cmocka_unit_test(test_set_params_is_all_or_nothing),
        cmocka_unit_test(test_set_scene_rebuilds),
        cmocka_unit_test(test_pins_refuse_bad_vertices_and_hold),
        cmocka_unit_test(test_grab_moves_at_grab_speed),
        cmocka_unit_test(test_threads_setting),
        cmocka_unit_test(test_only_steps_open_teams),
        cmocka_unit_test(test_split_steps_agree),
        cmocka_unit_test(test_batch_steps_like_alone),
    };
    return cmocka_run_group_tests(tests, NULL, NULL);
}
