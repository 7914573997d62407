/* implicit_cpu.c - integrator implicit_euler on the CPU backend: the functions of
 * clothsim/implicit.h looped over the grid with OpenMP, in the sequence below (kernels/MODEL.md,
 * "The implicit solver").
 *
 * A substep of length h (cut into equal parts while a rock or vertex would cross the contact layer
 * in it: cs_im_splits), each part:
 *   1. the rocks predicted: sub-cycled to cs_phys.rock_dt, each sub-cycle v += d (a_cloth + F_other
 *      / M), w likewise, then drift - a_cloth being the cloth's force over mass of the last solve
 *      (the rock's a, alpha), F_other the rocks', the ground's and gravity (cs_rock_force without
 *      the cloth); the rock contacts taken for the part (cs_im_contact, at the part's start);
 *   2. the cloth and the dynamic rocks' translation: x_n and v_n kept aside, the first guess x = x_n
 *      + h v_n + h^2 g (pinned vertices stay, the grabbed one moves at its grab velocity), then
 *      Newton: assemble (residual, blocks, the rocks' partials and rows) at the iterate, stop at
 *      solver_tolerance of the first residual, at float's floor, after solver_iterations or once an
 *      iteration no longer halves it, else solve A dx = R by conjugate gradients preconditioned with
 *      one multigrid V-cycle (at most cg_iterations) and step along dx with a backtracking line
 *      search, v = (x - x_n)/h;
 *   3. a = (v - v_n)/h; the rocks' a, alpha from the last assembly's partials; with strain, the rest
 *      lengths from the new positions (cs_cpu_strain_row), swapped.
 * (Rocks are refused under implicit_euler for now, by the guard: MODEL.md's "Known gaps".)
 * Every loop's iterations are independent (each writes its own vertex or chunk), and every sum goes
 * through per-chunk trees summed in chunk order, so the result is the same for any thread count. */
#include <math.h>
#include <stdlib.h>
#include <string.h>

#include "clothsim/implicit.h"
#include "cpu_internal.h"

typedef struct im_level {
    int32_t nx, ny, n;
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
    cs_im_contact *ct;                     /* the part's rock contacts, CS_IM_SLOTS a vertex */
    /* The rocks in the solve: their translation is solved with the cloth (entries 3 n + 3 r of
     * every vector; 0 for a kinematic rock). */
    cs_rock_state *star;                   /* each rock where it would be without the cloth */
    float *rD, *rDinv;                     /* its diagonal block M/h^2 + its contacts' blocks */
    float *rxo;                            /* its position where a line search starts */
    int32_t *lost;                         /* per chunk: contacts that did not fit */
    im_level lv[CS_IM_MAX_LEVELS];
    void *mem;
};

void cs_im_free(cs_im_work *w)
{
    if (!w) return;
    free(w->mem);
    free(w->ct);
    free(w->lost);
    free(w->star);
    free(w);
}

