/* test_parity.c - a backend against the CPU backend: the same scenes and commands at the same
 * steps, and the states compared bit for bit - positions, velocities, accelerations, rest lengths,
 * rocks, torn springs, the state hash. Any difference fails; there is no tolerance.
 *
 * Every scene starts with its rocks already pressing into the cloth (so even the quick run sums
 * rock reactions through the chunk trees and the chunk groups) and steps in calls of odd lengths
 * (1, 7, 37, ... substeps: the rest-length and position double buffers end on either half), reading
 * a frame (positions and rocks, as the daemon does) between calls and comparing it too. Scenes
 * cover both integrators and friction models, plasticity and tearing, a grab (one that tears),
 * rocks dynamic and kinematic, spinning, touching each other and the ground, more than 32 and more
 * than 64 rocks, vertices touching two rocks at once, more than 64 chunks with rocks, rows of
 * several chunks, a 3 x 2 cloth; both contact models (surface: stone rocks resting over a
 * triangle, an edge, a vertex and a diagonal, with friction from spin and a sliding kinematic rock,
 * two rocks sharing vertices, 40 rocks, a tearing grab); implicit_euler (the ground within reach,
 * plasticity and tearing, a grab and one that tears, rows of two chunks; its solver's statistics
 * compared too, in shorter calls: each substep is a solve), without rocks and with them (a rock
 * thrown onto the cloth with surface contact, two rocks at once with vertex contact, two rocks
 * and a grab that tears, a dynamic rock and a kinematic one: the carried mass, the push and
 * substeps cut into parts, up to the cap; shorter calls still: each part is a solve); and commands
 * mid-run: releasing the grab, moving a rock, set_params, switching integrator (also to and from
 * implicit_euler, with a rock in contact too), friction model and contact model, a snapshot saved
 * by the CPU backend and loaded into both (under implicit_euler with rocks too), a scene resized.
 *
 * Plain C (no cmocka: a GPU machine may have no -dev packages). Exit 0 pass, 1 fail, 77 skipped (no
 * CUDA build or no device). `test_parity cuda` runs the CUDA backend - on a GPU in tests/gpu/run.sh,
 * and on the CPU imitation of CUDA in ctest (emu.parity); `test_parity cpu` compares the CPU
 * backend on one thread with itself on two; `quick` as the second argument runs about a tenth of
 * the substeps (for compute-sanitizer); with CLOTHD_SANITIZED set as well (the ASan build of the
 * emulated backend) it stops after four calls of 22 substeps in all.
 *
 * Every full run ends with the batch check (run_batch; `batch` as the second argument runs it
 * alone): mixed scenes (three under implicit_euler, of two sizes, with rocks and without, which
 * the batch steps together after the explicit ones) stepped together by cs_sims_step, each bitwise
 * equal to a copy stepped
 * alone on the same backend and to one on the CPU backend, with scenes leaving and joining between
 * rounds and one poisoned scene failing alone. */
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>

#include "clothsim/backend.h"
#include "clothsim/clothsim.h"
#include "cs_testhooks.h"

static int quick;

static double now(void)
{
    struct timespec ts;
    clock_gettime(CLOCK_MONOTONIC, &ts);
    return (double)ts.tv_sec + 1e-9 * (double)ts.tv_nsec;
}

/* Mid-run commands of a scene's script. */
enum {
    S_GRAB = 1,      /* a grab from the start, released after the second call */
    S_TEAR = 2,      /* the grab pulls far enough to tear */
    S_ROCK_SET = 4,  /* rock 0 thrown upward mid-run */
    S_PARAMS = 8,    /* set_params: stiffer, more drag, wind, tilted gravity, thicker contact */
    S_SWITCH = 16,   /* integrator and friction model switched, then switched back */
    S_SNAPSHOT = 32, /* the CPU sim's snapshot loaded into both */
    S_RESIZE = 64,   /* cs_sim_set_scene to another size, rocks added again */
    S_PAIR = 128,    /* two rocks side by side, sunk to the cloth: vertices between touch both */
    S_SPOTS = 256,   /* stone rocks resting over a triangle, a structural edge, a vertex, a diagonal */
    S_CONTACT = 512, /* contact_model switched mid-run, then switched back */
    S_SWITCH_IM = 1024, /* integrator switched between velocity_verlet and implicit_euler, then back */
    S_REST = 2048,      /* the rocks set down on the cloth at rest (not thrown), spinning */
    S_SELF = 4096       /* self_collision: a free towel pinned along its middle row, 1.2 m up, its
                           halves falling against each other in a side wind (the explicit run's
                           fabric soft enough for few substeps a frame, so that they meet in it) */
};

typedef struct variant {
    const char *name;
    int nx, ny, integrator, friction, strain, rocks;
    unsigned script;
    float radius; /* rock radius (0: 0.04 m + 0.01 m per rock) */
    int contact;  /* cs_contact_model: 0 vertex (the rows that leave it out), 1 surface */
} variant;

