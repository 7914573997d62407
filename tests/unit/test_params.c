/* test_params.c - the parameter table against the model's list (kernels/MODEL.md), and its checks. */
#include "testkit.h"

/* Every tunable of the model that belongs to the engine, with the contact model's
 * (contact_model, max_depenetration_speed, placement_overlap) (time_scale, max_speed,
 * auto_drop_interval, auto_drop_max, seed and checkpoint_interval are the daemon's: the server's
 * settings table and its test hold them). */
static const char *const design_names[] = {
    "nx", "ny", "size_x", "size_y", "height", "orientation", "pins", "areal_density", "gravity", "wind",
    "k_structural", "k_shear", "k_bend", "c_spring", "drag", "plastic_yield", "tear_strain", "plastic_rate",
    "k_contact", "c_contact", "c_tangent", "mu", "contact_offset", "friction_model", "contact_model",
    "max_depenetration_speed", "placement_overlap", "k_rock", "c_rock", "mu_rock",
    "ground", "ground_z", "frame_rate", "substeps", "max_substeps", "auto_substeps", "stability_safety",
    "integrator", "grab_speed", "implicit_substeps", "solver_iterations", "solver_tolerance", "cg_iterations",
    "self_collision", "self_thickness"};

static void test_table_has_every_design_parameter_once(void **unused)
{
    (void)unused;
    const size_t n = sizeof design_names / sizeof design_names[0];
    assert_int_equal(cs_param_count(), n);
    for (size_t i = 0; i < n; i++) {
        const cs_param_info *p = cs_param_find(design_names[i]);
        if (!p) fail_msg("parameter %s missing", design_names[i]);
        for (size_t k = 0; k < cs_param_count(); k++)
            if (cs_param_at(k) != p) assert_string_not_equal(cs_param_at(k)->name, design_names[i]);
    }
    assert_null(cs_param_find("no_such_parameter"));
    assert_null(cs_param_find(NULL));
    assert_null(cs_param_at(cs_param_count()));
}

static void test_rows_are_complete_and_defaults_valid(void **unused)
{
    (void)unused;
    char why[200];
    for (size_t i = 0; i < cs_param_count(); i++) {
        const cs_param_info *p = cs_param_at(i);
        assert_true(strlen(p->unit) > 0);
        assert_true(strlen(p->help) > 10);
        assert_true(p->min <= p->max);
        if (cs_param_check(p, p->def, why, sizeof why) != 0) fail_msg("default of %s refused: %s", p->name, why);
        if (p->type == CS_T_ENUM) {
            assert_non_null(p->choices);
            assert_true(p->min == 0 && p->max == cs_param_choice_count(p) - 1);
        } else {
            assert_null(p->choices);
        }
    }
}

static void test_scene_rows_are_scene_kind(void **unused)
{
    (void)unused;
    static const char *const scene[] = {"nx", "ny", "size_x", "size_y", "height", "orientation", "pins", "areal_density"};
    for (size_t i = 0; i < cs_param_count(); i++) {
        const cs_param_info *p = cs_param_at(i);
        int is_scene = 0;
        for (size_t k = 0; k < 8; k++) is_scene |= strcmp(p->name, scene[k]) == 0;
        assert_int_equal(p->kind, is_scene ? CS_KIND_SCENE : CS_KIND_LIVE);
    }
    assert_string_equal(cs_param_kind_name(CS_KIND_SCENE), "scene");
    assert_string_equal(cs_param_kind_name(CS_KIND_LIVE), "live");
    assert_string_equal(cs_param_type_name(CS_T_VEC3), "vec3");
}

