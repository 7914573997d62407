/* test_self_collision.c - self_collision: a folding cloth never passes through itself.
 *
 * The scene: a 1 m square cloth hanging free (orientation vertical, no pins) with its lower edge
 * 0.1 m above the ground, blown sideways by a 2 m/s wind, falls and crumples onto the ground in
 * folds. The crossing counter (tests/support/tk_geom.h) is written from geometry alone: two grid
 * triangles that share no vertex cross when an edge of one passes through the other
 * (Moller-Trumbore in double precision), never from the product's contact code. With self_collision off the scene crosses
 * itself (so it really folds); with it on it never does, at any frame, under each integrator. */
#include <sys/resource.h>

#include "testkit.h"
#include "tk_geom.h"

#define SIDE 16
/* Frames run: the lower edge lands at about 0.15 s, the cloth has folded onto itself by 1.1 s. */
#define FRAMES 80

/* The tests' cloth: free, 1 m square, SIDE x SIDE, at height, under the given integrator. */
static void free_cloth(cs_scene *sc, cs_params *p, float height, int integrator, int self)
{
    cs_scene_default(sc);
    cs_params_default(p);
    sc->nx = sc->ny = SIDE;
    sc->size_x = sc->size_y = 1.0f;
    sc->pins = CS_PINS_NONE;
    sc->height = height;
    p->integrator = integrator;
    p->self_collision = self;
}

static cs_sim *fold_scene(int integrator, int self)
{
    cs_scene sc;
    cs_params p;
    free_cloth(&sc, &p, 0.6f, integrator, self);
    sc.orientation = CS_VERTICAL;
    p.wind[1] = 2.0f;
    return tk_sim_serial(&sc, &p); /* one thread: ctest runs two tests at once on two cores */
}

/* Runs the scene; returns the most crossings seen at any frame (and the frame they first showed). */
static long run_fold(cs_sim *sim, int frames, int *first)
{
    float xyz[3 * SIDE * SIDE];
    long most = 0;
    *first = -1;
    for (int f = 0; f < frames; f++) {
        assert_int_equal(cs_sim_step_frames(sim, 1), CS_OK);
        assert_int_equal(cs_read_positions(sim, xyz, 3 * SIDE * SIDE), CS_OK);
        const long c = crossings(xyz, SIDE, SIDE);
        if (c > 0 && *first < 0) *first = f;
        most = c > most ? c : most;
    }
    return most;
}

static void check_integrator(int integrator)
{
    int first;
    cs_sim *off = fold_scene(integrator, 0);
    const long crossed = run_fold(off, FRAMES, &first);
    print_message("integrator %d, self_collision off: up to %ld crossing pairs (first at frame %d)\n", integrator,
                  crossed, first);
    assert_true(crossed > 0); /* the scene folds through itself without it */
    cs_sim_destroy(off);
    cs_sim *on = fold_scene(integrator, 1);
    const long kept = run_fold(on, FRAMES, &first);
    print_message("integrator %d, self_collision on: up to %ld crossing pairs\n", integrator, kept);
    assert_int_equal(kept, 0);
    cs_sim_destroy(on);
}

/* Under AddressSanitizer (some 20 times slower) implicit_euler's fold and the short checks only:
 * the explicit integrators run the same passes after every substep. */
static void test_fold_velocity_verlet(void **unused)
{
    (void)unused;
    if (SANITIZED) skip();
    check_integrator(CS_VELOCITY_VERLET);
}

static void test_fold_symplectic_euler(void **unused)
{
    (void)unused;
    if (SANITIZED) skip();
    check_integrator(CS_SYMPLECTIC_EULER);
}

static void test_fold_implicit_euler(void **unused)
{
    (void)unused;
    check_integrator(CS_IMPLICIT_EULER);
}

/* Head-on: a free 1 m cloth without gravity, its corner grabbed and lifted over the cloth, then
 * driven down through it at grab_speed (5 m/s): the folded-over part meets the flat part face on.
 * Returns the most crossings at any frame, and the lowest the corner got (so the test knows the
 * drive went through the flat part's plane without it). */