#define VV CS_VELOCITY_VERLET
#define SE CS_SYMPLECTIC_EULER
#define IM CS_IMPLICIT_EULER
#define CV CS_FRICTION_COULOMB_VISCOUS
#define RS CS_FRICTION_RESULTANT
static const variant variants[] = {
    {"verlet coulomb strain rocks", 48, 40, VV, CV, 1, 5, S_GRAB | S_ROCK_SET, 0, 0},
    {"verlet resultant strain rocks", 48, 40, VV, RS, 1, 5, S_GRAB | S_ROCK_SET, 0, 0},
    {"euler coulomb strain rocks", 48, 40, SE, CV, 1, 5, S_GRAB | S_ROCK_SET, 0, 0},
    {"euler resultant strain rocks", 48, 40, SE, RS, 1, 5, S_GRAB | S_ROCK_SET, 0, 0},
    {"verlet plain", 64, 64, VV, CV, 0, 0, 0, 0, 0},
    {"wide rows (3 chunks a row)", 600, 6, VV, CV, 1, 3, S_GRAB, 0, 0},
    {"tiny 3x2", 3, 2, VV, RS, 1, 1, S_GRAB, 0, 0},
    {"70 chunks (two chunk groups)", 20, 70, VV, CV, 1, 6, 0, 0.05f, 0},
    {"40 rocks", 40, 40, VV, CV, 1, 40, 0, 0.025f, 0},
    {"100 rocks", 40, 40, SE, RS, 1, 100, 0, 0.02f, 0},
    {"grab that tears", 32, 32, VV, CV, 1, 2, S_GRAB | S_TEAR, 0, 0},
    {"set_params, integrator and friction switches", 40, 36, VV, CV, 1, 4, S_GRAB | S_PARAMS | S_SWITCH, 0, 0},
    {"snapshot loaded into both", 40, 36, SE, CV, 1, 4, S_GRAB | S_SNAPSHOT, 0, 0},
    {"scene resized", 36, 30, VV, RS, 1, 3, S_GRAB | S_RESIZE, 0, 0},
    {"vertices touching two rocks at once", 21, 21, VV, CV, 1, 2, S_PAIR, 0.05f, 0},
    /* surface contact */
    {"surface: face, edge, vertex, diagonal", 41, 41, VV, CV, 1, 4, S_SPOTS, 0.06f, 1},
    {"surface: the same, euler resultant", 41, 41, SE, RS, 1, 4, S_SPOTS, 0.06f, 1},
    {"surface: strain rocks grab", 48, 40, VV, RS, 1, 5, S_GRAB | S_ROCK_SET, 0, 1},
    {"surface: two rocks at once", 21, 21, VV, CV, 1, 2, S_PAIR, 0.05f, 1},
    {"surface: 40 rocks", 40, 40, SE, CV, 1, 40, 0, 0.025f, 1},
    {"surface: params, switches, contact model", 40, 36, VV, CV, 1, 4, S_GRAB | S_PARAMS | S_SWITCH | S_CONTACT, 0, 1},
    {"surface: wide rows, tearing grab", 600, 6, VV, CV, 1, 3, S_GRAB | S_TEAR, 0, 1},
    /* implicit_euler; the ground close below the cloth */
    {"implicit: plain, ground", 24, 20, IM, CV, 0, 0, 0, 0, 0},
    {"implicit: strain, grab, ground", 24, 20, IM, RS, 1, 0, S_GRAB, 0, 0},
    {"implicit: grab that tears", 24, 20, IM, CV, 1, 0, S_GRAB | S_TEAR, 0, 0},
    {"implicit: switched to and from velocity_verlet", 24, 20, VV, CV, 1, 0, S_GRAB | S_SWITCH_IM, 0, 0},
    {"implicit: snapshot loaded into both", 24, 20, IM, CV, 1, 0, S_GRAB | S_SNAPSHOT, 0, 0},
    {"implicit: wide rows (2 chunks a row), grab", 300, 3, IM, CV, 1, 0, S_GRAB, 0, 0},
    /* more than 1,024 vertices: the V-cycle's finest level by launches, the rest in one block */
    {"implicit: 36 x 30, grab", 36, 30, IM, RS, 0, 0, S_GRAB, 0, 0},
    /* implicit_euler with rocks: carried mass, the push, substeps cut into parts (and the cap) */
    {"implicit: a rock thrown on the cloth, surface", 24, 20, IM, CV, 1, 1, 0, 0.06f, 1},
    {"implicit: vertex contact, two rocks at once", 21, 21, IM, RS, 1, 2, S_PAIR, 0.02f, 0},
    {"implicit: two rocks, a grab that tears", 16, 14, IM, CV, 1, 2, S_GRAB | S_TEAR, 0, 1},
    {"implicit: switched to and from verlet, a rock", 24, 20, VV, CV, 1, 1, S_GRAB | S_SWITCH_IM | S_REST, 0.06f, 1},
    {"implicit: snapshot loaded into both, rocks", 24, 20, IM, CV, 1, 2, S_SNAPSHOT, 0, 0},
    /* self_collision */
    {"self: verlet, a towel folding in the wind", 16, 16, VV, CV, 0, 0, S_SELF, 0, 0},
    {"self: implicit, a towel folding in the wind", 16, 16, IM, CV, 0, 0, S_SELF, 0, 0},
    {"self: implicit, strain, a rock on the towel", 16, 16, IM, RS, 1, 1, S_SELF, 0.05f, 1},
};

static void scene_of(const variant *vr, int nx, int ny, cs_scene *sc)
{
    cs_scene_default(sc);
    sc->nx = nx, sc->ny = ny;
    sc->size_x = 0.03f * (float)(nx - 1);
    sc->size_y = 0.03f * (float)(ny - 1);
    sc->pins = CS_PINS_EDGES;
    if (vr->script & S_SELF) sc->pins = CS_PINS_NONE, sc->height = 1.2f;
    if ((vr->script & S_SELF) && vr->integrator != CS_IMPLICIT_EULER) sc->areal_density *= 10.0f; /* (params_of) */
}

static float radius_of(const variant *vr, int r) { return vr->radius > 0 ? vr->radius : 0.04f + 0.01f * (float)r; }

/* Rocks pressing into the cloth from the start, spread over it; neighbours close enough to touch
 * each other; rock 1 kinematic and sweeping. */
