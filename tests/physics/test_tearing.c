/* test_tearing.c - tearing (kernels/MODEL.md, Cloth): after each substep, from the new
 * positions, a spring whose strain (|d| - L0)/L0 exceeds tear_strain is removed for good
 * (rest length CS_TORN); else past plastic_yield its rest length flows.
 *
 * The strains are recomputed here, in double precision, from the positions after exactly one
 * substep (positions do not change after the drift within a substep, backend.h) and the rest
 * lengths read before it. Springs within a relative 1e-5 of a threshold are left out of the
 * comparison (float and double may decide them differently); the tests report how many. */
#include "testkit.h"


/* Springs in an nx x ny grid: (nx-1) ny + nx (ny-1) structural, 2 (nx-1)(ny-1) shear,
 * (nx-2) ny + nx (ny-2) bend. */
static int64_t springs_in_grid(int64_t nx, int64_t ny)
{
    return (nx - 1) * ny + nx * (ny - 1) + 2 * (nx - 1) * (ny - 1) + (nx > 2 ? (nx - 2) * ny : 0) +
           (ny > 2 ? nx * (ny - 2) : 0);
}


static uint32_t rng = 99;
static float frand(void) /* uniform in [-0.5, 0.5) */
{
    rng = rng * 1664525u + 1013904223u;
    return (float)(rng >> 8) / 16777216.0f - 0.5f;
}

/* Displaces every free vertex by up to +-amp per component and gives it a random velocity up to
 * +-vmax per component, as a command would (sync, poke, commit). */
static void shake(cs_sim *sim, float amp, float vmax)
{
    assert_int_equal(cs_sim_sync(sim, CS_SYNC_ALL), CS_OK);
    cs_state *s = &sim->state;
    for (int32_t v = 0; v < s->n; v++) {
        if (s->pinned[v]) continue;
        s->x[v] += amp * frand();
        s->y[v] += amp * frand();
        s->z[v] += amp * frand();
        s->vx[v] = vmax * frand();
        s->vy[v] = vmax * frand();
        s->vz[v] = vmax * frand();
    }
    assert_int_equal(cs_sim_commit(sim), CS_OK);
}

typedef struct tally {
    int64_t torn_new, torn_total, flowed, kept, skipped;
    double e_min, e_max; /* strains of the intact springs seen */
} tally;

/* Steps exactly one substep and checks every spring against the strain computed from the
 * positions after it: tear past tear (and only then), else flow to the length past yield (when
 * yield > 0; rate 0), else untouched; torn ones stay torn. */
static void step_and_check(cs_sim *sim, double tear, double yield, tally *tl)
{
    cs_scene sc;
    cs_sim_scene(sim, &sc);
    const int32_t nx = sc.nx, ny = sc.ny, n = nx * ny;
    float *before = tk_rest_lengths(sim);
    cs_info info0;
    cs_sim_info(sim, &info0);
    tk_step(sim, 1);
    float *after = tk_rest_lengths(sim);
    float *X = tk_positions(sim);
    int64_t torn_expected = 0; /* torn in all, as this test counts them */
    memset(tl, 0, sizeof *tl);
    tl->e_min = INFINITY;
    tl->e_max = -INFINITY;
    uint32_t *want_ids = malloc(sizeof(uint32_t) * (size_t)n * CS_NTYPES);
    assert_non_null(want_ids);
    int64_t n_want = 0;
    for (int t = 0; t < CS_NTYPES; t++) {
        for (int32_t v = 0; v < n; v++) {
            const size_t li = (size_t)t * n + v;
            const int32_t o = cs_spring_far_end(nx, ny, t, v);
            if (o < 0) {
                assert_true(after[li] == CS_TORN); /* absent: stays marked absent */
                continue;
            }
            if (before[li] <= 0.0f) { /* torn before: stays torn */
                assert_true(after[li] == CS_TORN);
                want_ids[n_want++] = (uint32_t)li;
                torn_expected++;
                continue;
            }
            const double dx = (double)X[3 * o] - X[3 * v], dy = (double)X[3 * o + 1] - X[3 * v + 1],
                         dz = (double)X[3 * o + 2] - X[3 * v + 2];
            const double len = sqrt(dx * dx + dy * dy + dz * dz);
            const double L0 = before[li], e = (len - L0) / L0;
            if (e < tl->e_min) tl->e_min = e;
            if (e > tl->e_max) tl->e_max = e;
            if (fabs(e - tear) <= 1e-5 * tear || (yield > 0 && fabs(e - yield) <= 1e-5 * yield)) {
                tl->skipped++;
                if (after[li] == CS_TORN) want_ids[n_want++] = (uint32_t)li, torn_expected++;
                continue;
            }
            if (e > tear) {
                if (after[li] != CS_TORN)
                    fail_msg("spring %d/%d: strain %.6f > %.3f but not torn (L0 %.6f -> %.6f)", t, (int)v, e, tear,
                             L0, (double)after[li]);
                want_ids[n_want++] = (uint32_t)li;
                torn_expected++;
                tl->torn_new++;
            } else if (yield > 0 && e > yield) {
                /* plastic_rate 0: L0 <- |d| */
                if (!(fabs(after[li] - len) <= 2e-6 * len))
                    fail_msg("spring %d/%d: strain %.6f in (%.3f, %.3f]: L0 %.7f, expected the length %.7f", t,
                             (int)v, e, yield, tear, (double)after[li], len);
                tl->flowed++;
            } else {
                if (memcmp(&after[li], &before[li], sizeof(float)) != 0)
                    fail_msg("spring %d/%d: strain %.6f below the thresholds but L0 %.7f -> %.7f", t, (int)v, e, L0,
                             (double)after[li]);
                tl->kept++;
            }
        }
    }
    tl->torn_total = torn_expected;
    /* The library's counts agree with this count and with each other. */
    cs_info info;
    cs_sim_info(sim, &info);
    assert_int_equal(info.n_torn, torn_expected);
    assert_int_equal(info.n_springs, springs_in_grid(nx, ny) - torn_expected);
    assert_int_equal(info.step, info0.step + 1);
    uint32_t *ids = malloc(sizeof(uint32_t) * (size_t)(n_want + 1));
    assert_non_null(ids);
    assert_int_equal(cs_read_torn(sim, ids, (size_t)n_want + 1), torn_expected);
    /* Ids are type n + v; both lists are in that order. */
    for (int64_t k = 0; k < n_want; k++)
        if (ids[k] != want_ids[k]) fail_msg("torn id %lld: %u, expected %u", (long long)k, ids[k], want_ids[k]);
    /* A short buffer still gets the full count. */
    if (n_want > 2) assert_int_equal(cs_read_torn(sim, ids, 2), torn_expected);
    free(ids);
    free(want_ids);
    free(X);
    free(before);
    free(after);
}