/* Lays out the workspace for an nx x ny cloth in one allocation; NULL when out of memory. */
static cs_im_work *work_new(int32_t nx, int32_t ny, int32_t nchunks)
{
    cs_im_work *w = calloc(1, sizeof *w);
    if (!w) return NULL;
    w->nx = nx, w->ny = ny, w->n = nx * ny, w->nchunks = nchunks;
    size_t floats = (size_t)w->n * (9 + 3 + 18 + 15 + 18) + (size_t)nchunks + 6 * 3 * (size_t)CS_MAX_ROCKS +
                    (9 + 9 + 3) * (size_t)CS_MAX_ROCKS;
    int32_t lx[CS_IM_MAX_LEVELS], ly[CS_IM_MAX_LEVELS];
    const int L = w->levels = cs_im_levels(nx, ny, lx, ly);
    for (int l = 0; l < L; l++) {
        w->lv[l].nx = lx[l], w->lv[l].ny = ly[l], w->lv[l].n = lx[l] * ly[l];
        floats += (size_t)w->lv[l].n * CS_IM_LEVEL_FLOATS;
    }
    float *m = malloc(sizeof(float) * floats);
    w->ct = malloc(sizeof *w->ct * (size_t)w->n * CS_IM_SLOTS);
    w->lost = calloc((size_t)nchunks, sizeof *w->lost);
    w->star = calloc(CS_MAX_ROCKS, sizeof *w->star);
    if (!m || !w->ct || !w->lost || !w->star) {
        free(m);
        free(w->ct);
        free(w->lost);
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
    const size_t nv = 3 * n + 3 * (size_t)CS_MAX_ROCKS; /* a vector: the cloth, then the rocks */
    w->R = TAKE(nv);
    w->B[0] = TAKE(9 * n), w->B[1] = TAKE(9 * n);
    w->fo = TAKE(18 * n);
    w->dx = TAKE(nv), w->r = TAKE(nv), w->z = TAKE(nv), w->p = TAKE(nv), w->q = TAKE(nv);
    w->rD = TAKE(9 * (size_t)CS_MAX_ROCKS), w->rDinv = TAKE(9 * (size_t)CS_MAX_ROCKS);
    w->rxo = TAKE(3 * (size_t)CS_MAX_ROCKS);
    w->part = TAKE((size_t)nchunks);
    for (int l = 0; l < L; l++) {
        im_level *v = &w->lv[l];
        const size_t k = (size_t)v->n;
        v->D = TAKE(9 * k), v->Dinv = TAKE(9 * k);
        for (int t = 0; t < 4; t++) v->F[t] = TAKE(9 * k);
        v->mask = TAKE(k);
        v->b = TAKE(3 * k), v->x = TAKE(3 * k), v->t = TAKE(3 * k);
    }
#undef TAKE
    memset(w->mem, 0, sizeof(float) * floats);
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
    L.nx = v->nx, L.ny = v->ny;
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
static void put9(float *a, int32_t v, const cs_mat3 *m) { memcpy(a + 9 * (size_t)v, m->m, sizeof m->m); }

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

/* The springs each vertex of chunk (row j, columns i0 .. i1) owns, evaluated once from their
 * owner (cs_im_spring): forces into fo, negated blocks into level 0's F and the bending blocks
 * (blocks: 1; zero where the grid has no such spring). */
static void chunk_owned(const cs_phys *p, float h, const cs_state *s, cs_im_work *w, int32_t j, int32_t i0, int32_t i1,
                        int blocks)
{
    const int32_t nx = p->nx, ny = p->ny;
    const size_t n = (size_t)p->n;
    im_level *l0 = &w->lv[0];
    for (int32_t i = i0; i < i1; i++) {
        const int32_t v = j * nx + i;
        const cs_vec3 xi = LOADX(v), vi = LOADV(v);
        for (int t = 0; t < CS_NTYPES; t++) {
            cs_vec3 F = cs_v3(0.0f, 0.0f, 0.0f);
            cs_mat3 b = cs_m3_zero();
            if (cs_far_end_on_grid(nx, ny, i, j, cs_type_di[t], cs_type_dj[t])) {
                const int32_t q = v + cs_type_di[t] + cs_type_dj[t] * nx;
                F = cs_im_spring(xi, vi, LOADX(q), LOADV(q), s->L0[(size_t)t * n + (size_t)v], p->k[t], p->c_spring, h,
                                 &b);
            }
            put3(w->fo + (size_t)t * 3 * n, v, F);
            if (!blocks) continue;
            for (int k = 0; k < 9; k++) b.m[k] = -b.m[k];
            put9(t < 4 ? l0->F[t] : w->B[t - 4], v, &b);
        }
    }
}

/* The springs, air and gravity of chunk c's vertices at the iterate, gathered in
 * CS_SPRING_SLOTS order from their owners' evaluations (the same bits as cs_im_springs: a spring
 * from its other end is the exact negation, its block the same): force into R (the residual comes
 * later), Ro into q (resultant friction reads it), the diagonal into level 0 (blocks: 1). */
static void chunk_springs(const cs_phys *p, float h, const cs_state *s, cs_im_work *w, int32_t j, int32_t i0,
                          int32_t i1, int blocks)
{
    const int32_t nx = p->nx, ny = p->ny;
    const size_t n = (size_t)p->n;
    im_level *l0 = &w->lv[0];
    for (int32_t i = i0; i < i1; i++) {
        const int32_t v = j * nx + i;
        cs_vec3 f = cs_v3(0.0f, 0.0f, 0.0f);
        cs_mat3 d = cs_m3_zero();
#define CS_IM_GATHER(t, di, dj, fwd)                                                                \
    {                                                                                              \
        const int32_t ii = i + (di), jj = j + (dj);                                                \
        if (ii >= 0 && ii < nx && jj >= 0 && jj < ny) {                                            \
            const int32_t o = (fwd) ? v : jj * nx + ii; /* the owner */                            \
            const cs_vec3 F = cs_v3_from(w->fo + (size_t)(t) * 3 * n + 3 * (size_t)o);             \
            f = cs_add(f, (fwd) ? F : cs_neg(F));                                                  \
            if (blocks) {                                                                          \
                const float *B = ((t) < 4 ? l0->F[(t) & 3] : w->B[((t) - 4) & 1]) + 9 * (size_t)o; \
                for (int k = 0; k < 9; k++) d.m[k] += -B[k];                                       \
            }                                                                                      \
        }                                                                                          \
    }
        CS_SPRING_SLOTS(CS_IM_GATHER)
#undef CS_IM_GATHER
        f = cs_add(f, cs_air_gravity(LOADV(v), p));
        put3(w->R, v, f);
        put3(w->q, v, f);
        if (blocks) {
            const cs_mat3 D = cs_im_inertia(p, h, d);
            put9(l0->D, v, &D);
        }
    }
}

static void add3(float *a, int32_t v, cs_vec3 x)
{
    a[3 * (size_t)v] += x.x, a[3 * (size_t)v + 1] += x.y, a[3 * (size_t)v + 2] += x.z;
}
static void add9(float *a, int32_t v, const cs_mat3 *m)
{
    for (int k = 0; k < 9; k++) a[9 * (size_t)v + k] += m->m[k];
}

/* The 1-ring of vertex (i, j) at the iterate (cs_ring; slots off the grid repeat the vertex). */
static void ring_of(const cs_phys *p, const cs_state *s, const float *ro, int32_t i, int32_t j, cs_ring *g,
                    float *reach)
{
    const int32_t nx = p->nx, ny = p->ny, v = j * nx + i;
    float most = 0.0f;
    for (int k = 0; k < CS_RING; k++) {
        const int32_t ii = i + cs_ring_di(k), jj = j + cs_ring_dj(k);
        const int32_t o = (ii >= 0 && ii < nx && jj >= 0 && jj < ny) ? jj * nx + ii : v;
        g->x[k] = LOADX(o);
        const float d = cs_len(cs_sub(g->x[k], g->x[0]));
        most = d > most ? d : most;
    }
    g->v = LOADV(v);
    g->ro = cs_v3(ro[3 * (size_t)v], ro[3 * (size_t)v + 1], ro[3 * (size_t)v + 2]);
    g->faces = cs_ring_faces(s->L0, nx, ny, i, j);
    *reach = most;
}

/* The box (lo, hi) of rows j-1 .. j+1 over columns i0-1 .. i1: every triangle of the chunk's
 * rings. */
static void chunk_box(const cs_phys *p, const cs_state *s, int32_t j, int32_t i0, int32_t i1, cs_vec3 *lo, cs_vec3 *hi)
{
    const int32_t nx = p->nx, ny = p->ny, r0 = j > 0 ? j - 1 : 0, r1 = j + 1 < ny ? j + 1 : j;
    const int32_t c0 = i0 > 0 ? i0 - 1 : 0, c1 = i1 < nx ? i1 : nx - 1;
    cs_vec3 l = LOADX(r0 * nx + c0), h = l;
    for (int32_t jj = r0; jj <= r1; jj++)
        for (int32_t ii = c0; ii <= c1; ii++) {
            const cs_vec3 x = LOADX(jj * nx + ii);
            l = cs_v3(x.x < l.x ? x.x : l.x, x.y < l.y ? x.y : l.y, x.z < l.z ? x.z : l.z);
            h = cs_v3(x.x > h.x ? x.x : h.x, x.y > h.y ? x.y : h.y, x.z > h.z ? x.z : h.z);
        }
    *lo = l, *hi = h;
}

/* Whether a sphere (c, reach) may touch the box (never a false no). */
static int near_box(cs_vec3 c, float reach, cs_vec3 lo, cs_vec3 hi)
{
    const float ex = c.x < lo.x ? lo.x - c.x : c.x > hi.x ? c.x - hi.x : 0.0f;
    const float ey = c.y < lo.y ? lo.y - c.y : c.y > hi.y ? c.y - hi.y : 0.0f;
    const float ez = c.z < lo.z ? lo.z - c.z : c.z > hi.z ? c.z - hi.z : 0.0f;
    const float r = reach * 1.001f + 1e-6f;
    return ex * ex + ey * ey + ez * ez <= r * r;
}

/* A part's contacts with the rocks (cs_im_contact), taken at its start for chunk (row j, columns
 * i0 .. i1): each vertex's, in rock order, into its CS_IM_SLOTS slots; returns those that did not
 * fit (counted, never silently dropped). */
static int32_t chunk_contact_setup(const cs_phys *p, const cs_state *s, cs_im_work *w, int32_t j, int32_t i0,
                                   int32_t i1, float margin)
{
    const int32_t nx = p->nx, nr = s->n_rocks;
    int32_t lost = 0;
    for (int32_t i = i0; i < i1; i++)
        for (int k = 0; k < CS_IM_SLOTS; k++) w->ct[(size_t)(j * nx + i) * CS_IM_SLOTS + k].rock = -1;
    if (!nr) return 0;
    cs_vec3 lo, hi;
    chunk_box(p, s, j, i0, i1, &lo, &hi);
    for (int32_t r = 0; r < nr; r++) {
        cs_rock_state grown = s->rocks[r];
        grown.radius += margin; /* so that what comes within margin in the part is taken */
        const float lim = cs_surface_lim(&grown, p);
        if (!near_box(grown.x, lim, lo, hi)) continue;
        for (int32_t i = i0; i < i1; i++) {
            const int32_t v = j * nx + i;
            cs_im_contact c;
            c.rock = r;
            int got;
            if (p->contact_model == CS_CONTACT_SURFACE) {
                cs_ring g;
                float ext;
                ring_of(p, s, w->q, i, j, &g, &ext);
                if (cs_len(cs_sub(g.x[0], grown.x)) > lim * 1.001f + 1e-6f + ext) continue;
                /* touching now: its own force; else what the margin finds, less the margin */
                cs_surface_out o;
                cs_surface_gather(&g, &s->rocks[r], p, cs_v3(0.0f, 0.0f, 0.0f), 0.0f, &o);
                got = cs_im_contact_surface(&o, &s->rocks[r], p, 0.0f, &c);
                if (!got) {
                    cs_surface_gather(&g, &grown, p, cs_v3(0.0f, 0.0f, 0.0f), 0.0f, &o);
                    got = cs_im_contact_surface(&o, &s->rocks[r], p, margin, &c);
                }
            } else {
                got = cs_im_contact_vertex(LOADX(v), &s->rocks[r], p, margin, &c);
            }
            if (!got) continue;
            cs_im_contact *slot = w->ct + (size_t)v * CS_IM_SLOTS;
            int k = 0;
            while (k < CS_IM_SLOTS && slot[k].rock >= 0) k++;
            if (k == CS_IM_SLOTS) lost++;
            else slot[k] = c;
        }
    }
    return lost;
}

/* Contacts of chunk (row j, columns i0 .. i1) in rock order (the part's slots), then the ground:
 * forces onto R, blocks onto level 0's D, each rock's reaction from the chunk into its partial
 * (chunk tree). */
static void chunk_contacts(const cs_phys *p, float h, const cs_state *s, cs_im_work *w, int32_t j, int32_t i0,
                           int32_t i1, int32_t chunk, float *partials, int blocks)
{
    const int32_t nx = p->nx, nr = s->n_rocks;
    float contrib[6][CS_CHUNK];
    uint8_t idx[CS_CHUNK];
    float *D = w->lv[0].D;
    for (int32_t r = 0; r < nr; r++) {
        const cs_rock_state *rock = &s->rocks[r];
        int n_idx = 0;
        for (int32_t i = i0; i < i1; i++) {
            const int32_t v = j * nx + i, l = i - i0;
            const cs_im_contact *slot = w->ct + (size_t)v * CS_IM_SLOTS;
            for (int k = 0; k < CS_IM_SLOTS && slot[k].rock >= 0; k++) {
                if (slot[k].rock != r) continue;
                const cs_vec3 ro = cs_v3(w->q[3 * (size_t)v], w->q[3 * (size_t)v + 1], w->q[3 * (size_t)v + 2]);
                cs_mat3 b;
                const cs_vec3 dr = cs_sub(rock->x, w->star[r].x);
                const cs_vec3 F = cs_im_contact_force(&slot[k], LOADX(v), cs_v3(w->xb[v], w->yb[v], w->zb[v]), dr,
                                                      LOADV(v), ro, rock, p, h, s->w[v], &b);
                add3(w->R, v, F);
                if (blocks) {
                    add9(D, v, &b);
                    memcpy(w->ct[(size_t)v * CS_IM_SLOTS + k].K, b.m, sizeof b.m);
                }
                const cs_vec3 Rr = cs_neg(F), T = cs_cross(cs_v3(slot[k].arm[0], slot[k].arm[1], slot[k].arm[2]), Rr);
                contrib[0][l] = Rr.x, contrib[1][l] = Rr.y, contrib[2][l] = Rr.z;
                contrib[3][l] = T.x, contrib[4][l] = T.y, contrib[5][l] = T.z;
                idx[n_idx++] = (uint8_t)l;
            }
        }
        cs_cpu_tree_sum_sparse((const float(*)[CS_CHUNK])contrib, idx, n_idx, 0,
                               partials + ((size_t)chunk * (size_t)nr + (size_t)r) * 6);
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
            add9(D, v, &b);
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
                put9(w->lv[0].D, v, &I);
            }
        }
        put3(w->R, v, R);
        buf[i - i0] = cs_dot(R, R);
    }
    w->part[chunk] = cs_tree_sum(buf);
}