static int add_rocks(cs_sim *sim, const variant *vr, const cs_scene *sc, const cs_params *p)
{
    if (vr->script & S_PAIR) {
        /* Rims 5 mm apart, centres a few mm above the cloth and off its grid lines: the vertices
         * between are inside both (radius + offset), so their forces add two rocks' in order. Not
         * mirror images (a symmetric pair sums the same in either order). */
        for (int r = 0; r < 2; r++) {
            cs_rock_def d;
            cs_rock_def_default(&d);
            d.radius = vr->radius * (r ? 0.9f : 1.0f);
            d.density = 250.0f;
            d.position[0] = r ? 0.9f * vr->radius + 0.0025f + 0.003f : -vr->radius - 0.0025f + 0.003f;
            d.position[1] = r ? 0.011f : 0.004f;
            d.position[2] = sc->height + (r ? 0.003f : 0.006f);
            d.angular_velocity[2] = r ? 3.0f : -2.0f;
            /* under implicit_euler pressed in at 2 m/s: contact cuts its substeps into parts */
            if (vr->integrator == CS_IMPLICIT_EULER) d.velocity[2] = -2.0f;
            if (cs_rock_add(sim, &d, NULL) != CS_OK) return -1;
        }
        return 0;
    }
    const int cols = vr->rocks > 8 ? (int)ceil(sqrt((double)vr->rocks)) : vr->rocks;
    for (int r = 0; r < vr->rocks; r++) {
        cs_rock_def d;
        cs_rock_def_default(&d);
        d.radius = radius_of(vr, r);
        d.density = 250.0f;
        const int cx = r % cols, cy = r / cols, rows = (vr->rocks + cols - 1) / cols;
        /* Centres over the middle 80% of the cloth; many-rock grids packed so neighbours overlap. */
        const float fx = cols > 1 ? (float)cx / (float)(cols - 1) - 0.5f : 0.0f;
        const float fy = rows > 1 ? (float)cy / (float)(rows - 1) - 0.5f : 0.0f;
        const float span = vr->rocks > 8 ? 1.9f * d.radius * (float)(cols - 1) : 0.8f * sc->size_x;
        d.position[0] = fx * (span < 0.8f * sc->size_x ? span : 0.8f * sc->size_x);
        d.position[1] = fy * (vr->rocks > 8 ? 1.9f * d.radius * (float)(rows - 1) : 0.5f * sc->size_y) +
                        0.3f * (float)(r % 2) * d.radius;
        if (vr->rocks <= 8) d.position[1] = 0.02f * (float)r;
        d.position[2] = sc->height + d.radius + 0.5f * p->contact_offset;
        d.velocity[2] = (vr->script & S_REST) ? 0.0f : vr->rocks > 8 ? -0.5f : -2.5f;
        d.angular_velocity[0] = 4.0f;
        d.angular_velocity[2] = -3.0f;
        if (vr->script & S_SPOTS) {
            /* Four quadrants of the flat cloth (odd sizes: the origin is a vertex, the grid 3 cm):
             * the centre over the centroid of a triangle A (2/3, 1/3 of a cell), the middle of a
             * structural x edge, a vertex, the middle of a diagonal - the closest feature of the
             * cloth a face, an edge, a vertex, an edge. Stone, 5 mm into the contact layer,
             * sinking and spinning (friction). */
            const float h = 0.03f, off[4][2] = {{2 * h / 3, h / 3}, {h / 2, 0}, {0, 0}, {h / 2, h / 2}};
            d.density = 2500.0f;
            d.position[0] = (r % 2 ? 6 * h : -6 * h) + off[r % 4][0];
            d.position[1] = (r / 2 % 2 ? 6 * h : -6 * h) + off[r % 4][1];
            d.velocity[2] = -0.5f;
            d.angular_velocity[1] = -2.0f;
        }
        if (r == 1) {
            d.kinematic = true;
            d.velocity[0] = 0.3f;
            d.velocity[2] = 0.0f;
        }
        if (cs_rock_add(sim, &d, NULL) != CS_OK) return -1;
    }
    return 0;
}

static int32_t grab_vertex(int nx, int ny) { return (ny / 2) * nx + nx / 3; }

static cs_status grab(cs_sim *sim, const variant *vr, int nx, int ny)
{
    const int32_t g = grab_vertex(nx, ny);
    const size_t n3 = (size_t)nx * (size_t)ny * 3;
    float *xyz = malloc(sizeof(float) * n3), x[3];
    if (!xyz || cs_read_positions(sim, xyz, n3) != CS_OK) {
        free(xyz);
        return CS_E_NOMEM;
    }
    x[0] = xyz[3 * g], x[1] = xyz[3 * g + 1], x[2] = xyz[3 * g + 2] + ((vr->script & S_TEAR) ? 2.0f : 0.4f);
    free(xyz);
    return cs_grab(sim, g, x);
}

static void params_of(const variant *vr, const cs_scene *sc, cs_params *p)
{
    cs_params_default(p);
    p->integrator = vr->integrator;
    p->friction_model = vr->friction;
    p->plastic_yield = vr->strain ? 0.05f : 0.0f;
    p->plastic_rate = vr->strain ? 30.0f : 0.0f;
    p->tear_strain = vr->strain ? ((vr->script & S_TEAR) ? 0.15f : 0.3f) : 0.0f;
    p->ground_z = sc->height - 0.3f;
    /* implicit_euler's scenes are short: the ground within reach of the sagging cloth */
    if (vr->integrator == CS_IMPLICIT_EULER || (vr->script & S_SWITCH_IM)) p->ground_z = sc->height - 0.02f;
    p->wind[1] = 2.0f;
    p->max_substeps = 100000;
    /* implicit_euler with rocks: at most 6 parts a substep, max_substeps / implicit_substeps (the
     * cap taken too: torn and thrown pieces are fast, and each part is a solve); substeps, unused
     * under it, brought within max_substeps */
    if (vr->integrator == CS_IMPLICIT_EULER && vr->rocks) p->max_substeps = p->substeps = 6 * p->implicit_substeps;
    p->contact_model = vr->contact;
    /* The scenes start with rocks sunk into the cloth and into each other: allowed here. */
    p->placement_overlap = 1.0f;
    if (vr->script & S_TEAR) p->grab_speed = 20.0f;
    if (vr->script & S_SELF) {
        p->self_collision = 1;
        p->wind[1] = 3.0f;
        p->ground_z = sc->height - 1.0f;
        if (vr->integrator != CS_IMPLICIT_EULER) { /* 2 substeps a frame: the quick run's 100 are 0.8 s */
            p->k_structural = 2.0f, p->k_shear = 0.2f, p->k_bend = 0.02f, p->k_contact = 2.0f;
            p->c_spring = p->c_contact = p->c_tangent = 0.0f;
            p->auto_substeps = 0, p->substeps = 2;
        }
    }
}

static cs_sim *build(const variant *vr, const char *backend, int threads, char *err, size_t err_len)
{
    cs_scene sc;
    cs_params p;
    scene_of(vr, vr->nx, vr->ny, &sc);
    params_of(vr, &sc, &p);
    cs_sim *sim = NULL;
    if (cs_sim_create(&sc, &p, backend, &sim, err, err_len) != CS_OK) return NULL;
    cs_sim_set_threads(sim, threads);
    int32_t row[64];
    for (int32_t i = 0; i < sc.nx && i < 64; i++) row[i] = (sc.ny / 2) * sc.nx + i;
    if (((vr->script & S_SELF) && cs_pin(sim, row, (size_t)(sc.nx < 64 ? sc.nx : 64), true) != CS_OK) ||
        add_rocks(sim, vr, &sc, &p) != 0 || ((vr->script & S_GRAB) && grab(sim, vr, vr->nx, vr->ny) != CS_OK)) {
        snprintf(err, err_len, "setting up: %s", cs_sim_error(sim));
        cs_sim_destroy(sim);
        return NULL;
    }
    return sim;
}

