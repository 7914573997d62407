/* test_plasticity.c - plastic flow (kernels/MODEL.md, Cloth): past plastic_yield a stretched
 * spring's rest length grows, L0 <- L0 + f (|d| - L0) with f = 1 when plastic_rate is 0, else
 * f = min(1, plastic_rate dt); tension only.
 *
 * 1. A permanent dent: an edges-pinned cloth is pressed by a rock moving down, the rock is
 *    removed, the cloth settles under gravity with drag; with plasticity its centre stays clearly
 *    below where the same run without plasticity settles, and at rest (so the dent is a new rest
 *    shape, not a motion). Rest lengths only grew, some of them.
 * 2. plastic_rate, hand-computed on springs whose length cannot change (all stiffnesses 0, no
 *    external force: nothing moves), so the recursion L0_k = L0_{k-1} + f (len - L0_{k-1}) while
 *    (len - L0_{k-1}) / L0_{k-1} > yield can be evaluated by hand and in double precision. */
#include "testkit.h"



/* ---- 1. the dent ---- */

typedef struct dent_result {
    double centre_z;   /* settled height of the centre vertex */
    double max_speed;  /* fastest vertex at the end */
    int32_t grown, shrunk, torn;
    double max_growth; /* largest relative growth of a rest length */
} dent_result;

#define DENT_N 21

static void run_dent(float plastic_yield, int integrator, int press, dent_result *out)
{
    cs_scene sc;
    cs_params p;
    cs_scene_default(&sc);
    cs_params_default(&p);
    sc.nx = sc.ny = DENT_N;
    sc.size_x = sc.size_y = 1.0f;
    sc.height = 1.0f;
    sc.pins = CS_PINS_EDGES;
    p.ground = 0;
    p.drag = 4.0f;        /* settle within a few seconds */
    p.c_spring = 0.05f;
    p.plastic_yield = plastic_yield;
    p.plastic_rate = 0.0f; /* instant: L0 <- |d| */
    p.integrator = integrator;
    cs_sim *sim = tk_sim(&sc, &p);
    /* One thread: results do not depend on it (test_determinism), and OpenMP barriers at every
     * substep crawl when ctest runs tests side by side on two cores. */
    assert_int_equal(cs_sim_set_threads(sim, 1), CS_OK);
    float *L_before = tk_rest_lengths(sim);

    /* A kinematic rock (it presses as hard as it takes) comes down on the centre at 0.5 m/s for
     * 0.5 s, rests 0.25 s, and is removed. */
    const float R = 0.15f;
    const int32_t c = (DENT_N / 2) * DENT_N + DENT_N / 2;
    if (press) {
        cs_rock_def d;
        cs_rock_def_default(&d);
        d.radius = R;
        d.density = 2500.0f;
        d.kinematic = true;
        d.position[2] = sc.height + R + p.contact_offset;
        d.velocity[2] = -0.5f;
        uint32_t id = 0;
        assert_int_equal(cs_rock_add(sim, &d, &id), CS_OK);
        assert_int_equal(cs_sim_step_frames(sim, 30), CS_OK);
        cs_rock r = tk_rock(sim, id);
        assert_true(fabsf(r.def.position[2] - (d.position[2] - 0.25f)) < 1e-3f); /* it did move 0.25 m */
        r.def.velocity[2] = 0.0f;
        assert_int_equal(cs_rock_set(sim, id, &r.def), CS_OK);
        assert_int_equal(cs_sim_step_frames(sim, 15), CS_OK);
        float *x = tk_positions(sim);
        /* The cloth was pressed down: the centre is well below its initial height. */
        assert_true(x[3 * c + 2] < sc.height - 0.15f);
        free(x);
        assert_int_equal(cs_rock_remove(sim, id), CS_OK);
        assert_int_equal(cs_rock_count(sim), 0);
    } else {
        assert_int_equal(cs_sim_step_frames(sim, 45), CS_OK); /* the same time without the rock */
    }

    /* Settle: 4 simulated seconds. */
    assert_int_equal(cs_sim_step_frames(sim, 240), CS_OK);
    float *x = tk_positions(sim);
    out->centre_z = x[3 * c + 2];
    free(x);
    const size_t n = (size_t)sim->state.n;
    float *v = malloc(3 * n * sizeof(float));
    assert_non_null(v);
    assert_int_equal(cs_read_velocities(sim, v, 3 * n), CS_OK);
    out->max_speed = 0;
    for (size_t k = 0; k < n; k++) {
        const double s = sqrt((double)v[3 * k] * v[3 * k] + (double)v[3 * k + 1] * v[3 * k + 1] +
                              (double)v[3 * k + 2] * v[3 * k + 2]);
        if (s > out->max_speed) out->max_speed = s;
    }
    free(v);

    float *L_after = tk_rest_lengths(sim);
    out->grown = out->shrunk = out->torn = 0;
    out->max_growth = 0;
    for (int t = 0; t < CS_NTYPES; t++) {
        for (int32_t k = 0; k < (int32_t)n; k++) {
            const size_t li = (size_t)t * n + (size_t)k;
            if (cs_spring_far_end(DENT_N, DENT_N, t, k) < 0) {
                assert_true(L_after[li] == CS_TORN); /* absent at the border */
                continue;
            }
            if (L_after[li] <= 0.0f) out->torn++;
            else if (L_after[li] > L_before[li]) out->grown++;
            else if (L_after[li] < L_before[li]) out->shrunk++;
            const double g = ((double)L_after[li] - L_before[li]) / L_before[li];
            if (g > out->max_growth) out->max_growth = g;
        }
    }
    free(L_before);
    free(L_after);
    cs_sim_destroy(sim);
}