static cs_sim *spread_cloth(int integrator, float tear, float yield)
{
    cs_scene sc;
    cs_params p;
    cs_scene_default(&sc);
    cs_params_default(&p);
    sc.nx = 24;
    sc.ny = 20;
    sc.size_x = 1.15f;
    sc.size_y = 0.95f; /* spacing 0.05 m */
    sc.pins = CS_PINS_CORNERS;
    p.tear_strain = tear;
    p.plastic_yield = yield;
    p.plastic_rate = 0.0f;
    p.integrator = integrator;
    cs_sim *sim = tk_sim(&sc, &p);
    /* Displacements up to +-0.01 m per component on a 0.05 m grid and velocities up to +-4 m/s
     * (2 mm per substep): strains after one substep from about -0.35 to +0.44 (measured). */
    shake(sim, 0.02f, 8.0f);
    return sim;
}

/* Exactly the springs past tear_strain tear, for both integrators; a second substep after another
 * shake tears the newly overstretched ones and keeps the torn ones torn. */
static void test_tear_exactly_past_threshold(void **unused)
{
    (void)unused;
    for (int integ = 0; integ < 2; integ++) {
        cs_sim *sim = spread_cloth(integ, 0.15f, 0.0f);
        tally a, b;
        step_and_check(sim, 0.15, 0.0, &a);
        shake(sim, 0.02f, 8.0f);
        step_and_check(sim, 0.15, 0.0, &b);
        print_message("integrator %d: substep 1 strains %.3f..%.3f, tore %lld, kept %lld, skipped %lld; substep 2 "
                      "tore %lld more (%lld torn in all), kept %lld, skipped %lld\n",
                      integ, a.e_min, a.e_max, (long long)a.torn_new, (long long)a.kept, (long long)a.skipped,
                      (long long)b.torn_new, (long long)b.torn_total, (long long)b.kept, (long long)b.skipped);
        /* The scene did spread the strains across the threshold. */
        assert_true(a.torn_new > 100 && a.kept > 100);
        assert_true(b.torn_new > 20 && b.kept > 100);
        assert_true(a.skipped <= 3 && b.skipped <= 3);
        cs_sim_destroy(sim);
    }
}

/* With plasticity too: past tear torn, between yield and tear the rest length jumps to the
 * length (plastic_rate 0), below both untouched. */
static void test_tear_and_flow(void **unused)
{
    (void)unused;
    for (int integ = 0; integ < 2; integ++) {
        cs_sim *sim = spread_cloth(integ, 0.25f, 0.05f);
        tally a, b;
        step_and_check(sim, 0.25, 0.05, &a);
        shake(sim, 0.02f, 8.0f);
        step_and_check(sim, 0.25, 0.05, &b);
        print_message("integrator %d: tore %lld + %lld, flowed %lld + %lld, kept %lld + %lld, skipped %lld + %lld\n",
                      integ, (long long)a.torn_new, (long long)b.torn_new, (long long)a.flowed, (long long)b.flowed,
                      (long long)a.kept, (long long)b.kept, (long long)a.skipped, (long long)b.skipped);
        assert_true(a.torn_new > 50 && a.flowed > 50 && a.kept > 100);
        assert_true(b.torn_new > 10 && b.flowed > 50 && b.kept > 100);
        cs_sim_destroy(sim);
    }
}

