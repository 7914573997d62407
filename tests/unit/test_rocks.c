/* test_rocks.c - adding, reading, changing and removing rocks; bad rocks are refused. */
#include "testkit.h"

static cs_sim *small_sim(void)
{
    cs_scene sc;
    cs_params p;
    cs_scene_default(&sc);
    cs_params_default(&p);
    p.integrator = CS_VELOCITY_VERLET; /* a step of a few ms: rocks move little in one */
    sc.nx = sc.ny = 8;
    return tk_sim(&sc, &p);
}

static void test_ids_count_up_and_are_never_reused(void **unused)
{
    (void)unused;
    cs_sim *sim = small_sim();
    const uint32_t a = tk_add_rock(sim, 0, 0, 3, 0.1f, 300);
    const uint32_t b = tk_add_rock(sim, 1, 0, 3, 0.1f, 300);
    const uint32_t c = tk_add_rock(sim, 2, 0, 3, 0.1f, 300);
    assert_int_equal(a, 1);
    assert_int_equal(b, 2);
    assert_int_equal(c, 3);
    assert_int_equal(cs_rock_remove(sim, b), CS_OK);
    assert_int_equal(cs_rock_count(sim), 2);
    assert_int_equal(tk_add_rock(sim, 3, 0, 3, 0.1f, 300), 4);
    /* In order of addition. */
    cs_rock r;
    assert_int_equal(cs_rock_at(sim, 0, &r), CS_OK);
    assert_int_equal(r.id, 1);
    assert_int_equal(cs_rock_at(sim, 1, &r), CS_OK);
    assert_int_equal(r.id, 3);
    assert_int_equal(cs_rock_at(sim, 2, &r), CS_OK);
    assert_int_equal(r.id, 4);
    assert_int_equal(cs_rock_at(sim, 3, &r), CS_E_RANGE);
    assert_int_equal(cs_rock_at(sim, -1, &r), CS_E_RANGE);
    assert_int_equal(cs_rock_get(sim, 2, &r), CS_E_NOT_FOUND);
    assert_string_equal(cs_sim_error_param(sim), "id");
    assert_int_equal(cs_rock_remove(sim, 2), CS_E_NOT_FOUND);
    assert_int_equal(cs_rock_set(sim, 99, &r.def), CS_E_NOT_FOUND);
    assert_int_equal(cs_rock_clear(sim), 3);
    assert_int_equal(cs_rock_count(sim), 0);
    assert_int_equal(tk_add_rock(sim, 0, 0, 3, 0.1f, 300), 5);
    cs_sim_destroy(sim);
}

static void test_read_back_and_mass(void **unused)
{
    (void)unused;
    cs_sim *sim = small_sim();
    cs_rock_def d;
    cs_rock_def_default(&d);
    d.position[0] = 0.5f, d.position[1] = -0.25f, d.position[2] = 4;
    d.velocity[0] = 1, d.angular_velocity[2] = 2;
    d.orientation[0] = 0, d.orientation[3] = 2; /* normalised to (0, 0, 0, 1) */
    d.radius = 0.2f, d.density = 1000;
    uint32_t id;
    assert_int_equal(cs_rock_add(sim, &d, &id), CS_OK);
    const cs_rock r = tk_rock(sim, id);
    assert_true(r.def.position[0] == 0.5f && r.def.position[1] == -0.25f && r.def.position[2] == 4.0f);
    assert_true(r.def.velocity[0] == 1.0f && r.def.angular_velocity[2] == 2.0f);
    assert_true(r.def.orientation[3] == 1.0f && r.def.orientation[0] == 0.0f);
    assert_false(r.def.kinematic);
    const double M = 1000 * 4.0 / 3.0 * TK_PI * 0.008;
    tk_assert_near(r.mass, M, 1e-4);
    tk_assert_near(r.inertia, 0.4 * M * 0.04, 1e-5);
    cs_sim_destroy(sim);
}

