/* implicit_cpu.c - integrator implicit_euler on the CPU backend: the functions of
 * clothsim/implicit.h looped over the grid with OpenMP, in the sequence below (kernels/MODEL.md,
 * "The implicit solver").
 *
 * A substep of length h (cut into equal parts while a cloth vertex near a rock would close on it
 * by more than cs_im_depth in one: cs_im_closing, cs_im_splits), each part:
 *   1. the rocks advanced without the cloth (cs_im_rocks_advance: sub-cycled to cs_phys.rock_dt
 *      under gravity, rock-rock and ground contact), and the mass each dynamic rock lends the
 *      vertices that may touch it in the part (cs_im_rocks_share; implicit.h, "rock contact" and
 *      "the rock steps of a part");
 *   2. the cloth: x_n and v_n kept aside, the first guess x = x_n + h v_n + h^2 a (a:
 *      cs_im_guess_accel; pinned vertices stay, the grabbed one moves at its grab velocity), then
 *      Newton: assemble (the residual, and the blocks where another iteration may follow, the
 *      carried mass and the ground included) at the iterate, stop at solver_tolerance
 *      of the first residual, at float's floor, after solver_iterations or once an iteration no
 *      longer halves it, else solve A dx = R by conjugate gradients preconditioned with one
 *      multigrid V-cycle (at most cg_iterations) and step along dx with a backtracking line
 *      search, v = (x - x_n)/h;
 *   3. the rocks moved by what their vertices carried (no touching pair pressed closer than the
 *      advance left it: cs_im_rocks_apart), then rocks and cloth pushed apart
 *      (cs_im_rocks_push), the cloth's velocities (x - x_n)/h again; a = (v - v_n)/h; with strain,
 *      the rest lengths from the new positions (cs_cpu_strain_row), swapped.
 * The rock steps (cs_im_rocks_advance, _share, _push: implicit.h, shared with the CUDA backend)
 * run on one thread in a fixed order: they touch only the few triangles near each rock after one
 * scan of the grid.
 * Every loop's iterations are independent (each writes its own vertex or chunk), and every sum goes
 * through per-chunk trees summed in chunk order, so the result is the same for any thread count. */
#include <math.h>
#include <stdlib.h>
#include <string.h>

#include "clothsim/implicit.h"
#include "cpu_internal.h"
#include "clothsim/selfcontact.h"

typedef struct im_level {
    int32_t nx, ny, n;
    size_t S;                       /* the blocks' stride (cs_im_stride) */
    float *D, *Dinv, *F[4], *mask; /* coarse levels own mask; level 0 points at the state's w */
    float *b, *x, *t;               /* 3 n each: right side, solution, scratch */
} im_level;

struct cs_im_work {
    int32_t nx, ny, n, nchunks, levels;
    float *xb, *yb, *zb, *vxb, *vyb, *vzb; /* the substep's x_n and v_n */
    float *xo, *yo, *zo;                   /* the Newton iterate a line search starts from */
    float *R;                              /* residual, 3 n (AoS) */
    float *fo;                             /* each vertex's owned springs' forces, CS_NTYPES x 3 n */
    float *B[2];                           /* bending blocks of level 0 */
    float *dx, *r, *z, *p, *q;             /* conjugate gradients, 3 n each */
    float *part;                           /* per-chunk partials of a dot product */
    cs_rock_state *star;                   /* each rock where it would be without the cloth */
    int32_t *cand;                         /* a rock's triangles (2 quad + face) or vertices near it */
    float *sh, *sn;                        /* per vertex: the rock mass it carries, its normal (3 n) */
    float *sg;                             /* per vertex: what a rock's push moved it (0 between pushes) */
    int32_t *sr;                           /* per vertex: the rock it carries (-1 none) */
    float *rowbox;                         /* per grid row: the box of it and the next (cs_im_row_box) */
    int32_t rows[2 * CS_MAX_ROCKS];        /* each rock's vertex span in cs_im_rocks_share */
    cs_vec3 rx0[CS_MAX_ROCKS];             /* each rock at the part's start */
    cs_vec3 rf[CS_MAX_ROCKS], rt[CS_MAX_ROCKS]; /* the rock steps' scratch (cs_im_rocks' F, T) */
    im_level lv[CS_IM_MAX_LEVELS];
    void *mem;
};

void cs_im_free(cs_im_work *w)
{
    if (!w) return;
    free(w->mem);
    free(w->star);
    free(w->cand);
    free(w->sr);
    free(w);
}

/* Floats of the workspace's block for an nx x ny cloth of nchunks chunks (work_new's layout). */
static size_t work_floats(int32_t nx, int32_t ny, int32_t nchunks)
{
    const size_t n = (size_t)nx * (size_t)ny, S0 = cs_im_stride(n); /* level 0's, which the bending blocks share */
    size_t floats = n * (9 + 3 + 15 + 18 + 5) + 2 * CS_IM_SYM * S0 + (size_t)nchunks + 6 * (size_t)ny;
    int32_t lx[CS_IM_MAX_LEVELS], ly[CS_IM_MAX_LEVELS];
    const int L = cs_im_levels(nx, ny, lx, ly);
    for (int l = 0; l < L; l++) floats += cs_im_level_floats((size_t)lx[l] * (size_t)ly[l]);
    return floats;
}

uint64_t cs_im_work_bytes(int32_t nx, int32_t ny, int32_t nchunks)
{
    const uint64_t n = (uint64_t)nx * (uint64_t)ny;
    return sizeof(float) * (uint64_t)work_floats(nx, ny, nchunks) + sizeof(cs_im_work) +
           sizeof(cs_rock_state) * CS_MAX_ROCKS + sizeof(int32_t) * 3 * n;
}