/* Whether rock r's translation is solved (a dynamic rock). */
static int rock_free(const cs_state *s, int32_t r) { return s->rocks[r].inv_mass > 0.0f; }

/* The rocks' rows: the residual F_cloth - M (v - v*)/h of each dynamic rock (v* its velocity
 * without the cloth; 0 for a kinematic one) into R after the cloth's, and with blocks its
 * diagonal block M/h^2 + the blocks of its contacts (vertex by vertex, in order) and its inverse.
 * Returns the rocks' part of |R|^2, rock by rock. */
static float rocks_residual(const cs_phys *p, float h, const cs_state *s, cs_im_work *w, const float *partials,
                            int blocks)
{
    const int32_t nr = s->n_rocks;
    const size_t o = 3 * (size_t)p->n;
    float sum = 0.0f;
    for (int32_t r = 0; r < nr; r++) {
        const cs_rock_state *q = &s->rocks[r];
        cs_vec3 F, T, R = cs_v3(0.0f, 0.0f, 0.0f);
        if (rock_free(s, r)) {
            cs_rock_cloth_force(partials, nr, r, p->nchunks, &F, &T);
            /* the prediction applied M a of it already */
            R = cs_sub(cs_sub(F, cs_scale(w->star[r].a, q->mass)), cs_scale(cs_sub(q->v, w->star[r].v), q->mass / h));
        }
        put3(w->R + o, r, R);
        sum += cs_dot(R, R);
        if (blocks) {
            cs_mat3 d = cs_m3_diag(rock_free(s, r) ? q->mass / (h * h) : 1.0f);
            put9(w->rD, r, &d);
        }
    }
    if (blocks && nr) {
        for (int32_t v = 0; v < p->n; v++) {
            const cs_im_contact *slot = w->ct + (size_t)v * CS_IM_SLOTS;
            for (int k = 0; k < CS_IM_SLOTS && slot[k].rock >= 0; k++)
                if (rock_free(s, slot[k].rock)) {
                    cs_mat3 K;
                    memcpy(K.m, slot[k].K, sizeof K.m);
                    add9(w->rD, slot[k].rock, &K);
                }
        }
        for (int32_t r = 0; r < nr; r++) {
            const cs_mat3 inv = cs_m3_inverse(w->rD + 9 * (size_t)r);
            put9(w->rDinv, r, &inv);
        }
    }
    return sum;
}