static void test_permanent_dent(void **unused)
{
    (void)unused;
    for (int integ = 0; integ < 2; integ++) {
        dent_result free_, el, pl;
        run_dent(0.0f, integ, 0, &free_);
        run_dent(0.0f, integ, 1, &el);
        run_dent(0.03f, integ, 1, &pl);
        print_message("integrator %d: centre z untouched %.4f elastic %.4f plastic %.4f (dent %.4f m); max speed %.2e / %.2e; "
                      "rest lengths grown %d (max +%.1f%%), shrunk %d\n",
                      integ, free_.centre_z, el.centre_z, pl.centre_z, el.centre_z - pl.centre_z, el.max_speed, pl.max_speed,
                      (int)pl.grown, 100 * pl.max_growth, (int)pl.shrunk);
        /* Without plasticity the rest lengths never change, and the cloth forgets the rock: it
         * settles where the same cloth settles under gravity alone (within 5 mm). */
        assert_int_equal(el.grown, 0);
        assert_int_equal(el.shrunk, 0);
        assert_int_equal(el.torn, 0);
        assert_true(fabs(el.centre_z - free_.centre_z) < 5e-3);
        /* Gravity alone sags the centre by less than 10 cm. */
        assert_true(free_.centre_z > 0.90 && free_.centre_z < 1.0);
        /* With it, a dent of more than 5 cm stays. */
        assert_true(pl.centre_z < el.centre_z - 0.05);
        /* Both have settled: the dent is a rest shape. */
        assert_true(el.max_speed < 1e-2);
        assert_true(pl.max_speed < 1e-2);
        /* Tension only: many rest lengths grew, none shrank, none tore (tearing is off). */
        assert_true(pl.grown > 50);
        assert_int_equal(pl.shrunk, 0);
        assert_int_equal(pl.torn, 0);
        assert_true(pl.max_growth > 0.03);
    }
}

/* ---- 2. plastic_rate on springs that cannot move ---- */

/* A cloth with every force off (stiffness 0, no gravity, drag, damping, ground, pins): nothing
 * moves, so the spring lengths stay as set while the rest lengths flow. */
static cs_sim *frozen(int nx, int ny, float size, float yield, float rate, int integrator)
{
    cs_scene sc;
    cs_params p;
    tk_quiet(&sc, &p);
    sc.nx = nx;
    sc.ny = ny;
    sc.size_x = sc.size_y = size;
    sc.pins = CS_PINS_NONE;
    p.k_structural = p.k_shear = p.k_bend = 0.0f;
    p.plastic_yield = yield;
    p.plastic_rate = rate;
    p.integrator = integrator;
    p.frame_rate = 60.0f;
    p.substeps = 30;
    cs_sim *sim = tk_sim(&sc, &p);
    cs_info info;
    cs_sim_info(sim, &info);
    assert_int_equal(info.substeps, 30); /* so dt is 1/1800 s */
    assert_true(fabs(info.dt - 1.0 / 1800.0) < 1e-12);
    return sim;
}

