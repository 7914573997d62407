/* test_surface_force.c - surface contact on a flat cloth is one contact wherever the rock is.
 *
 * Every vertex of a flat horizontal cloth is pinned, gravity is off, and a rock (dynamic, at rest)
 * is placed with its contact sphere (radius R + contact_offset) reaching DEPTH below the cloth's
 * plane. The cloth's plane is the closest surface wherever the rock is, so the contact law gives
 * one normal force k_contact DEPTH, straight up: the analytic value the rock's acceleration
 * (white-box: what the force pass gave it) is checked against, within 0.5 %, with the rock over a
 * triangle, over each kind of edge (structural x, structural y, the diagonal), over a vertex, and
 * 0.1 mm beside each, on cloths of 8 to 128 vertices a side. A rule that took one contact per
 * triangle would give 2 k DEPTH over an edge and up to 6 over a vertex; one that dropped a contact
 * would give 0. The placement itself is allowed: the cloth comes DEPTH < contact_offset into the
 * rock's contact layer. The same holds with the cloth turned vertical (a curtain) and a rock in
 * front of it pushing along -y. */
#include "testkit.h"

#define DEPTH 0.004 /* m into the 0.01 m contact layer */
#define RADIUS 0.1f

/* The rock's normal force after a force pass, at the given offsets (in grid spacings) from vertex
 * (i0, j0). */
static void check_spot(cs_sim *sim, int32_t i0, int32_t j0, double di, double dj, const char *what, int vertical)
{
    const cs_state *s = &sim->state;
    const int32_t nx = sim->model.phys.nx, v0 = j0 * nx + i0, v1 = v0 + 1 + nx;
    /* spacings from the grid itself */
    const double hx = (double)s->x[v0 + 1] - s->x[v0];
    const double hw = vertical ? (double)s->z[v1] - s->z[v0 + 1] : (double)s->y[v1] - s->y[v0 + 1];
    cs_rock_def d;
    cs_rock_def_default(&d);
    d.radius = RADIUS;
    const float reach = (float)(RADIUS + sim->model.params.contact_offset - DEPTH);
    d.position[0] = (float)(s->x[v0] + di * hx);
    if (vertical) {
        d.position[1] = s->y[v0] - reach;
        d.position[2] = (float)(s->z[v0] + dj * hw);
    } else {
        d.position[1] = (float)(s->y[v0] + dj * hw);
        d.position[2] = s->z[v0] + reach;
    }
    uint32_t id;
    if (cs_rock_add(sim, &d, &id) != CS_OK) fail_msg("%s: %s", what, cs_sim_error(sim));
    const cs_rock_state *r = &sim->state.rocks[sim->state.n_rocks - 1];
    const cs_vec3 F = cs_scale(r->a, r->mass);
    /* What the placement really is in float: the distance from the centre to the plane. */
    const double dist = vertical ? (double)s->y[v0] - r->x.y : (double)r->x.z - s->z[v0];
    const double want = sim->model.params.k_contact * (RADIUS + sim->model.params.contact_offset - dist);
    const double normal = vertical ? -F.y : F.z;
    const double side = vertical ? hypot(F.x, F.z) : hypot(F.x, F.y);
    print_message("  %-28s normal %.6f N (k delta %.6f N, ratio %.6f), sideways %.2e N\n", what, normal, want,
                  normal / want, side);
    if (!(fabs(normal / want - 1) <= 0.005)) fail_msg("%s: normal force %.6f N, expected %.6f N", what, normal, want);
    assert_true(side <= 1e-4 * want);
    assert_int_equal(cs_rock_remove(sim, id), CS_OK);
}

static void flat_cloth(int n, int vertical)
{
    cs_scene sc;
    cs_params p;
    cs_scene_default(&sc);
    cs_params_default(&p);
    p.integrator = CS_VELOCITY_VERLET; /* the contact law's force (implicit_euler holds rocks otherwise: MODEL.md) */
    sc.nx = sc.ny = n;
    sc.orientation = vertical ? CS_VERTICAL : CS_HORIZONTAL;
    p.gravity[2] = 0.0f;
    p.ground = 0;
    assert_int_equal(p.contact_model, CS_CONTACT_SURFACE); /* the default */
    cs_sim *sim = tk_sim_serial(&sc, &p);
    int32_t *all = malloc(sizeof(int32_t) * (size_t)(n * n));
    assert_non_null(all);
    for (int32_t v = 0; v < n * n; v++) all[v] = v;
    assert_int_equal(cs_pin(sim, all, (size_t)(n * n), true), CS_OK);
    free(all);
    print_message("%d x %d, %s:\n", n, n, vertical ? "vertical" : "horizontal");
    const int32_t i0 = n / 2 - 1, j0 = n / 2 - 1;
    const double e = 1e-4 / (2.0 / (n - 1)); /* 0.1 mm in grid spacings */
    /* over a triangle (A, below the diagonal; B, above it), and beside */
    check_spot(sim, i0, j0, 0.62, 0.29, "over triangle A", vertical);
    check_spot(sim, i0, j0, 0.27, 0.71, "over triangle B", vertical);
    /* over edges: their midpoints exactly, then 0.1 mm to either side */
    check_spot(sim, i0, j0, 0.5, 0.0, "over a structural x edge", vertical);
    check_spot(sim, i0, j0, 0.5, e, "  0.1 mm beside it", vertical);
    check_spot(sim, i0, j0, 0.5, -e, "  0.1 mm beside it, the other way", vertical);
    check_spot(sim, i0, j0, 0.0, 0.5, "over a structural y edge", vertical);
    check_spot(sim, i0, j0, e, 0.5, "  0.1 mm beside it", vertical);
    check_spot(sim, i0, j0, 0.5, 0.5, "over a diagonal", vertical);
    check_spot(sim, i0, j0, 0.5 + e, 0.5 - e, "  0.1 mm beside it", vertical);
    check_spot(sim, i0, j0, 0.5 - e, 0.5 + e, "  0.1 mm beside it, the other way", vertical);
    /* over a vertex, then 0.1 mm off it along and between the edges that leave it */
    check_spot(sim, i0, j0, 0.0, 0.0, "over a vertex", vertical);
    check_spot(sim, i0, j0, e, 0.0, "  0.1 mm off it, +x", vertical);
    check_spot(sim, i0, j0, -e, -e, "  0.1 mm off it, -x -y", vertical);
    check_spot(sim, i0, j0, -e, e, "  0.1 mm off it, -x +y", vertical);
    check_spot(sim, i0, j0, e, -0.4 * e, "  0.1 mm off it, +x -y", vertical);
    cs_sim_destroy(sim);
}

static void test_one_contact_8(void **unused)
{
    (void)unused;
    flat_cloth(8, 0);
}

static void test_one_contact_33(void **unused)
{
    (void)unused;
    flat_cloth(33, 0);
}

static void test_one_contact_64(void **unused)
{
    (void)unused;
    flat_cloth(64, 0);
}

static void test_one_contact_128(void **unused)
{
    (void)unused;
    flat_cloth(128, 0);
}

static void test_one_contact_vertical(void **unused)
{
    (void)unused;
    flat_cloth(40, 1);
}

int main(void)
{
    const struct CMUnitTest tests[] = {
        cmocka_unit_test(test_one_contact_8),
        cmocka_unit_test(test_one_contact_33),
        cmocka_unit_test(test_one_contact_64),
        cmocka_unit_test(test_one_contact_128),
        cmocka_unit_test(test_one_contact_vertical),
    };
    return cmocka_run_group_tests(tests, NULL, NULL);
}