/* Assembles at the iterate (the state's x and v): R, and with blocks level 0's matrix; rock
 * partials; the rocks' rows. Returns |R|. */
static float assemble(const cs_phys *p, float h, const cs_state *s, cs_im_work *w, float *partials, int blocks,
                      int threads)
{
    const int32_t nchunks = p->nchunks;
#pragma omp parallel for num_threads(threads) schedule(static)
    for (int32_t c = 0; c < nchunks; c++) {
        int32_t j, i0, i1;
        chunk_span(p, c, &j, &i0, &i1);
        chunk_owned(p, h, s, w, j, i0, i1, blocks);
    }
#pragma omp parallel for num_threads(threads) schedule(dynamic, 4)
    for (int32_t c = 0; c < nchunks; c++) {
        int32_t j, i0, i1;
        chunk_span(p, c, &j, &i0, &i1);
        chunk_springs(p, h, s, w, j, i0, i1, blocks);
        chunk_contacts(p, h, s, w, j, i0, i1, c, partials, blocks);
        chunk_residual(p, h, s, w, j, i0, i1, c, blocks);
    }
    const float cloth = cs_im_chunk_total(w->part, nchunks);
    return sqrtf(cloth + rocks_residual(p, h, s, w, partials, blocks));
}

/* The part's rock contacts (chunk_contact_setup) from the state as it is; returns those lost. */
static int32_t contact_setup(const cs_phys *p, const cs_state *s, cs_im_work *w, int threads)
{
    const int32_t nchunks = p->nchunks;
    const float margin = p->contact_offset + 1e-3f;
#pragma omp parallel for num_threads(threads) schedule(dynamic, 4)
    for (int32_t c = 0; c < nchunks; c++) {
        int32_t j, i0, i1;
        chunk_span(p, c, &j, &i0, &i1);
        w->lost[c] = chunk_contact_setup(p, s, w, j, i0, i1, margin);
    }
    int32_t lost = 0;
    for (int32_t c = 0; c < nchunks; c++) lost += w->lost[c];
    return lost;
}

