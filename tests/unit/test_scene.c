/* test_scene.c - building the grid: positions, springs, rest lengths, pin presets, memory. */
#include <malloc.h>
#include <stdint.h>
#include <string.h>
#include "testkit.h"

static cs_sim *grid(int nx, int ny, float sx, float sy, float height, int orientation, int pins)
{
    cs_scene sc;
    cs_params p;
    tk_quiet(&sc, &p);
    sc.nx = nx, sc.ny = ny, sc.size_x = sx, sc.size_y = sy, sc.height = height;
    sc.orientation = orientation;
    sc.pins = pins;
    return tk_sim(&sc, &p);
}

/* A 3 x 3 cloth, 2 m by 4 m at height 1: vertex (i, j) at (-1 + i, -2 + 2 j, 1), or hanging at
 * (-1 + i, 0, 1 - 2 + 2 j). */
static void test_positions_horizontal_and_vertical(void **unused)
{
    (void)unused;
    for (int o = 0; o < 2; o++) {
        cs_sim *sim = grid(3, 3, 2.0f, 4.0f, 1.0f, o, CS_PINS_NONE);
        float *x = tk_positions(sim);
        for (int j = 0; j < 3; j++) {
            for (int i = 0; i < 3; i++) {
                const float *q = &x[3 * (j * 3 + i)];
                assert_float_equal(q[0], -1.0f + i, 1e-6);
                if (o == CS_HORIZONTAL) {
                    assert_float_equal(q[1], -2.0f + 2.0f * j, 1e-6);
                    assert_float_equal(q[2], 1.0f, 1e-6);
                } else {
                    assert_float_equal(q[1], 0.0f, 0);
                    assert_float_equal(q[2], -1.0f + 2.0f * j, 1e-6);
                }
            }
        }
        free(x);
        cs_sim_destroy(sim);
    }
}

/* Rest lengths are the grid distances; springs off the grid are absent. For 3 x 3 there are
 * 6 + 6 structural, 4 + 4 shear and 3 + 3 bend springs: 26. */
static void test_springs_and_rest_lengths(void **unused)
{
    (void)unused;
    cs_sim *sim = grid(3, 3, 2.0f, 4.0f, 1.0f, CS_HORIZONTAL, CS_PINS_NONE);
    float L[9 * CS_NTYPES];
    assert_int_equal(cs_read_rest_lengths(sim, L, 9 * CS_NTYPES), CS_OK);
    const float want[CS_NTYPES] = {1.0f, 2.0f, sqrtf(5.0f), sqrtf(5.0f), 2.0f, 4.0f};
    int present = 0;
    for (int t = 0; t < CS_NTYPES; t++) {
        for (int v = 0; v < 9; v++) {
            const float l = L[t * 9 + v];
            if (cs_spring_exists(3, 3, t, v)) {
                present++;
                assert_float_equal(l, want[t], 1e-6);
            } else {
                assert_true(l == CS_TORN);
            }
        }
    }
    assert_int_equal(present, 26);
    cs_info info;
    cs_sim_info(sim, &info);
    assert_int_equal(info.n_springs, 26);
    assert_int_equal(info.n_torn, 0);
    assert_int_equal(info.n_vertices, 9);
    /* Which springs exist, by hand: (2,0) has no +x spring, (0,1) no -x diagonal, (1,1) no +2 ones. */
    assert_false(cs_spring_exists(3, 3, CS_SX, 2));
    assert_true(cs_spring_exists(3, 3, CS_SX, 1));
    assert_false(cs_spring_exists(3, 3, CS_D2, 3));
    assert_true(cs_spring_exists(3, 3, CS_D2, 4));
    assert_false(cs_spring_exists(3, 3, CS_BX, 4));
    assert_true(cs_spring_exists(3, 3, CS_BY, 1));
    assert_false(cs_spring_exists(3, 3, CS_SY, 7));
    /* A cloth at rest exerts no spring force: accelerations are exactly 0 without gravity. */
    for (int v = 0; v < 9; v++) assert_true(sim->state.ax[v] == 0.0f && sim->state.az[v] == 0.0f);
    cs_sim_destroy(sim);
}

static int count_pins(cs_sim *sim, int n)
{
    int c = 0;
    for (int v = 0; v < n; v++) c += cs_is_pinned(sim, v);
    return c;
}

