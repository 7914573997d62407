/* test_batch.c - stepping many simulations in one call (cs_sims_step) on the CPU backend, which
 * shares a batch among its threads: small scenes each whole on one thread, large ones by all of
 * them together. Whatever the batch holds and however it is shared, each simulation must end
 * bitwise where cs_sim_step alone takes a twin of it, and one that fails fails alone. */
#include "testkit.h"

/* One scene of the mixed batch: its size and what in it differs from the defaults. */
typedef struct spec {
    int nx, ny;
    int integrator;       /* CS_VELOCITY_VERLET or CS_SYMPLECTIC_EULER */
    int contact;          /* CS_CONTACT_VERTEX or CS_CONTACT_SURFACE */
    int rocks;            /* rocks dropped onto it */
    float rock_density;   /* kg/m^3 (a heavy one tears the cloth) */
    float yield, tear;    /* plastic_yield, tear_strain */
    float wind;           /* m/s along x */
    int pins;             /* cs_pins */
    int friction;         /* cs_friction */
    int grab;             /* 1: its middle vertex is dragged up */
    int threads;          /* cs_sim_set_threads */
} spec;

/* 12 x 10 .. 64 x 64: both integrators, both contact models, rocks light and heavy (thrown down), plasticity
 * and tearing, wind, a grab, pins of every preset, and models asking for 1, 2 or 3 threads (the
 * batch runs on the most any asks for). Scene 2 yields, 3 and 5 tear. */
static const spec MIXED[8] = {
    {12, 10, CS_VELOCITY_VERLET, CS_CONTACT_SURFACE, 0, 0, 0, 0, 0, CS_PINS_EDGES, 0, 0, 1},
    {16, 16, CS_SYMPLECTIC_EULER, CS_CONTACT_VERTEX, 1, 300, 0, 0, 1.5f, CS_PINS_EDGES, 0, 0, 3},
    {24, 20, CS_VELOCITY_VERLET, CS_CONTACT_SURFACE, 2, 300, 0.002f, 0, 0, CS_PINS_EDGES, 0, 0, 2},
    {32, 32, CS_SYMPLECTIC_EULER, CS_CONTACT_SURFACE, 1, 20000, 0, 0.03f, 0, CS_PINS_EDGES, 0, 0, 2},
    {40, 30, CS_VELOCITY_VERLET, CS_CONTACT_VERTEX, 1, 300, 0, 0, 0, CS_PINS_CORNERS, CS_FRICTION_RESULTANT, 1, 2},
    {64, 64, CS_VELOCITY_VERLET, CS_CONTACT_SURFACE, 1, 20000, 0, 0.03f, 0, CS_PINS_EDGES, 0, 0, 2},
    {64, 64, CS_SYMPLECTIC_EULER, CS_CONTACT_SURFACE, 0, 0, 0, 0, -2.0f, CS_PINS_CORNERS, 0, 0, 2},
    {64, 64, CS_VELOCITY_VERLET, CS_CONTACT_VERTEX, 0, 0, 0, 0, 0, CS_PINS_NONE, 0, 0, 2},
};

static cs_sim *make(const spec *sp)
{
    cs_scene sc;
    cs_params p;
    cs_scene_default(&sc);
    cs_params_default(&p);
    sc.nx = sp->nx, sc.ny = sp->ny, sc.pins = sp->pins;
    sc.height = 0.3f; /* unpinned, it reaches the ground within the test */
    p.integrator = sp->integrator;
    p.contact_model = sp->contact;
    p.plastic_yield = sp->yield, p.tear_strain = sp->tear;
    p.wind[0] = sp->wind;
    p.friction_model = sp->friction;
    cs_sim *sim = tk_sim(&sc, &p);
    assert_int_equal(cs_sim_set_threads(sim, sp->threads), CS_OK);
    for (int r = 0; r < sp->rocks; r++) {
        cs_rock_def d;
        cs_rock_def_default(&d);
        d.position[0] = 0.45f * (float)r - 0.225f * (float)(sp->rocks - 1);
        d.position[1] = 0.1f, d.position[2] = sc.height + 0.21f;
        d.radius = 0.2f, d.density = sp->rock_density;
        d.velocity[2] = sp->rock_density > 1000.0f ? -4.0f : 0.0f; /* a heavy one is thrown down */
        if (cs_rock_add(sim, &d, NULL) != CS_OK) fail_msg("cs_rock_add: %s", cs_sim_error(sim));
    }
    if (sp->grab) {
        const float target[3] = {0.0f, 0.0f, sc.height + 0.5f};
        assert_int_equal(cs_grab(sim, (sp->ny / 2) * sp->nx + sp->nx / 2, target), CS_OK);
    }
    return sim;
}