/* ---- the linear solve ---- */

/* a . b over level 0 (chunk trees, then chunks in order), then the rocks' entries in order. */
static float dot(const cs_phys *p, cs_im_work *w, const float *a, const float *b, int nr, int threads)
{
#pragma omp parallel for num_threads(threads) schedule(static)
    for (int32_t c = 0; c < p->nchunks; c++) {
        int32_t j, i0, i1;
        chunk_span(p, c, &j, &i0, &i1);
        float buf[CS_CHUNK];
        for (int k = 0; k < CS_CHUNK; k++) buf[k] = 0.0f;
        for (int32_t i = i0; i < i1; i++) buf[i - i0] = cs_im_dot3(a, b, j * p->nx + i);
        w->part[c] = cs_tree_sum(buf);
    }
    float sum = cs_im_chunk_total(w->part, p->nchunks);
    const size_t o = 3 * (size_t)p->n;
    for (int32_t r = 0; r < nr; r++) sum += cs_im_dot3(a + o, b + o, r);
    return sum;
}

/* y = A x on level l (bend: the true operator of level 0, bending blocks included). */
static void apply(const cs_im_level *L, const float *x, float *y, int bend, int threads)
{
    const int32_t e = bend ? 2 : 1, nx = L->nx, ny = L->ny;
#pragma omp parallel for num_threads(threads) schedule(static)
    for (int32_t j = 0; j < ny; j++) {
        if (j < e || j >= ny - e) {
            for (int32_t i = 0; i < nx; i++) put3(y, j * nx + i, cs_im_apply(L, x, i, j, bend));
            continue;
        }
        for (int32_t i = 0; i < nx; i++)
            put3(y, j * nx + i,
                 i < e || i >= nx - e ? cs_im_apply(L, x, i, j, bend) : cs_im_apply_inner(L, x, j * nx + i, bend));
    }
}

/* x = x + omega Dinv (b - t) where t = A x (first: x = omega Dinv b, from x = 0). */
static void jacobi(const cs_im_level *L, float *x, const float *b, const float *t, int first, int threads)
{
    const int32_t n = L->nx * L->ny;
#pragma omp parallel for num_threads(threads) schedule(static)
    for (int32_t v = 0; v < n; v++) {
        const cs_vec3 zero = cs_v3(0.0f, 0.0f, 0.0f);
        const cs_vec3 xv = first ? zero : cs_v3_from(x + 3 * (size_t)v);
        put3(x, v, cs_im_jacobi(L, v, xv, cs_v3_from(b + 3 * (size_t)v), first ? zero : cs_v3_from(t + 3 * (size_t)v)));
    }
}

/* One V-cycle from level l: x = B b (x and b on that level; level 0's are the caller's). */
static void vcycle(cs_im_work *w, const cs_state *s, int l, const float *b, float *x, int threads)
{
    const cs_im_level L = view(w, l, s);
    im_level *lv = &w->lv[l];
    float *t = lv->t;
    const int last = l + 1 == w->levels;
    const int sweeps = last ? CS_IM_COARSE_SWEEPS : CS_IM_SMOOTH;
    jacobi(&L, x, b, t, 1, threads);
    for (int k = 1; k < sweeps; k++) {
        apply(&L, x, t, 0, threads);
        jacobi(&L, x, b, t, 0, threads);
    }
    if (last) return;
    /* the residual, restricted */
    apply(&L, x, t, 0, threads);
    const int32_t n = lv->n;
#pragma omp parallel for num_threads(threads) schedule(static)
    for (int32_t k = 0; k < 3 * n; k++) t[k] = b[k] - t[k];
    im_level *c = &w->lv[l + 1];
#pragma omp parallel for num_threads(threads) schedule(static)
    for (int32_t J = 0; J < c->ny; J++)
        for (int32_t I = 0; I < c->nx; I++) put3(c->b, J * c->nx + I, cs_im_restrict(&L, t, I, J));
    vcycle(w, s, l + 1, c->b, c->x, threads);
    /* the coarse correction, interpolated (constant over each aggregate) and scaled */
#pragma omp parallel for num_threads(threads) schedule(static)
    for (int32_t j = 0; j < L.ny; j++)
        for (int32_t i = 0; i < L.nx; i++) {
            const int32_t v = j * L.nx + i;
            if (L.mask[v] == 0.0f) continue;
            const cs_vec3 e = cs_v3_from(c->x + 3 * (size_t)((j / 2) * c->nx + i / 2));
            put3(x, v, cs_add(cs_v3_from(x + 3 * (size_t)v), cs_scale(e, CS_IM_COARSE_SCALE)));
        }
    for (int k = 0; k < sweeps; k++) {
        apply(&L, x, t, 0, threads);
        jacobi(&L, x, b, t, 0, threads);
    }
}

