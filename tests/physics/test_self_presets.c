/* test_self_presets.c - the scene presets that show self_collision (kernels/src/presets.c, PUT
 * /v1/scene {"preset"}): each really folds onto itself - with self_collision off its triangles
 * cross - and with it on none cross at any frame, under each integrator (sheet-crumple: below). The crossings are counted
 * by the tests' own geometry (tests/support/tk_geom.h), never by the product's contact code. */
#include "testkit.h"
#include "tk_geom.h"

/* Frames run: 1.5 s. Without self_collision the first crossings come at frames 22-33. */
#define FRAMES 90

/* The most crossing triangle pairs at any of FRAMES frames of preset k under the integrator, with
 * self_collision on or off. */
static long most_crossings(int k, int integrator, int self)
{
    cs_scene sc;
    cs_params p;
    cs_scene_default(&sc);
    cs_params_default(&p);
    cs_preset_scene(k, &sc, &p);
    p.integrator = integrator;
    p.self_collision = self;
    cs_sim *sim = tk_sim_serial(&sc, &p); /* one thread: ctest runs two tests at once on two cores */
    assert_int_equal(cs_preset_populate(sim, k), CS_OK);
    const size_t nf = 3 * (size_t)sc.nx * (size_t)sc.ny;
    float *xyz = malloc(sizeof(float) * nf);
    assert_non_null(xyz);
    long most = 0;
    for (int f = 0; f < FRAMES; f++) {
        assert_int_equal(cs_sim_step_frames(sim, 1), CS_OK);
        assert_int_equal(cs_read_positions(sim, xyz, nf), CS_OK);
        const long c = crossings(xyz, sc.nx, sc.ny);
        assert_true(c >= 0);
        most = c > most ? c : most;
        if (self && c > 0) break;
    }
    free(xyz);
    cs_sim_destroy(sim);
    return most;
}

/* Preset name folds with self_collision off, and with it on never crosses under implicit_euler (the
 * presets' own) and, with all, under the explicit integrators as well. */
static void check_preset(const char *name, int all)
{
    const int k = cs_preset_find(name);
    assert_true(k >= 0);
    const long off = most_crossings(k, CS_IMPLICIT_EULER, 0);
    print_message("%s, self_collision off (implicit_euler): up to %ld crossing pairs\n", name, off);
    assert_true(off > 0); /* it folds onto itself */
    static const int integrators[] = {CS_IMPLICIT_EULER, CS_VELOCITY_VERLET, CS_SYMPLECTIC_EULER};
    for (int q = 0; q < (all ? 3 : 1); q++) {
        const long on = most_crossings(k, integrators[q], 1);
        print_message("%s, self_collision on (integrator %d): up to %ld crossing pairs\n", name, integrators[q], on);
        assert_int_equal(on, 0);
    }
}

/* Under AddressSanitizer (some 20 times slower) none: physics.self_collision's fold runs the same
 * passes there. */
static void test_towel_on_line(void **unused)
{
    (void)unused;
    if (SANITIZED) skip();
    check_preset("towel-on-line", 1);
}

static void test_cloth_over_stone(void **unused)
{
    (void)unused;
    if (SANITIZED) skip();
    check_preset("cloth-over-stone", 1);
}

/* implicit_euler alone: the pile under the explicit integrators, a pass every substep, took 26 and
 * 34 s of one core for 1 s (build machine, 2026-12-08); physics.self_collision folds the same scene
 * at 16 x 16 under each of them. */
static void test_sheet_crumple(void **unused)
{
    (void)unused;
    if (SANITIZED) skip();
    check_preset("sheet-crumple", 0);
}

int main(void)
{
    const struct CMUnitTest tests[] = {
        cmocka_unit_test(test_towel_on_line),
        cmocka_unit_test(test_cloth_over_stone),
        cmocka_unit_test(test_sheet_crumple),
    };
    return cmocka_run_group_tests(tests, NULL, NULL);
}