static void destroy_all(cs_sim **a, cs_sim **b, int n)
{
    for (int k = 0; k < n; k++) {
        cs_sim_destroy(a[k]);
        cs_sim_destroy(b[k]);
    }
}

/* a and b are in the same state, bit for bit, on the same clock. */
static void assert_same(cs_sim *a, cs_sim *b, const char *what, int k)
{
    cs_info ia, ib;
    cs_sim_info(a, &ia);
    cs_sim_info(b, &ib);
    if (ia.step != ib.step || ia.time != ib.time || ia.n_torn != ib.n_torn)
        fail_msg("%s, scene %d: step %llu / %llu, time %.17g / %.17g, torn %lld / %lld", what, k,
                 (unsigned long long)ia.step, (unsigned long long)ib.step, ia.time, ib.time, (long long)ia.n_torn,
                 (long long)ib.n_torn);
    if (cs_state_hash(a) != cs_state_hash(b)) fail_msg("%s, scene %d: the state hashes differ", what, k);
}

/* Steps the batch by sub[] and each twin alone by the same, and compares them all. */
static void round_trip(cs_sim **batch, cs_sim **alone, int n, const int64_t *sub, const char *what)
{
    cs_status each[8];
    assert_int_equal(cs_sims_step(batch, (size_t)n, sub, each), CS_OK);
    for (int k = 0; k < n; k++) {
        if (each[k] != CS_OK) fail_msg("%s, scene %d: %s", what, k, cs_sim_error(batch[k]));
        tk_step(alone[k], sub[k]);
        assert_same(batch[k], alone[k], what, k);
    }
}

/* Rounds that hand the batch out differently (plan_batch in backend_cpu.c), at 3 threads unless
 * said: every scene a few substeps, all on one thread each; the three 64 x 64 alone at 2 threads;
 * one 64 x 64 with most of the work, so the team steps it and the threads share the rest; the
 * small scenes with most of the work. */
static void test_mixed_batch_bitwise_as_alone(void **unused)
{
    (void)unused;
    cs_sim *batch[8], *alone[8];
    for (int k = 0; k < 8; k++) {
        batch[k] = make(&MIXED[k]);
        alone[k] = make(&MIXED[k]);
    }
    const int64_t r1[8] = {13, 7, 20, 9, 16, 11, 5, 8};
    round_trip(batch, alone, 8, r1, "mixed");
    const int64_t r2[3] = {10, 10, 10};
    round_trip(batch + 5, alone + 5, 3, r2, "the three largest");
    const int64_t r3[8] = {3, 3, 3, 3, 3, 60, 3, 3};
    round_trip(batch, alone, 8, r3, "one large");
    const int64_t r4[8] = {40, 40, 40, 40, 40, 2, 2, 2};
    round_trip(batch, alone, 8, r4, "the small ones");
    for (int k = 0; k < 4; k++) round_trip(batch, alone, 8, r1, "mixed again");
    /* What the cases are there for happened: springs yielded, and the heavy rocks tore their cloths. */
    cs_info info;
    cs_sim *fresh = make(&MIXED[2]);
    float *L = tk_rest_lengths(batch[2]), *L0 = tk_rest_lengths(fresh);
    int grown = 0;
    for (size_t i = 0; i < (size_t)6 * 24 * 20; i++) grown += L[i] > L0[i] + 1e-6f;
    assert_true(grown > 0);
    free(L);
    free(L0);
    cs_sim_destroy(fresh);
    cs_sim_info(batch[3], &info);
    assert_true(info.n_torn > 0);
    cs_sim_info(batch[5], &info);
    assert_true(info.n_torn > 0);
    destroy_all(batch, alone, 8);
}

/* One scene run alone in a batch, then beside 7 different ones, then while others are added and
 * deleted between calls (its place in the batch moving): its hash equals its twin's stepped alone
 * by cs_sim_step at every checkpoint. */