/* One spring isolated by hand: a 2 x 2 cloth of 1 m, vertex 1 moved from x = 0.5 to 0.7, so the
 * structural spring 0-1 is 1.2 m long over L0 = 1 (strain 0.2), the others below the yield of
 * 0.15 (1-3: 1.0198 over 1, strain 0.02; 1-2: 1.5620 over 1.4142, strain 0.104). */
static void test_rate_one_spring(void **unused)
{
    (void)unused;
    for (int integ = 0; integ < 2; integ++) {
        /* rate 60/s, dt 1/1800 s: f = 1/30 per substep. The excess 0.2 shrinks by 29/30 per
         * substep while (1.2 - L0)/L0 > 0.15, i.e. L0 < 1.2/1.15: the updates at substeps 1..8
         * (0.2 (29/30)^7 = 0.1580 > 0.1565 > 0.2 (29/30)^8 = 0.1525), then it stops. */
        cs_sim *sim = frozen(2, 2, 1.0f, 0.15f, 60.0f, integ);
        const float x1[3] = {0.7f, -0.5f, 1.0f}, zero[3] = {0, 0, 0};
        tk_set_vertex(sim, 1, x1, zero);
        float *L0 = tk_rest_lengths(sim);
        assert_true(L0[CS_SX * 4 + 0] == 1.0f);
        double expect = 1.0;
        for (int k = 1; k <= 12; k++) {
            tk_step(sim, 1);
            if (k <= 8) expect += (1.2 - expect) / 30.0;
            float *L = tk_rest_lengths(sim);
            const double got = L[CS_SX * 4 + 0];
            if (fabs(got - expect) > 2e-6) fail_msg("integrator %d substep %d: L0 %.9f, expected %.9f", integ, k, got, expect);
            /* The other springs are below the yield: untouched, bit for bit. */
            for (int q = 0; q < 4 * CS_NTYPES; q++)
                if (q != CS_SX * 4 + 0) assert_memory_equal(&L[q], &L0[q], sizeof(float));
            free(L);
        }
        /* In closed form: 1.2 - 0.2 (29/30)^8. */
        float *L = tk_rest_lengths(sim);
        assert_true(fabs(L[0] - (1.2 - 0.2 * pow(29.0 / 30.0, 8))) < 2e-6);
        assert_true(fabs(L[0] - 1.0 - 0.2 / 30.0 * (1 + 29.0 / 30 + pow(29.0 / 30, 2) + pow(29.0 / 30, 3) +
                                                        pow(29.0 / 30, 4) + pow(29.0 / 30, 5) +
                                                        pow(29.0 / 30, 6) + pow(29.0 / 30, 7))) < 2e-6);
        free(L);
        free(L0);
        cs_sim_destroy(sim);

        /* rate dt >= 1 (rate 1e4/s: 5.6 per substep) and rate 0 both jump to the length at once. */
        const float rates[2] = {1e4f, 0.0f};
        for (int q = 0; q < 2; q++) {
            sim = frozen(2, 2, 1.0f, 0.15f, rates[q], integ);
            tk_set_vertex(sim, 1, x1, zero);
            tk_step(sim, 1);
            L = tk_rest_lengths(sim);
            assert_true(fabs(L[0] - 1.2) < 1e-6);
            tk_step(sim, 3); /* strain 0 now: stays */
            float *L2 = tk_rest_lengths(sim);
            assert_memory_equal(L, L2, 4 * CS_NTYPES * sizeof(float));
            free(L2);
            free(L);
            cs_sim_destroy(sim);
        }
    }
}

static uint32_t rng = 2024;
static double urand(void) /* uniform in [0, 1) */
{
    rng = rng * 1664525u + 1013904223u;
    return (double)(rng >> 8) / 16777216.0;
}

/* Every spring of a randomly displaced 5 x 4 cloth against the recursion in double precision,
 * substep by substep, with f = rate dt = 90/1800 = 0.05. Springs whose strain comes within a
 * relative 1e-4 of the yield at some substep are skipped (float and double may decide them
 * differently); the test says how many. */
