/* test_guard.c - the stability guard's formula on hand-computed cases, and its decisions. */
#include "testkit.h"

/* The model's formula as written (kernels/MODEL.md): dt_i = (sqrt(C^2 + 2 m K) - C) / K. */
static double design_dt(double m, double K, double C) { return (sqrt(C * C + 2 * m * K) - C) / K; }

/* The vertex contact model (one contact per vertex: k_contact, c_contact + c_tangent). */
static void small_scene(cs_scene *sc, cs_params *p, int nx, int ny)
{
    cs_scene_default(sc);
    cs_params_default(p);
    p->integrator = CS_VELOCITY_VERLET; /* the guard bounds the explicit integrators' substeps */
    sc->nx = nx, sc->ny = ny, sc->size_x = 1, sc->size_y = 1, sc->areal_density = 1;
    p->k_structural = 100, p->k_shear = 10, p->k_bend = 1, p->k_contact = 50;
    p->c_spring = 0.1f, p->c_contact = 0.2f, p->c_tangent = 0.3f, p->drag = 2;
    p->contact_model = CS_CONTACT_VERTEX;
    p->substeps = 1, p->max_substeps = 100000;
    p->stability_safety = 0.5f;
}

/* 2 x 2: every vertex has 2 structural springs, 1 shear, no bend; m = 1/4. */
static void test_two_by_two(void **unused)
{
    (void)unused;
    cs_scene sc;
    cs_params p;
    small_scene(&sc, &p, 2, 2);
    cs_sim *sim = tk_sim(&sc, &p);
    const double m = 0.25, K = 2 * 100 + 10 + 50, C = 3 * 0.1 + (0.2 + 0.3) + m * 2 / 2;
    cs_info info;
    cs_sim_info(sim, &info);
    tk_assert_near(info.dt_max, 0.5 * design_dt(m, K, C), 1e-9);
    assert_int_equal(info.substeps, (int)ceil(1.0 / (60.0 * info.dt_max)));
    tk_assert_near(info.dt, 1.0 / (60.0 * info.substeps), 1e-12);
    cs_sim_destroy(sim);
}

/* 5 x 5: the centre vertex has all 12 springs, the stiffest combination. */
static void test_interior_vertex_limits(void **unused)
{
    (void)unused;
    cs_scene sc;
    cs_params p;
    small_scene(&sc, &p, 5, 5);
    cs_sim *sim = tk_sim(&sc, &p);
    const double m = 1.0 / 25, K = 4 * 100 + 4 * 10 + 4 * 1 + 50, C = 12 * 0.1 + (0.2 + 0.3) + m * 2 / 2;
    cs_info info;
    cs_sim_info(sim, &info);
    tk_assert_near(info.dt_max, 0.5 * design_dt(m, K, C), 1e-9);
    cs_sim_destroy(sim);
}

/* Surface contact: a rock's contacts can weigh 6 at a vertex (six triangles), against a far
 * heavier body, so the guard counts 3 k_contact and 3 (c_contact + c_tangent), and half a contact
 * more for the ground. */
static void test_surface_contact_counts_more(void **unused)
{
    (void)unused;
    cs_scene sc;
    cs_params p;
    small_scene(&sc, &p, 5, 5);
    p.contact_model = CS_CONTACT_SURFACE;
    const double m = 1.0 / 25;
    for (int ground = 0; ground <= 1; ground++) {
        p.ground = ground;
        cs_sim *sim = tk_sim(&sc, &p);
        const double w = ground ? 3.5 : 3.0;
        const double K = 4 * 100 + 4 * 10 + 4 * 1 + w * 50, C = 12 * 0.1 + w * (0.2 + 0.3) + m * 2 / 2;
        cs_info info;
        cs_sim_info(sim, &info);
        tk_assert_near(info.dt_max, 0.5 * design_dt(m, K, C), 1e-9);
        cs_sim_destroy(sim);
    }
}

/* A dynamic rock on stiff rock contact sets the limit, the same whatever its mass (rock contacts
 * scale with it: k_rock M, c_rock M); a kinematic one never does. */
