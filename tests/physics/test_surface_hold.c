/* test_surface_hold.c - with surface contact, tearing is the only way through the cloth.
 *
 * Rocks of 0.02 to 0.2 m and 300 to 3,000 kg/m^3 are dropped from up to 2 m, or thrown down at
 * 10 m/s, onto cloths of 8 x 8 to 128 x 128 pinned at their edges or only at their corners, on the
 * default material and contact, tearing off. At every frame the rock must still have cloth under
 * it: the vertical line through its centre meets the cloth's surface below the centre (a rock
 * through the cloth has the surface only above it). The rocks span a grid's spacing and more: 2 cm
 * is smaller than the spacing of every grid here from 64 x 64 down (3.2 cm at 64 x 64, 29 cm at
 * 8 x 8), and a 10 m/s rock moves 1.7 mm a substep. The heaviest ones reach the ground with the
 * cloth under them: held between rock and ground.
 *
 * The rock of the issue - 2,500 kg/m^3, R 0.15 m, dropped from 0.5 m onto the default 64 x 64
 * cloth - is followed more closely: no energy is gained over the run (all the model's dissipation
 * only takes energy away; the total counts the contacts' elastic energy), the cloth's surface never
 * comes more than a few millimetres into the rock's contact layer, and it is held above the
 * ground. The sample is lean (a few seconds of simulated time in all, under ASan too). The sweep
 * runs again under implicit_euler. */
#include "testkit.h"

/* Under AddressSanitizer (SANITIZED, testkit.h) every other case of the sweep and the first second
 * of the real rock's drop: the same code paths, within the suite's time. */

typedef struct drop_case {
    int n;          /* vertices a side */
    int pins;       /* cs_pins */
    float radius, density;
    float height;   /* of its lowest point above the cloth at release, m */
    float vz;       /* initial vertical velocity, m/s */
    float x, y;     /* where, m */
    double seconds; /* simulated */
    int integrator; /* cs_integrator (0 is velocity_verlet, not the default) */
} drop_case;

typedef struct drop_result {
    double max_depth;  /* deepest the surface came into the contact layer, m */
    double end_depth;  /* and at the last frame (at rest) */
    double e0, e_max;  /* total energy at release and at its highest after, J */
    double z_end, under_end;
} drop_result;

/* The case's cloth (default material and contact, tearing off), without a rock yet. */
static cs_sim *drop_cloth(const drop_case *c, cs_scene *sc, cs_params *p)
{
    cs_scene_default(sc);
    cs_params_default(p);
    p->integrator = c->integrator;
    sc->nx = sc->ny = c->n;
    sc->pins = c->pins;
    assert_true(p->tear_strain == 0.0f && p->contact_model == CS_CONTACT_SURFACE);
    cs_sim *sim = tk_sim(sc, p);
    assert_int_equal(cs_sim_set_threads(sim, c->n >= 64 ? 2 : 1), CS_OK);
    return sim;
}