/* Lays out the workspace for an nx x ny cloth in one allocation; NULL when out of memory. */
static cs_im_work *work_new(int32_t nx, int32_t ny, int32_t nchunks)
{
    cs_im_work *w = calloc(1, sizeof *w);
    if (!w) return NULL;
    w->nx = nx, w->ny = ny, w->n = nx * ny, w->nchunks = nchunks;
    const size_t S0 = cs_im_stride((size_t)w->n); /* level 0's, which the bending blocks share */
    const size_t floats = work_floats(nx, ny, nchunks);
    int32_t lx[CS_IM_MAX_LEVELS], ly[CS_IM_MAX_LEVELS];
    const int L = w->levels = cs_im_levels(nx, ny, lx, ly);
    for (int l = 0; l < L; l++) {
        w->lv[l].nx = lx[l], w->lv[l].ny = ly[l], w->lv[l].n = lx[l] * ly[l];
        w->lv[l].S = cs_im_stride((size_t)w->lv[l].n);
    }
    float *m = malloc(sizeof(float) * floats);
    w->star = calloc(CS_MAX_ROCKS, sizeof *w->star);
    w->cand = malloc(sizeof *w->cand * 2 * (size_t)w->n);
    w->sr = malloc(sizeof *w->sr * (size_t)w->n);
    if (!m || !w->star || !w->cand || !w->sr) {
        free(w->cand);
        free(w->sr);
        free(m);
        free(w->star);
        free(w);
        return NULL;
    }
    w->mem = m;
    const size_t n = (size_t)w->n;
#define TAKE(k) (m += (k), m - (k))
    w->xb = TAKE(n), w->yb = TAKE(n), w->zb = TAKE(n);
    w->vxb = TAKE(n), w->vyb = TAKE(n), w->vzb = TAKE(n);
    w->xo = TAKE(n), w->yo = TAKE(n), w->zo = TAKE(n);
    const size_t nv = 3 * n;
    w->R = TAKE(nv);
    w->B[0] = TAKE(CS_IM_SYM * S0), w->B[1] = TAKE(CS_IM_SYM * S0);
    w->fo = TAKE(18 * n);
    w->dx = TAKE(nv), w->r = TAKE(nv), w->z = TAKE(nv), w->p = TAKE(nv), w->q = TAKE(nv);
    w->part = TAKE((size_t)nchunks);
    w->sh = TAKE(n), w->sn = TAKE(3 * n), w->sg = TAKE(n);
    w->rowbox = TAKE(6 * (size_t)ny);
    for (int l = 0; l < L; l++) {
        im_level *v = &w->lv[l];
        m = cs_im_carve_level(m, (size_t)v->n, &v->D, &v->Dinv, v->F, &v->mask, &v->b, &v->x, &v->t);
    }
#undef TAKE
    memset(w->mem, 0, sizeof(float) * floats);
    for (int32_t v = 0; v < w->n; v++) w->sr[v] = -1;
    return w;
}

static cs_status work_fit(cs_im_work **w, const cs_phys *p)
{
    if (*w && (*w)->nx == p->nx && (*w)->ny == p->ny) return CS_OK;
    cs_im_work *n = work_new(p->nx, p->ny, p->nchunks);
    if (!n) return CS_E_NOMEM;
    cs_im_free(*w);
    *w = n;
    return CS_OK;
}

/* The level as implicit.h's functions read it (level 0's mask is the state's w). */
static cs_im_level view(const cs_im_work *w, int l, const cs_state *s)
{
    const im_level *v = &w->lv[l];
    cs_im_level L;
    L.nx = v->nx, L.ny = v->ny, L.S = v->S;
    L.mask = l == 0 ? s->w : v->mask;
    L.D = v->D, L.Dinv = v->Dinv;
    for (int t = 0; t < 4; t++) L.F[t] = v->F[t];
    L.B[0] = l == 0 ? w->B[0] : NULL, L.B[1] = l == 0 ? w->B[1] : NULL;
    return L;
}

static void put3(float *a, int32_t v, cs_vec3 x)
{
    a[3 * (size_t)v] = x.x, a[3 * (size_t)v + 1] = x.y, a[3 * (size_t)v + 2] = x.z;
}
/* Block m as vertex v's of an array of blocks of S vertices (implicit.h: element major). */
static void put_sym(float *a, size_t S, int32_t v, const cs_mat3 *m) { cs_im_sym_put(a + v, S, m); }

/* ---- assembly ---- */

/* Chunk c: its row j and columns i0 .. i1 (physics.h, CS_CHUNK). */
static void chunk_span(const cs_phys *p, int32_t c, int32_t *j, int32_t *i0, int32_t *i1)
{
    *j = c / p->nseg;
    *i0 = (c % p->nseg) * CS_CHUNK;
    *i1 = *i0 + CS_CHUNK < p->nx ? *i0 + CS_CHUNK : p->nx;
}

#define LOADX(o) cs_v3(s->x[(o)], s->y[(o)], s->z[(o)])
#define LOADV(o) cs_v3(s->vx[(o)], s->vy[(o)], s->vz[(o)])

/* Before a loop whose iterations touch disjoint data that the compiler cannot tell apart (the rows
 * of one restrict array of blocks): GCC vectorizes it without checks of overlap at run time.
 * (Clang's assume_safety warns where it does not vectorize, as at -O1: left to its own checks.) */
#if defined(__GNUC__) && !defined(__clang__)
#define IVDEP _Pragma("GCC ivdep")
#else
#define IVDEP
#endif

/* The springs of type t that vertices v0 .. v1 - 1 own, each reaching v + off (on the grid), evaluated
 * once from their owner (cs_im_spring): forces into fo (3 a vertex), with blocks their negated
 * blocks into blk (stride S). Plain loops that vectorize (the outputs restrict, as they are: in
 * functions of their own, as apply_run_bend). */