/* ---- comparison ---- */

typedef struct pair {
    cs_sim *a, *b; /* the CPU backend, the backend under test */
    const variant *vr;
    const char *phase;
    int fail;
} pair;

static void report(pair *pr, const char *what, size_t index, double va, double vb)
{
    if (!pr->fail)
        printf("%-46s DIFFERS after %s: %s [%zu] %.9g vs %.9g\n", pr->vr->name, pr->phase, what, index, va, vb);
    pr->fail = 1;
}

static void same_floats(pair *pr, const char *what, const float *a, const float *b, size_t n)
{
    for (size_t i = 0; i < n; i++)
        if (memcmp(&a[i], &b[i], sizeof(float)) != 0) {
            size_t differing = 0;
            for (size_t k = i; k < n; k++) differing += memcmp(&a[k], &b[k], sizeof(float)) != 0;
            char label[96];
            snprintf(label, sizeof label, "%s (%zu of %zu differ), first at", what, differing, n);
            report(pr, label, i, a[i], b[i]);
            return;
        }
}

/* What a frame reads: positions and rocks (the daemon's publish path). */
static void compare_frame(pair *pr)
{
    cs_info ia, ib;
    cs_sim_info(pr->a, &ia);
    cs_sim_info(pr->b, &ib);
    if (ia.step != ib.step || ia.n_vertices != ib.n_vertices || ia.n_rocks != ib.n_rocks || ia.substeps != ib.substeps) {
        report(pr, "step, size, rocks or substeps", 0, (double)ia.step, (double)ib.step);
        return;
    }
    /* implicit_euler's solver statistics of the last call (zeros under the others) */
    if (ia.solver.substeps != ib.solver.substeps || ia.solver.newton != ib.solver.newton ||
        ia.solver.cg != ib.solver.cg || ia.solver.lost != ib.solver.lost)
        report(pr, "solver substeps, Newton or CG iterations", 0, (double)ia.solver.newton * 1e6 + ia.solver.cg,
               (double)ib.solver.newton * 1e6 + ib.solver.cg);
    same_floats(pr, "solver residual", &ia.solver.residual, &ib.solver.residual, 1);
    const size_t n3 = (size_t)ia.n_vertices * 3;
    float *fa = malloc(sizeof(float) * n3), *fb = malloc(sizeof(float) * n3);
    if (cs_read_positions(pr->a, fa, n3) != CS_OK || cs_read_positions(pr->b, fb, n3) != CS_OK)
        report(pr, "reading positions failed", 0, 0, 0);
    else same_floats(pr, "frame positions", fa, fb, n3);
    free(fa);
    free(fb);
    for (int32_t r = 0; r < ia.n_rocks; r++) {
        cs_rock ra, rb;
        if (cs_rock_at(pr->a, r, &ra) != CS_OK || cs_rock_at(pr->b, r, &rb) != CS_OK) {
            report(pr, "reading rocks failed", (size_t)r, 0, 0);
            return;
        }
        same_floats(pr, "frame rock position", ra.def.position, rb.def.position, 3);
        same_floats(pr, "frame rock orientation", ra.def.orientation, rb.def.orientation, 4);
    }
}

/* The whole state. */
static void compare_all(pair *pr)
{
    compare_frame(pr);
    cs_info ia, ib;
    cs_sim_info(pr->a, &ia);
    cs_sim_info(pr->b, &ib);
    if (ia.n_vertices != ib.n_vertices) return;
    const size_t n = (size_t)ia.n_vertices;
    float *fa = malloc(sizeof(float) * n * CS_NTYPES), *fb = malloc(sizeof(float) * n * CS_NTYPES);
    cs_read_velocities(pr->a, fa, n * 3);
    cs_read_velocities(pr->b, fb, n * 3);
    same_floats(pr, "velocities", fa, fb, n * 3);
    cs_read_rest_lengths(pr->a, fa, n * CS_NTYPES);
    cs_read_rest_lengths(pr->b, fb, n * CS_NTYPES);
    same_floats(pr, "rest lengths", fa, fb, n * CS_NTYPES);
    free(fa);
    free(fb);
    for (int32_t r = 0; r < ia.n_rocks && r < ib.n_rocks; r++) {
        cs_rock ra, rb;
        cs_rock_at(pr->a, r, &ra);
        cs_rock_at(pr->b, r, &rb);
        same_floats(pr, "rock velocity", ra.def.velocity, rb.def.velocity, 3);
        same_floats(pr, "rock spin", ra.def.angular_velocity, rb.def.angular_velocity, 3);
    }
    if (ia.n_torn != ib.n_torn) report(pr, "torn springs", 0, (double)ia.n_torn, (double)ib.n_torn);
    /* The hash covers the rest: accelerations, rock accelerations, ids. */
    const uint64_t ha = cs_state_hash(pr->a), hb = cs_state_hash(pr->b);
    if (ha != hb) report(pr, "state hash (accelerations or rock state)", 0, (double)ha, (double)hb);
}

static int step_both(pair *pr, int64_t substeps)
{
    const cs_status sa = cs_sim_step(pr->a, substeps), sb = cs_sim_step(pr->b, substeps);
    if (sa != sb || sa != CS_OK) {
        printf("%-46s stepping failed after %s: %s / %s\n", pr->vr->name, pr->phase, cs_sim_error(pr->a),
               cs_sim_error(pr->b));
        pr->fail = 1;
        return -1;
    }
    return 0;
}

static int both(pair *pr, cs_status sa, cs_status sb, const char *what)
{
    if (sa != CS_OK || sb != CS_OK) {
        printf("%-46s %s failed: %s / %s\n", pr->vr->name, what, cs_sim_error(pr->a), cs_sim_error(pr->b));
        pr->fail = 1;
        return -1;
    }
    return 0;
}