static void test_rate_every_spring(void **unused)
{
    (void)unused;
    const int nx = 5, ny = 4, n = nx * ny, steps = 40;
    const double yield = 0.04, f = 90.0 / 1800.0;
    int flowed_total = 0, skipped_total = 0, checked_total = 0;
    for (int integ = 0; integ < 2; integ++) {
        cs_sim *sim = frozen(nx, ny, 1.0f, (float)yield, 90.0f, integ);
        assert_int_equal(cs_sim_sync(sim, CS_SYNC_ALL), CS_OK);
        cs_state *s = &sim->state;
        for (int32_t v = 0; v < n; v++) {
            s->x[v] += (float)(0.12 * (urand() - 0.5));
            s->y[v] += (float)(0.12 * (urand() - 0.5));
            s->z[v] += (float)(0.12 * (urand() - 0.5));
        }
        assert_int_equal(cs_sim_commit(sim), CS_OK);
        float *X = tk_positions(sim);
        float *L0 = tk_rest_lengths(sim);
        double *len = calloc((size_t)n * CS_NTYPES, sizeof(double));
        double *want = calloc((size_t)n * CS_NTYPES, sizeof(double));
        int *skip = calloc((size_t)n * CS_NTYPES, sizeof(int));
        int *flowed = calloc((size_t)n * CS_NTYPES, sizeof(int));
        for (int t = 0; t < CS_NTYPES; t++) {
            for (int32_t v = 0; v < n; v++) {
                const size_t li = (size_t)t * n + v;
                const int32_t o = cs_spring_far_end(nx, ny, t, v);
                want[li] = L0[li];
                if (o < 0) continue;
                const double dx = (double)X[3 * o] - X[3 * v], dy = (double)X[3 * o + 1] - X[3 * v + 1],
                             dz = (double)X[3 * o + 2] - X[3 * v + 2];
                len[li] = sqrt(dx * dx + dy * dy + dz * dz);
            }
        }
        for (int k = 1; k <= steps; k++) {
            tk_step(sim, 1);
            float *L = tk_rest_lengths(sim);
            for (int t = 0; t < CS_NTYPES; t++) {
                for (int32_t v = 0; v < n; v++) {
                    const size_t li = (size_t)t * n + v;
                    if (cs_spring_far_end(nx, ny, t, v) < 0) {
                        assert_true(L[li] == CS_TORN);
                        continue;
                    }
                    const double e = (len[li] - want[li]) / want[li];
                    if (fabs(e - yield) < 1e-4 * yield) skip[li] = 1;
                    if (e > yield) {
                        want[li] += f * (len[li] - want[li]);
                        flowed[li] = 1;
                    }
                    if (!skip[li] && fabs(L[li] - want[li]) > 2e-6 * want[li])
                        fail_msg("integrator %d substep %d spring %d/%d: L0 %.9f, expected %.9f", integ, k, t,
                                 (int)v, (double)L[li], want[li]);
                }
            }
            free(L);
        }
        /* The positions never moved (no forces), as the hand computation assumed. */
        float *X2 = tk_positions(sim);
        assert_memory_equal(X, X2, 3 * (size_t)n * sizeof(float));
        for (size_t li = 0; li < (size_t)n * CS_NTYPES; li++) {
            if (len[li] <= 0) continue;
            flowed_total += flowed[li] && !skip[li];
            skipped_total += skip[li];
            checked_total += !skip[li];
        }
        free(X2);
        free(X);
        free(L0);
        free(len);
        free(want);
        free(skip);
        free(flowed);
        cs_sim_destroy(sim);
    }
    print_message("plastic_rate: %d springs checked over 40 substeps, %d of them flowed, %d skipped near the yield\n",
                  checked_total, flowed_total, skipped_total);
    assert_true(flowed_total >= 20);
    assert_true(checked_total - flowed_total >= 20);
    assert_true(skipped_total <= 4);
}

int main(void)
{
    const struct CMUnitTest tests[] = {
        cmocka_unit_test(test_rate_one_spring),
        cmocka_unit_test(test_rate_every_spring),
        cmocka_unit_test(test_permanent_dent),
    };
    return cmocka_run_group_tests(tests, NULL, NULL);
}