#define OWNED_RUN(name, blocks)                                                                                   \
    __attribute__((noinline)) static void name(const cs_phys *p, float h, const cs_state *s, int t, int32_t v0,   \
                                               int32_t v1, int32_t off, float *restrict fo, float *restrict blk,  \
                                               size_t S)                                                          \
    {                                                                                                            \
        const float *L0 = s->L0 + (size_t)t * (size_t)p->n;                                                      \
        const float k = p->k[t], c = p->c_spring;                                                                \
        IVDEP                                                                                                    \
        for (int32_t v = v0; v < v1; v++) {                                                                      \
            const int32_t q = v + off;                                                                           \
            cs_mat3 b;                                                                                           \
            const cs_vec3 F = cs_im_spring(LOADX(v), LOADV(v), LOADX(q), LOADV(q), L0[v], k, c, h, &b);          \
            fo[3 * (size_t)v] = F.x, fo[3 * (size_t)v + 1] = F.y, fo[3 * (size_t)v + 2] = F.z;                   \
            if (!(blocks)) continue;                                                                             \
            for (int e = 0; e < 9; e++) b.m[e] = -b.m[e];                                                        \
            cs_im_sym_put(blk + v, S, &b);                                                                       \
        }                                                                                                        \
    }
OWNED_RUN(owned_run_blocks, 1)
OWNED_RUN(owned_run_forces, 0)
#undef OWNED_RUN

/* Vertex v has no spring of the type whose forces are fo and blocks blk (NULL: none kept). */
static void no_spring(float *fo, float *blk, size_t S, int32_t v)
{
    put3(fo, v, cs_v3(0.0f, 0.0f, 0.0f));
    if (blk) {
        const cs_mat3 zero = cs_m3_zero();
        put_sym(blk, S, v, &zero);
    }
}

/* The springs each vertex of chunk (row j, columns i0 .. i1) owns, evaluated once from their
 * owner (owned_run_*): forces into fo, negated blocks into level 0's F and the bending blocks
 * (blocks: 1; zero where the grid has no such spring). */
static void chunk_owned(const cs_phys *p, float h, const cs_state *s, cs_im_work *w, int32_t j, int32_t i0, int32_t i1,
                        int blocks)
{
    const int32_t nx = p->nx, ny = p->ny;
    const size_t n = (size_t)p->n;
    im_level *l0 = &w->lv[0];
    for (int t = 0; t < CS_NTYPES; t++) {
        float *fo = w->fo + (size_t)t * 3 * n, *blk = t < 4 ? l0->F[t] : w->B[t - 4];
        const int di = cs_type_di[t], dj = cs_type_dj[t];
        /* the columns whose spring of type t reaches the grid: i + di in 0 .. nx - 1, j + dj < ny */
        int32_t a = i0 > -di ? i0 : -di, e = i1 < nx - di ? i1 : nx - di;
        if (j + dj >= ny || a > e) a = e = i1;
        for (int32_t i = i0; i < a; i++) no_spring(fo, blocks ? blk : NULL, l0->S, j * nx + i);
        if (a < e)
            (blocks ? owned_run_blocks : owned_run_forces)(p, h, s, t, j * nx + a, j * nx + e, di + dj * nx, fo, blk,
                                                         l0->S);
        for (int32_t i = e; i < i1; i++) no_spring(fo, blocks ? blk : NULL, l0->S, j * nx + i);
    }
}

/* d + (-B), element by element, written out (a loop over the elements keeps a vectorizer from the
 * loop around it). */
static inline cs_mat3 minus(cs_mat3 d, const cs_mat3 *B)
{
    d.m[0] += -B->m[0], d.m[1] += -B->m[1], d.m[2] += -B->m[2];
    d.m[3] += -B->m[3], d.m[4] += -B->m[4], d.m[5] += -B->m[5];
    d.m[6] += -B->m[6], d.m[7] += -B->m[7], d.m[8] += -B->m[8];
    return d;
}

/* The springs, air and gravity of vertex v = (i, j) at the iterate, gathered in CS_SPRING_SLOTS
 * order from their owners' evaluations (the same bits as cs_im_springs: a spring from its other end
 * is the exact negation, its block the same): force into R (the residual comes later), Ro into q
 * (resultant friction reads it), the diagonal into D (stride S; blocks: 1). inner: every slot's
 * neighbour is on the grid (2 <= i < nx - 2, 2 <= j < ny - 2), which skips the tests. */
__attribute__((always_inline)) static inline void springs_at(const cs_phys *p, float h, const cs_state *s,
                                                            const cs_im_work *w, int32_t i, int32_t j, int blocks,
                                                            int inner, float *restrict R, float *restrict q,
                                                            float *restrict D)
{
    const int32_t nx = p->nx, ny = p->ny, v = j * nx + i;
    const size_t n = (size_t)p->n, S = w->lv[0].S;
    const float *const blk[CS_NTYPES] = {w->lv[0].F[0], w->lv[0].F[1], w->lv[0].F[2], w->lv[0].F[3], w->B[0], w->B[1]};
    cs_vec3 f = cs_v3(0.0f, 0.0f, 0.0f);
    cs_mat3 d = cs_m3_zero();
#define CS_IM_GATHER(t, di, dj, fwd)                                                                \
    {                                                                                              \
        const int32_t ii = i + (di), jj = j + (dj);                                                \
        if (inner || (ii >= 0 && ii < nx && jj >= 0 && jj < ny)) {                                 \
            const int32_t o = (fwd) ? v : jj * nx + ii; /* the owner */                            \
            const cs_vec3 F = cs_v3_from(w->fo + (size_t)(t) * 3 * n + 3 * (size_t)o);             \
            f = cs_add(f, (fwd) ? F : cs_neg(F));                                                  \
            if (blocks) {                                                                          \
                const cs_mat3 B = cs_im_sym_get(blk[t] + o, S);                                    \
                d = minus(d, &B);                                                                  \
            }                                                                                      \
        }                                                                                          \
    }
    CS_SPRING_SLOTS(CS_IM_GATHER)
#undef CS_IM_GATHER
    f = cs_add(f, cs_air_gravity(LOADV(v), p));
    R[3 * (size_t)v] = f.x, R[3 * (size_t)v + 1] = f.y, R[3 * (size_t)v + 2] = f.z;
    q[3 * (size_t)v] = f.x, q[3 * (size_t)v + 1] = f.y, q[3 * (size_t)v + 2] = f.z;
    if (blocks) {
        const cs_mat3 Dv = cs_im_inertia(p, h, d);
        cs_im_sym_put(D + v, S, &Dv);
    }
}