/* Whether any dynamic rock's velocity changed by more than gravity alone explains: the cloth or
 * another rock pushed it. */
static int rocks_were_pushed(cs_sim *sim, const cs_rock *before, int32_t n, double seconds, const float *g)
{
    for (int32_t r = 0; r < n; r++) {
        cs_rock now;
        if (before[r].def.kinematic || cs_rock_at(sim, r, &now) != CS_OK) continue;
        for (int c = 0; c < 3; c++)
            if (fabs(now.def.velocity[c] - before[r].def.velocity[c] - g[c] * seconds) > 1e-3) return 1;
    }
    return 0;
}

/* Vertices within reach (radius + contact_offset) of two rocks at once, now. */
static int shared_contacts(cs_sim *sim)
{
    cs_info info;
    cs_params p;
    cs_sim_info(sim, &info);
    cs_sim_params(sim, &p);
    const size_t n3 = (size_t)info.n_vertices * 3;
    float *x = malloc(sizeof(float) * n3);
    cs_rock a, b;
    int count = 0;
    if (x && info.n_rocks >= 2 && cs_read_positions(sim, x, n3) == CS_OK && cs_rock_at(sim, 0, &a) == CS_OK &&
        cs_rock_at(sim, 1, &b) == CS_OK)
        for (int32_t v = 0; v < info.n_vertices; v++) {
            int both = 1;
            for (int k = 0; k < 2; k++) {
                const cs_rock *r = k ? &b : &a;
                double d2 = 0;
                for (int c = 0; c < 3; c++) d2 += pow(x[3 * v + c] - r->def.position[c], 2);
                both &= sqrt(d2) < r->def.radius + p.contact_offset;
            }
            count += both;
        }
    free(x);
    return count;
}

/* The lowest z of the cloth now. */
static float lowest(cs_sim *sim)
{
    cs_info info;
    cs_sim_info(sim, &info);
    const size_t n3 = (size_t)info.n_vertices * 3;
    float *x = malloc(sizeof(float) * n3), low = 3.0e38f;
    if (x && cs_read_positions(sim, x, n3) == CS_OK)
        for (size_t v = 0; v < n3; v += 3) low = x[v + 2] < low ? x[v + 2] : low;
    free(x);
    return low;
}

