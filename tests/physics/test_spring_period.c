/* test_spring_period.c - one spring's oscillation period against 2 pi sqrt(mu/k).
 *
 * A 2 x 2 cloth (4 vertices, 1 kg each: 1 kg/m^2 x 2 m x 2 m / 4) with k_shear = 0 has no bend
 * springs (a 2-wide grid has none) and four structural springs: two along x (0-1, 2-3), two
 * along y (0-2, 1-3). Stretched along x, with both ends of each y-spring moved alike, the
 * y-springs stay parallel to y at their rest length and exert nothing; each x-spring is an
 * oscillator of its own:
 *   - both ends free, stretched symmetrically: reduced mass mu = m/2, omega = sqrt(2 k / m);
 *   - column i = 0 pinned: mu = m, omega = sqrt(k / m).
 * The period is measured from the zero crossings of the extension (linear interpolation between
 * substeps) over many periods. Velocity Verlet and symplectic Euler both map x_{n+1} - 2 x_n +
 * x_{n-1} = -(omega dt)^2 x_n, whose solutions are sampled sinusoids of frequency w~ with
 * sin(w~ dt/2) = omega dt/2: the period is short by about (omega dt)^2/24. */
#include "testkit.h"

#define PI 3.14159265358979323846
#define K 400.0     /* k_structural, N/m */
#define MASS 1.0    /* vertex mass, kg */
#define AMP 0.05f   /* stretch, m */

typedef struct period_run {
    double period;  /* measured, s */
    double dt;      /* substep, s */
    int crossings;
    double amp_min, amp_max; /* extremes of the extension seen after the start */
} period_run;

/* Runs the oscillator for about `periods` periods and measures its period from the first and
 * last zero crossing of the x-extension of spring 0-1. */
static period_run run_oscillator(int pinned_column, int integrator, int32_t substeps, double periods)
{
    cs_scene sc;
    cs_params p;
    tk_quiet(&sc, &p);
    sc.nx = sc.ny = 2;
    sc.pins = CS_PINS_NONE;
    p.k_structural = (float)K;
    p.k_shear = 0.0f;
    p.integrator = integrator;
    p.substeps = substeps;
    cs_sim *sim = tk_sim_serial(&sc, &p);
    assert_float_equal(sim->model.phys.mass, MASS, 0.0);
    if (pinned_column) {
        const int32_t col[2] = {0, 2};
        assert_int_equal(cs_pin(sim, col, 2, true), CS_OK);
    }
    /* Stretch along x: each x-spring by AMP, split between its ends unless one is pinned. */
    float *x = tk_positions(sim), start[12];
    const float L0 = x[3] - x[0];
    for (int32_t v = 0; v < 4; v++) {
        const int right = v % 2;
        float d = pinned_column ? (right ? AMP : 0.0f) : (right ? 0.5f * AMP : -0.5f * AMP);
        float pos[3] = {x[3 * v] + d, x[3 * v + 1], x[3 * v + 2]};
        tk_set_vertex(sim, v, pos, NULL);
    }
    free(x);
    assert_int_equal(cs_read_positions(sim, start, 12), CS_OK);
    cs_info info;
    cs_sim_info(sim, &info);
    assert_int_equal(info.substeps, substeps); /* the guard left the step alone */
    const double omega = sqrt(K / (pinned_column ? MASS : MASS / 2));
    const int64_t steps = (int64_t)(periods * 2 * PI / omega / info.dt) + 1;
    period_run out = {0, info.dt, 0, 1e30, -1e30};
    double prev_e = AMP, first = -1, last = -1;
    float pos[12];
    for (int64_t s = 1; s <= steps; s++) {
        tk_step(sim, 1);
        assert_int_equal(cs_read_positions(sim, pos, 12), CS_OK);
        const double e = (double)pos[3] - pos[0] - L0;
        /* The other x-spring moves in step, the y-springs only translate along x: y and z stay
         * exactly where they started. */
        assert_true(pos[9] - pos[6] == pos[3] - pos[0]);
        for (int v = 0; v < 4; v++)
            assert_true(pos[3 * v + 1] == start[3 * v + 1] && pos[3 * v + 2] == start[3 * v + 2]);
        if (e < out.amp_min) out.amp_min = e;
        if (e > out.amp_max) out.amp_max = e;
        if ((prev_e > 0) != (e > 0)) {
            const double tc = (s - 1 + prev_e / (prev_e - e)) * info.dt;
            if (first < 0) first = tc;
            last = tc;
            out.crossings++;
        }
        prev_e = e;
    }
    out.period = 2 * (last - first) / (out.crossings - 1);
    cs_sim_destroy(sim);
    return out;
}