/* A 3 x 3 cloth with its border pinned: the centre vertex (4) is shot up at 20 m/s with no
 * gravity or drag; its 8 springs (4 structural, 4 shear; a 3 x 3 grid has no bend spring at the
 * centre) tear and nothing else does. Then it flies freely: zero acceleration, constant velocity,
 * x = x0 + k dt v. Put back at its grid position, or displaced, the torn springs stay torn and
 * exert no force. */
static void test_torn_spring_stays_torn_and_exerts_no_force(void **unused)
{
    (void)unused;
    for (int integ = 0; integ < 2; integ++) {
        cs_scene sc;
        cs_params p;
        tk_quiet(&sc, &p);
        sc.nx = sc.ny = 3;
        sc.size_x = sc.size_y = 1.0f;
        sc.pins = CS_PINS_EDGES;
        p.tear_strain = 0.1f;
        p.integrator = integ;
        cs_sim *sim = tk_sim(&sc, &p);
        /* One thread: 1300 substeps of 9 vertices, where OpenMP barriers would dominate. */
        assert_int_equal(cs_sim_set_threads(sim, 1), CS_OK);
        const float up[3] = {0, 0, 20.0f};
        tk_set_vertex(sim, 4, NULL, up);
        /* 0.5 s is far more than needed: 0.23 m of rise tears the structural springs, 0.32 m the
         * shear ones, and 20 m/s carries 3 J, more than the 2.8 J they store by then. */
        assert_int_equal(cs_sim_step_frames(sim, 30), CS_OK);
        cs_info info;
        cs_sim_info(sim, &info);
        assert_int_equal(info.n_torn, 8);
        uint32_t ids[16];
        assert_int_equal(cs_read_torn(sim, ids, 16), 8);
        /* By hand (id = type 9 + owner): SX 3-4, 4-5: 3, 4; SY 1-4, 4-7: 10, 13; D1 0-4, 4-8: 18, 22;
         * D2 (owner reaches i-1, j+1) 2-4, 4-6: 29, 31. */
        const uint32_t want[8] = {3, 4, 10, 13, 18, 22, 29, 31};
        assert_memory_equal(ids, want, sizeof want);

        /* Free flight: record, step, compare with x0 + k dt v exactly in velocity and to float
         * rounding in position. */
        assert_int_equal(cs_sim_sync(sim, CS_SYNC_ALL), CS_OK);
        const cs_state *s = &sim->state;
        assert_true(s->ax[4] == 0.0f && s->ay[4] == 0.0f && s->az[4] == 0.0f);
        const float v0[3] = {s->vx[4], s->vy[4], s->vz[4]};
        const double z0 = s->z[4];
        assert_true(v0[2] > 5.0f); /* it kept most of its speed */
        tk_step(sim, 100);
        assert_int_equal(cs_sim_sync(sim, CS_SYNC_ALL), CS_OK);
        assert_true(s->vx[4] == v0[0] && s->vy[4] == v0[1] && s->vz[4] == v0[2]);
        assert_true(fabs(s->z[4] - (z0 + 100 * info.dt * v0[2])) < 1e-4);

        /* Back at its grid position at rest (every strain 0): nothing resurrects the springs. */
        const float home[3] = {0.0f, 0.0f, sc.height}, zero[3] = {0, 0, 0};
        tk_set_vertex(sim, 4, home, zero);
        tk_step(sim, 30);
        float *L = tk_rest_lengths(sim);
        for (int k = 0; k < 8; k++) assert_true(L[want[k]] == CS_TORN);
        free(L);
        cs_sim_info(sim, &info);
        assert_int_equal(info.n_torn, 8);

        /* Displaced 0.1 m sideways (intact springs would pull it back with about 40 N): no force. */
        const float aside[3] = {0.1f, 0.05f, sc.height + 0.02f};
        tk_set_vertex(sim, 4, aside, zero);
        assert_true(s->ax[4] == 0.0f && s->ay[4] == 0.0f && s->az[4] == 0.0f);
        tk_step(sim, 200);
        float *x = tk_positions(sim);
        assert_true(x[12] == aside[0] && x[13] == aside[1] && x[14] == aside[2]);
        free(x);
        cs_sim_info(sim, &info);
        assert_int_equal(info.n_torn, 8);
        assert_int_equal(info.n_springs, springs_in_grid(3, 3) - 8);
        cs_sim_destroy(sim);
    }
}

int main(void)
{
    const struct CMUnitTest tests[] = {
        cmocka_unit_test(test_tear_exactly_past_threshold),
        cmocka_unit_test(test_tear_and_flow),
        cmocka_unit_test(test_torn_spring_stays_torn_and_exerts_no_force),
    };
    return cmocka_run_group_tests(tests, NULL, NULL);
}