static drop_result run_drop(const drop_case *c)
{
    cs_scene sc;
    cs_params p;
    cs_sim *sim = drop_cloth(c, &sc, &p);
    cs_rock_def d;
    cs_rock_def_default(&d);
    d.radius = c->radius;
    d.density = c->density;
    d.position[0] = c->x, d.position[1] = c->y;
    d.position[2] = sc.height + p.contact_offset + c->radius + c->height;
    d.velocity[2] = c->vz;
    uint32_t id;
    assert_int_equal(cs_rock_add(sim, &d, &id), CS_OK);
    cs_info info;
    cs_sim_info(sim, &info);
    drop_result res = {0, 0, 0, 0, 0, 0};
    cs_energy e;
    assert_int_equal(cs_energy_get(sim, &e), CS_OK);
    res.e0 = res.e_max = e.total;
    const int frames = (int)(c->seconds * 60 + 0.5);
    const cs_rock_state *r = &sim->state.rocks[0];
    for (int f = 1; f <= frames; f++) {
        tk_step(sim, info.substeps);
        double lo = 0, hi = 0;
        const int has = tk_surface_on_line(sim, 2, r->x.x, r->x.y, &lo, &hi);
        if (!has || !(lo < r->x.z))
            fail_msg("%d x %d, R %.2f, %.0f kg/m^3: at %.3f s the rock (z %.4f) has %s", c->n, c->n, (double)c->radius,
                     (double)c->density, f / 60.0, (double)r->x.z, has ? "the cloth only above it" : "no cloth under it");
        /* the deepest contact: what a placement check would see */
        double depth = 0;
        for (int32_t v = 0; v < sim->state.n; v++) {
            cs_ring g;
            cs_surface_out o;
            const int32_t i = v % c->n, j = v / c->n;
            for (int q = 0; q < CS_RING; q++) {
                int32_t ii = i + cs_ring_di(q), jj = j + cs_ring_dj(q);
                if (ii < 0 || ii >= c->n || jj < 0 || jj >= c->n) ii = i, jj = j;
                const int32_t k = jj * c->n + ii;
                g.x[q] = cs_v3(sim->state.x[k], sim->state.y[k], sim->state.z[k]);
            }
            g.v = g.ro = cs_v3(0, 0, 0);
            g.faces = cs_ring_faces(sim->state.L0, c->n, c->n, i, j);
            cs_surface_gather(&g, r, &sim->model.phys, cs_v3(0, 0, 0), 0.0f, &o);
            if (o.depth > depth) depth = o.depth;
        }
        if (depth > res.max_depth) res.max_depth = depth;
        if (f == frames) res.end_depth = depth;
        assert_int_equal(cs_energy_get(sim, &e), CS_OK);
        if (e.total > res.e_max) res.e_max = e.total;
        if (f == frames) res.z_end = r->x.z, res.under_end = lo;
    }
    print_message("%3d x %-3d %-7s R %.2f m %4.0f kg/m^3 (%6.2f kg) from %.1f m at %5.1f m/s: %3d substeps, rock ends at z "
                  "%.3f over cloth at %.3f, deepest %.2f mm into the layer (%.2f at the end), energy %.2f J -> at most %+.4f J\n",
                  c->n, c->n, c->pins == CS_PINS_EDGES ? "edges" : "corners", (double)c->radius, (double)c->density,
                  (double)r->mass, (double)c->height, (double)c->vz, (int)info.substeps, res.z_end, res.under_end,
                  1e3 * res.max_depth, 1e3 * res.end_depth, res.e0, res.e_max - res.e0);
    cs_sim_destroy(sim);
    return res;
}

/* The same cloth without the rock, over the same frames: the most its total energy rises above
 * its start, J (implicit_euler's own, which the rock's contact must not add to). */
static double cloth_gain(const drop_case *c)
{
    cs_scene sc;
    cs_params p;
    cs_sim *sim = drop_cloth(c, &sc, &p);
    cs_info info;
    cs_sim_info(sim, &info);
    cs_energy e;
    assert_int_equal(cs_energy_get(sim, &e), CS_OK);
    const double e0 = e.total;
    double most = 0;
    const int frames = (int)(c->seconds * 60 + 0.5);
    for (int f = 1; f <= frames; f++) {
        tk_step(sim, info.substeps);
        assert_int_equal(cs_energy_get(sim, &e), CS_OK);
        if (e.total - e0 > most) most = e.total - e0;
    }
    cs_sim_destroy(sim);
    return most;
}

/* The sweep: every rock ends, and stays throughout, above the cloth under it. */
static void test_sweep_never_through(void **unused)
{
    (void)unused;
    const drop_case cases[] = {
        {8, CS_PINS_CORNERS, 0.02f, 3000, 2.0f, 0, 0.05f, 0.1f, 1.5, 0},  /* 10 g, far smaller than the 29 cm grid */
        {8, CS_PINS_EDGES, 0.2f, 3000, 2.0f, 0, 0, 0, 2.0, 0},            /* 100 kg: on the ground, under it the cloth */
        {16, CS_PINS_EDGES, 0.15f, 2500, 1.0f, 0, 0.2f, -0.1f, 1.5, 0},
        {24, CS_PINS_CORNERS, 0.08f, 3000, 0.0f, -10.0f, 0.1f, 0, 1.0, 0}, /* thrown down at 10 m/s */
        {32, CS_PINS_CORNERS, 0.2f, 300, 2.0f, 0, 0, 0.15f, 1.5, 0},
        {48, CS_PINS_EDGES, 0.1f, 1000, 1.0f, 0, -0.3f, 0.2f, 1.2, 0},
        {64, CS_PINS_EDGES, 0.02f, 2500, 0.0f, -10.0f, 0.01f, 0.02f, 0.6, 0}, /* smaller than the 3.2 cm grid, 10 m/s */
        {128, CS_PINS_EDGES, 0.05f, 3000, 0.3f, 0, 0.1f, 0.1f, 0.4, 0},
    };
    for (size_t k = 0; k < sizeof cases / sizeof cases[0]; k += SANITIZED ? 2 : 1) run_drop(&cases[k]);
}