static double discrete_period(double omega, double dt) { return 2 * PI * dt / (2 * asin(0.5 * omega * dt)); }

static void check(int pinned_column, int integrator, int32_t substeps, double tol)
{
    const double mu = pinned_column ? MASS : MASS / 2;
    const double omega = sqrt(K / mu), T = 2 * PI * sqrt(mu / K);
    const period_run r = run_oscillator(pinned_column, integrator, substeps, 40);
    const double rel = r.period / T - 1, shift = (omega * r.dt) * (omega * r.dt) / 24;
    print_message("%s, %s, dt = %.3g s: period %.7f s vs 2 pi sqrt(mu/k) = %.7f s (rel %.2e; (w dt)^2/24 = %.2e, "
                  "tolerance %.1e), %d crossings, extension %.5f .. %.5f m\n",
                  pinned_column ? "mu = m  " : "mu = m/2", integrator == CS_VELOCITY_VERLET ? "verlet" : "euler ", r.dt,
                  r.period, T, rel, shift, tol, r.crossings, r.amp_min, r.amp_max);
    assert_true(r.crossings >= 79);
    assert_true(fabs(rel) <= tol);
    /* Finer: the measured period is the discrete one, within 5e-6 relative (measured: 3e-7). */
    assert_true(fabs(r.period / discrete_period(omega, r.dt) - 1) < 5e-6);
    /* No damping anywhere: the amplitude stays AMP (Verlet's and Euler's energy errors are
     * bounded, O(omega dt) here). */
    assert_true(fabs(r.amp_max - AMP) < 0.02 * AMP + omega * r.dt * AMP);
    assert_true(fabs(-r.amp_min - AMP) < 0.02 * AMP + omega * r.dt * AMP);
}

/* The default step (30 substeps per frame): omega dt = 0.016 (mu = m/2) or 0.011 (mu = m), the
 * integrator's shift 1.0e-5 or 5.1e-6 relative. Tolerance against 2 pi sqrt(mu/k): 1e-4, ten
 * times the shift, room for the crossings' interpolation and float rounding (measured: -1.0e-5
 * and -5.3e-6, i.e. the shift itself). */
static void test_two_free_masses(void **unused)
{
    (void)unused;
    check(0, CS_VELOCITY_VERLET, 30, 1e-4);
    check(0, CS_SYMPLECTIC_EULER, 30, 1e-4);
}

static void test_one_end_pinned(void **unused)
{
    (void)unused;
    check(1, CS_VELOCITY_VERLET, 30, 1e-4);
    check(1, CS_SYMPLECTIC_EULER, 30, 1e-4);
}

/* One substep per frame: omega dt = 0.47, the period is short by 0.93%. The measured period
 * must match the discrete prediction 2 pi dt / (2 asin(omega dt / 2)) within 1e-3 relative and
 * be clearly apart from the continuous one, which shows the measurement resolves the shift. */
static void test_coarse_step_matches_discrete_period(void **unused)
{
    (void)unused;
    for (int integ = 0; integ < 2; integ++) {
        const double mu = MASS / 2, omega = sqrt(K / mu), T = 2 * PI * sqrt(mu / K);
        const period_run r = run_oscillator(0, integ, 1, 40);
        const double Td = discrete_period(omega, r.dt);
        print_message("coarse %s: dt = %.4g s: period %.6f s, discrete prediction %.6f s (rel %.2e), continuous %.6f s\n",
                      integ == CS_VELOCITY_VERLET ? "verlet" : "euler ", r.dt, r.period, Td, r.period / Td - 1, T);
        assert_true(fabs(r.period / Td - 1) < 1e-3);
        assert_true(T - r.period > 0.005 * T);
    }
}

int main(void)
{
    const struct CMUnitTest tests[] = {
        cmocka_unit_test(test_two_free_masses),
        cmocka_unit_test(test_one_end_pinned),
        cmocka_unit_test(test_coarse_step_matches_discrete_period),
    };
    return cmocka_run_group_tests(tests, NULL, NULL);
}