static void test_bad_rocks_are_refused(void **unused)
{
    (void)unused;
    cs_sim *sim = small_sim();
    const uint64_t h = cs_state_hash(sim);
    cs_rock_def d;
#define REFUSE(field_expr, param, code)                                                                \
    do {                                                                                               \
        cs_rock_def_default(&d);                                                                       \
        d.position[2] = 3;                                                                             \
        field_expr;                                                                                    \
        assert_int_equal(cs_rock_add(sim, &d, NULL), code);                                            \
        assert_string_equal(cs_sim_error_param(sim), param);                                           \
        assert_int_equal(cs_rock_count(sim), 0);                                                       \
        assert_true(cs_state_hash(sim) == h);                                                          \
    } while (0)
    REFUSE(d.position[0] = NAN, "position", CS_E_INVALID);
    REFUSE(d.position[1] = 2e6f, "position", CS_E_RANGE);
    REFUSE(d.velocity[2] = INFINITY, "velocity", CS_E_INVALID);
    REFUSE(d.angular_velocity[0] = -NAN, "angular_velocity", CS_E_INVALID);
    REFUSE(d.orientation[3] = 0, "orientation", CS_E_INVALID);
    REFUSE(d.orientation[1] = NAN, "orientation", CS_E_INVALID);
    REFUSE(d.radius = 0, "radius", CS_E_RANGE);
    REFUSE(d.radius = -0.1f, "radius", CS_E_RANGE);
    REFUSE(d.radius = NAN, "radius", CS_E_RANGE);
    REFUSE(d.density = 0, "density", CS_E_RANGE);
    REFUSE(d.density = INFINITY, "density", CS_E_RANGE);
#undef REFUSE
    assert_int_equal(cs_rock_add(sim, NULL, NULL), CS_E_INVALID);
    /* A refused change leaves the rock as it was. */
    const uint32_t id = tk_add_rock(sim, 0, 0, 3, 0.1f, 300);
    cs_rock before = tk_rock(sim, id);
    d = before.def;
    d.radius = -1;
    assert_int_equal(cs_rock_set(sim, id, &d), CS_E_RANGE);
    cs_rock after = tk_rock(sim, id);
    assert_memory_equal(&before, &after, sizeof before);
    cs_sim_destroy(sim);
}

/* Teleporting keeps the id; a kinematic rock moves with its velocity and ignores gravity. */
static void test_change_and_kinematic_motion(void **unused)
{
    (void)unused;
    cs_sim *sim = small_sim();
    const uint32_t id = tk_add_rock(sim, 0, 0, 3, 0.1f, 300);
    cs_rock r = tk_rock(sim, id);
    r.def.position[0] = 5;
    r.def.velocity[0] = 2;
    r.def.kinematic = true;
    assert_int_equal(cs_rock_set(sim, id, &r.def), CS_OK);
    cs_info info;
    cs_sim_info(sim, &info);
    tk_step(sim, 600);
    r = tk_rock(sim, id);
    assert_int_equal(r.id, id);
    tk_assert_near(r.def.position[0], 5 + 2 * 600 * info.dt, 1e-4);
    assert_true(r.def.position[2] == 3.0f);
    assert_true(r.def.velocity[2] == 0.0f);
    assert_true(r.def.kinematic);
    cs_sim_destroy(sim);
}

static void test_rock_limit(void **unused)
{
    (void)unused;
    cs_scene sc;
    cs_params p;
    cs_scene_default(&sc);
    cs_params_default(&p);
    sc.nx = sc.ny = 2;
    cs_sim *sim = tk_sim(&sc, &p);
    for (int k = 0; k < CS_MAX_ROCKS; k++) tk_add_rock(sim, (float)(k % 32), (float)(k / 32), 10, 0.1f, 300);
    assert_int_equal(cs_rock_add(sim, &(cs_rock_def){.radius = 0.1f, .density = 300, .orientation = {0, 0, 0, 1}}, NULL),
                     CS_E_LIMIT);
    assert_int_equal(cs_rock_count(sim), CS_MAX_ROCKS);
    cs_sim_destroy(sim);
}

int main(void)
{
    const struct CMUnitTest tests[] = {
        cmocka_unit_test(test_ids_count_up_and_are_never_reused),
        cmocka_unit_test(test_read_back_and_mass),
        cmocka_unit_test(test_bad_rocks_are_refused),
        cmocka_unit_test(test_change_and_kinematic_motion),
        cmocka_unit_test(test_rock_limit),
    };
    return cmocka_run_group_tests(tests, NULL, NULL);
}