static void test_rocks_limit(void **unused)
{
    (void)unused;
    cs_scene sc;
    cs_params p;
    small_scene(&sc, &p, 5, 5);
    p.k_rock = 1e6f, p.c_rock = 10;
    cs_sim *sim = tk_sim(&sc, &p);
    cs_info before, after;
    cs_sim_info(sim, &before);
    cs_rock_def d;
    cs_rock_def_default(&d);
    d.position[2] = 5;
    d.radius = 0.01f, d.density = 100;
    d.kinematic = true;
    uint32_t kid;
    assert_int_equal(cs_rock_add(sim, &d, &kid), CS_OK);
    cs_sim_info(sim, &after);
    tk_assert_near(after.dt_max, before.dt_max, 0);
    d.kinematic = false;
    d.position[1] = 0.5f; /* clear of the kinematic one */
    uint32_t id;
    assert_int_equal(cs_rock_add(sim, &d, &id), CS_OK);
    cs_sim_info(sim, &after);
    const double M = 100 * 4.0 / 3.0 * TK_PI * 1e-6;
    tk_assert_near(after.dt_max, 0.5 * design_dt(M, 1e6 * M, 10 * M), 1e-6 * after.dt_max);
    assert_true(after.substeps > before.substeps);
    /* A rock 1000 times heavier: the same limit. */
    d.density = 1e5f;
    d.position[0] = 0.5f; /* clear of the other */
    uint32_t heavy;
    assert_int_equal(cs_rock_add(sim, &d, &heavy), CS_OK);
    cs_info with_heavy;
    cs_sim_info(sim, &with_heavy);
    tk_assert_near(with_heavy.dt_max, after.dt_max, 1e-6 * after.dt_max);
    assert_int_equal(cs_rock_remove(sim, heavy), CS_OK);
    /* Removing it gives the cloth's limit back. */
    assert_int_equal(cs_rock_remove(sim, id), CS_OK);
    cs_sim_info(sim, &after);
    tk_assert_near(after.dt_max, before.dt_max, 0);
    assert_int_equal(after.substeps, before.substeps);
    cs_sim_destroy(sim);
}

/* The requested substeps stay when they are enough; the guard only ever raises them. */
static void test_requested_substeps_kept_when_stable(void **unused)
{
    (void)unused;
    cs_scene sc;
    cs_params p;
    small_scene(&sc, &p, 5, 5);
    p.substeps = 5000;
    cs_sim *sim = tk_sim(&sc, &p);
    cs_info info;
    cs_sim_info(sim, &info);
    assert_int_equal(info.substeps, 5000);
    cs_sim_destroy(sim);
}

static void test_refusals(void **unused)
{
    (void)unused;
    cs_scene sc;
    cs_params p;
    small_scene(&sc, &p, 5, 5);
    p.substeps = 60;
    cs_sim *sim = tk_sim(&sc, &p);
    cs_info info;
    cs_sim_info(sim, &info);
    /* auto_substeps off: the same change is refused rather than absorbed. */
    p.auto_substeps = 0;
    p.k_structural = 1e6f;
    assert_int_equal(cs_sim_set_params(sim, &p), CS_E_UNSTABLE);
    assert_non_null(strstr(cs_sim_error(sim), "auto_substeps"));
    /* Too many substeps needed for max_substeps. */
    p.auto_substeps = 1;
    p.max_substeps = 100;
    assert_int_equal(cs_sim_set_params(sim, &p), CS_E_UNSTABLE);
    assert_non_null(strstr(cs_sim_error(sim), "max_substeps"));
    cs_params now;
    cs_sim_params(sim, &now);
    assert_true(now.k_structural == 100.0f);
    /* A creation that needs too many substeps is refused too. */
    cs_sim *other = NULL;
    char err[256];
    assert_int_equal(cs_sim_create(&sc, &p, "cpu", &other, err, sizeof err), CS_E_UNSTABLE);
    assert_null(other);
    assert_non_null(strstr(err, "max_substeps"));
    cs_sim_destroy(sim);
}

int main(void)
{
    const struct CMUnitTest tests[] = {
        cmocka_unit_test(test_two_by_two),
        cmocka_unit_test(test_interior_vertex_limits),
        cmocka_unit_test(test_surface_contact_counts_more),
        cmocka_unit_test(test_rocks_limit),
        cmocka_unit_test(test_requested_substeps_kept_when_stable),
        cmocka_unit_test(test_refusals),
    };
    return cmocka_run_group_tests(tests, NULL, NULL);
}