/* springs_at over the inner vertices v0 .. v1 - 1 of a row: plain loops that vectorize (as
 * owned_run_blocks). */
#define SPRINGS_RUN(name, blocks)                                                                                 \
    __attribute__((noinline)) static void name(const cs_phys *p, float h, const cs_state *s, const cs_im_work *w, \
                                               int32_t j, int32_t i0, int32_t i1, float *restrict R,             \
                                               float *restrict q, float *restrict D)                             \
    {                                                                                                            \
        const cs_phys P = *p; /* its floats in registers: R, q, D are floats too */                               \
        IVDEP                                                                                                    \
        for (int32_t i = i0; i < i1; i++) springs_at(&P, h, s, w, i, j, blocks, 1, R, q, D);                     \
    }
SPRINGS_RUN(springs_run_blocks, 1)
SPRINGS_RUN(springs_run_forces, 0)
#undef SPRINGS_RUN

/* springs_at for chunk (row j, columns i0 .. i1). */
static void chunk_springs(const cs_phys *p, float h, const cs_state *s, cs_im_work *w, int32_t j, int32_t i0,
                          int32_t i1, int blocks)
{
    const int32_t nx = p->nx, ny = p->ny;
    float *R = w->R, *q = w->q, *D = w->lv[0].D;
    /* the inner columns of an inner row, a run; the rest one by one */
    int32_t a = i0 > 2 ? i0 : 2, e = i1 < nx - 2 ? i1 : nx - 2;
    if (j < 2 || j >= ny - 2 || a > e) a = e = i1;
    for (int32_t i = i0; i < a; i++) springs_at(p, h, s, w, i, j, blocks, 0, R, q, D);
    if (a < e) (blocks ? springs_run_blocks : springs_run_forces)(p, h, s, w, j, a, e, R, q, D);
    for (int32_t i = e; i < i1; i++) springs_at(p, h, s, w, i, j, blocks, 0, R, q, D);
}

static void add3(float *a, int32_t v, cs_vec3 x)
{
    a[3 * (size_t)v] += x.x, a[3 * (size_t)v + 1] += x.y, a[3 * (size_t)v + 2] += x.z;
}
/* Adds block m to the stored block a of vertex v. */
static void add_sym(float *a, size_t S, int32_t v, const cs_mat3 *m)
{
    cs_mat3 s = cs_im_sym_get(a + v, S);
    cs_m3_addto(&s, m);
    put_sym(a, S, v, &s);
}

/* Contacts of chunk (row j, columns i0 .. i1): the rock mass each vertex carries (rocks_share:
 * cs_im_carried_at), then the ground: forces onto R, blocks onto level 0's D (blocks: 1). */
static void chunk_contacts(const cs_phys *p, float h, const cs_state *s, cs_im_work *w, const cs_im_rocks *rv,
                           int32_t j, int32_t i0, int32_t i1, int blocks)
{
    const int32_t nx = p->nx;
    float *D = w->lv[0].D;
    for (int32_t i = i0; i < i1; i++) {
        const int32_t v = j * nx + i;
        cs_vec3 F;
        cs_mat3 b;
        if (!cs_im_carried_at(rv, v, LOADX(v), cs_v3(w->xb[v], w->yb[v], w->zb[v]), h, &F, &b)) continue;
        add3(w->R, v, F);
        if (blocks) add_sym(D, w->lv[0].S, v, &b);
    }
    if (!p->ground) return;
    for (int32_t i = i0; i < i1; i++) {
        const int32_t v = j * nx + i;
        const cs_vec3 xi = LOADX(v), vi = LOADV(v);
        const cs_vec3 ro = cs_v3(w->q[3 * (size_t)v], w->q[3 * (size_t)v + 1], w->q[3 * (size_t)v + 2]);
        cs_vec3 Fc;
        if (!cs_vertex_ground_contact(xi, vi, ro, p, &Fc)) continue;
        add3(w->R, v, Fc);
        if (blocks) {
            const cs_mat3 b = cs_im_ground_block(xi, vi, p, h);
            add_sym(D, w->lv[0].S, v, &b);
        }
    }
}

/* The residual R = F - m (v - v_n)/h of chunk's vertices (0 where out of the solve, whose D becomes
 * the identity), and the partial of |R|^2 (chunk tree). */
static void chunk_residual(const cs_phys *p, float h, const cs_state *s, cs_im_work *w, int32_t j, int32_t i0,
                           int32_t i1, int32_t chunk, int blocks)
{
    float buf[CS_CHUNK];
    for (int k = 0; k < CS_CHUNK; k++) buf[k] = 0.0f;
    for (int32_t i = i0; i < i1; i++) {
        const int32_t v = j * p->nx + i;
        const cs_vec3 F = cs_v3_from(w->R + 3 * (size_t)v);
        cs_vec3 R = cs_im_residual(p, F, LOADV(v), cs_v3(w->vxb[v], w->vyb[v], w->vzb[v]), h);
        if (s->w[v] == 0.0f) {
            R = cs_v3(0.0f, 0.0f, 0.0f);
            if (blocks) {
                const cs_mat3 I = cs_m3_diag(1.0f);
                put_sym(w->lv[0].D, w->lv[0].S, v, &I);
            }
        }
        put3(w->R, v, R);
        buf[i - i0] = cs_dot(R, R);
    }
    w->part[chunk] = cs_tree_sum(buf);
}

/* Assembles at the iterate (the state's x and v; the carried mass as rv holds it): R, and with
 * blocks level 0's matrix. Returns |R|. */