/* The script: calls of odd lengths with frames read between them, and the variant's commands. */
static int run(const variant *vr, const char *other, int other_threads)
{
    char err[256];
    /* Under sanitizers one self_collision scene (the one with strain and a rock) runs: the same
     * kernels, at a fraction of the time the imitation takes there. */
    if (quick && getenv("CLOTHD_SANITIZED") && (vr->script & S_SELF) && vr->rocks == 0) {
        printf("%-46s left to the unsanitized run\n", vr->name);
        return 0;
    }
    const double t0 = now();
    pair pr = {NULL, NULL, vr, "building", 0};
    pr.a = build(vr, "cpu", 1, err, sizeof err);
    if (!pr.a) {
        printf("%-46s cpu: %s\n", vr->name, err);
        return 1;
    }
    pr.b = build(vr, other, other_threads, err, sizeof err);
    if (!pr.b) {
        printf("%-46s %s: %s\n", vr->name, other, err);
        cs_sim_destroy(pr.a);
        return 1;
    }
    /* Under sanitizers (CLOTHD_SANITIZED, with quick) only the first four calls, and shorter: the
     * same paths (a switch of integrator comes at the fourth). */
    const int64_t full[] = {1, 7, 37, 101, 231, 353, 270}, fast[] = {1, 7, 13, 29, 23, 27};
    /* implicit_euler's substeps are a solve each (a few hundred launches): fewer of them */
    const int64_t implicit_calls[] = {1, 3, 5, 7, 9, 5, 3};
    /* with rocks contact cuts them into parts (a solve each): fewer still (a switch to and from it
     * runs two calls of it: those of the others) */
    const int64_t implicit_rock_calls[] = {1, 2, 5, 3, 2, 1, 1};
    const int is_implicit = vr->integrator == CS_IMPLICIT_EULER || (vr->script & S_SWITCH_IM);
    /* under sanitizers shorter calls still (the first two as long: a rock's push is judged after
     * 8 substeps), still of odd lengths */
    const int64_t sanitized[] = {1, 7, 5, 9};
    const int64_t *calls = quick ? (getenv("CLOTHD_SANITIZED") ? sanitized : fast) : full;
    /* and under sanitizers with rocks, the same four calls at a substep or two each */
    const int64_t implicit_rock_sanitized[] = {1, 2, 1, 1};
    /* (the rock on the towel: self_collision cuts parts only for layers that may meet, and its
     * layers meet from about 0.3 s) */
    if (is_implicit)
        calls = vr->rocks && vr->integrator == IM && !(vr->script & S_SELF)
                    ? (quick && getenv("CLOTHD_SANITIZED") ? implicit_rock_sanitized : implicit_rock_calls)
                : vr->rocks && vr->integrator == IM && quick && getenv("CLOTHD_SANITIZED") ? implicit_rock_sanitized
                                                                                          : implicit_calls;
    const int n_calls = quick ? (getenv("CLOTHD_SANITIZED") ? 4 : 6) : 7;
    cs_params p;
    cs_sim_params(pr.a, &p);
    cs_info info;
    cs_sim_info(pr.a, &info);
    cs_rock before[128];
    const int32_t n_before = cs_rock_count(pr.a) < 128 ? cs_rock_count(pr.a) : 128;
    for (int32_t r = 0; r < n_before; r++) cs_rock_at(pr.a, r, &before[r]);
    compare_all(&pr);
    const int shared = (vr->script & S_PAIR) ? shared_contacts(pr.a) : -1;
    /* (the wide rows' one free row sags too little to reach the ground) */
    int pushed = vr->rocks == 0, solved = !is_implicit, grounded = !is_implicit || vr->ny < 10 || (vr->script & S_SELF);
    int cut = !(vr->integrator == IM && vr->rocks); /* with rocks: some substep cut into parts */
    int64_t self_contacts = 0, self_cut = 0; /* self_collision's, on the CPU backend */
    for (int k = 0; k < n_calls && !pr.fail; k++) {
        char phase[64];
        snprintf(phase, sizeof phase, "call %d (%lld substeps)", k + 1, (long long)calls[k]);
        pr.phase = phase;
        if (step_both(&pr, calls[k]) != 0) break;
        if (is_implicit) {
            /* implicit_euler's calls: the solver ran, and the cloth came down to the ground */
            cs_info now_info;
            cs_params now_p;
            cs_sim_info(pr.b, &now_info);
            cs_sim_params(pr.b, &now_p);
            /* (a solve a part: contact cuts a substep into parts, so at least a solve a substep) */
            solved |= now_p.integrator == IM && now_info.solver.substeps >= calls[k] && now_info.solver.newton > 0 &&
                       now_info.solver.cg > 0;
            cut |= now_p.integrator == IM && now_info.solver.substeps > calls[k];
            /* after any call (the cloth may bounce off it again: under the sanitizers' short calls
             * a thrown rock's cloth ended 0.24 mm above the layer it had been in) */
            if (lowest(pr.b) < now_p.ground_z + now_p.contact_offset) grounded = 1;
        }
        if (k == 1 && !pushed) pushed = rocks_were_pushed(pr.a, before, n_before, 8 * info.dt, p.gravity);
        if (vr->script & S_SELF) {
            cs_info si;
            cs_sim_info(pr.a, &si);
            self_contacts += si.self.contacts;
            self_cut += si.self.cut;
        }
        compare_frame(&pr);
        if (k == 1 && (vr->script & S_GRAB) && !(vr->script & S_TEAR)) both(&pr, cs_release(pr.a), cs_release(pr.b), "release");
        if (k == 2 && (vr->script & S_ROCK_SET)) {
            cs_rock r;
            cs_rock_at(pr.a, 0, &r);
            r.def.velocity[2] = 1.0f;
            both(&pr, cs_rock_set(pr.a, r.id, &r.def), cs_rock_set(pr.b, r.id, &r.def), "rock_set");
        }
        if (k == 2 && (vr->script & S_PARAMS)) {
            cs_params q = p;
            q.k_structural *= 1.5f;
            q.drag = 0.5f;
            q.wind[0] = -1.0f;
            q.gravity[0] = 0.5f;
            q.c_spring = 0.02f;
            q.contact_offset = 0.015f;
            both(&pr, cs_sim_set_params(pr.a, &q), cs_sim_set_params(pr.b, &q), "set_params");
        }
        if ((k == 2 || k == 4) && (vr->script & S_SWITCH)) {
            cs_params q;
            cs_sim_params(pr.a, &q);
            q.integrator = q.integrator == VV ? SE : VV;
            q.friction_model = q.friction_model == CV ? RS : CV;
            both(&pr, cs_sim_set_params(pr.a, &q), cs_sim_set_params(pr.b, &q), "switching integrator and friction");
        }
        if ((k == 2 || k == 4) && (vr->script & S_SWITCH_IM)) {
            cs_params q;
            cs_sim_params(pr.a, &q);
            q.integrator = q.integrator == IM ? VV : IM;
            both(&pr, cs_sim_set_params(pr.a, &q), cs_sim_set_params(pr.b, &q), "switching integrator to or from implicit_euler");
        }
        if ((k == 2 || k == 4) && (vr->script & S_CONTACT)) {
            cs_params q;
            cs_sim_params(pr.a, &q);
            q.contact_model = q.contact_model == CS_CONTACT_SURFACE ? CS_CONTACT_VERTEX : CS_CONTACT_SURFACE;
            both(&pr, cs_sim_set_params(pr.a, &q), cs_sim_set_params(pr.b, &q), "switching contact model");
        }
        if (k == 3 && (vr->script & S_SNAPSHOT)) {
            const size_t cap = cs_snapshot_size(pr.a);
            unsigned char *buf = malloc(cap);
            size_t len = 0;
            if (!buf || both(&pr, cs_snapshot_save(pr.a, buf, cap, &len), CS_OK, "snapshot save") == 0)
                both(&pr, cs_snapshot_load(pr.a, buf, len), cs_snapshot_load(pr.b, buf, len), "snapshot load");
            free(buf);
            pr.phase = "loading the snapshot";
            compare_all(&pr);
        }
        if (k == 3 && (vr->script & S_RESIZE)) {
            cs_scene sc;
            scene_of(vr, vr->nx + 5, vr->ny - 3, &sc);
            if (both(&pr, cs_sim_set_scene(pr.a, &sc), cs_sim_set_scene(pr.b, &sc), "set_scene") == 0) {
                const variant grown = {vr->name, sc.nx, sc.ny, vr->integrator, vr->friction, vr->strain, vr->rocks,
                                       vr->script, vr->radius, vr->contact};
                both(&pr, (cs_status)add_rocks(pr.a, &grown, &sc, &p), (cs_status)add_rocks(pr.b, &grown, &sc, &p),
                     "adding rocks again");
                both(&pr, grab(pr.a, vr, sc.nx, sc.ny), grab(pr.b, vr, sc.nx, sc.ny), "grab again");
            }
        }
    }
    pr.phase = "the last call";
    if (!pr.fail) compare_all(&pr);
    cs_sim_info(pr.a, &info);
    /* The scene must have done what it is there for. */
    if (!pushed) {
        printf("%-46s no rock touched the cloth in the first calls: the scene tests less than it says\n", vr->name);
        pr.fail = 1;
    }
    if (!solved) {
        printf("%-46s no call ran implicit_euler's solver\n", vr->name);
        pr.fail = 1;
    }
    if (!cut) {
        printf("%-46s no substep was cut into parts\n", vr->name);
        pr.fail = 1;
    }
    if (!grounded) {
        printf("%-46s the cloth did not reach the ground\n", vr->name);
        pr.fail = 1;
    }
    /* (under sanitizers the rock on the towel's four short calls, 0.08 s, run the pass's host
     * sequence and kernels, and the unsanitized run checks that it acts) */
    if ((vr->script & S_SELF) && !(quick && getenv("CLOTHD_SANITIZED")) && !(self_contacts + self_cut > 0)) {
        printf("%-46s self_collision: %lld contacts and %lld cuts in %.2f s (it never acted)\n",
               vr->name, (long long)self_contacts, (long long)self_cut, info.time);
        pr.fail = 1;
    }
    if (shared == 0) {
        printf("%-46s no vertex touches both rocks\n", vr->name);
        pr.fail = 1;
    }
    if ((vr->script & S_TEAR) && info.n_torn == 0) {
        printf("%-46s the grab tore nothing\n", vr->name);
        pr.fail = 1;
    }
    if (!pr.fail)
        printf("%-46s bitwise equal (hash %016llx, %lld substeps, %lld torn, %.1f s)\n", vr->name,
               (unsigned long long)cs_state_hash(pr.a), (long long)info.step, (long long)info.n_torn, now() - t0);
    cs_sim_destroy(pr.a);
    cs_sim_destroy(pr.b);
    return pr.fail;
}