static void test_pin_presets(void **unused)
{
    (void)unused;
    const int nx = 7, ny = 5, n = nx * ny;
    cs_sim *sim = grid(nx, ny, 1, 1, 1, CS_VERTICAL, CS_PINS_CORNERS);
    assert_int_equal(count_pins(sim, n), 4);
    assert_true(cs_is_pinned(sim, 0) && cs_is_pinned(sim, nx - 1) && cs_is_pinned(sim, n - nx) && cs_is_pinned(sim, n - 1));
    assert_int_equal(cs_pins_preset(sim, CS_PINS_EDGES), CS_OK);
    assert_int_equal(count_pins(sim, n), 2 * nx + 2 * ny - 4);
    assert_false(cs_is_pinned(sim, nx + 1));
    assert_int_equal(cs_pins_preset(sim, CS_PINS_TOP_EDGE), CS_OK);
    assert_int_equal(count_pins(sim, n), nx);
    /* The pinned row is the highest one when hanging. */
    float *x = tk_positions(sim);
    for (int v = 0; v < n; v++)
        if (cs_is_pinned(sim, v)) assert_float_equal(x[3 * v + 2], 1.5f, 1e-6);
    free(x);
    assert_int_equal(cs_pins_preset(sim, CS_PINS_NONE), CS_OK);
    assert_int_equal(count_pins(sim, n), 0);
    assert_int_equal(cs_pins_preset(sim, (cs_pins)9), CS_E_RANGE);
    assert_int_equal(count_pins(sim, n), 0);
    assert_false(cs_is_pinned(sim, -1));
    assert_false(cs_is_pinned(sim, n));
    cs_sim_destroy(sim);
}

static void test_memory_estimate(void **unused)
{
    (void)unused;
    cs_scene sc;
    cs_params p;
    cs_scene_default(&sc);
    cs_params_default(&p);
    p.integrator = CS_VELOCITY_VERLET; /* the state and scratch alone; the workspaces below */
    uint64_t small, big;
    assert_int_equal(cs_scene_memory(&sc, &p, CS_MAX_ROCKS, &small), CS_OK);
    sc.nx = sc.ny = 4096;
    assert_int_equal(cs_scene_memory(&sc, &p, CS_MAX_ROCKS, &big), CS_OK);
    /* At least the 22 floats a vertex holds (positions, velocities, accelerations, mask, two
     * rest-length buffers of 6). */
    assert_true(big >= 4096ull * 4096ull * 22 * 4);
    assert_true(small < big);
    /* 2^31 x 2^31 vertices of 89 bytes overflow 64 bits: refused, not wrapped to a small size;
     * and no engine runs more than 2^31 - 1 vertices. */
    sc.nx = sc.ny = INT32_MAX;
    assert_int_equal(cs_scene_memory(&sc, &p, CS_MAX_ROCKS, &big), CS_E_LIMIT);
    sc.nx = sc.ny = 65536;
    assert_int_equal(cs_scene_memory(&sc, &p, CS_MAX_ROCKS, &big), CS_E_LIMIT);
    sc.nx = 1;
    assert_int_equal(cs_scene_memory(&sc, &p, CS_MAX_ROCKS, &small), CS_E_RANGE);
    assert_int_equal(cs_scene_memory(NULL, &p, CS_MAX_ROCKS, &small), CS_E_INVALID);
    assert_int_equal(cs_scene_memory(&sc, &p, -1, &small), CS_E_INVALID);
    /* Rocks cost their state (twice: a rock change copies the list) and the CPU backend's
     * partials, 6 floats per chunk of a row (256 vertices) and rock. A 300 x 300 cloth has 600
     * chunks; 10 rocks instead of none (which still take one row of partials) add 20 rock states
     * and 600 x 9 x 6 x 4 bytes of partials. */
    cs_scene_default(&sc);
    sc.nx = sc.ny = 300;
    uint64_t r0, r10;
    assert_int_equal(cs_scene_memory(&sc, &p, 0, &r0), CS_OK);
    assert_int_equal(cs_scene_memory(&sc, &p, 10, &r10), CS_OK);
    assert_true(r10 - r0 == 20 * sizeof(cs_rock_state) + 600ull * 9 * 6 * 4);
    /* With no rocks, under velocity_verlet without self_collision: the state of 89 bytes a vertex,
     * twice (a rebuild makes the new one beside the old), one row of partials per chunk and a
     * float4 staging buffer per vertex. */
    assert_true(r0 == 2 * (90000ull * 89 + sizeof(cs_state)) + 600ull * 6 * 4 + 90000ull * 16);
    /* implicit_euler adds its workspace, at least its 50 floats a vertex of vectors;
     * self_collision its own, at least its pair lists full: three sets of 341 keys of 8 bytes a
     * vertex; no parameters count both (test_memory_covers_workspaces checks them against the
     * heap). */
    uint64_t im, self, both;
    p.integrator = CS_IMPLICIT_EULER;
    assert_int_equal(cs_scene_memory(&sc, &p, 0, &im), CS_OK);
    assert_true(im >= r0 + 90000ull * 50 * 4);
    cs_params_default(&p);
    p.integrator = CS_VELOCITY_VERLET;
    p.self_collision = true;
    assert_int_equal(cs_scene_memory(&sc, &p, 0, &self), CS_OK);
    assert_true(self >= r0 + 90000ull * 3 * 341 * 8);
    assert_int_equal(cs_scene_memory(&sc, NULL, 0, &both), CS_OK);
    assert_true(both == im + self - r0);
}