static float assemble(const cs_phys *p, float h, const cs_state *s, cs_im_work *w, const cs_im_rocks *rv, int blocks,
                      int threads)
{
    const int32_t nchunks = p->nchunks;
    CS_PARALLEL_FOR(threads, schedule(static),
    for (int32_t c = 0; c < nchunks; c++) {
        int32_t j, i0, i1;
        chunk_span(p, c, &j, &i0, &i1);
        chunk_owned(p, h, s, w, j, i0, i1, blocks);
    });
    CS_PARALLEL_FOR(threads, schedule(static),
    for (int32_t c = 0; c < nchunks; c++) {
        int32_t j, i0, i1;
        chunk_span(p, c, &j, &i0, &i1);
        chunk_springs(p, h, s, w, j, i0, i1, blocks);
        chunk_contacts(p, h, s, w, rv, j, i0, i1, blocks);
        chunk_residual(p, h, s, w, j, i0, i1, c, blocks);
    });
    return sqrtf(cs_im_chunk_total(w->part, nchunks));
}

/* ---- the linear solve ---- */

/* a . b over level 0 (chunk trees, then chunks in order). */
static float dot(const cs_phys *p, cs_im_work *w, const float *a, const float *b, int threads)
{
    CS_PARALLEL_FOR(threads, schedule(static),
    for (int32_t c = 0; c < p->nchunks; c++) {
        int32_t j, i0, i1;
        chunk_span(p, c, &j, &i0, &i1);
        float buf[CS_CHUNK];
        for (int k = 0; k < CS_CHUNK; k++) buf[k] = 0.0f;
        for (int32_t i = i0; i < i1; i++) buf[i - i0] = cs_im_dot3(a, b, j * p->nx + i);
        w->part[c] = cs_tree_sum(buf);
    });
    return cs_im_chunk_total(w->part, p->nchunks);
}

/* y = A x over a row's vertices v0 .. v1 - 1, each of whose neighbours is on the grid: plain loops
 * that the compiler vectorizes (cs_im_apply_inner with bend a constant), each a function of its own
 * so that y's restrict holds (as it does: without it the compiler would need more overlap checks
 * than it makes; inlined into the OpenMP body, the qualifier is lost). */
#define APPLY_RUN(name, bend)                                                                                     \
    __attribute__((noinline)) static void name(const cs_im_level *L, const float *x, float *restrict y, int32_t v0, \
                                               int32_t v1)                                                       \
    {                                                                                                            \
        for (int32_t v = v0; v < v1; v++) {                                                                      \
            const cs_vec3 r = cs_im_apply_inner(L, x, v, bend);                                                  \
            y[3 * (size_t)v] = r.x, y[3 * (size_t)v + 1] = r.y, y[3 * (size_t)v + 2] = r.z;                     \
        }                                                                                                        \
    }
APPLY_RUN(apply_run_bend, 1)
APPLY_RUN(apply_run_flat, 0)
#undef APPLY_RUN

/* y = A x on level l (bend: the true operator of level 0, bending blocks included). */
static void apply(const cs_im_level *L, const float *x, float *y, int bend, int threads)
{
    const int32_t e = bend ? 2 : 1, nx = L->nx, ny = L->ny;
    CS_PARALLEL_FOR(threads, schedule(static),
    for (int32_t j = 0; j < ny; j++) {
        if (j < e || j >= ny - e || nx <= 2 * e) {
            for (int32_t i = 0; i < nx; i++) put3(y, j * nx + i, cs_im_apply(L, x, i, j, bend));
            continue;
        }
        for (int32_t i = 0; i < e; i++) put3(y, j * nx + i, cs_im_apply(L, x, i, j, bend));
        (bend ? apply_run_bend : apply_run_flat)(L, x, y, j * nx + e, j * nx + nx - e);
        for (int32_t i = nx - e; i < nx; i++) put3(y, j * nx + i, cs_im_apply(L, x, i, j, bend));
    });
}

/* The Jacobi update (cs_im_jacobi) of vertices v0 .. v1 - 1: plain loops that vectorize, functions
 * of their own for x's restrict (apply_run_bend's reasons). */
#define JACOBI_RUN(name, first)                                                                                   \
    __attribute__((noinline)) static void name(const cs_im_level *L, float *restrict x, const float *b,          \
                                               const float *t, int32_t v0, int32_t v1)                           \
    {                                                                                                            \
        const cs_vec3 zero = cs_v3(0.0f, 0.0f, 0.0f);                                                            \
        for (int32_t v = v0; v < v1; v++) {                                                                      \
            const cs_vec3 xv = (first) ? zero : cs_v3(x[3 * (size_t)v], x[3 * (size_t)v + 1], x[3 * (size_t)v + 2]); \
            const cs_vec3 r = cs_im_jacobi(L, v, xv, cs_v3_from(b + 3 * (size_t)v),                              \
                                           (first) ? zero : cs_v3_from(t + 3 * (size_t)v));                      \
            x[3 * (size_t)v] = r.x, x[3 * (size_t)v + 1] = r.y, x[3 * (size_t)v + 2] = r.z;                      \
        }                                                                                                        \
    }
JACOBI_RUN(jacobi_first, 1)
JACOBI_RUN(jacobi_next, 0)
#undef JACOBI_RUN

/* The vertices a thread's piece of a loop over a level takes at once. */
#define PIECE 1024

/* x = x + omega Dinv (b - t) where t = A x (first: x = omega Dinv b, from x = 0). */
static void jacobi(const cs_im_level *L, float *x, const float *b, const float *t, int first, int threads)
{
    const int32_t n = L->nx * L->ny;
    CS_PARALLEL_FOR(threads, schedule(static),
    for (int32_t v0 = 0; v0 < n; v0 += PIECE)
        (first ? jacobi_first : jacobi_next)(L, x, b, t, v0, v0 + PIECE < n ? v0 + PIECE : n););
}