/* The model's choices and the defaults it names. */
static void test_choices_and_named_defaults(void **unused)
{
    (void)unused;
    assert_int_equal(cs_param_choice(cs_param_find("integrator"), "velocity_verlet"), CS_VELOCITY_VERLET);
    assert_int_equal(cs_param_choice(cs_param_find("integrator"), "symplectic_euler"), CS_SYMPLECTIC_EULER);
    assert_int_equal(cs_param_choice(cs_param_find("integrator"), "implicit_euler"), CS_IMPLICIT_EULER);
    assert_int_equal(cs_param_choice(cs_param_find("friction_model"), "coulomb_viscous"), CS_FRICTION_COULOMB_VISCOUS);
    assert_int_equal(cs_param_choice(cs_param_find("friction_model"), "resultant"), CS_FRICTION_RESULTANT);
    assert_int_equal(cs_param_choice(cs_param_find("orientation"), "vertical"), CS_VERTICAL);
    assert_int_equal(cs_param_choice(cs_param_find("pins"), "corners"), CS_PINS_CORNERS);
    assert_int_equal(cs_param_choice(cs_param_find("pins"), "edges"), CS_PINS_EDGES);
    assert_int_equal(cs_param_choice(cs_param_find("pins"), "top-edge"), CS_PINS_TOP_EDGE);
    assert_int_equal(cs_param_choice(cs_param_find("pins"), "none"), CS_PINS_NONE);
    assert_int_equal(cs_param_choice(cs_param_find("pins"), "Edges"), -1);
    assert_int_equal(cs_param_choice(cs_param_find("k_bend"), "edges"), -1);

    cs_scene s;
    cs_params p;
    cs_scene_default(&s);
    cs_params_default(&p);
    assert_int_equal(s.nx, 64);
    assert_int_equal(s.ny, 64);
    assert_int_equal(s.pins, CS_PINS_EDGES);
    assert_int_equal(p.integrator, CS_IMPLICIT_EULER);
    /* the CPU's is the table's; CUDA's velocity_verlet (MODEL.md, "Decisions the model leaves open") */
    assert_int_equal(cs_params_default_integrator("cpu"), CS_IMPLICIT_EULER);
    assert_int_equal(cs_params_default_integrator("cuda"), CS_VELOCITY_VERLET);
    assert_true(p.frame_rate == 60.0f);
    assert_int_equal(p.auto_substeps, 1);
    assert_true(p.plastic_yield == 0.0f && p.tear_strain == 0.0f && p.plastic_rate == 0.0f);
    assert_true(p.gravity[0] == 0.0f && p.gravity[1] == 0.0f && p.gravity[2] < -9.0f);
    assert_true(p.substeps <= 30);
    const char *bad = NULL;
    char why[200];
    assert_int_equal(cs_scene_validate(&s, &bad, why, sizeof why), 0);
    assert_int_equal(cs_params_validate(&p, &bad, why, sizeof why), 0);
}

static void test_check_refuses_bad_values(void **unused)
{
    (void)unused;
    char why[200];
    const cs_param_info *k = cs_param_find("k_structural"), *nx = cs_param_find("nx");
    const cs_param_info *g = cs_param_find("ground"), *in = cs_param_find("integrator");
    const cs_param_info *grav = cs_param_find("gravity");
    const double bad_float[] = {NAN, INFINITY, -INFINITY, -1.0, 2e9, 1e-50};
    for (size_t i = 0; i < sizeof bad_float / sizeof bad_float[0]; i++) {
        why[0] = '\0';
        assert_int_equal(cs_param_check(k, &bad_float[i], why, sizeof why), -1);
        assert_non_null(strstr(why, "k_structural"));
    }
    const double bad_nx[] = {1, 4097, 64.5, NAN};
    for (size_t i = 0; i < 4; i++) assert_int_equal(cs_param_check(nx, &bad_nx[i], why, sizeof why), -1);
    const double two = 2, half = 0.5, five = 5;
    assert_int_equal(cs_param_check(g, &two, why, sizeof why), -1);
    assert_int_equal(cs_param_check(g, &half, why, sizeof why), -1);
    assert_int_equal(cs_param_check(in, &five, why, sizeof why), -1);
    assert_int_equal(cs_param_check(in, &half, why, sizeof why), -1);
    const double vec_bad[3] = {0, NAN, -9.81}, vec_far[3] = {0, 0, -2000}, vec_ok[3] = {1, 2, -3};
    assert_int_equal(cs_param_check(grav, vec_bad, why, sizeof why), -1);
    assert_int_equal(cs_param_check(grav, vec_far, why, sizeof why), -1);
    assert_int_equal(cs_param_check(grav, vec_ok, why, sizeof why), 0);
    const double lo = 2, hi = 4096, zero = 0;
    assert_int_equal(cs_param_check(nx, &lo, why, sizeof why), 0);
    assert_int_equal(cs_param_check(nx, &hi, why, sizeof why), 0);
    assert_int_equal(cs_param_check(k, &zero, why, sizeof why), 0);
}

static void test_set_and_get_round_trip_and_refusal_changes_nothing(void **unused)
{
    (void)unused;
    char why[200];
    cs_scene s;
    cs_params p;
    cs_scene_default(&s);
    cs_params_default(&p);
    const cs_param_info *k = cs_param_find("k_shear"), *wind = cs_param_find("wind"), *nx = cs_param_find("nx");
    const double v = 123.5, w[3] = {1.5, -2.0, 0.25}, n = 17;
    assert_int_equal(cs_param_set(k, CS_PARAM_BASE(k, &s, &p), &v, why, sizeof why), 0);
    assert_true(p.k_shear == 123.5f);
    assert_true(cs_param_get(k, &p, 0) == 123.5);
    assert_int_equal(cs_param_set(wind, &p, w, why, sizeof why), 0);
    assert_true(p.wind[0] == 1.5f && p.wind[1] == -2.0f && p.wind[2] == 0.25f);
    assert_true(cs_param_get(wind, &p, 1) == -2.0);
    assert_int_equal(cs_param_set(nx, CS_PARAM_BASE(nx, &s, &p), &n, why, sizeof why), 0);
    assert_int_equal(s.nx, 17);
    const cs_params before = p;
    const double nan = NAN;
    assert_int_equal(cs_param_set(k, &p, &nan, why, sizeof why), -1);
    assert_memory_equal(&before, &p, sizeof p);
}