/* The same sweep under implicit_euler (its rock contact: implicit.h, "rock contact"): every rock
 * stays above the cloth under it, and the contact gains no energy: the total rises at most 0.5 %
 * of the start above what the same cloth without the rock gains by itself. (The solver's own: a
 * cloth released flat, whose Newton stops at a few % of residual while it is slack - MODEL.md,
 * "Known gaps" - rises by up to 0.68 J in the 128 x 128 case; measured on 2026-12-05: with the
 * rock, none in eight cases and that same 0.68 J of 32.7 J in the 128 x 128 one.) */
static void test_sweep_never_through_implicit(void **unused)
{
    (void)unused;
    const drop_case cases[] = {
        {8, CS_PINS_CORNERS, 0.02f, 3000, 2.0f, 0, 0.05f, 0.1f, 1.5, CS_IMPLICIT_EULER},
        {8, CS_PINS_EDGES, 0.2f, 3000, 2.0f, 0, 0, 0, 2.0, CS_IMPLICIT_EULER},
        {16, CS_PINS_EDGES, 0.15f, 2500, 1.0f, 0, 0.2f, -0.1f, 1.5, CS_IMPLICIT_EULER},
        {24, CS_PINS_CORNERS, 0.08f, 3000, 0.0f, -10.0f, 0.1f, 0, 1.0, CS_IMPLICIT_EULER},
        {32, CS_PINS_CORNERS, 0.2f, 300, 2.0f, 0, 0, 0.15f, 1.5, CS_IMPLICIT_EULER},
        {48, CS_PINS_EDGES, 0.1f, 1000, 1.0f, 0, -0.3f, 0.2f, 1.2, CS_IMPLICIT_EULER},
        {64, CS_PINS_EDGES, 0.02f, 2500, 0.0f, -10.0f, 0.01f, 0.02f, 0.6, CS_IMPLICIT_EULER},
        {128, CS_PINS_EDGES, 0.05f, 3000, 0.3f, 0, 0.1f, 0.1f, 0.4, CS_IMPLICIT_EULER},
        {64, CS_PINS_EDGES, 0.15f, 2500, 0.5f, 0, 0, 0, 2.5, CS_IMPLICIT_EULER},
    };
    for (size_t k = 0; k < sizeof cases / sizeof cases[0]; k += SANITIZED ? 3 : 1) {
        const drop_result r = run_drop(&cases[k]);
        const double own = cloth_gain(&cases[k]);
        if (own > 0) print_message("    the cloth alone gains %.4f J\n", own);
        assert_true(r.e_max <= r.e0 + own + 5e-3 * fabs(r.e0));
    }
}

/* The rock on the default cloth: held, the surface within a few millimetres of the rock's
 * contact sphere, no energy gained. */
static void test_default_cloth_holds_a_real_rock(void **unused)
{
    (void)unused;
    const drop_case c = {64, CS_PINS_EDGES, 0.15f, 2500, 0.5f, 0, 0, 0, SANITIZED ? 1.0 : 2.5, 0};
    const drop_result r = run_drop(&c);
    /* At rest the surface lies within 3 mm of the contact sphere (measured: 0.2 mm; the
     * velocity-level part holds the weight, the penalty only the last fraction of a millimetre).
     * During the first impact (3.1 m/s) the surface comes at most 1 cm into the rock itself, past
     * the 1 cm contact layer (measured: 7.9 mm; 2.9 mm with k_contact 2000). */
    if (!SANITIZED) assert_true(r.end_depth < 0.003); /* at rest by 2.5 s */
    assert_true(r.max_depth < 0.01 + 0.01);
    /* damping, friction and the velocity-level contact only take energy away: the total never
     * rises above its start by more than float rounding of a 600 J sum (measured: 0) */
    assert_true(r.e_max <= r.e0 + 1e-4 * fabs(r.e0));
    /* it is still in the cloth's keeping, above the ground */
    assert_true(r.z_end > c.radius);
}

int main(void)
{
    const struct CMUnitTest tests[] = {
        cmocka_unit_test(test_sweep_never_through),
        cmocka_unit_test(test_default_cloth_holds_a_real_rock),
        cmocka_unit_test(test_sweep_never_through_implicit),
    };
    return cmocka_run_group_tests(tests, NULL, NULL);
}