static long head_on(int integrator, int self, float *lowest)
{
    cs_scene sc;
    cs_params p;
    free_cloth(&sc, &p, 0.5f, integrator, self);
    p.gravity[0] = p.gravity[1] = p.gravity[2] = 0.0f;
    cs_sim *sim = tk_sim_serial(&sc, &p);
    const float up[3] = {0.2f, 0.2f, 0.8f}, down[3] = {0.2f, 0.2f, 0.1f};
    float xyz[3 * SIDE * SIDE];
    long most = 0;
    *lowest = 1.0f;
    for (int f = 0; f < 70; f++) {
        if (f == 0) assert_int_equal(cs_grab(sim, 0, up), CS_OK);
        if (f == 30) assert_int_equal(cs_grab(sim, 0, down), CS_OK);
        assert_int_equal(cs_sim_step_frames(sim, 1), CS_OK);
        assert_int_equal(cs_read_positions(sim, xyz, 3 * SIDE * SIDE), CS_OK);
        const long c = crossings(xyz, SIDE, SIDE);
        most = c > most ? c : most;
        if (f >= 30) *lowest = xyz[2] < *lowest ? xyz[2] : *lowest;
    }
    cs_sim_destroy(sim);
    return most;
}

static void test_head_on(void **unused)
{
    (void)unused;
    if (SANITIZED) skip();
    const int integrators[2] = {CS_VELOCITY_VERLET, CS_IMPLICIT_EULER};
    for (int k = 0; k < 2; k++) {
        float low_off, low_on;
        const long off = head_on(integrators[k], 0, &low_off), on = head_on(integrators[k], 1, &low_on);
        print_message("head-on, integrator %d: %ld crossing pairs without self_collision (corner down to z %.3f), "
                      "%ld with it (corner down to z %.3f)\n",
                      integrators[k], off, (double)low_off, on, (double)low_on);
        /* velocity Verlet's drive goes through the flat part without it (implicit_euler's, whose
         * stiff springs drag the flat part along, happens not to cross: the check with it on still
         * holds it to none) */
        if (integrators[k] == CS_VELOCITY_VERLET) assert_true(off > 0 && low_off < 0.45f);
        assert_int_equal(on, 0);
    }
}

/* The folded cloth at rest on the ground: layers stay at least half the thickness apart (every
 * vertex from every triangle more than two rings away in the grid, by the distance of tk_geom.h). */
static void test_layers_keep_apart(void **unused)
{
    (void)unused;
    if (SANITIZED) skip();
    cs_sim *sim = fold_scene(CS_IMPLICIT_EULER, 1);
    int first;
    assert_int_equal(run_fold(sim, 150, &first), 0);
    float xyz[3 * SIDE * SIDE];
    assert_int_equal(cs_read_positions(sim, xyz, 3 * SIDE * SIDE), CS_OK);
    cs_params p;
    cs_sim_params(sim, &p);
    double least = 1e300;
    int layered = 0;
    for (int v = 0; v < SIDE * SIDE; v++)
        for (int j = 0; j < SIDE - 1; j++)
            for (int i = 0; i < SIDE - 1; i++) {
                const int q = j * SIDE + i;
                const int tri[2][3] = {{q, q + 1, q + SIDE + 1}, {q, q + SIDE + 1, q + SIDE}};
                for (int f = 0; f < 2; f++) {
                    int near = 0;
                    for (int k = 0; k < 3; k++) {
                        const int di = abs(v % SIDE - tri[f][k] % SIDE), dj = abs(v / SIDE - tri[f][k] / SIDE);
                        near |= (di > dj ? di : dj) <= 2;
                    }
                    if (near) continue;
                    const d3 P = {xyz[3 * v], xyz[3 * v + 1], xyz[3 * v + 2]};
                    d3 c[3];
                    for (int k = 0; k < 3; k++)
                        c[k] = (d3){xyz[3 * tri[f][k]], xyz[3 * tri[f][k] + 1], xyz[3 * tri[f][k] + 2]};
                    const double d = point_triangle(P, c[0], c[1], c[2]);
                    layered += d < 2.0 * p.self_thickness;
                    least = d < least ? d : least;
                }
            }
    print_message("folded cloth: %d vertex-triangle pairs within twice the thickness, the nearest %.2f mm "
                  "(thickness %.1f mm)\n", layered, least * 1e3, p.self_thickness * 1e3);
    assert_true(layered > 0); /* it did fold into layers */
    assert_true(least >= 0.5 * p.self_thickness);
    cs_sim_destroy(sim);
}

/* Bitwise the same for one thread or two, and stepped in a batch or alone. */
static void test_deterministic(void **unused)
{
    (void)unused;
    if (SANITIZED) skip(); /* the passes are the fold's; the normal build checks the bits */
    const int frames = 70;
    cs_sim *a = fold_scene(CS_VELOCITY_VERLET, 1), *b = fold_scene(CS_VELOCITY_VERLET, 1),
           *c = fold_scene(CS_VELOCITY_VERLET, 1);
    cs_sim_set_threads(a, 1);
    cs_sim_set_threads(b, 2);
    cs_sim_set_threads(c, 2);
    assert_int_equal(cs_sim_step_frames(a, frames), CS_OK);
    assert_int_equal(cs_sim_step_frames(b, frames), CS_OK);
    cs_info info;
    cs_sim_info(c, &info);
    cs_sim *const batch[2] = {c, a};
    const int64_t substeps[2] = {(int64_t)frames * info.substeps, 0};
    cs_status each[2];
    assert_int_equal(cs_sims_step(batch, 2, substeps, each), CS_OK);
    assert_int_equal(each[0], CS_OK);
    assert_true(cs_state_hash(a) == cs_state_hash(b));
    assert_true(cs_state_hash(a) == cs_state_hash(c));
    cs_sim_destroy(a);
    cs_sim_destroy(b);
    cs_sim_destroy(c);
}