/* ---- batches: cs_sims_step ---- */

/* Scenes of different sizes, integrators, friction and contact models, rock paths (none, fused,
 * split past 64) and substeps per frame, stepped together in one batch. */
static const variant batch_variants[] = {
    {"batch: verlet coulomb strain rocks grab", 24, 20, VV, CV, 1, 3, S_GRAB, 0, 0},
    {"batch: euler resultant strain rocks", 20, 16, SE, RS, 1, 2, 0, 0, 0},
    {"batch: verlet plain, soft (few substeps a frame)", 16, 12, VV, CV, 0, 0, 0, 0, 0},
    {"batch: surface contact, two rocks at once", 21, 21, VV, CV, 1, 2, S_PAIR, 0.05f, 1},
    {"batch: 66 rocks (the split rock kernels)", 20, 20, SE, CV, 1, 66, 0, 0.012f, 0},
    {"batch: wide rows (2 chunks a row), grab", 300, 3, VV, RS, 1, 1, S_GRAB, 0, 0},
    {"batch: implicit_euler strain grab", 18, 12, IM, CV, 1, 0, S_GRAB, 0, 0},
    {"batch: implicit_euler rocks", 18, 12, IM, CV, 1, 2, 0, 0, 1},
    {"batch: implicit_euler 40 x 32 rocks (a level above the tail)", 40, 32, IM, RS, 0, 1, 0, 0, 1},
    {"batch: joins mid-run, euler surface", 18, 18, SE, CV, 1, 2, 0, 0, 1},
};
#define BATCH_N 9 /* the first nine start together; the tenth joins when the second leaves */

typedef struct batch_scene {
    const variant *vr;
    cs_sim *cpu, *alone, *batched; /* the CPU backend alone, the backend under test alone and in the batch */
    int live;
} batch_scene;

static cs_sim *batch_build(const variant *vr, const char *backend, int threads, char *err, size_t err_len)
{
    cs_sim *sim = build(vr, backend, threads, err, err_len);
    /* The soft one: fewer substeps a frame than a call runs, so a call crosses the lone step's graphs. */
    if (sim && vr->nx == 16) {
        cs_params q;
        cs_sim_params(sim, &q);
        q.frame_rate = 1000.0f, q.substeps = 1;
        if (cs_sim_set_params(sim, &q) != CS_OK) {
            snprintf(err, err_len, "softening: %s", cs_sim_error(sim));
            cs_sim_destroy(sim);
            return NULL;
        }
    }
    return sim;
}

/* A copy of the CPU sim on a backend: its scene and parameters, then its snapshot (rocks, pins,
 * grab and all in one load, where adding 66 rocks one by one would refresh the device 66 times). */
static cs_sim *batch_copy(cs_sim *cpu, const char *backend, char *err, size_t err_len)
{
    cs_scene sc;
    cs_params p;
    cs_sim_scene(cpu, &sc);
    cs_sim_params(cpu, &p);
    cs_sim *sim = NULL;
    if (cs_sim_create(&sc, &p, backend, &sim, err, err_len) != CS_OK) return NULL;
    const size_t cap = cs_snapshot_size(cpu);
    unsigned char *buf = malloc(cap);
    size_t len = 0;
    if (!buf || cs_snapshot_save(cpu, buf, cap, &len) != CS_OK || cs_snapshot_load(sim, buf, len) != CS_OK) {
        snprintf(err, err_len, "copying the scene: %s", cs_sim_error(sim));
        cs_sim_destroy(sim);
        sim = NULL;
    }
    free(buf);
    return sim;
}

static int batch_add(batch_scene *b, const variant *vr, const char *other)
{
    char err[256];
    b->vr = vr;
    b->cpu = batch_build(vr, "cpu", 1, err, sizeof err);
    b->alone = b->cpu ? batch_copy(b->cpu, other, err, sizeof err) : NULL;
    b->batched = b->alone ? batch_copy(b->cpu, other, err, sizeof err) : NULL;
    b->live = b->batched != NULL;
    if (!b->live) printf("%-46s %s\n", vr->name, err);
    return b->live ? 0 : -1;
}

static void batch_drop(batch_scene *b)
{
    cs_sim_destroy(b->cpu);
    cs_sim_destroy(b->alone);
    cs_sim_destroy(b->batched);
    b->cpu = b->alone = b->batched = NULL;
    b->live = 0;
}

/* The batched copy against the backend alone and the CPU backend, all of it or the frame. */
static int batch_compare(batch_scene *b, const char *phase, int all)
{
    pair alone = {b->batched, b->alone, b->vr, phase, 0}, cpu = {b->batched, b->cpu, b->vr, phase, 0};
    if (all) {
        compare_all(&alone);
        compare_all(&cpu);
    } else {
        compare_frame(&alone);
        compare_frame(&cpu);
    }
    if (alone.fail) printf("%-46s   (batched vs alone on the same backend)\n", b->vr->name);
    if (cpu.fail) printf("%-46s   (batched vs the CPU backend alone)\n", b->vr->name);
    return alone.fail | cpu.fail;
}

/* Rounds of one cs_sims_step each, every scene by its own substeps (some finish early and idle),
 * with the same substeps stepped alone beside; a scene deleted and another added between rounds;
 * then one scene's state poisoned with a NaN: it alone fails the round, the others go on. */