static void test_validate_names_the_bad_field(void **unused)
{
    (void)unused;
    char why[200];
    const char *bad = NULL;
    cs_params p;
    cs_params_default(&p);
    p.substeps = 50;
    p.max_substeps = 40;
    assert_int_equal(cs_params_validate(&p, &bad, why, sizeof why), -1);
    assert_string_equal(bad, "substeps");
    cs_params_default(&p);
    p.mu = -0.5f;
    assert_int_equal(cs_params_validate(&p, &bad, why, sizeof why), -1);
    assert_string_equal(bad, "mu");
    cs_scene s;
    cs_scene_default(&s);
    s.size_y = NAN;
    assert_int_equal(cs_scene_validate(&s, &bad, why, sizeof why), -1);
    assert_string_equal(bad, "size_y");
    cs_scene_default(&s);
    s.orientation = 7;
    assert_int_equal(cs_scene_validate(&s, &bad, why, sizeof why), -1);
    assert_string_equal(bad, "orientation");
}

/* A change of parameters past the memory limit (cs_sim_set_memory_limit: implicit_euler's
 * workspace, self_collision's) is CS_E_LIMIT naming the parameter and changes nothing; the same
 * change fits once the limit allows what cs_scene_memory counts for it, and a change that costs
 * less always goes through. */
static void test_params_past_the_memory_limit(void **unused)
{
    (void)unused;
    cs_scene sc;
    cs_params vv, im, both, now;
    cs_scene_default(&sc);
    cs_params_default(&vv);
    vv.integrator = CS_VELOCITY_VERLET;
    sc.nx = sc.ny = 64;
    im = vv, im.integrator = CS_IMPLICIT_EULER;
    both = im, both.self_collision = true;
    cs_sim *sim = tk_sim(&sc, &vv);
    const int32_t rocks = cs_sim_rock_limit(sim);
    uint64_t b_vv, b_im, b_both;
    assert_int_equal(cs_scene_memory(&sc, &vv, rocks, &b_vv), CS_OK);
    assert_int_equal(cs_scene_memory(&sc, &im, rocks, &b_im), CS_OK);
    assert_int_equal(cs_scene_memory(&sc, &both, rocks, &b_both), CS_OK);
    assert_true(b_vv < b_im && b_im < b_both);
    assert_int_equal(cs_sim_set_memory_limit(sim, b_im - 1, NULL, NULL), CS_OK);
    const uint64_t h0 = cs_state_hash(sim);
    assert_int_equal(cs_sim_set_params(sim, &im), CS_E_LIMIT);
    assert_string_equal(cs_sim_error_param(sim), "integrator");
    cs_sim_params(sim, &now);
    assert_int_equal(now.integrator, CS_VELOCITY_VERLET);
    assert_true(cs_state_hash(sim) == h0);
    assert_int_equal(cs_sim_set_memory_limit(sim, b_im, NULL, NULL), CS_OK);
    assert_int_equal(cs_sim_set_params(sim, &im), CS_OK);
    tk_step(sim, 2);
    assert_int_equal(cs_sim_set_params(sim, &both), CS_E_LIMIT);
    assert_string_equal(cs_sim_error_param(sim), "self_collision");
    cs_sim_params(sim, &now);
    assert_false(now.self_collision);
    /* back to velocity_verlet costs less: it goes through below the limit too */
    assert_int_equal(cs_sim_set_memory_limit(sim, b_vv, NULL, NULL), CS_OK);
    assert_int_equal(cs_sim_set_params(sim, &vv), CS_OK);
    cs_sim_destroy(sim);
}

int main(void)
{
    const struct CMUnitTest tests[] = {
        cmocka_unit_test(test_table_has_every_design_parameter_once),
        cmocka_unit_test(test_rows_are_complete_and_defaults_valid),
        cmocka_unit_test(test_scene_rows_are_scene_kind),
        cmocka_unit_test(test_choices_and_named_defaults),
        cmocka_unit_test(test_check_refuses_bad_values),
        cmocka_unit_test(test_params_past_the_memory_limit),
        cmocka_unit_test(test_set_and_get_round_trip_and_refusal_changes_nothing),
        cmocka_unit_test(test_validate_names_the_bad_field),
    };
    return cmocka_run_group_tests(tests, NULL, NULL);
}