/* The hierarchy from level 0's matrix: each level's Dinv, the coarse levels' Galerkin products. */
static void hierarchy(cs_im_work *w, const cs_state *s, int threads)
{
    for (int l = 0; l < w->levels; l++) {
        im_level *lv = &w->lv[l];
        if (l > 0) {
            const cs_im_level F = view(w, l - 1, s);
#pragma omp parallel for num_threads(threads) schedule(static)
            for (int32_t J = 0; J < lv->ny; J++)
                for (int32_t I = 0; I < lv->nx; I++) {
                    const int32_t v = J * lv->nx + I;
                    float *Fc[4];
                    for (int t = 0; t < 4; t++) Fc[t] = lv->F[t] + 9 * (size_t)v;
                    cs_im_galerkin(&F, I, J, lv->D + 9 * (size_t)v, Fc, lv->mask + v);
                }
        }
#pragma omp parallel for num_threads(threads) schedule(static)
        for (int32_t v = 0; v < lv->n; v++) {
            const cs_mat3 inv = cs_m3_inverse(lv->D + 9 * (size_t)v);
            put9(lv->Dinv, v, &inv);
        }
    }
}

/* y = A x with the rocks: the cloth's operator (bending included), then each contact's coupling
 * between its vertex and its rock (the vertices' in parallel, each rock's row vertex by vertex in
 * order). */
static void apply_full(const cs_phys *p, cs_im_work *w, const cs_state *s, const float *x, float *y, int threads)
{
    const cs_im_level L0 = view(w, 0, s);
    apply(&L0, x, y, 1, threads);
    const int32_t nr = s->n_rocks, n = p->n;
    if (!nr) return;
    const size_t o = 3 * (size_t)n;
#pragma omp parallel for num_threads(threads) schedule(static)
    for (int32_t v = 0; v < n; v++) {
        if (s->w[v] == 0.0f) continue;
        const cs_im_contact *slot = w->ct + (size_t)v * CS_IM_SLOTS;
        for (int k = 0; k < CS_IM_SLOTS && slot[k].rock >= 0; k++)
            if (rock_free(s, slot[k].rock))
                put3(y, v, cs_sub(cs_v3_from(y + 3 * (size_t)v), cs_m3_mul(slot[k].K, cs_v3_from(x + o + 3 * (size_t)slot[k].rock))));
    }
    for (int32_t r = 0; r < nr; r++)
        put3(y + o, r, rock_free(s, r) ? cs_m3_mul(w->rD + 9 * (size_t)r, cs_v3_from(x + o + 3 * (size_t)r))
                                       : cs_v3(0.0f, 0.0f, 0.0f));
    for (int32_t v = 0; v < n; v++) {
        const cs_im_contact *slot = w->ct + (size_t)v * CS_IM_SLOTS;
        for (int k = 0; k < CS_IM_SLOTS && slot[k].rock >= 0; k++) {
            const int32_t r = slot[k].rock;
            if (rock_free(s, r) && s->w[v] != 0.0f)
                put3(y + o, r, cs_sub(cs_v3_from(y + o + 3 * (size_t)r), cs_m3_mul(slot[k].K, cs_v3_from(x + 3 * (size_t)v))));
        }
    }
}

/* The preconditioner: the V-cycle on the cloth, each rock's block inverted. */
static void precondition(const cs_phys *p, cs_im_work *w, const cs_state *s, const float *r, float *z, int threads)
{
    vcycle(w, s, 0, r, z, threads);
    const size_t o = 3 * (size_t)p->n;
    for (int32_t k = 0; k < s->n_rocks; k++)
        put3(z + o, k, rock_free(s, k) ? cs_m3_mul(w->rDinv + 9 * (size_t)k, cs_v3_from(r + o + 3 * (size_t)k))
                                       : cs_v3(0.0f, 0.0f, 0.0f));
}

/* Conjugate gradients on A dx = R, preconditioned by a V-cycle; stops at |r| <= target or after
 * most iterations. Returns the iterations run. */
static int pcg(const cs_phys *p, cs_im_work *w, const cs_state *s, float target, int most, int threads)
{
    const int nr = s->n_rocks;
    const int32_t n3 = 3 * p->n + 3 * nr;
    memset(w->dx, 0, sizeof(float) * (size_t)n3);
    memcpy(w->r, w->R, sizeof(float) * (size_t)n3);
    precondition(p, w, s, w->r, w->z, threads);
    memcpy(w->p, w->z, sizeof(float) * (size_t)n3);
    float rz = dot(p, w, w->r, w->z, nr, threads);
    int it = 0;
    while (it < most) {
        apply_full(p, w, s, w->p, w->q, threads);
        const float pq = dot(p, w, w->p, w->q, nr, threads);
        if (!(pq > 0.0f) || !(rz > 0.0f)) break;
        const float alpha = rz / pq;
#pragma omp parallel for num_threads(threads) schedule(static)
        for (int32_t k = 0; k < n3; k++) {
            w->dx[k] += alpha * w->p[k];
            w->r[k] -= alpha * w->q[k];
        }
        it++;
        if (!(sqrtf(dot(p, w, w->r, w->r, nr, threads)) > target)) break;
        precondition(p, w, s, w->r, w->z, threads);
        const float rz2 = dot(p, w, w->r, w->z, nr, threads);
        const float beta = rz2 / rz;
        rz = rz2;
#pragma omp parallel for num_threads(threads) schedule(static)
        for (int32_t k = 0; k < n3; k++) w->p[k] = w->z[k] + beta * w->p[k];
    }
    return it;
}

/* ---- the substep ---- */