/* self_thickness 0, negative, NaN or past its range: refused, nothing changed. */
static void test_bad_thickness(void **unused)
{
    (void)unused;
    cs_sim *sim = fold_scene(CS_VELOCITY_VERLET, 1);
    cs_params before, p;
    cs_sim_params(sim, &before);
    const float bad[] = {0.0f, -0.01f, NAN, 1.0f, INFINITY};
    for (size_t k = 0; k < sizeof bad / sizeof bad[0]; k++) {
        p = before;
        p.self_thickness = bad[k];
        assert_int_equal(cs_sim_set_params(sim, &p), CS_E_RANGE);
        cs_sim_params(sim, &p);
        assert_memory_equal(&p, &before, sizeof p);
    }
    cs_sim_destroy(sim);
}

/* Turned on in a state that already crosses: the state stays finite, and the crossings it had are
 * not undone (the bound keeps what does not cross from crossing; docs: kernels/MODEL.md). */
static void test_on_in_a_crossed_state(void **unused)
{
    (void)unused;
    cs_sim *sim = fold_scene(CS_VELOCITY_VERLET, 0);
    int first;
    assert_true(run_fold(sim, 60, &first) > 0);
    cs_params p;
    cs_sim_params(sim, &p);
    p.self_collision = 1;
    assert_int_equal(cs_sim_set_params(sim, &p), CS_OK);
    assert_int_equal(cs_sim_step_frames(sim, SANITIZED ? 10 : 30), CS_OK);
    float xyz[3 * SIDE * SIDE];
    assert_int_equal(cs_read_positions(sim, xyz, 3 * SIDE * SIDE), CS_OK);
    for (int k = 0; k < 3 * SIDE * SIDE; k++) assert_true(isfinite(xyz[k]));
    cs_sim_destroy(sim);
}

/* A cloth far finer than its thickness (64 x 64, self_thickness 0.5 m: most of the cloth is within
 * a list's radius of each vertex, about 2 GB of lists): the lists stop at their cap and are
 * reported lost, the bound finds the pairs in the grid, and one frame ends finite with the process
 * grown by a bounded amount (the three lists' 64 MiB floors, and what the allocator keeps). */
static void test_lists_bounded(void **unused)
{
    (void)unused;
    cs_scene sc;
    cs_params p;
    cs_scene_default(&sc);
    cs_params_default(&p);
    sc.nx = sc.ny = 64;
    p.integrator = CS_IMPLICIT_EULER;
    p.self_collision = 1;
    p.self_thickness = 0.5f;
    struct rusage r0, r1;
    getrusage(RUSAGE_SELF, &r0);
    cs_sim *sim = tk_sim(&sc, &p);
    assert_int_equal(cs_sim_step_frames(sim, 1), CS_OK);
    cs_info info;
    cs_sim_info(sim, &info);
    assert_true(info.self.lost > 0);
    getrusage(RUSAGE_SELF, &r1);
    const long grew = r1.ru_maxrss - r0.ru_maxrss; /* KiB */
    printf("lists given up for %lld vertices; peak RSS grew %ld KiB\n", (long long)info.self.lost, grew);
    assert_true(grew < 1024 * 1024);
    float *x = tk_positions(sim);
    for (int32_t v = 0; v < 3 * sc.nx * sc.ny; v++) assert_true(isfinite(x[v]));
    free(x);
    cs_sim_destroy(sim);
}

int main(void)
{
    const struct CMUnitTest tests[] = {
        cmocka_unit_test(test_fold_velocity_verlet),  cmocka_unit_test(test_fold_symplectic_euler),
        cmocka_unit_test(test_fold_implicit_euler),   cmocka_unit_test(test_layers_keep_apart),
        cmocka_unit_test(test_deterministic),         cmocka_unit_test(test_bad_thickness),
        cmocka_unit_test(test_on_in_a_crossed_state), cmocka_unit_test(test_head_on),
        cmocka_unit_test(test_lists_bounded),
    };
    return cmocka_run_group_tests(tests, NULL, NULL);
}