/* The fewest vertices a level shares among threads. */
#define PARALLEL_MIN 2048

/* One V-cycle from level l: x = B b (x and b on that level; level 0's are the caller's). */
static void vcycle(cs_im_work *w, const cs_state *s, int l, const float *b, float *x, int threads)
{
    const cs_im_level L = view(w, l, s);
    im_level *lv = &w->lv[l];
    float *t = lv->t;
    const int last = l + 1 == w->levels;
    const int sweeps = last ? CS_IM_COARSE_SWEEPS : CS_IM_SMOOTH;
    /* a coarse level is less work than waking the threads: one thread (each vertex is computed on
     * its own, so the result does not depend on it) */
    threads = lv->n >= PARALLEL_MIN ? threads : 1;
    jacobi(&L, x, b, t, 1, threads);
    for (int k = 1; k < sweeps; k++) {
        apply(&L, x, t, 0, threads);
        jacobi(&L, x, b, t, 0, threads);
    }
    if (last) return;
    /* the residual, restricted */
    apply(&L, x, t, 0, threads);
    const int32_t n = lv->n;
    CS_PARALLEL_FOR(threads, schedule(static),
    for (int32_t k = 0; k < 3 * n; k++) t[k] = b[k] - t[k];);
    im_level *c = &w->lv[l + 1];
    CS_PARALLEL_FOR(threads, schedule(static),
    for (int32_t J = 0; J < c->ny; J++)
        for (int32_t I = 0; I < c->nx; I++) put3(c->b, J * c->nx + I, cs_im_restrict(&L, t, I, J)););
    vcycle(w, s, l + 1, c->b, c->x, threads);
    /* the coarse correction, interpolated (constant over each aggregate) and scaled */
    CS_PARALLEL_FOR(threads, schedule(static),
    for (int32_t j = 0; j < L.ny; j++)
        for (int32_t i = 0; i < L.nx; i++) {
            const int32_t v = j * L.nx + i;
            if (L.mask[v] == 0.0f) continue;
            const cs_vec3 e = cs_v3_from(c->x + 3 * (size_t)((j / 2) * c->nx + i / 2));
            put3(x, v, cs_add(cs_v3_from(x + 3 * (size_t)v), cs_scale(e, CS_IM_COARSE_SCALE)));
        });
    for (int k = 0; k < sweeps; k++) {
        apply(&L, x, t, 0, threads);
        jacobi(&L, x, b, t, 0, threads);
    }
}

/* Coarse vertex (I, J) of level lv from the finer level F (cs_im_galerkin). */
static void galerkin_one(const cs_im_level *F, im_level *lv, int32_t I, int32_t J)
{
    const int32_t v = J * lv->nx + I;
    float *Fc[4];
    for (int t = 0; t < 4; t++) Fc[t] = lv->F[t] + v;
    cs_im_galerkin(F, I, J, lv->D + v, Fc, lv->S, lv->mask + v);
}

/* cs_im_galerkin_inner over coarse row J's vertices I0 .. I1 - 1 (each inner; the coarse level
 * cnx wide): a plain loop that vectorizes, the outputs restrict (apply_run_bend's reasons). */
__attribute__((noinline)) static void galerkin_run(const cs_im_level *F, int32_t J, int32_t I0, int32_t I1,
                                                   int32_t cnx, float *restrict D, float *restrict F0,
                                                   float *restrict F1, float *restrict F2, float *restrict F3,
                                                   size_t Sc, float *restrict mask)
{
    IVDEP
    for (int32_t I = I0; I < I1; I++) {
        const int32_t v = J * cnx + I;
        float *Fc[4] = {F0 + v, F1 + v, F2 + v, F3 + v};
        cs_im_galerkin_inner(F, I, J, D + v, Fc, Sc, mask + v);
    }
}

/* The hierarchy from level 0's matrix: each level's Dinv, the coarse levels' Galerkin products. */
static void hierarchy(cs_im_work *w, const cs_state *s, int threads)
{
    for (int l = 0; l < w->levels; l++) {
        im_level *lv = &w->lv[l];
        if (l > 0) {
            const cs_im_level F = view(w, l - 1, s);
            CS_PARALLEL_FOR(threads, schedule(static),
            for (int32_t J = 0; J < lv->ny; J++) {
                /* the inner coarse vertices of a row, a run; the rest one by one */
                int32_t a = 1, e = (F.nx - 3) / 2 + 1;
                if (!cs_im_galerkin_is_inner(F.nx, F.ny, a, J) || a >= e) a = e = lv->nx;
                for (int32_t I = 0; I < a; I++) galerkin_one(&F, lv, I, J);
                if (a < e)
                    galerkin_run(&F, J, a, e, lv->nx, lv->D, lv->F[0], lv->F[1], lv->F[2], lv->F[3], lv->S, lv->mask);
                for (int32_t I = e; I < lv->nx; I++) galerkin_one(&F, lv, I, J);
            });
        }
        CS_PARALLEL_FOR(threads, schedule(static),
        for (int32_t v = 0; v < lv->n; v++) {
            const cs_mat3 D = cs_im_sym_get(lv->D + v, lv->S), inv = cs_m3_inverse(D.m);
            put_sym(lv->Dinv, lv->S, v, &inv);
        });
    }
}

/* Conjugate gradients on A dx = R (bending included), preconditioned by a V-cycle; stops at |r| <= target or after
 * most iterations. Returns the iterations run. */