/* The rocks over h as predicted: sub-cycles of at most rock_dt under their own contacts and
 * gravity (cs_rock_force without the cloth) and the cloth's last force (a, alpha), each v += d (a
 * + F / M), w likewise, then drift (step 1) - so that a rock the cloth holds against the ground is
 * not first driven through it. Where that leaves each rock is kept (w->star): the solve moves the
 * dynamic ones from there by the cloth's force less the last one. */
static void rocks_advance(const cs_phys *p, cs_state *s, cs_im_work *w, float h)
{
    const int32_t nr = s->n_rocks;
    if (!nr) return;
    int32_t sub = 1;
    if (p->rock_dt > 0.0f && h > p->rock_dt) {
        const float k = h / p->rock_dt;
        sub = k > 1e6f ? 1000000 : (int32_t)k + 1;
    }
    const float d = h / (float)sub;
    cs_vec3 F[CS_MAX_ROCKS], T[CS_MAX_ROCKS];
    for (int32_t k = 0; k < sub; k++) {
        for (int32_t r = 0; r < nr; r++) cs_rock_force(s->rocks, nr, r, NULL, 0, p, &F[r], &T[r]);
        for (int32_t r = 0; r < nr; r++) {
            cs_rock_state *q = &s->rocks[r];
            q->v = cs_add(q->v, cs_scale(cs_add(q->a, cs_scale(F[r], q->inv_mass)), d));
            q->w = cs_add(q->w, cs_scale(cs_add(q->alpha, cs_scale(T[r], q->inv_inertia)), d));
            cs_rock_drift(q, d);
        }
    }
    memcpy(w->star, s->rocks, sizeof *s->rocks * (size_t)nr);
}

/* The rocks' a and alpha: the cloth's force and torque over mass and inertia (step 3, and a
 * refresh), which the next part's prediction applies. */
static void rocks_take(const cs_phys *p, cs_state *s, const float *partials)
{
    for (int32_t r = 0; r < s->n_rocks; r++) {
        cs_rock_state *q = &s->rocks[r];
        cs_vec3 F, T;
        cs_rock_cloth_force(partials, s->n_rocks, r, p->nchunks, &F, &T);
        q->a = cs_scale(F, q->inv_mass);
        q->alpha = cs_scale(T, q->inv_inertia);
    }
}

/* x = x_k + a dx for the vertices and rocks in the solve, and v = (x - x_n)/h (a rock's: v* +
 * (x - x*)/h). */
static void move(cs_im_work *w, cs_state *s, float a, float inv_h, int threads)
{
    const float *d = w->dx + 3 * (size_t)s->n;
    for (int32_t r = 0; r < s->n_rocks; r++) {
        if (!rock_free(s, r)) continue;
        cs_rock_state *q = &s->rocks[r];
        q->x = cs_add(cs_v3_from(w->rxo + 3 * (size_t)r), cs_scale(cs_v3_from(d + 3 * (size_t)r), a));
        q->v = cs_add(w->star[r].v, cs_scale(cs_sub(q->x, w->star[r].x), inv_h));
    }
#pragma omp parallel for num_threads(threads) schedule(static)
    for (int32_t v = 0; v < s->n; v++) {
        if (s->w[v] == 0.0f) continue;
        s->x[v] = w->xo[v] + a * w->dx[3 * (size_t)v];
        s->y[v] = w->yo[v] + a * w->dx[3 * (size_t)v + 1];
        s->z[v] = w->zo[v] + a * w->dx[3 * (size_t)v + 2];
        s->vx[v] = (s->x[v] - w->xb[v]) * inv_h;
        s->vy[v] = (s->y[v] - w->yb[v]) * inv_h;
        s->vz[v] = (s->z[v] - w->zb[v]) * inv_h;
    }
}