static int run_batch(const char *other)
{
    const double t0 = now();
    /* Under sanitizers (CLOTHD_SANITIZED) shorter rounds: the same paths. */
    const int sanitized = getenv("CLOTHD_SANITIZED") != NULL;
    batch_scene sc[BATCH_N + 1];
    memset(sc, 0, sizeof sc);
    int fail = 0;
    for (int k = 0; k < BATCH_N; k++) fail |= batch_add(&sc[k], &batch_variants[k], other);
    if (!fail && shared_contacts(sc[3].cpu) == 0) {
        printf("%-46s no vertex touches both rocks\n", sc[3].vr->name);
        fail = 1;
    }
    int64_t soft_call = 0; /* the longest call of the soft scene */
    const int64_t base_full[] = {1, 9, 37, 23, 61}, base_fast[] = {1, 5, 11, 3};
    const int64_t *base = sanitized ? base_fast : base_full;
    const int rounds = sanitized ? 4 : 5, poison_round = rounds - 1;
    int poisoned = -1;
    for (int r = 0; r < rounds && !fail; r++) {
        if (r == 2) { /* one leaves, another joins */
            batch_drop(&sc[1]);
            fail |= batch_add(&sc[BATCH_N], &batch_variants[BATCH_N], other);
        }
        if (r == 1) /* a command right before a batch: its upload must land first */
            for (int k = 0; k < BATCH_N; k++) {
                if (!sc[k].live) continue;
                cs_params q;
                cs_sim_params(sc[k].cpu, &q);
                q.wind[0] = 1.5f + 0.25f * (float)k;
                cs_sim *three[3] = {sc[k].cpu, sc[k].alone, sc[k].batched};
                for (int c = 0; c < 3; c++)
                    if (cs_sim_set_params(three[c], &q) != CS_OK) {
                        printf("%-46s set_params failed: %s\n", sc[k].vr->name, cs_sim_error(three[c]));
                        fail = 1;
                    }
            }
        if (r == poison_round) {
            poisoned = 0;
            const int32_t v = 5 * sc[0].vr->nx + 7;
            if (cs_test_poison(sc[0].cpu, v) != CS_OK || cs_test_poison(sc[0].alone, v) != CS_OK ||
                cs_test_poison(sc[0].batched, v) != CS_OK) {
                printf("%-46s poisoning failed: %s\n", sc[0].vr->name, cs_sim_error(sc[0].batched));
                fail = 1;
                break;
            }
        }
        cs_sim *batch[BATCH_N + 1];
        int64_t substeps[BATCH_N + 1];
        cs_status each[BATCH_N + 1];
        int of[BATCH_N + 1], n = 0;
        for (int k = 0; k <= BATCH_N; k++)
            if (sc[k].live) {
                substeps[n] = base[r] + 2 * k; /* each its own: the shorter ones idle */
                /* implicit_euler's substeps are a solve each (with rocks, a solve a part): fewer */
                if (sc[k].vr->integrator == IM) substeps[n] = sc[k].vr->rocks ? 1 + r : 1 + 2 * r;
                if (k == 2 && substeps[n] > soft_call) soft_call = substeps[n];
                batch[n] = sc[k].batched;
                of[n++] = k;
            }
        const cs_status st = cs_sims_step(batch, (size_t)n, substeps, each);
        if (st != CS_OK) {
            printf("batch: cs_sims_step refused the round (%s)\n", cs_status_name(st));
            fail = 1;
            break;
        }
        char phase[64];
        snprintf(phase, sizeof phase, "batch round %d", r + 1);
        for (int j = 0; j < n; j++) {
            batch_scene *b = &sc[of[j]];
            const cs_status want = of[j] == poisoned ? CS_E_NONFINITE : CS_OK;
            const cs_status sa = cs_sim_step(b->cpu, substeps[j]);
            const cs_status sb = cs_sim_step(b->alone, substeps[j]);
            if (each[j] != want || sa != want || sb != want) {
                printf("%-46s %s: %s batched, %s alone, %s on the CPU backend (expected %s): %s\n", b->vr->name, phase,
                       cs_status_name(each[j]), cs_status_name(sb), cs_status_name(sa), cs_status_name(want),
                       cs_sim_error(b->batched));
                fail = 1;
            } else if (want == CS_OK) {
                fail |= batch_compare(b, phase, r == rounds - 1 || r == 2);
            }
        }
    }
    int crossed = 0; /* some call ran past a frame of the soft scene: its graphs split the call */
    for (int k = 0; k <= BATCH_N; k++) {
        if (!sc[k].live) continue;
        cs_info info;
        cs_sim_info(sc[k].batched, &info);
        if (k == 2) crossed = info.substeps < soft_call;
        batch_drop(&sc[k]);
    }
    if (!crossed && !fail) {
        printf("batch: no call crossed a frame of the soft scene (it tests less than it says)\n");
        fail = 1;
    }
    if (fail) printf("batch: FAILED\n");
    else
        printf("batch: %d scenes in rounds of cs_sims_step bitwise equal to each alone on the same backend and on the "
               "CPU backend; the poisoned one alone failed (%.1f s)\n",
               BATCH_N + 1, now() - t0);
    return fail;
}

int main(int argc, char **argv)
{
    const char *other = argc > 1 ? argv[1] : "cuda";
    quick = argc > 2 && strcmp(argv[2], "quick") == 0;
    /* `test_parity cuda batch`: the batch check alone (emu.batch); every full run ends with it. */
    const int batch_only = argc > 2 && strcmp(argv[2], "batch") == 0;
    if (strcmp(other, "cuda") == 0) {
        char why[160] = "this build has no CUDA backend";
        const cs_backend *cuda = cs_backend_cuda();
        if (!cuda || !cuda->available(why, sizeof why)) {
            printf("skipped: %s\n", why);
            return 77;
        }
    } else if (strcmp(other, "cpu") != 0) {
        fprintf(stderr, "usage: test_parity cuda|cpu [quick]\n");
        return 2;
    }
    /* PARITY_ONLY=text runs the scenes whose names contain it (for looking into one). */
    const char *only = getenv("PARITY_ONLY");
    int fail = 0;
    for (size_t k = 0; k < sizeof variants / sizeof variants[0] && !batch_only; k++)
        if (!only || strstr(variants[k].name, only)) fail |= run(&variants[k], other, strcmp(other, "cpu") == 0 ? 2 : 0);
    if (batch_only || (!quick && !only)) fail |= run_batch(other);
    printf(fail ? "parity: FAILED\n" : "parity: passed\n");
    return fail;
}