/* In-use heap bytes (glibc). */
static size_t heap_in_use(void)
{
    const struct mallinfo2 m = mallinfo2();
    return m.uordblks + m.hblkhd;
}

/* cs_scene_memory covers what the engine holds once implicit_euler and self_collision have run on
 * a scene: the heap's growth, measured by glibc (skipped where malloc is not glibc's: ASan). */
static void test_memory_covers_workspaces(void **unused)
{
    (void)unused;
    const size_t probe_bytes = 1u << 20, h = heap_in_use();
    char *probe = malloc(probe_bytes);
    assert_non_null(probe);
    memset(probe, 1, probe_bytes);
    const int counted = heap_in_use() - h >= probe_bytes;
    free(probe);
    if (!counted) skip();
    cs_scene sc;
    cs_params p;
    cs_scene_default(&sc);
    cs_params_default(&p);
    sc.nx = sc.ny = 200;
    p.integrator = CS_IMPLICIT_EULER;
    p.self_collision = true;
    uint64_t counted_bytes;
    assert_int_equal(cs_scene_memory(&sc, &p, 0, &counted_bytes), CS_OK);
    const size_t h0 = heap_in_use();
    cs_sim *sim = tk_sim_serial(&sc, &p);
    cs_info info;
    cs_sim_info(sim, &info);
    tk_step(sim, 3 * (int64_t)info.substeps);
    const size_t used = heap_in_use() - h0;
    print_message("200 x 200, implicit_euler with self_collision: the heap grew by %.1f MB, cs_scene_memory counts %.1f MB\n",
                  used / 1e6, counted_bytes / 1e6);
    assert_true(used <= counted_bytes);
    /* the workspaces are most of it: the state twice would not cover it */
    assert_true(used > 2 * 40000ull * 89);
    cs_sim_destroy(sim);
}

/* M = rho 4/3 pi R^3, I = 2/5 M R^2: R = 0.5, rho = 6 gives M = pi, I = pi/10. */
static void test_rock_mass_and_inertia(void **unused)
{
    (void)unused;
    cs_rock_state r;
    memset(&r, 0, sizeof r);
    r.radius = 0.5f;
    r.density = 6.0f;
    cs_rock_mass(&r);
    assert_float_equal(r.mass, 3.14159265f, 1e-6);
    assert_float_equal(r.inertia, 0.314159265f, 1e-7);
    assert_float_equal(r.inv_mass, 1.0f / 3.14159265f, 1e-6);
    r.kinematic = 1;
    cs_rock_mass(&r);
    assert_true(r.inv_mass == 0.0f && r.inv_inertia == 0.0f);
}

/* m = areal_density size_x size_y / (nx ny). */
static void test_vertex_mass(void **unused)
{
    (void)unused;
    cs_scene sc;
    cs_params p;
    tk_quiet(&sc, &p);
    sc.nx = 4, sc.ny = 5, sc.size_x = 3, sc.size_y = 2, sc.areal_density = 0.5f;
    cs_sim *sim = tk_sim(&sc, &p);
    assert_float_equal(sim->model.phys.mass, 0.5f * 3 * 2 / 20, 1e-7);
    cs_sim_destroy(sim);
}

int main(void)
{
    const struct CMUnitTest tests[] = {
        cmocka_unit_test(test_positions_horizontal_and_vertical),
        cmocka_unit_test(test_springs_and_rest_lengths),
        cmocka_unit_test(test_pin_presets),
        cmocka_unit_test(test_memory_estimate),
        cmocka_unit_test(test_memory_covers_workspaces),
        cmocka_unit_test(test_rock_mass_and_inertia),
        cmocka_unit_test(test_vertex_mass),
    };
    return cmocka_run_group_tests(tests, NULL, NULL);
}