/* One part of a substep, of length h (the sequence at the top). */
static int64_t part(const cs_phys *p0, cs_im_work *w, float *partials, cs_state *s, float h, int threads,
                    cs_solver_stats *st)
{
    cs_phys P = *p0; /* the part's own step */
    cs_phys *p = &P;
    p->dt = h, p->hdt = 0.5f * h;
    if (p->plastic_rate > 0.0f) p->plastic_f = p->plastic_rate * h < 1.0f ? p->plastic_rate * h : 1.0f;
    const int32_t n = p->n, g = s->grab;
    rocks_advance(p, s, w, h);
    st->lost += contact_setup(p, s, w, threads);
    const cs_vec3 vg = g >= 0 ? cs_grab_velocity(LOADX(g), s->grab_target, p) : cs_v3(0.0f, 0.0f, 0.0f);
    const float inv_h = 1.0f / h;
    float reach = 0.0f; /* the largest coordinate, for float's floor (cs_im_float_floor) */
#pragma omp parallel for num_threads(threads) schedule(static) reduction(max : reach)
    for (int32_t v = 0; v < n; v++) {
        w->xb[v] = s->x[v], w->yb[v] = s->y[v], w->zb[v] = s->z[v];
        w->vxb[v] = s->vx[v], w->vyb[v] = s->vy[v], w->vzb[v] = s->vz[v];
        cs_vec3 x = LOADX(v);
        reach = cs_im_reach(x, reach);
        if (s->w[v] != 0.0f)
            x = cs_add(x, cs_add(cs_scale(LOADV(v), h), cs_scale(p->gravity, h * h)));
        else if (v == g)
            x = cs_add(x, cs_scale(vg, h));
        s->x[v] = x.x, s->y[v] = x.y, s->z[v] = x.z;
        s->vx[v] = (x.x - w->xb[v]) * inv_h, s->vy[v] = (x.y - w->yb[v]) * inv_h, s->vz[v] = (x.z - w->zb[v]) * inv_h;
    }
    const int most = p->solver_iterations;
    float r = assemble(p, h, s, w, partials, 1, threads);
    const float r0 = r;
    int k = 0;
    float prev = 2.0f * r0 + 1.0f;
    /* Newton stops at the tolerance, at float rounding's floor, after solver_iterations, or once
     * an iteration no longer halves the residual (the floor, where the estimate is low) */
    const float floor = cs_im_float_floor(p, reach);
    while (k < most && r > p->solver_tolerance * r0 && r > floor && r < 0.5f * prev) {
        prev = r;
        hierarchy(w, s, threads);
        const float aim = 0.5f * p->solver_tolerance * r0, step = 0.05f * r;
        st->cg += pcg(p, w, s, aim > step ? aim : step, p->cg_iterations, threads);
        /* x = x_k + a dx, a = 1, 1/2, 1/4, 1/8 while the residual does not fall (a contact that
         * switches on or off within the step makes a full Newton step overshoot) */
#pragma omp parallel for num_threads(threads) schedule(static)
        for (int32_t v = 0; v < n; v++) w->xo[v] = s->x[v], w->yo[v] = s->y[v], w->zo[v] = s->z[v];
        for (int32_t q = 0; q < s->n_rocks; q++) put3(w->rxo, q, s->rocks[q].x);
        float a = 1.0f, rn = r;
        for (int tries = 0; tries < 4; tries++, a *= 0.5f) {
            move(w, s, a, inv_h, threads);
            rn = assemble(p, h, s, w, partials, 1, threads);
            if (rn < r) break;
        }
        if (!(rn < r)) { /* no step along dx helps: back to x_k, and stop */
            move(w, s, 0.0f, inv_h, threads);
            rn = assemble(p, h, s, w, partials, 1, threads);
            prev = rn;
        }
        k++;
        r = rn;
    }
    st->newton += k;
    const float rel = r0 > 0.0f ? r / r0 : 0.0f;
    st->residual = rel > st->residual ? rel : st->residual;
    st->substeps++;
#pragma omp parallel for num_threads(threads) schedule(static)
    for (int32_t v = 0; v < n; v++) {
        s->ax[v] = (s->vx[v] - w->vxb[v]) * inv_h * s->w[v];
        s->ay[v] = (s->vy[v] - w->vyb[v]) * inv_h * s->w[v];
        s->az[v] = (s->vz[v] - w->vzb[v]) * inv_h * s->w[v];
    }
    rocks_take(p, s, partials);
    int64_t torn = 0;
    if (p->strain_on) {
#pragma omp parallel for num_threads(threads) schedule(static) reduction(+ : torn)
        for (int32_t j = 0; j < p->ny; j++) torn += cs_cpu_strain_row(p, s, j);
        float *t = s->L0;
        s->L0 = s->L0_next;
        s->L0_next = t;
    }
    return torn;
}

/* The fastest a rock, or with rocks about a cloth vertex, moves toward a contact now (for the
 * parts of a substep): rocks at their speed plus what gravity adds in h. */
static float fastest(const cs_phys *p, const cs_state *s, float h, int threads)
{
    float most = 0.0f;
    const float gain = cs_len(p->gravity) * h;
    for (int32_t r = 0; r < s->n_rocks; r++) {
        const float v = cs_len(s->rocks[r].v) + (s->rocks[r].kinematic ? 0.0f : gain);
        most = v > most ? v : most;
    }
    if (!s->n_rocks) return most;
    float sq = 0.0f;
#pragma omp parallel for num_threads(threads) schedule(static) reduction(max : sq)
    for (int32_t v = 0; v < s->n; v++) {
        const float q = s->vx[v] * s->vx[v] + s->vy[v] * s->vy[v] + s->vz[v] * s->vz[v];
        sq = q > sq ? q : sq;
    }
    const float vv = sqrtf(sq) + gain;
    return vv > most ? vv : most;
}

cs_status cs_im_step(cs_im_work **wp, float *partials, const cs_model *m, cs_state *s, int32_t substeps, int threads,
                     cs_step_report *rep, int64_t *torn)
{
    const cs_phys *p = &m->phys;
    if (work_fit(wp, p) != CS_OK) return CS_E_NOMEM;
    cs_im_work *w = *wp;
    cs_solver_stats st = {0, 0, 0, 0.0f, 0};
    int64_t t = 0;
    for (int32_t k = 0; k < substeps; k++) {
        const int32_t parts = cs_im_splits(fastest(p, s, p->dt, threads), p->dt, p->contact_offset, p->most_splits);
        const float h = p->dt / (float)parts;
        for (int32_t q = 0; q < parts; q++) t += part(p, w, partials, s, h, threads, &st);
    }
    rep->solver = st;
    *torn = t;
    return CS_OK;
}

cs_status cs_im_refresh(cs_im_work **wp, float *partials, const cs_model *m, cs_state *s, int threads)
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
    if (s->n_rocks) memcpy(w->star, s->rocks, sizeof *s->rocks * (size_t)s->n_rocks);
    contact_setup(p, s, w, threads);
    assemble(p, p->dt, s, w, partials, 0, threads);
    /* R = F there (v = v_n): the cloth's force */
    for (int32_t v = 0; v < n; v++) {
        const float k = p->inv_mass * s->w[v];
        s->ax[v] = w->R[3 * (size_t)v] * k, s->ay[v] = w->R[3 * (size_t)v + 1] * k;
        s->az[v] = w->R[3 * (size_t)v + 2] * k;
    }
    rocks_take(p, s, partials);
    return CS_OK;
}