static int pcg(const cs_phys *p, cs_im_work *w, const cs_state *s, float target, int most, int threads)
{
    const int32_t n3 = 3 * p->n;
    const cs_im_level L0 = view(w, 0, s);
    memset(w->dx, 0, sizeof(float) * (size_t)n3);
    memcpy(w->r, w->R, sizeof(float) * (size_t)n3);
    vcycle(w, s, 0, w->r, w->z, threads);
    memcpy(w->p, w->z, sizeof(float) * (size_t)n3);
    float rz = dot(p, w, w->r, w->z, threads);
    int it = 0;
    while (it < most) {
        apply(&L0, w->p, w->q, 1, threads);
        const float pq = dot(p, w, w->p, w->q, threads);
        if (!(pq > 0.0f) || !(rz > 0.0f)) break;
        const float alpha = rz / pq;
        CS_PARALLEL_FOR(threads, schedule(static),
        for (int32_t k = 0; k < n3; k++) {
            w->dx[k] += alpha * w->p[k];
            w->r[k] -= alpha * w->q[k];
        });
        it++;
        if (!(sqrtf(dot(p, w, w->r, w->r, threads)) > target)) break;
        vcycle(w, s, 0, w->r, w->z, threads);
        const float rz2 = dot(p, w, w->r, w->z, threads);
        const float beta = rz2 / rz;
        rz = rz2;
        CS_PARALLEL_FOR(threads, schedule(static),
        for (int32_t k = 0; k < n3; k++) w->p[k] = w->z[k] + beta * w->p[k];);
    }
    return it;
}

/* ---- the substep ---- */

/* x = x_k + a dx for the vertices in the solve, and v = (x - x_n)/h. */
static void move(cs_im_work *w, cs_state *s, float a, float inv_h, int threads)
{
    CS_PARALLEL_FOR(threads, schedule(static),
    for (int32_t v = 0; v < s->n; v++) {
        if (s->w[v] == 0.0f) continue;
        s->x[v] = w->xo[v] + a * w->dx[3 * (size_t)v];
        s->y[v] = w->yo[v] + a * w->dx[3 * (size_t)v + 1];
        s->z[v] = w->zo[v] + a * w->dx[3 * (size_t)v + 2];
        s->vx[v] = (s->x[v] - w->xb[v]) * inv_h;
        s->vy[v] = (s->y[v] - w->yb[v]) * inv_h;
        s->vz[v] = (s->z[v] - w->zb[v]) * inv_h;
    });
}

/* The rock steps' view of the state and the workspace (implicit.h, "the rock steps of a part"):
 * the state's positions, the part's start, the rest lengths the state holds now. */
static cs_im_rocks rock_view(cs_state *s, cs_im_work *w)
{
    cs_im_rocks R;
    R.x = s->x, R.y = s->y, R.z = s->z, R.vx = s->vx, R.vy = s->vy, R.vz = s->vz;
    R.xb = w->xb, R.yb = w->yb, R.zb = w->zb;
    R.w = s->w, R.L0 = s->L0;
    R.rocks = s->rocks, R.nr = s->n_rocks;
    R.star = w->star, R.rx0 = w->rx0, R.F = w->rf, R.T = w->rt;
    R.cand = w->cand, R.sr = w->sr, R.sh = w->sh, R.sn = w->sn, R.sg = w->sg;
    R.rowbox = w->rowbox, R.rows = w->rows;
    return R;
}

/* The rows' boxes of the cloth as it is (cs_im_rocks' rowbox). */
static void row_boxes(const cs_phys *p, const cs_im_rocks *rv, int threads)
{
    CS_PARALLEL_FOR(threads, schedule(static),
    for (int32_t j = 0; j < p->ny; j++) cs_im_row_box(p, rv->x, rv->y, rv->z, j, rv->rowbox + 6 * (size_t)j););
}

/* Step 3 of a part: the rocks follow what their vertices carried, rocks and cloth are pushed
 * apart, the approach is stopped and friction acts (cs_im_rocks_push, one thread). */
static void rocks_push(const cs_phys *p, const cs_im_rocks *rv, float h, int threads)
{
    if (!rv->nr) return;
    row_boxes(p, rv, threads);
    cs_im_rocks_push(p, rv, h);
}

