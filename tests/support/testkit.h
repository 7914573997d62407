/* testkit.h - what the C tests share: building simulations with a few fields changed, and
 * white-box access to the state (setting a vertex, reading a rock) through the core's internal
 * header. Tests only; nothing here is compiled into the library. */
#ifndef CLOTHD_TESTKIT_H
#define CLOTHD_TESTKIT_H

#include <math.h>
#include <setjmp.h>
#include <stdarg.h>
#include <stddef.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <cmocka.h>

#include "clothsim/backend.h"
#include "clothsim/clothsim.h"
#include "clothsim/physics.h"
#include "sim_internal.h"

#define TK_PI 3.14159265358979323846

/* 1 under AddressSanitizer (build-asan, some 20 times slower), where long tests run a shorter
 * sample of the same code paths. */
#if defined(__SANITIZE_ADDRESS__)
#define SANITIZED 1
#elif defined(__has_feature)
#if __has_feature(address_sanitizer)
#define SANITIZED 1
#endif
#endif
#ifndef SANITIZED
#define SANITIZED 0
#endif

/* |a - b| <= tol, reporting both values when not (cmocka 1.1 has no assert_double_equal). */
#define tk_assert_near(a, b, tol)                                                                        \
    do {                                                                                                 \
        const double tk_a_ = (a), tk_b_ = (b), tk_t_ = (tol);                                           \
        if (!(fabs(tk_a_ - tk_b_) <= tk_t_))                                                             \
            fail_msg("%s = %.12g, expected %s = %.12g within %.3g", #a, tk_a_, #b, tk_b_, tk_t_);       \
    } while (0)

/* A simulation on the CPU backend, failing the test if it cannot be made. */
static inline cs_sim *tk_sim(const cs_scene *scene, const cs_params *params)
{
    cs_sim *sim = NULL;
    char err[256];
    const cs_status st = cs_sim_create(scene, params, "cpu", &sim, err, sizeof err);
    if (st != CS_OK) fail_msg("cs_sim_create: %s (%s)", err, cs_status_name(st));
    return sim;
}

/* Like tk_sim, stepping on one CPU thread. For small scenes: OpenMP's per-substep barriers cost
 * more than they save there, and on a loaded machine (ctest -j, other builds) a descheduled
 * thread stalls every barrier - a run of 0.4 s was seen to take 9 s. Results do not depend on
 * the thread count. */
static inline cs_sim *tk_sim_serial(const cs_scene *scene, const cs_params *params)
{
    cs_sim *sim = tk_sim(scene, params);
    assert_int_equal(cs_sim_set_threads(sim, 1), CS_OK);
    return sim;
}

/* The soft material of the first defaults (1 kg/m^2, 400/80/20 N/m springs, k_contact 400 N/m,
 * c_tangent 0.5 N s/m), which the analytic expectations of several tests are written in: they
 * pin it rather than follow the defaults. */
static inline void tk_v1_material(cs_scene *sc, cs_params *p)
{
    sc->areal_density = 1.0f;
    p->k_structural = 400.0f, p->k_shear = 80.0f, p->k_bend = 20.0f;
    p->k_contact = 400.0f, p->c_tangent = 0.5f;
}

/* Defaults on the v1 material with every external influence off: no gravity, drag, damping or
 * ground. */
static inline void tk_quiet(cs_scene *sc, cs_params *p)
{
    cs_scene_default(sc);
    cs_params_default(p);
    tk_v1_material(sc, p);
    p->gravity[2] = 0.0f;
    p->drag = 0.0f;
    p->c_spring = 0.0f;
    p->c_contact = 0.0f;
    p->ground = 0;
}

/* Sets a vertex's position and velocity (either may be NULL) as a command would. */
static inline void tk_set_vertex(cs_sim *sim, int32_t v, const float *x, const float *vel)
{
    assert_int_equal(cs_sim_sync(sim, CS_SYNC_ALL), CS_OK);
    cs_state *s = &sim->state;
    if (x) s->x[v] = x[0], s->y[v] = x[1], s->z[v] = x[2];
    if (vel) s->vx[v] = vel[0], s->vy[v] = vel[1], s->vz[v] = vel[2];
    assert_int_equal(cs_sim_commit(sim), CS_OK);
}

static inline cs_rock tk_rock(cs_sim *sim, uint32_t id)
{
    cs_rock r;
    assert_int_equal(cs_rock_get(sim, id, &r), CS_OK);
    return r;
}

static inline uint32_t tk_add_rock(cs_sim *sim, float x, float y, float z, float radius, float density)
{
    cs_rock_def d;
    cs_rock_def_default(&d);
    d.position[0] = x, d.position[1] = y, d.position[2] = z;
    d.radius = radius;
    d.density = density;
    uint32_t id = 0;
    const cs_status st = cs_rock_add(sim, &d, &id);
    if (st != CS_OK) fail_msg("cs_rock_add: %s", cs_sim_error(sim));
    return id;
}

/* Puts a rock into the state as it is, past cs_rock_add's overlap refusal: for tests that press
 * rocks into the cloth or into each other on purpose. Guarded and committed like a command. */
static inline uint32_t tk_place_rock(cs_sim *sim, const cs_rock_def *d)
{
    assert_int_equal(cs_sim_sync(sim, CS_SYNC_ALL), CS_OK);
    cs_state *s = &sim->state;
    cs_rock_state *rocks = realloc(s->rocks, sizeof *rocks * (size_t)(s->n_rocks + 1));
    assert_non_null(rocks);
    cs_rock_state *r = &rocks[s->n_rocks];
    memset(r, 0, sizeof *r);
    const float *q = d->orientation;
    const float inv = 1.0f / sqrtf(q[0] * q[0] + q[1] * q[1] + q[2] * q[2] + q[3] * q[3]);
    r->x = cs_v3_from(d->position), r->v = cs_v3_from(d->velocity), r->w = cs_v3_from(d->angular_velocity);
    for (int i = 0; i < 4; i++) r->q[i] = q[i] * inv;
    r->radius = d->radius, r->density = d->density, r->kinematic = d->kinematic;
    cs_rock_mass(r);
    r->id = s->next_rock_id++;
    s->rocks = rocks, s->rock_cap = s->n_rocks + 1;
    s->n_rocks++;
    assert_int_equal(cs_sim_reguard(sim, s->rocks, s->n_rocks, NULL), CS_OK);
    assert_int_equal(cs_sim_commit(sim), CS_OK);
    return r->id;
}

/* Rest lengths (6 n, type-major) as a freshly allocated array. */
static inline float *tk_rest_lengths(cs_sim *sim)
{
    const size_t n = (size_t)sim->state.n * CS_NTYPES;
    float *L = malloc(n * sizeof(float));
    assert_non_null(L);
    assert_int_equal(cs_read_rest_lengths(sim, L, n), CS_OK);
    return L;
}

/* The cloth's surface on the line through (a, b) along axis ax (0 x, 1 y, 2 z; a, b the other two
 * coordinates in order): the lowest and highest coordinate along ax of its intact triangles
 * there; 0 when none meets the line. */
static inline int tk_surface_on_line(const cs_sim *sim, int ax, double a, double b, double *lo, double *hi)
{
    const cs_state *s = &sim->state;
    const float *P[3] = {s->x, s->y, s->z};
    const float *A = P[ax == 0 ? 1 : 0], *B = P[ax == 2 ? 1 : 2], *D = P[ax];
    int found = 0;
    int32_t t[3];
    for (int64_t k = 0; cs_next_triangle(s->L0, sim->model.phys.nx, sim->model.phys.ny, &k, t);) {
        const double ax0 = A[t[0]], ay0 = B[t[0]], bx = A[t[1]], by = B[t[1]], cx = A[t[2]], cy = B[t[2]];
        const double det = (bx - ax0) * (cy - ay0) - (cx - ax0) * (by - ay0);
        if (fabs(det) < 1e-14) continue;
        const double u = ((a - ax0) * (cy - ay0) - (cx - ax0) * (b - ay0)) / det;
        const double v = ((bx - ax0) * (b - ay0) - (a - ax0) * (by - ay0)) / det;
        if (u < 0 || v < 0 || u + v > 1) continue;
        const double d = D[t[0]] + u * (D[t[1]] - D[t[0]]) + v * (D[t[2]] - D[t[0]]);
        if (!found || d < *lo) *lo = d;
        if (!found || d > *hi) *hi = d;
        found = 1;
    }
    return found;
}

/* Positions as a freshly allocated xyz array. */
static inline float *tk_positions(cs_sim *sim)
{
    const size_t n = (size_t)sim->state.n;
    float *xyz = malloc(sizeof(float) * 3 * n);
    assert_non_null(xyz);
    assert_int_equal(cs_read_positions(sim, xyz, 3 * n), CS_OK);
    return xyz;
}

static inline void tk_step(cs_sim *sim, int64_t substeps)
{
    const cs_status st = cs_sim_step(sim, substeps);
    if (st != CS_OK) fail_msg("cs_sim_step: %s", cs_sim_error(sim));
}

/* Total linear momentum of cloth and dynamic rocks. */
static inline void tk_momentum(cs_sim *sim, double out[3])
{
    assert_int_equal(cs_sim_sync(sim, CS_SYNC_ALL), CS_OK);
    const cs_state *s = &sim->state;
    const double m = sim->model.phys.mass;
    out[0] = out[1] = out[2] = 0;
    for (int32_t v = 0; v < s->n; v++) {
        out[0] += m * s->vx[v];
        out[1] += m * s->vy[v];
        out[2] += m * s->vz[v];
    }
    for (int32_t r = 0; r < s->n_rocks; r++) {
        const cs_rock_state *k = &s->rocks[r];
        if (k->kinematic) continue;
        out[0] += (double)k->mass * k->v.x;
        out[1] += (double)k->mass * k->v.y;
        out[2] += (double)k->mass * k->v.z;
    }
}

#endif