static void test_independent_of_company(void **unused)
{
    (void)unused;
    const spec me = {32, 24, CS_VELOCITY_VERLET, CS_CONTACT_SURFACE, 1, 300, 0.01f, 0, 0.5f, CS_PINS_EDGES, 0, 0, 2};
    cs_sim *mine = make(&me), *twin = make(&me);
    cs_sim *others[8] = {0};
    cs_sim *b[8];
    int64_t sub[8];
    cs_status each[8];
    const int64_t frame = 12;
    /* alone */
    b[0] = mine, sub[0] = frame;
    for (int r = 0; r < 2; r++) {
        assert_int_equal(cs_sims_step(b, 1, sub, each), CS_OK);
        assert_int_equal(each[0], CS_OK);
        tk_step(twin, frame);
        assert_same(mine, twin, "alone", r);
    }
    /* beside 7 different ones (the mixed batch's last seven, of 16 x 16 .. 64 x 64) */
    for (int k = 0; k < 7; k++) others[k] = make(&MIXED[k + 1]);
    for (int r = 0; r < 2; r++) {
        b[0] = mine, sub[0] = frame;
        for (int k = 0; k < 7; k++) b[k + 1] = others[k], sub[k + 1] = 5 + 3 * k;
        assert_int_equal(cs_sims_step(b, 8, sub, each), CS_OK);
        for (int k = 0; k < 8; k++) assert_int_equal(each[k], CS_OK);
        tk_step(twin, frame);
        assert_same(mine, twin, "beside 7", r);
    }
    /* others deleted and added between calls: delete 3, add 2 (one of them large), move to the
     * end; delete 4 more; add one back */
    const int dels[3][4] = {{1, 4, 6, -1}, {0, 2, 3, 5}, {-1, -1, -1, -1}};
    const int adds[3][2] = {{0, 7}, {-1, -1}, {4, -1}};
    for (int r = 0; r < 3; r++) {
        for (int d = 0; d < 4; d++)
            if (dels[r][d] >= 0) cs_sim_destroy(others[dels[r][d]]), others[dels[r][d]] = NULL;
        for (int a = 0; a < 2; a++) {
            if (adds[r][a] < 0) continue;
            int slot = 0;
            while (others[slot]) slot++;
            others[slot] = make(&MIXED[adds[r][a]]);
        }
        int n = 0;
        for (int k = 0; k < 8; k++)
            if (others[k]) b[n] = others[k], sub[n++] = 4 + 2 * k;
        b[n] = mine, sub[n++] = frame;
        assert_int_equal(cs_sims_step(b, (size_t)n, sub, each), CS_OK);
        for (int k = 0; k < n; k++) assert_int_equal(each[k], CS_OK);
        tk_step(twin, frame);
        assert_same(mine, twin, "after others came and went", r);
    }
    for (int k = 0; k < 8; k++) cs_sim_destroy(others[k]);
    cs_sim_destroy(mine);
    cs_sim_destroy(twin);
}

/* A scene whose state goes non-finite fails alone: its result is CS_E_NONFINITE, as its twin's
 * alone, and the others end as theirs do. Two of them: a large one (the team steps it) and a
 * small one (one thread does). */
static void test_nonfinite_fails_alone(void **unused)
{
    (void)unused;
    const spec big = {64, 64, CS_VELOCITY_VERLET, CS_CONTACT_SURFACE, 0, 0, 0, 0, 0, CS_PINS_EDGES, 0, 0, 2};
    const spec little = {16, 16, CS_SYMPLECTIC_EULER, CS_CONTACT_SURFACE, 0, 0, 0, 0, 0, CS_PINS_EDGES, 0, 0, 2};
    const spec *specs[5] = {&little, &big, &little, &little, &little};
    const int bad[5] = {0, 1, 0, 1, 0};
    cs_sim *batch[5], *alone[5];
    for (int k = 0; k < 5; k++) {
        batch[k] = make(specs[k]);
        alone[k] = make(specs[k]);
        if (bad[k]) {
            const float nan3[3] = {NAN, NAN, NAN};
            const int32_t v = specs[k]->nx * (specs[k]->ny / 2) + specs[k]->nx / 2;
            tk_set_vertex(batch[k], v, NULL, nan3);
            tk_set_vertex(alone[k], v, NULL, nan3);
        }
    }
    const int64_t sub[5] = {20, 20, 20, 20, 20};
    cs_status each[5];
    assert_int_equal(cs_sims_step(batch, 5, sub, each), CS_OK);
    for (int k = 0; k < 5; k++) {
        assert_int_equal(each[k], bad[k] ? CS_E_NONFINITE : CS_OK);
        assert_int_equal(cs_sim_step(alone[k], sub[k]), bad[k] ? CS_E_NONFINITE : CS_OK);
        if (!bad[k]) assert_same(batch[k], alone[k], "beside a failing scene", k);
        else assert_non_null(strstr(cs_sim_error(batch[k]), "non-finite"));
    }
    /* The good ones go on stepping together; the failed ones sit out. */
    const int64_t next[5] = {0, 0, 7, 0, 9};
    assert_int_equal(cs_sims_step(batch, 5, next, each), CS_OK);
    for (int k = 0; k < 5; k++) {
        tk_step(alone[k], next[k]);
        if (!bad[k]) assert_same(batch[k], alone[k], "after the failure", k);
    }
    destroy_all(batch, alone, 5);
}

int main(void)
{
    const struct CMUnitTest tests[] = {
        cmocka_unit_test(test_mixed_batch_bitwise_as_alone),
        cmocka_unit_test(test_independent_of_company),
        cmocka_unit_test(test_nonfinite_fails_alone),
    };
    return cmocka_run_group_tests(tests, NULL, NULL);
}