/* One part of a substep, of length h (the sequence at the top). */
static int64_t part(const cs_phys *p0, cs_im_work *w, cs_state *s, float h, int threads,
                    cs_solver_stats *st)
{
    cs_phys P = cs_im_part_phys(p0, h); /* the part's own step */
    cs_phys *p = &P;
    const int32_t n = p->n, g = s->grab;
    const cs_im_rocks rv = rock_view(s, w);
    cs_im_rocks_advance(p, &rv, h);
    if (rv.nr) row_boxes(p, &rv, threads);
    cs_im_rocks_share(p, &rv);
    const cs_vec3 vg = g >= 0 ? cs_grab_velocity(LOADX(g), s->grab_target, p) : cs_v3(0.0f, 0.0f, 0.0f);
    const float inv_h = 1.0f / h;
    float reach = 0.0f; /* the largest coordinate, for float's floor (cs_im_float_floor) */
    CS_PARALLEL_FOR(threads, schedule(static) reduction(max : reach),
    for (int32_t v = 0; v < n; v++) {
        w->xb[v] = s->x[v], w->yb[v] = s->y[v], w->zb[v] = s->z[v];
        w->vxb[v] = s->vx[v], w->vyb[v] = s->vy[v], w->vzb[v] = s->vz[v];
        cs_vec3 x = LOADX(v);
        reach = cs_im_reach(x, reach);
        if (s->w[v] != 0.0f)
            x = cs_add(x, cs_add(cs_scale(LOADV(v), h),
                                 cs_scale(cs_im_guess_accel(p, cs_v3(s->ax[v], s->ay[v], s->az[v])), h * h)));
        else if (v == g)
            x = cs_add(x, cs_scale(vg, h));
        s->x[v] = x.x, s->y[v] = x.y, s->z[v] = x.z;
        s->vx[v] = (x.x - w->xb[v]) * inv_h, s->vy[v] = (x.y - w->yb[v]) * inv_h, s->vz[v] = (x.z - w->zb[v]) * inv_h;
    });
    float r = assemble(p, h, s, w, &rv, 1, threads);
    const float r0 = r;
    int k = 0;
    float prev = 2.0f * r0 + 1.0f;
    const float floor = cs_im_float_floor(p, reach);
    while (cs_im_newton_more(p, k, r, r0, prev, floor)) {
        prev = r;
        hierarchy(w, s, threads);
        st->cg += pcg(p, w, s, cs_im_cg_target(p, r0, r), p->cg_iterations, threads);
        /* x = x_k + a dx, a = 1, 1/2, 1/4, 1/8 while the residual does not fall (a contact that
         * switches on or off within the step makes a full Newton step overshoot) */
        CS_PARALLEL_FOR(threads, schedule(static),
        for (int32_t v = 0; v < n; v++) w->xo[v] = s->x[v], w->yo[v] = s->y[v], w->zo[v] = s->z[v];);
        /* the matrix only where another iteration may follow (the residual is the same bits) */
        const int blocks = k + 1 < p->solver_iterations;
        float a = 1.0f, rn = r;
        for (int tries = 0; tries < 4; tries++, a *= 0.5f) {
            move(w, s, a, inv_h, threads);
            rn = assemble(p, h, s, w, &rv, blocks, threads);
            if (rn < r) break;
        }
        if (!(rn < r)) { /* no step along dx helps: back to x_k, and stop */
            move(w, s, 0.0f, inv_h, threads);
            rn = assemble(p, h, s, w, &rv, 0, threads);
            prev = rn;
        }
        k++;
        r = rn;
    }
    st->newton += k;
    const float rel = r0 > 0.0f ? r / r0 : 0.0f;
    st->residual = rel > st->residual ? rel : st->residual;
    st->substeps++;
    rocks_push(p, &rv, h, threads);
    CS_PARALLEL_FOR(threads, schedule(static),
    for (int32_t v = 0; v < n; v++) {
        s->ax[v] = (s->vx[v] - w->vxb[v]) * inv_h * s->w[v];
        s->ay[v] = (s->vy[v] - w->vyb[v]) * inv_h * s->w[v];
        s->az[v] = (s->vz[v] - w->vzb[v]) * inv_h * s->w[v];
    });
    int64_t torn = 0;
    if (p->strain_on) {
        CS_PARALLEL_FOR(threads, schedule(static) reduction(+ : torn),
        for (int32_t j = 0; j < p->ny; j++) torn += cs_cpu_strain_row(p, s, j););
        float *t = s->L0;
        s->L0 = s->L0_next;
        s->L0_next = t;
    }
    return torn;
}

/* The fastest a cloth vertex closes on a rock near it now (cs_im_closing), as a rate: the parts of
 * a substep. */
static float fastest(const cs_phys *p, const cs_state *s, float h, int threads)
{
    float most = 0.0f;
    if (s->n_rocks) {
        CS_PARALLEL_FOR(threads, schedule(static) reduction(max : most),
        for (int32_t v = 0; v < s->n; v++) {
            const float c = cs_im_closing(p, s->rocks, s->n_rocks, s->x, s->y, s->z, s->vx, s->vy, s->vz, v, h);
            most = c > most ? c : most;
        });
    }
    return most;
}

cs_status cs_im_step(cs_im_work **wp, const cs_model *m, cs_state *s, int32_t substeps, int threads,
                     cs_step_report *rep, int64_t *torn, cs_sc_work **sc)
{
    const cs_phys *p = &m->phys;
    if (work_fit(wp, p) != CS_OK) return CS_E_NOMEM;
    cs_im_work *w = *wp;
    cs_solver_stats st = {0, 0, 0, 0.0f, 0};
    int64_t t = 0;
    for (int32_t k = 0; k < substeps; k++) {
        float rate = fastest(p, s, p->dt, threads), layers = 0.0f;
        if (p->self_on && cs_sc_part_rate(sc, p, s, p->dt, threads, &layers) != CS_OK) return CS_E_NOMEM;
        rate = layers > rate ? layers : rate; /* (self_collision: layers that may meet, cs_sc_part_rate) */
        const int32_t parts = cs_im_splits(rate, p->dt, p->most_splits);
        const float h = p->dt / (float)parts;
        for (int32_t q = 0; q < parts; q++) {
            if (p->self_on && cs_sc_begin(sc, s) != CS_OK) return CS_E_NOMEM;
            const int64_t torn = part(p, w, s, h, threads, &st);
            t += torn;
            if (p->self_on && torn) cs_sc_forget(*sc); /* its lists may hold torn triangles */
            if (p->self_on) cs_sc_end(*sc, p, s, threads, &rep->self);
        }
    }
    rep->solver = st;
    *torn = t;
    return CS_OK;
}

cs_status cs_im_refresh(cs_im_work **wp, const cs_model *m, cs_state *s, int threads)
{
    const cs_phys *p = &m->phys;
    if (work_fit(wp, p) != CS_OK) return CS_E_NOMEM;
    cs_im_work *w = *wp;
    const int32_t n = p->n;
    memcpy(w->vxb, s->vx, sizeof(float) * (size_t)n);
    memcpy(w->vyb, s->vy, sizeof(float) * (size_t)n);
    memcpy(w->vzb, s->vz, sizeof(float) * (size_t)n);
    memcpy(w->xb, s->x, sizeof(float) * (size_t)n);
    memcpy(w->yb, s->y, sizeof(float) * (size_t)n);
    memcpy(w->zb, s->z, sizeof(float) * (size_t)n);
    for (int32_t v = 0; v < n; v++) w->sr[v] = -1; /* nothing carried: the cloth's own force */
    const cs_im_rocks rv = rock_view(s, w);
    assemble(p, p->dt, s, w, &rv, 0, threads);
    /* R = F there (v = v_n): the cloth's force */
    for (int32_t v = 0; v < n; v++) {
        const float k = p->inv_mass * s->w[v];
        s->ax[v] = w->R[3 * (size_t)v] * k, s->ay[v] = w->R[3 * (size_t)v + 1] * k;
        s->az[v] = w->R[3 * (size_t)v + 2] * k;
    }
    return CS_OK;
}
