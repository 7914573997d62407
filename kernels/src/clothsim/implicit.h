/* clothsim/implicit.h - the pieces of integrator implicit_euler (kernels/MODEL.md, "The implicit
 * solver"), written once for every backend: the Hessian blocks of the springs and contacts, the
 * per-vertex residual and diagonal, the multigrid hierarchy's Galerkin product, its smoother, the
 * fixed-order sums the conjugate gradients need, and the rock steps of a part (serial, one thread
 * in a fixed order). Rules as physics.h: SIM_HD, no libc beyond sqrtf, no globals, plain structs;
 * every sum in a fixed order.
 *
 * A substep of length h solves backward Euler, x = argmin G(x) with
 *   G(x) = 1/(2 h^2) |x - y|^2_M + E(x),  y = x_n + h v_n,  v = (x - x_n) / h,
 * whose gradient is the explicit integrators' force law evaluated at the new state (physics.h:
 * springs with their damping, air drag and wind, gravity, contacts): the residual of vertex i is
 *   R_i = F_i(x, v) - m (v_i - v_n,i) / h  (= -dG/dx_i).
 * Newton's method linearises R; the linear system A dx = R, with A the mass term m/h^2 plus the
 * springs' and contacts' stiffness blocks (projected to be positive: a spring in compression keeps
 * only its axial block), is solved by conjugate gradients preconditioned by one multigrid V-cycle.
 *
 * Storage of a level's matrix (all levels alike): per vertex the diagonal block D (CS_IM_SYM
 * floats: its upper triangle) and four forward off-diagonal blocks F_t, t = 0..3, coupling vertex (i, j) to (i, j) +
 * CS_IM_FWD(t) = (1, 0), (0, 1), (1, 1), (-1, 1); the block to (i, j) - CS_IM_FWD(t) is the
 * neighbour's F_t transposed (the matrix is symmetric). On the finest level these are the negated
 * stiffness blocks of the structural and shear springs (whose directions they are); the bending
 * springs' blocks are kept apart (they reach two vertices) and enter the true operator only, not
 * the preconditioner's (dropping them keeps its matrix positive definite and changes little: k_bend
 * is a hundredth of k_structural). A coarse level aggregates 2 x 2 vertices (i, j) -> (i/2, j/2)
 * and its matrix is the Galerkin product P^T A P for that piecewise-constant P, which keeps the
 * same nine-point shape on every level. Vertices of inverse mass 0 (pinned, grabbed) are left out:
 * their rows and columns are dropped (Dirichlet), a coarse vertex is out when all of its are. */
#ifndef CLOTHSIM_IMPLICIT_H
#define CLOTHSIM_IMPLICIT_H

#include "clothsim/clothsim.h" /* CS_MAX_ROCKS */
#include "clothsim/physics.h"

/* Forward directions of a level's off-diagonal blocks (t = 0..3). */
SIM_HD static inline int cs_im_fwd_di(int t) { return t == 3 ? -1 : (t == 1 ? 0 : 1); }
SIM_HD static inline int cs_im_fwd_dj(int t) { return t == 0 ? 0 : 1; }

/* The most levels a hierarchy has, and the size at which coarsening stops. */
#define CS_IM_MAX_LEVELS 12
#define CS_IM_COARSEST 4
/* Damped Jacobi's weight, sweeps before and after the coarse correction, sweeps on the coarsest
 * level, and the scale of the coarse correction (piecewise-constant interpolation underestimates a
 * smooth error's correction: over-correcting makes up for it). Chosen by measurement (MODEL.md). */
#define CS_IM_OMEGA 0.6f
#define CS_IM_SMOOTH 1
#define CS_IM_COARSE_SWEEPS 16
#define CS_IM_COARSE_SCALE 1.6f

typedef struct cs_mat3 {
    float m[9];
} cs_mat3;

SIM_HD static inline cs_mat3 cs_m3_zero(void)
{
    cs_mat3 a;
    for (int k = 0; k < 9; k++) a.m[k] = 0.0f;
    return a;
}
SIM_HD static inline cs_mat3 cs_m3_diag(float s)
{
    cs_mat3 a = cs_m3_zero();
    a.m[0] = a.m[4] = a.m[8] = s;
    return a;
}
SIM_HD static inline void cs_m3_addto(cs_mat3 *a, const cs_mat3 *b)
{
    for (int k = 0; k < 9; k++) a->m[k] += b->m[k];
}
SIM_HD static inline void cs_m3_addto_t(cs_mat3 *a, const cs_mat3 *b)
{
    for (int r = 0; r < 3; r++)
        for (int c = 0; c < 3; c++) a->m[3 * r + c] += b->m[3 * c + r];
}
/* s u u^T + t (I - u u^T) for a unit u. */
SIM_HD static inline cs_mat3 cs_m3_axial(cs_vec3 u, float s, float t)
{
    const float uu[3] = {u.x, u.y, u.z};
    cs_mat3 a;
    for (int r = 0; r < 3; r++)
        for (int c = 0; c < 3; c++) a.m[3 * r + c] = (s - t) * (uu[r] * uu[c]) + (r == c ? t : 0.0f);
    return a;
}
SIM_HD static inline cs_vec3 cs_m3_mul(const float *a, cs_vec3 x)
{
    return cs_v3(a[0] * x.x + a[1] * x.y + a[2] * x.z, a[3] * x.x + a[4] * x.y + a[5] * x.z,
                 a[6] * x.x + a[7] * x.y + a[8] * x.z);
}
SIM_HD static inline cs_vec3 cs_m3_mul_t(const float *a, cs_vec3 x)
{
    return cs_v3(a[0] * x.x + a[3] * x.y + a[6] * x.z, a[1] * x.x + a[4] * x.y + a[7] * x.z,
                 a[2] * x.x + a[5] * x.y + a[8] * x.z);
}
/* The inverse of a symmetric positive definite block (the identity where it is not invertible). */
SIM_HD static inline cs_mat3 cs_m3_inverse(const float *a)
{
    cs_mat3 r;
    r.m[0] = a[4] * a[8] - a[5] * a[7];
    r.m[1] = a[2] * a[7] - a[1] * a[8];
    r.m[2] = a[1] * a[5] - a[2] * a[4];
    r.m[3] = a[5] * a[6] - a[3] * a[8];
    r.m[4] = a[0] * a[8] - a[2] * a[6];
    r.m[5] = a[2] * a[3] - a[0] * a[5];
    r.m[6] = a[3] * a[7] - a[4] * a[6];
    r.m[7] = a[1] * a[6] - a[0] * a[7];
    r.m[8] = a[0] * a[4] - a[1] * a[3];
    const float det = a[0] * r.m[0] + a[1] * r.m[3] + a[2] * r.m[6];
    if (!(det > 1e-30f)) return cs_m3_diag(1.0f);
    const float inv = 1.0f / det;
    for (int k = 0; k < 9; k++) r.m[k] *= inv;
    return r;
}

/* ---- blocks as the solver stores them ----
 * Every block the solver keeps is symmetric bit for bit: a spring's, a contact's and a carried
 * mass's are cs_m3_axial (u_r u_c == u_c u_r in floating point), the diagonal and the Galerkin
 * products are sums of them (and of their transposes, the same bits), and cs_m3_inverse of a
 * symmetric block is symmetric (its cofactors pair up as commuted products). So a block is stored
 * as its upper triangle, xx xy xz yy yz zz: two thirds of the bytes the operator reads, with the
 * same bits as the full block (cs_im_sym_mul is cs_m3_mul and cs_m3_mul_t of it). An array of a
 * level's blocks is element-major: element k of vertex v's block at a[k S + v], S the level's
 * vertex count, so that a loop over vertices reads each element contiguously (the CPU's vector
 * units, the GPU's coalesced loads). The functions below take a = the array + v, and S. */
#define CS_IM_SYM 6

/* S for a level of k vertices (cs_im_stride): k below 1024; above, k rounded up to 1024 floats and
 * 16 more, so that the element rows lie 64 bytes apart modulo 4 KiB. With S = k, a grid of a power
 * of two (128 x 128: rows 64 KiB apart) would put the forty-odd streams of a loop over vertices
 * into one set of the CPU's caches, which thrash (measured: the step 1.3 x slower at 128 x 128). */
SIM_HD static inline size_t cs_im_stride(size_t k) { return k < 1024 ? k : (k + 1023) / 1024 * 1024 + 16; }

SIM_HD static inline void cs_im_sym_put(float *a, size_t S, const cs_mat3 *m)
{
    a[0] = m->m[0], a[S] = m->m[1], a[2 * S] = m->m[2], a[3 * S] = m->m[4], a[4 * S] = m->m[5], a[5 * S] = m->m[8];
}
SIM_HD static inline cs_mat3 cs_im_sym_get(const float *a, size_t S)
{
    const float a0 = a[0], a1 = a[S], a2 = a[2 * S], a3 = a[3 * S], a4 = a[4 * S], a5 = a[5 * S];
    cs_mat3 m;
    m.m[0] = a0, m.m[1] = a1, m.m[2] = a2;
    m.m[3] = a1, m.m[4] = a3, m.m[5] = a4;
    m.m[6] = a2, m.m[7] = a4, m.m[8] = a5;
    return m;
}
/* The block a (stored) times x: the sums of cs_m3_mul, term for term. */
SIM_HD static inline cs_vec3 cs_im_sym_mul(const float *a, size_t S, cs_vec3 x)
{
    const float a0 = a[0], a1 = a[S], a2 = a[2 * S], a3 = a[3 * S], a4 = a[4 * S], a5 = a[5 * S];
    return cs_v3(a0 * x.x + a1 * x.y + a2 * x.z, a1 * x.x + a3 * x.y + a4 * x.z, a2 * x.x + a4 * x.y + a5 * x.z);
}

/* ---- the linearised force law ---- */

/* The stiffness block of the spring from xi to xj (positive semi-definite): k u u^T + k max(0,
 * 1 - L0/l) (I - u u^T) + (c/h) u u^T - the elastic Hessian with its transverse part dropped in
 * compression, plus the damping's along u. Zero for a torn spring or below CS_MIN_LEN. Both ends
 * compute the same bits. _of: from d = xj - xi and its length l = sqrtf(d . d). */
SIM_HD static inline cs_mat3 cs_im_spring_block_of(cs_vec3 d, float l, float L0, float k, float c_over_h)
{
    if (!(l > CS_MIN_LEN && L0 > 0.0f)) return cs_m3_zero();
    const cs_vec3 u = cs_scale(d, 1.0f / l);
    const float g = 1.0f - L0 / l;
    return cs_m3_axial(u, k + c_over_h, g > 0.0f ? k * g : 0.0f);
}
SIM_HD static inline cs_mat3 cs_im_spring_block(cs_vec3 xi, cs_vec3 xj, float L0, float k, float c_over_h)
{
    const cs_vec3 d = cs_sub(xj, xi);
    return cs_im_spring_block_of(d, sqrtf(cs_dot(d, d)), L0, k, c_over_h);
}

/* One spring seen from xi: its force on xi (cs_spring_force) and its block (cs_im_spring_block, from
 * the length the force computed: the same bits). From the other end the force is exactly the
 * negation and the block the same bits, so a backend may evaluate each spring once, from the end
 * that owns it, and gather (cs_im_springs' order). */
SIM_HD static inline cs_vec3 cs_im_spring(cs_vec3 xi, cs_vec3 vi, cs_vec3 xj, cs_vec3 vj, float L0, float k, float c,
                                         float h, cs_mat3 *blk)
{
    float len;
    const cs_vec3 F = cs_spring_force(xi, vi, xj, vj, L0, k, c, &len);
    *blk = cs_im_spring_block_of(cs_sub(xj, xi), len, L0, k, c / h);
    return F;
}

/* A penalty contact's block at a vertex, normal n: kn along n, kt across it. */
SIM_HD static inline cs_mat3 cs_im_contact_block(cs_vec3 n, float kn, float kt) { return cs_m3_axial(n, kn, kt); }

/* The linearisation of cs_contact_law along n (penetration delta, normal velocity vn): the normal
 * force max(0, k delta - c vn) grows by k + c/h per unit of approach while it pushes; the viscous
 * friction (coulomb_viscous) by at most c_tangent/h across n. */
SIM_HD static inline cs_mat3 cs_im_law_block(cs_vec3 n, float delta, float vn, float k, float c, float ct, float h,
                                             int32_t friction, float vmax)
{
    const float fn = k * delta - c * vn;
    const float kn = (fn > 0.0f && vn <= vmax) ? k + c / h : 0.0f;
    const float kt = friction == CS_FRICTION_COULOMB_VISCOUS && kn > 0.0f ? ct / h : 0.0f;
    return cs_im_contact_block(n, kn, kt);
}

/* The same for the ground (cs_vertex_ground_contact). */
SIM_HD static inline cs_mat3 cs_im_ground_block(cs_vec3 xi, cs_vec3 vi, const cs_phys *p, float h)
{
    const float delta = p->ground_z + p->contact_offset - xi.z;
    if (!(p->ground && delta > 0.0f)) return cs_m3_zero();
    return cs_im_law_block(cs_v3(0.0f, 0.0f, 1.0f), delta, vi.z, p->k_contact, p->c_contact, p->c_tangent, h,
                           p->friction, p->max_sep);
}

/* ---- rock contact: carried mass in the solve, a constraint after it ----
 *
 * A rock's contact with the cloth is not a force in the solve (a penalty stiff enough to hold a
 * heavy rock makes Newton stall, and a vertex's own tangent plane lets a rock into a stretched
 * face). Instead, at each part's start every dynamic rock lends its mass M to the vertices that
 * may touch it within the part - those of the triangles (surface model; vertices, vertex model)
 * whose closest point to the rock's centre lies within R + 2 contact_offset - in proportion to
 * their barycentric weights there, along the weighted mean normal n_i (cs_im_share_tri): in the
 * solve vertex i carries mass m_i' along n_i, a force -(m_i'/h^2) n_i (n_i . (x_i - x_n,i - d_r))
 * where d_r is the rock's own path over the part (gravity, rock-rock and ground contact), so the
 * cloth under a rock feels the rock's inertia and the cloth's springs decelerate it. After the
 * solve the rock moves by sum m_i'/M n_i (n_i . (x_i - x_n,i - d_r)) beyond its path (the
 * momentum it lent), no touching pair of rocks coming closer than its path left it
 * (cs_im_rocks_apart), and then every rock and the cloth are pushed apart to the contact sphere
 * R + contact_offset: the point p of a triangle closest to the centre c, with barycentric weights
 * b, and the centre move along n = (p - c)/|p - c| in inverse proportion to their masses - dx_k
 * = b_k w_k lambda n, dc = -w_r lambda n, lambda = (R + offset - |p - c|) / (w_r + sum b_k^2
 * w_k), CS_IM_PUSH_SWEEPS sweeps over each rock's triangles in grid order. The push moves
 * positions only: a correction turned into velocity (dx / h) made the cloth around a stone
 * jitter at metres a second. The velocities meet the contact inelastically instead: each
 * contact's approach along its normal is stopped by an impulse shared the same way, then its
 * nearest vertex's (cs_im_stop_tri, CS_IM_STOP_SWEEPS sweeps), so momentum is kept and no energy
 * is added. Then
 * Coulomb friction, once per rock (cs_im_rock_friction): the rock's contact point (its surface
 * toward the cloth, spin included) and the patch of cloth pressing on it (each vertex weighted by
 * the normal impulse it gave: carried and stopped) are brought to the same tangential
 * velocity by an impulse shared in inverse proportion to their masses, at most mu times the
 * rock's normal impulse. */
#define CS_IM_PUSH_SWEEPS 4
#define CS_IM_STOP_SWEEPS 2

/* Triangle x[3] against a rock centred at c: the barycentric weights b of its point closest to c,
 * and the normal n from c to it, when that point lies within reach; 0 when not. */
SIM_HD static inline int cs_im_share_tri(const cs_vec3 x[3], cs_vec3 c, float reach, float b[3], cs_vec3 *n)
{
    cs_closest_on_triangle(c, x[0], x[1], x[2], b);
    const cs_vec3 p = cs_tri_point(x[0], x[1], x[2], b);
    const cs_vec3 d = cs_sub(p, c);
    const float len = cs_len(d);
    if (!(len < reach) || !(len > CS_MIN_LEN)) return 0;
    *n = cs_scale(d, 1.0f / len);
    return 1;
}

/* Triangle x[3] (inverse masses wv) against rock centre c (inverse mass wr) and sphere Rc: the
 * vertices' moves dx and the centre's dc (the caller applies them); returns lambda, 0 when apart. */
SIM_HD static inline float cs_im_push_tri(const cs_vec3 x[3], const float wv[3], cs_vec3 c, float wr, float Rc,
                                          cs_vec3 dx[3], cs_vec3 *dc)
{
    float b[3];
    cs_vec3 n;
    if (!cs_im_share_tri(x, c, Rc, b, &n)) return 0.0f;
    const cs_vec3 p = cs_tri_point(x[0], x[1], x[2], b);
    const float W = wr + b[0] * b[0] * wv[0] + b[1] * b[1] * wv[1] + b[2] * b[2] * wv[2];
    if (!(W > 0.0f)) return 0.0f;
    const float lambda = (Rc - cs_len(cs_sub(p, c))) / W;
    for (int k = 0; k < 3; k++) dx[k] = cs_scale(n, b[k] * wv[k] * lambda);
    *dc = cs_scale(n, -wr * lambda);
    return lambda;
}

/* The carried mass's force on a vertex displaced d beyond the rock's path (n its normal, m' its
 * mass, h the part) and its block. */
SIM_HD static inline cs_vec3 cs_im_carried(cs_vec3 n, float m, cs_vec3 d, float h, cs_mat3 *blk)
{
    const float k = m / (h * h);
    *blk = cs_m3_axial(n, k, 0.0f);
    return cs_scale(n, -k * cs_dot(n, d));
}

/* ---- the rock steps of a part, written once for every backend ----
 *
 * A part of a substep (implicit_cpu.c's sequence) takes its rocks in three steps around the
 * cloth's solve: cs_im_rocks_advance (the rocks over the part without the cloth), cs_im_rocks_share
 * (the mass each dynamic rock lends the vertices that may touch it), and after the solve
 * cs_im_rocks_push (the rocks follow what their vertices carried, then rocks and cloth are pushed
 * apart, the approach stopped, friction). The three are serial by design: one
 * thread runs each in a fixed order (they touch only the few triangles near each rock after one
 * scan of the grid), so every backend gets the same bits. In the solve, cs_im_carried_at is a
 * vertex's carried term. A backend hands them its arrays in a cs_im_rocks. */
typedef struct cs_im_rocks {
    float *x, *y, *z;          /* the cloth's positions: the part's start (share), the iterate (push) */
    float *vx, *vy, *vz;       /* its velocities: the iterate's (x - x_n)/h (push) */
    const float *xb, *yb, *zb; /* the part's start x_n (the carried term, push) */
    const float *w;            /* per vertex: 0 out of the solve (pinned, grabbed) */
    const float *L0;           /* rest lengths, type-major (which triangles are intact) */
    cs_rock_state *rocks;
    int32_t nr;
    cs_rock_state *star;       /* each rock where cs_im_rocks_advance leaves it (without the cloth) */
    cs_vec3 *rx0;              /* each rock at the part's start */
    cs_vec3 *F, *T;            /* scratch, nr each: the rocks' forces and torques; the carried moves */
    int32_t *cand;             /* 2 n: a rock's triangles (2 quad + face) or vertices near it */
    int32_t *sr;               /* per vertex: the rock whose mass it carries (-1 none) */
    float *sh, *sn;            /* per vertex: the mass it carries, its normal (3 n) */
    float *sg;                 /* per vertex, 0 outside cs_im_rocks_push: the stop's impulse times h */
    /* Optional (NULL: none; the results are the same bits either way, only the scans longer):
     * rowbox, 6 a grid row, the box (lo xyz, hi xyz) of rows j and j + 1 at x as it is now
     * (cs_im_row_box; the backend fills it before cs_im_rocks_share and before cs_im_rocks_push,
     * which keeps it true as it moves vertices), which lets a rock's scan for candidates skip the
     * rows it cannot reach; rows, 2 a rock, the vertices v0 .. v1 - 1 that its candidates in
     * cs_im_rocks_share span (cs_im_cand_span: every vertex that carries it lies there). */
    float *rowbox;
    int32_t *rows;
} cs_im_rocks;

SIM_HD static inline cs_vec3 cs_im_rock_x(const cs_im_rocks *R, int32_t v) { return cs_v3(R->x[v], R->y[v], R->z[v]); }
SIM_HD static inline cs_vec3 cs_im_rock_xb(const cs_im_rocks *R, int32_t v)
{
    return cs_v3(R->xb[v], R->yb[v], R->zb[v]);
}

/* Whether a sphere (c, reach) may touch the box lo .. hi (never a false no). */
SIM_HD static inline int cs_im_near_box(cs_vec3 c, float reach, cs_vec3 lo, cs_vec3 hi)
{
    const float ex = c.x < lo.x ? lo.x - c.x : c.x > hi.x ? c.x - hi.x : 0.0f;
    const float ey = c.y < lo.y ? lo.y - c.y : c.y > hi.y ? c.y - hi.y : 0.0f;
    const float ez = c.z < lo.z ? lo.z - c.z : c.z > hi.z ? c.z - hi.z : 0.0f;
    const float r = reach * 1.001f + 1e-6f;
    return ex * ex + ey * ey + ez * ez <= r * r;
}

/* Row j's entry of cs_im_rocks' rowbox: the box of the positions of rows j and j + 1 (row j alone
 * on the last) into box[0..5] (lo xyz, hi xyz). */
SIM_HD static inline void cs_im_row_box(const cs_phys *p, const float *x, const float *y, const float *z, int32_t j,
                                        float *box)
{
    const int32_t nx = p->nx, v0 = j * nx, v1 = (j + 2 < p->ny ? j + 2 : p->ny) * nx;
    float lo[3] = {x[v0], y[v0], z[v0]}, hi[3] = {x[v0], y[v0], z[v0]};
    for (int32_t v = v0 + 1; v < v1; v++) {
        const float c[3] = {x[v], y[v], z[v]};
        for (int k = 0; k < 3; k++) {
            lo[k] = c[k] < lo[k] ? c[k] : lo[k];
            hi[k] = c[k] > hi[k] ? c[k] : hi[k];
        }
    }
    for (int k = 0; k < 3; k++) box[k] = lo[k], box[3 + k] = hi[k];
}

/* A vertex's move over the part beyond rock r's own path: (x - x_n) - (star_r - rx0_r). */
SIM_HD static inline cs_vec3 cs_im_beyond(const cs_im_rocks *R, int32_t r, cs_vec3 x, cs_vec3 xn)
{
    return cs_sub(cs_sub(x, xn), cs_sub(R->star[r].x, R->rx0[r]));
}

/* A rock's candidates (centre c) into R->cand, in grid order: the intact triangles (2 quad + face)
 * whose box comes within reach of c (surface model), or the vertices (vertex model); returns how
 * many. */
SIM_HD static inline int32_t cs_im_rock_candidates(const cs_phys *p, const cs_im_rocks *R, cs_vec3 c, float reach)
{
    const int32_t nx = p->nx, ny = p->ny;
    const int surface = p->contact_model == CS_CONTACT_SURFACE;
    int32_t nc = 0;
    for (int32_t j = 0; j + (surface ? 1 : 0) < ny; j++) {
        /* a row whose box (it and the next) is out of reach holds no candidate */
        if (R->rowbox) {
            const float *b = R->rowbox + 6 * (size_t)j;
            if (!cs_im_near_box(c, reach, cs_v3(b[0], b[1], b[2]), cs_v3(b[3], b[4], b[5]))) continue;
        }
        if (!surface) {
            for (int32_t v = j * nx; v < (j + 1) * nx; v++)
                if (cs_im_near_box(c, reach, cs_im_rock_x(R, v), cs_im_rock_x(R, v))) R->cand[nc++] = v;
            continue;
        }
        for (int32_t i = 0; i + 1 < nx; i++) {
            const int32_t f = cs_quad_faces(R->L0, nx, ny, i, j);
            if (!f) continue;
            const int32_t v = j * nx + i;
            cs_vec3 lo = cs_im_rock_x(R, v), hi = lo;
            const int32_t o[3] = {v + 1, v + nx, v + nx + 1};
            for (int k = 0; k < 3; k++) {
                const cs_vec3 x = cs_im_rock_x(R, o[k]);
                lo = cs_v3(x.x < lo.x ? x.x : lo.x, x.y < lo.y ? x.y : lo.y, x.z < lo.z ? x.z : lo.z);
                hi = cs_v3(x.x > hi.x ? x.x : hi.x, x.y > hi.y ? x.y : hi.y, x.z > hi.z ? x.z : hi.z);
            }
            if (!cs_im_near_box(c, reach, lo, hi)) continue;
            if (f & 1) R->cand[nc++] = 2 * v;
            if (f & 2) R->cand[nc++] = 2 * v + 1;
        }
    }
    return nc;
}

/* Candidate k's vertices (a vertex three times, vertex model). */
SIM_HD static inline void cs_im_cand_vertices(const cs_phys *p, const cs_im_rocks *R, int32_t k, int32_t t[3])
{
    if (p->contact_model != CS_CONTACT_SURFACE) {
        t[0] = t[1] = t[2] = R->cand[k];
        return;
    }
    const int32_t v = R->cand[k] >> 1, face = R->cand[k] & 1, nx = p->nx;
    t[0] = v, t[1] = face ? v + nx + 1 : v + 1, t[2] = face ? v + nx : v + nx + 1;
}

/* The vertices candidates 0 .. nc - 1 (in grid order) may touch: v0 .. v1 - 1, whole rows (their
 * first row to the row after their last). */
SIM_HD static inline void cs_im_cand_span(const cs_phys *p, const cs_im_rocks *R, int32_t nc, int32_t *v0, int32_t *v1)
{
    if (nc == 0) {
        *v0 = *v1 = 0;
        return;
    }
    /* a candidate's first vertex is in its row (cs_im_cand_vertices: the quad's corner, or itself) */
    const int32_t nx = p->nx;
    int32_t first[3], last[3];
    cs_im_cand_vertices(p, R, 0, first);
    cs_im_cand_vertices(p, R, nc - 1, last);
    const int32_t a = first[0] / nx, b = last[0] / nx;
    *v0 = a * nx;
    *v1 = (b + 2 < p->ny ? b + 2 : p->ny) * nx;
}

/* Step 1 of a part: the rocks over h without the cloth, sub-cycled at most rock_dt under their own
 * contacts and gravity (cs_rock_force without the cloth), each v += d F / M, w likewise, then
 * drift. Where each starts (rx0) and where this leaves it (star) are kept: the solve's carried
 * mass follows that path, and cs_im_rocks_push moves the rock from there. */
SIM_HD static inline void cs_im_rocks_advance(const cs_phys *p, const cs_im_rocks *R, float h)
{
    const int32_t nr = R->nr;
    if (!nr) return;
    for (int32_t r = 0; r < nr; r++) R->rx0[r] = R->rocks[r].x;
    int32_t sub = 1;
    if (p->rock_dt > 0.0f && h > p->rock_dt) {
        const float k = h / p->rock_dt;
        sub = k > 1e6f ? 1000000 : (int32_t)k + 1;
    }
    const float d = h / (float)sub;
    for (int32_t k = 0; k < sub; k++) {
        for (int32_t r = 0; r < nr; r++) cs_rock_force(R->rocks, nr, r, NULL, 0, p, &R->F[r], &R->T[r]);
        for (int32_t r = 0; r < nr; r++) {
            cs_rock_state *q = &R->rocks[r];
            q->v = cs_add(q->v, cs_scale(R->F[r], q->inv_mass * d));
            q->w = cs_add(q->w, cs_scale(R->T[r], q->inv_inertia * d));
            cs_rock_drift(q, d);
        }
    }
    for (int32_t r = 0; r < nr; r++) R->star[r] = R->rocks[r];
}

/* Step 1, after cs_im_rocks_advance: the mass each dynamic rock lends the vertices that may touch it
 * in the part (cs_im_share_tri over its candidates near rx0 within R + 2 contact_offset; a vertex
 * carries one rock, the first that reaches it), taken from the cloth as it is (R->x: the part's
 * start), so that nothing carries over from part to part: into sr, sh (M times the vertex's share
 * of the rock's weights) and sn (the unit mean normal). */
SIM_HD static inline void cs_im_rocks_share(const cs_phys *p, const cs_im_rocks *R)
{
    const int32_t n = p->n, nr = R->nr;
    const int surface = p->contact_model == CS_CONTACT_SURFACE;
    if (R->rows) { /* nothing carried: the last share's carriers lie within its spans, cleared too */
        for (int32_t r = 0; r < CS_MAX_ROCKS; r++) {
            for (int32_t v = R->rows[2 * r] > 0 ? R->rows[2 * r] : 0; v < R->rows[2 * r + 1] && v < n; v++)
                R->sr[v] = -1;
            R->rows[2 * r] = R->rows[2 * r + 1] = 0;
        }
    } else {
        for (int32_t v = 0; v < n; v++) R->sr[v] = -1;
    }
    for (int32_t r = 0; r < nr; r++) {
        const cs_rock_state *q = &R->rocks[r];
        if (!(q->inv_mass > 0.0f)) continue; /* a dynamic rock's translation only */
        const float Rc = q->radius + p->contact_offset + p->contact_offset;
        const int32_t nc = cs_im_rock_candidates(p, R, R->rx0[r], Rc);
        int32_t v0 = 0, v1 = n; /* the vertices that may carry it */
        if (R->rows) {
            cs_im_cand_span(p, R, nc, &v0, &v1);
            R->rows[2 * r] = v0, R->rows[2 * r + 1] = v1;
        }
        float total = 0.0f;
        for (int32_t k = 0; k < nc; k++) {
            int32_t t[3];
            cs_im_cand_vertices(p, R, k, t);
            cs_vec3 x[3];
            float b[3];
            for (int e = 0; e < 3; e++) x[e] = cs_im_rock_x(R, t[e]);
            cs_vec3 nn;
            if (!cs_im_share_tri(x, R->rx0[r], Rc, b, &nn)) continue;
            for (int e = 0; e < (surface ? 3 : 1); e++) {
                const int32_t v = t[e];
                if (R->w[v] == 0.0f || b[e] == 0.0f || (R->sr[v] >= 0 && R->sr[v] != r)) continue;
                if (R->sr[v] < 0) {
                    R->sr[v] = r, R->sh[v] = 0.0f;
                    R->sn[3 * (size_t)v] = R->sn[3 * (size_t)v + 1] = R->sn[3 * (size_t)v + 2] = 0.0f;
                }
                R->sh[v] += b[e];
                const cs_vec3 s = cs_add(cs_v3_from(R->sn + 3 * (size_t)v), cs_scale(nn, b[e]));
                R->sn[3 * (size_t)v] = s.x, R->sn[3 * (size_t)v + 1] = s.y, R->sn[3 * (size_t)v + 2] = s.z;
                total += b[e];
            }
        }
        /* each of its vertices once: M times its share of the weights, the unit mean normal */
        for (int32_t v = v0; v < v1 && total > 0.0f; v++) {
            if (R->sr[v] != r) continue;
            const cs_vec3 nv = cs_v3_from(R->sn + 3 * (size_t)v);
            const float len = cs_len(nv);
            R->sh[v] = q->mass * (R->sh[v] / total);
            const cs_vec3 u = len > 0.0f ? cs_scale(nv, 1.0f / len) : cs_v3(0.0f, 0.0f, 0.0f);
            R->sn[3 * (size_t)v] = u.x, R->sn[3 * (size_t)v + 1] = u.y, R->sn[3 * (size_t)v + 2] = u.z;
        }
    }
}

/* In the solve: vertex v's carried term at the iterate x (x_n its start), when it carries a rock's
 * mass (cs_im_rocks_share): its force into F and block into b (cs_im_carried); 0 when it carries
 * none. */
SIM_HD static inline int cs_im_carried_at(const cs_im_rocks *R, int32_t v, cs_vec3 x, cs_vec3 xn, float h, cs_vec3 *F,
                                          cs_mat3 *b)
{
    const int32_t r = R->sr[v];
    if (r < 0 || R->w[v] == 0.0f) return 0;
    *F = cs_im_carried(cs_v3_from(R->sn + 3 * (size_t)v), R->sh[v], cs_im_beyond(R, r, x, xn), h, b);
    return 1;
}

/* Vertex v's normal weight against rock r after the push (in kg m: its normal impulse over the part
 * times h): the impulse that stopped its approach times h (sg), plus, when it carries r, its
 * carried mass times how far it moved toward the rock's path (sh max(0, -n . d)). */
SIM_HD static inline float cs_im_pressed(const cs_im_rocks *R, int32_t r, int32_t v)
{
    float c = R->sg[v];
    if (R->sr[v] == r && R->w[v] != 0.0f) {
        const float nd = cs_dot(cs_v3_from(R->sn + 3 * (size_t)v), cs_im_beyond(R, r, cs_im_rock_x(R, v), cs_im_rock_xb(R, v)));
        c += nd < 0.0f ? -R->sh[v] * nd : 0.0f;
    }
    return c;
}

/* Coulomb friction between rock r and the cloth at the end of a part h (after the push; P the
 * rock's normal impulse times h, carried and stopped, away from the cloth): the patch's velocity V,
 * the mean of its vertices' weighted by cs_im_pressed, and the velocity of the rock's contact point
 * (centre plus spin at the arm a = -R P/|P|) are brought to the same tangential velocity by the
 * impulse J = -u_t / (1/M + R^2/I + sum beta_v^2 / m_v) (beta_v the weights normalised), at most
 * mu |P| / h: the rock gains J (and a x J of spin), the vertices -beta_v J, each moving by its
 * change of velocity times h, so momentum is kept and the spin's change matches the torque at the
 * contact; sticks within the cone, slides at mu beyond it. Clears sg. Over vertices v0 .. v1 - 1,
 * which hold every one it presses (cs_im_pressed > 0) and every nonzero sg. */
SIM_HD static inline void cs_im_rock_friction(const cs_phys *p, const cs_im_rocks *R, int32_t r, float h, cs_vec3 P,
                                              int32_t v0, int32_t v1)
{
    cs_rock_state *q = &R->rocks[r];
    const float pn = cs_len(P);
    float B = 0.0f, W2 = 0.0f;
    cs_vec3 V = cs_v3(0.0f, 0.0f, 0.0f);
    for (int32_t v = v0; v < v1; v++) {
        const float c = cs_im_pressed(R, r, v);
        if (!(c > 0.0f)) continue;
        B += c;
        V = cs_add(V, cs_scale(cs_v3(R->vx[v], R->vy[v], R->vz[v]), c));
        W2 += c * c * p->inv_mass * R->w[v];
    }
    cs_vec3 J = cs_v3(0.0f, 0.0f, 0.0f);
    if (B > 0.0f && pn > 0.0f && p->mu > 0.0f) {
        const cs_vec3 nb = cs_scale(P, 1.0f / pn), a = cs_scale(nb, -q->radius);
        V = cs_scale(V, 1.0f / B);
        const cs_vec3 u = cs_sub(cs_add(q->v, cs_cross(q->w, a)), V), ut = cs_sub(u, cs_scale(nb, cs_dot(nb, u)));
        const float W = q->inv_mass + q->radius * q->radius * q->inv_inertia + W2 / (B * B);
        if (W > 0.0f) {
            J = cs_scale(ut, -1.0f / W);
            const float j = cs_len(J), cap = p->mu * pn / h;
            if (j > cap) J = cs_scale(J, cap / j);
        }
        q->v = cs_add(q->v, cs_scale(J, q->inv_mass));
        q->x = cs_add(q->x, cs_scale(J, q->inv_mass * h));
        q->w = cs_add(q->w, cs_scale(cs_cross(a, J), q->inv_inertia));
    }
    for (int32_t v = v0; v < v1; v++) {
        const float c = cs_im_pressed(R, r, v);
        R->sg[v] = 0.0f;
        if (!(c > 0.0f)) continue;
        const cs_vec3 dv = cs_scale(J, -c / B * p->inv_mass * R->w[v]);
        R->vx[v] += dv.x, R->vy[v] += dv.y, R->vz[v] += dv.z;
        R->x[v] += dv.x * h, R->y[v] += dv.y * h, R->z[v] += dv.z * h;
    }
}

/* Triangle x[3] (velocities u[3], inverse masses wv) in contact with rock q centred at c, at the
 * contact sphere Rc (within a float's slack of it: after the push): the inelastic impulse along
 * the normal n (centre to cloth) that stops the triangle's closest point approaching the rock's
 * surface, then the one that stops the vertex nearest that point (the largest weight) approaching
 * it as well, into du[3] and the rock's dv (the caller applies them), b its barycentric weights;
 * returns the first impulse, 0 when apart or separating. Without the second a vertex wedged
 * between rocks runs into one at metres a second, put back by the push (positions only) every
 * part, and the parts count its speed; stopping every vertex of the triangle let the 100 kg rock
 * of the surface-hold sweep through the 8 x 8 cloth (kernels/MODEL.md, "A pile of stones"). */
SIM_HD static inline float cs_im_stop_tri(const cs_vec3 x[3], const cs_vec3 u[3], const float wv[3],
                                          const cs_rock_state *q, cs_vec3 c, float Rc, cs_vec3 du[3], cs_vec3 *dv,
                                          float b[3], cs_vec3 *nout)
{
    cs_vec3 n;
    if (!cs_im_share_tri(x, c, Rc * 1.0001f + 1e-6f, b, &n)) return 0.0f;
    const cs_vec3 up = cs_tri_point(u[0], u[1], u[2], b);
    const cs_vec3 us = cs_add(q->v, cs_cross(q->w, cs_scale(n, q->radius)));
    const float vn = cs_dot(cs_sub(up, us), n);
    const float W = q->inv_mass + b[0] * b[0] * wv[0] + b[1] * b[1] * wv[1] + b[2] * b[2] * wv[2];
    if (!(vn < 0.0f) || !(W > 0.0f)) return 0.0f;
    const float lambda = -vn / W;
    for (int k = 0; k < 3; k++) du[k] = cs_scale(n, b[k] * wv[k] * lambda);
    *dv = cs_scale(n, -q->inv_mass * lambda);
    {
        const int k = b[0] >= b[1] && b[0] >= b[2] ? 0 : b[1] >= b[2] ? 1 : 2;
        const float vk = cs_dot(cs_sub(cs_add(u[k], du[k]), us), n); /* its approach after the first */
        if (vk < 0.0f && wv[k] > 0.0f) {
            const float lk = -vk / (wv[k] + q->inv_mass);
            du[k] = cs_add(du[k], cs_scale(n, wv[k] * lk));
            *dv = cs_sub(*dv, cs_scale(n, q->inv_mass * lk));
        }
    }
    *nout = n;
    return lambda;
}

/* After the carried moves of cs_im_rocks_push: no pair of rocks ends closer, nor approaching faster,
 * than the advance left it (star) where it touches. The solve moves each rock with the cloth that
 * carries it and knows nothing of the rocks' contacts with one another: on a sagging cloth it drives
 * neighbours into each other part after part, and the next advance's stiff contact throws them
 * apart (a pile of stones that never settles). Each such pair, in index order, is put back along its
 * normal to the lesser of its distance at star and its contact distance, and its approach along it
 * brought back to star's (or 0), both mass-weighted: momentum kept, no energy added. */
SIM_HD static inline void cs_im_rocks_apart(const cs_im_rocks *R)
{
    for (int32_t a = 0; a < R->nr; a++)
        for (int32_t b = a + 1; b < R->nr; b++) {
            cs_rock_state *A = &R->rocks[a], *B = &R->rocks[b];
            const float W = A->inv_mass + B->inv_mass, touch = A->radius + B->radius;
            const cs_vec3 d = cs_sub(B->x, A->x);
            const float l = cs_len(d);
            if (!(W > 0.0f) || !(l < touch) || !(l > 0.0f)) continue;
            const cs_vec3 n = cs_scale(d, 1.0f / l);
            const float l0 = cs_len(cs_sub(R->star[b].x, R->star[a].x)), want = l0 < touch ? l0 : touch;
            if (l < want) {
                A->x = cs_sub(A->x, cs_scale(n, (want - l) * A->inv_mass / W));
                B->x = cs_add(B->x, cs_scale(n, (want - l) * B->inv_mass / W));
            }
            const float un = cs_dot(cs_sub(R->star[b].v, R->star[a].v), n), vn = cs_dot(cs_sub(B->v, A->v), n);
            const float floor = un < 0.0f ? un : 0.0f;
            if (vn < floor) {
                A->v = cs_sub(A->v, cs_scale(n, (floor - vn) * A->inv_mass / W));
                B->v = cs_add(B->v, cs_scale(n, (floor - vn) * B->inv_mass / W));
            }
        }
}

/* Step 3 of a part, after the solve (R->x the iterate): the rocks follow what their vertices
 * carried in it (each dynamic rock moved by the mass-weighted mean of its vertices' normal moves
 * beyond its own path: the momentum the carrying took from the cloth), then the rocks and the
 * cloth pushed apart (cs_im_push_tri, positions only), rock by rock, its candidates swept
 * CS_IM_PUSH_SWEEPS times; then the approach along each contact stopped (cs_im_stop_tri, the
 * velocities only) and friction (cs_im_rock_friction); a = the rock's change of velocity over the
 * part / h. R->v* must hold the iterate's velocities (x - x_n)/h on entry. */
SIM_HD static inline void cs_im_rocks_push(const cs_phys *p, const cs_im_rocks *R, float h)
{
    const int32_t nr = R->nr, n = p->n;
    if (!nr) return;
    const float inv_h = 1.0f / h;
    cs_vec3 *acc = R->F;
    /* each rock's carriers in vertex order (within its span of cs_im_rocks_share where kept) */
    for (int32_t r = 0; r < nr; r++) {
        acc[r] = cs_v3(0.0f, 0.0f, 0.0f);
        const int32_t v0 = R->rows ? R->rows[2 * r] : 0, v1 = R->rows ? R->rows[2 * r + 1] : n;
        for (int32_t v = v0; v < v1; v++) {
            if (R->sr[v] != r || R->w[v] == 0.0f) continue;
            const cs_vec3 nv = cs_v3_from(R->sn + 3 * (size_t)v);
            const cs_vec3 d = cs_im_beyond(R, r, cs_im_rock_x(R, v), cs_im_rock_xb(R, v));
            acc[r] = cs_add(acc[r], cs_scale(nv, R->sh[v] * R->rocks[r].inv_mass * cs_dot(nv, d)));
        }
    }
    for (int32_t r = 0; r < nr; r++) {
        cs_rock_state *q = &R->rocks[r];
        if (!(q->inv_mass > 0.0f)) continue;
        q->x = cs_add(R->star[r].x, acc[r]);
        q->v = cs_add(R->star[r].v, cs_scale(acc[r], inv_h));
        acc[r] = cs_scale(acc[r], q->mass); /* the carried impulse times h, for friction */
    }
    cs_im_rocks_apart(R);
    const int surface = p->contact_model == CS_CONTACT_SURFACE;
    for (int32_t r = 0; r < nr; r++) {
        cs_rock_state *q = &R->rocks[r];
        const cs_vec3 c0 = q->x;
        const float Rc = q->radius + p->contact_offset;
        const int32_t nc = cs_im_rock_candidates(p, R, c0, cs_surface_lim(q, p));
        /* the vertices it may press: its candidates' and those that carry it */
        int32_t v0 = 0, v1 = n;
        if (R->rows) {
            cs_im_cand_span(p, R, nc, &v0, &v1);
            const int32_t a = R->rows[2 * r], b = R->rows[2 * r + 1];
            if (a < b) v0 = v0 < v1 && v0 < a ? v0 : a, v1 = v1 > b ? v1 : b;
        }
        /* what the rock moves, summed apart from its position: a heavy rock's share of one push
         * can be below the float spacing of its coordinates */
        cs_vec3 moved = cs_v3(0.0f, 0.0f, 0.0f), P = q->inv_mass > 0.0f ? acc[r] : cs_v3(0.0f, 0.0f, 0.0f);
        for (int sweep = 0; sweep < CS_IM_PUSH_SWEEPS && nc; sweep++)
            for (int32_t k = 0; k < nc; k++) {
                int32_t t[3];
                cs_im_cand_vertices(p, R, k, t);
                cs_vec3 x[3], dx[3], dc;
                float wv[3];
                for (int e = 0; e < 3; e++) {
                    x[e] = cs_im_rock_x(R, t[e]);
                    wv[e] = surface || e == 0 ? p->inv_mass * R->w[t[e]] : 0.0f;
                }
                const float lambda = cs_im_push_tri(x, wv, cs_add(c0, moved), q->inv_mass, Rc, dx, &dc);
                if (lambda == 0.0f) continue;
                for (int e = 0; e < (surface ? 3 : 1); e++) {
                    const cs_vec3 y = cs_add(x[e], dx[e]);
                    R->x[t[e]] = y.x, R->y[t[e]] = y.y, R->z[t[e]] = y.z;
                }
                moved = cs_add(moved, dc);
            }
        q->x = cs_add(c0, moved);
        /* the velocities: each contact's approach along its normal stopped (inelastic), sweep by
         * sweep in the same order; the positions stay where the push left them */
        for (int sweep = 0; sweep < CS_IM_STOP_SWEEPS && nc; sweep++)
            for (int32_t k = 0; k < nc; k++) {
                int32_t t[3];
                cs_im_cand_vertices(p, R, k, t);
                cs_vec3 x[3], u[3], du[3], dv, nk;
                float wv[3], b[3];
                for (int e = 0; e < 3; e++) {
                    x[e] = cs_im_rock_x(R, t[e]);
                    u[e] = cs_v3(R->vx[t[e]], R->vy[t[e]], R->vz[t[e]]);
                    wv[e] = surface || e == 0 ? p->inv_mass * R->w[t[e]] : 0.0f;
                }
                const float lambda = cs_im_stop_tri(x, u, wv, q, q->x, Rc, du, &dv, b, &nk);
                if (lambda == 0.0f) continue;
                for (int e = 0; e < (surface ? 3 : 1); e++) {
                    R->vx[t[e]] += du[e].x, R->vy[t[e]] += du[e].y, R->vz[t[e]] += du[e].z;
                    R->sg[t[e]] += (surface ? b[e] : 1.0f) * lambda * h;
                }
                q->v = cs_add(q->v, dv);
                P = cs_sub(P, cs_scale(nk, lambda * h));
            }
        cs_im_rock_friction(p, R, r, h, P, v0, v1);
        /* the boxes of the rows whose vertices it moved, for the next rock's candidates */
        if (R->rowbox && v0 < v1)
            for (int32_t j = (v0 / p->nx > 0 ? v0 / p->nx - 1 : 0); j <= (v1 - 1) / p->nx; j++)
                cs_im_row_box(p, R->x, R->y, R->z, j, R->rowbox + 6 * (size_t)j);
        q->a = cs_scale(cs_sub(q->v, R->star[r].v), inv_h); /* the cloth's, as the state reports it */
        q->alpha = cs_v3(0.0f, 0.0f, 0.0f);
    }
}

/* How deep cloth may close on a rock of radius r within one part of a substep: the larger of the
 * contact layer (contact_offset) and a quarter of the radius. Deeper than the layer the push after
 * the solve, not the solve's contact, stops the cloth; it moves the cloth back out on the side it
 * came from while the depth stays well under r (MODEL.md, "Parts"). Never 0 (r > 0). */
#define CS_IM_DEPTH_OF_RADIUS 0.25f
SIM_HD static inline float cs_im_depth(const cs_phys *p, float r)
{
    const float d = CS_IM_DEPTH_OF_RADIUS * r;
    return p->contact_offset > d ? p->contact_offset : d;
}

/* How fast cloth vertex v may close on a rock over a substep h, as a rate: the closing speed over
 * the depth it may close by in a part (cs_im_depth), 1/s (for the parts of a substep,
 * cs_im_splits). Over the rocks that it, or a triangle it belongs to, may reach within the
 * substep - those whose centre lies within R + contact_offset + ring + (|v_r| + |v_v| + 2 gain) h,
 * ring the longest distance from v to its six render neighbours (a triangle's closest point lies
 * within its longest edge of each of its vertices), gain gravity's |g| h: the largest speed of
 * the vertex relative to the rock across the cloth's surface toward it ((v_v - v_r) . n over the
 * normals n of its six triangles, each turned to the side the rock's centre is on; surface model)
 * or toward the rock's centre (vertex model), plus gain. Motion along the surface cannot carry a
 * rock through it, nor motion away from the rock (a plane moving away from a centre only gets
 * farther from it); 0 when no rock is that near, so a fast cloth far from every rock, or a rock
 * falling through the air, costs no parts. x..vz: the state's arrays (a NaN is never taken). */
SIM_HD static inline float cs_im_closing(const cs_phys *p, const cs_rock_state *rocks, int32_t nr, const float *x,
                                         const float *y, const float *z, const float *vx, const float *vy,
                                         const float *vz, int32_t v, float h)
{
    if (!nr) return 0.0f;
    const int32_t nx = p->nx, ny = p->ny, i = v % nx, j = v / nx;
    const cs_vec3 xv = cs_v3(x[v], y[v], z[v]), uv = cs_v3(vx[v], vy[v], vz[v]);
    /* the ring in turning order: (1,0) (1,1) (0,1) (-1,0) (-1,-1) (0,-1); consecutive pairs and v
     * are the render triangles about v */
    cs_vec3 e[6];
    int has[6];
    float ring = 0.0f;
    for (int k = 0; k < 6; k++) {
        const int di = k == 0 || k == 1 ? 1 : k == 3 || k == 4 ? -1 : 0;
        const int dj = k == 1 || k == 2 ? 1 : k == 4 || k == 5 ? -1 : 0;
        has[k] = !(i + di < 0 || i + di >= nx || j + dj < 0 || j + dj >= ny);
        e[k] = cs_v3(0.0f, 0.0f, 0.0f);
        if (!has[k]) continue;
        const int32_t o = v + dj * nx + di;
        e[k] = cs_sub(cs_v3(x[o], y[o], z[o]), xv);
        const float l = cs_len(e[k]);
        ring = l > ring ? l : ring;
    }
    const float gain = cs_len(p->gravity) * h, sv = cs_len(uv);
    const int surface = p->contact_model == CS_CONTACT_SURFACE;
    float most = 0.0f;
    for (int32_t r = 0; r < nr; r++) {
        const cs_rock_state *q = &rocks[r];
        const cs_vec3 to = cs_sub(q->x, xv), rel = cs_sub(uv, q->v);
        const float dist = cs_len(to);
        const float reach = q->radius + p->contact_offset + ring + (cs_len(q->v) + sv + 2.0f * gain) * h;
        if (!(dist < reach)) continue;
        float c = 0.0f;
        if (surface) {
            for (int k = 0; k < 6; k++) {
                if (!has[k] || !has[(k + 1) % 6]) continue;
                const cs_vec3 f = cs_cross(e[k], e[(k + 1) % 6]);
                const float fl = cs_len(f);
                /* toward the rock: along the normal on the side its centre is on */
                const float a = cs_dot(rel, f) * (cs_dot(f, to) < 0.0f ? -1.0f : 1.0f);
                const float s = fl > 0.0f ? (a > 0.0f ? a / fl : 0.0f) : cs_len(rel);
                c = s > c ? s : c;
            }
        } else {
            const float s = dist > 0.0f ? cs_dot(rel, to) / dist : cs_len(rel);
            c = s > 0.0f ? s : 0.0f;
        }
        c = (c + gain) / cs_im_depth(p, q->radius);
        most = c > most ? c : most;
    }
    return most;
}

/* ---- a vertex's residual and diagonal ---- */

/* The diagonal d of the springs plus the inertia and drag terms m/h^2 + m drag/h. */
SIM_HD static inline cs_mat3 cs_im_inertia(const cs_phys *p, float h, cs_mat3 d)
{
    const float dm = p->mass / (h * h) + p->mass * p->drag / h;
    d.m[0] += dm;
    d.m[4] += dm;
    d.m[8] += dm;
    return d;
}

/* The non-contact part at vertex v = (i, j): its 12 springs in CS_SPRING_SLOTS order (each from
 * cs_spring_force at the iterate's positions and velocities v = (x - x_n)/h, so the result is the
 * explicit force law at the new state), then cs_air_gravity: the resultant Ro, which the caller
 * adds contacts to. D receives the springs' blocks, then the inertia and drag terms m/h^2 + m drag/h.
 * xs, vs: the slots' positions and velocities (ignored where on[slot] is 0: off the grid). owned[t]
 * receives the block of the spring of type t the vertex owns (zero where it has none). */
SIM_HD static inline cs_vec3 cs_im_springs(const cs_phys *p, cs_vec3 xi, cs_vec3 vi, const cs_vec3 *xs,
                                          const cs_vec3 *vs, const float *L0s, const int *on, float h, cs_mat3 *D,
                                          cs_mat3 *owned)
{
    cs_vec3 f = cs_v3(0.0f, 0.0f, 0.0f);
    cs_mat3 d = cs_m3_zero();
    int slot = 0;
#define CS_IM_SLOT(t, di, dj, fwd)                                                                      \
    if (on[slot]) {                                                                                    \
        cs_mat3 b;                                                                                     \
        f = cs_add(f, cs_im_spring(xi, vi, xs[slot], vs[slot], L0s[slot], p->k[t], p->c_spring, h, &b));  \
        cs_m3_addto(&d, &b);                                                                           \
        if (fwd) owned[t] = b;                                                                         \
    } else if (fwd) {                                                                                  \
        owned[t] = cs_m3_zero();                                                                       \
    }                                                                                                  \
    slot++;
    CS_SPRING_SLOTS(CS_IM_SLOT)
#undef CS_IM_SLOT
    *D = cs_im_inertia(p, h, d);
    return cs_add(f, cs_air_gravity(vi, p));
}

/* The residual once the contacts are in F: F - m (v - v_n)/h. */
SIM_HD static inline cs_vec3 cs_im_residual(const cs_phys *p, cs_vec3 F, cs_vec3 v, cs_vec3 v_old, float h)
{
    return cs_sub(F, cs_scale(cs_sub(v, v_old), p->mass / h));
}

/* The acceleration of a free vertex's first guess x_n + h v_n + h^2 a (MODEL.md, "Newton"):
 * gravity, scaled by the vertex's last acceleration a_last along it, clamped to 0 .. |g| - the
 * adaptive initialisation of Vertex Block Descent (Chen et al. 2024). A falling vertex guesses its
 * free fall (a cloth in free fall needs no Newton iteration), a supported one no fall, so a cloth
 * at rest starts at rest rather than pulled off its pins by h^2 g (which left Newton at 5 % of its
 * first residual after two iterations). A NaN in a_last guesses no fall. */
SIM_HD static inline cs_vec3 cs_im_guess_accel(const cs_phys *p, cs_vec3 a_last)
{
    const float g = cs_len(p->gravity);
    if (!(g > 0.0f)) return p->gravity;
    const cs_vec3 u = cs_scale(p->gravity, 1.0f / g);
    float a = cs_dot(a_last, u);
    a = a > 0.0f ? (a < g ? a : g) : 0.0f;
    return cs_scale(u, a);
}

/* ---- a level's operator ---- */

/* What a backend hands the functions below of one level: its grid, its vertices' mask (1 in the
 * solve, 0 out), D, the four forward blocks and on the finest level the two bending blocks
 * (B_0 to (i + 2, j), B_1 to (i, j + 2); NULL on coarse levels). Blocks are CS_IM_SYM floats each,
 * element major: element k of vertex v at D[k S + v], F[t][k S + v]. */
typedef struct cs_im_level {
    int32_t nx, ny;
    size_t S; /* the blocks' stride: cs_im_stride(nx ny) */
    const float *mask;
    const float *D, *Dinv;
    const float *F[4];
    const float *B[2];
} cs_im_level;

/* (A x)_v on a level: D x_v, then the forward blocks in order, then the backward ones (the
 * neighbours' forward blocks transposed), then (bend = 1, finest level) the bending blocks
 * likewise; 0 for a vertex out of the solve. x is 3 floats a vertex; 0 for a vertex out of the
 * solve. */
SIM_HD static inline cs_vec3 cs_im_apply(const cs_im_level *L, const float *x, int32_t i, int32_t j, int bend)
{
    const int32_t nx = L->nx, ny = L->ny, v = j * nx + i;
    if (L->mask[v] == 0.0f) return cs_v3(0.0f, 0.0f, 0.0f);
    const size_t S = L->S;
    cs_vec3 y = cs_im_sym_mul(L->D + v, S, cs_v3_from(x + 3 * (size_t)v));
    for (int t = 0; t < 4; t++) {
        const int32_t ii = i + cs_im_fwd_di(t), jj = j + cs_im_fwd_dj(t);
        if (ii < 0 || ii >= nx || jj >= ny) continue;
        const int32_t q = jj * nx + ii;
        y = cs_add(y, cs_im_sym_mul(L->F[t] + v, S, cs_v3_from(x + 3 * (size_t)q)));
    }
    for (int t = 0; t < 4; t++) {
        const int32_t ii = i - cs_im_fwd_di(t), jj = j - cs_im_fwd_dj(t);
        if (ii < 0 || ii >= nx || jj < 0) continue;
        const int32_t q = jj * nx + ii;
        y = cs_add(y, cs_im_sym_mul(L->F[t] + q, S, cs_v3_from(x + 3 * (size_t)q)));
    }
    if (bend) {
        for (int b = 0; b < 2; b++) {
            const int32_t ii = i + 2 * (1 - b), jj = j + 2 * b;
            if (ii < nx && jj < ny) {
                const int32_t q = jj * nx + ii;
                y = cs_add(y, cs_im_sym_mul(L->B[b] + v, S, cs_v3_from(x + 3 * (size_t)q)));
            }
            const int32_t ib = i - 2 * (1 - b), jb = j - 2 * b;
            if (ib >= 0 && jb >= 0) {
                const int32_t q = jb * nx + ib;
                y = cs_add(y, cs_im_sym_mul(L->B[b] + q, S, cs_v3_from(x + 3 * (size_t)q)));
            }
        }
    }
    return y;
}

/* cs_im_apply for a vertex whose every neighbour it reads is on the grid (1 <= i <= nx - 2 and
 * 1 <= j <= ny - 2; with bend, 2 .. n - 3): the same sums in the same order, written out without
 * branches or loops (the mask a select at the end) and always inlined, so that a CPU loop over a
 * row's vertices vectorizes. */
#if defined(__GNUC__)
#define CS_IM_FORCE_INLINE __attribute__((always_inline))
#else
#define CS_IM_FORCE_INLINE
#endif
SIM_HD static inline CS_IM_FORCE_INLINE cs_vec3 cs_im_apply_inner(const cs_im_level *L, const float *x, int32_t v,
                                                                  int bend)
{
    const int32_t nx = L->nx;
    const size_t S = L->S;
    /* the forward neighbours' offsets, in cs_im_fwd_di/dj's order: (1, 0), (0, 1), (1, 1), (-1, 1) */
    const int32_t o0 = 1, o1 = nx, o2 = nx + 1, o3 = nx - 1;
    const float *xv = x + 3 * (size_t)v; /* x of vertex v; of v + d at xv + 3 d */
#define CS_IM_X(d) cs_v3_from(xv + 3 * (d))
    cs_vec3 y = cs_im_sym_mul(L->D + v, S, CS_IM_X(0));
    y = cs_add(y, cs_im_sym_mul(L->F[0] + v, S, CS_IM_X(o0)));
    y = cs_add(y, cs_im_sym_mul(L->F[1] + v, S, CS_IM_X(o1)));
    y = cs_add(y, cs_im_sym_mul(L->F[2] + v, S, CS_IM_X(o2)));
    y = cs_add(y, cs_im_sym_mul(L->F[3] + v, S, CS_IM_X(o3)));
    y = cs_add(y, cs_im_sym_mul(L->F[0] + (v - o0), S, CS_IM_X(-o0)));
    y = cs_add(y, cs_im_sym_mul(L->F[1] + (v - o1), S, CS_IM_X(-o1)));
    y = cs_add(y, cs_im_sym_mul(L->F[2] + (v - o2), S, CS_IM_X(-o2)));
    y = cs_add(y, cs_im_sym_mul(L->F[3] + (v - o3), S, CS_IM_X(-o3)));
    if (bend) {
        const int32_t b0 = 2, b1 = 2 * nx;
        y = cs_add(y, cs_im_sym_mul(L->B[0] + v, S, CS_IM_X(b0)));
        y = cs_add(y, cs_im_sym_mul(L->B[0] + (v - b0), S, CS_IM_X(-b0)));
        y = cs_add(y, cs_im_sym_mul(L->B[1] + v, S, CS_IM_X(b1)));
        y = cs_add(y, cs_im_sym_mul(L->B[1] + (v - b1), S, CS_IM_X(-b1)));
    }
#undef CS_IM_X
    return L->mask[v] != 0.0f ? y : cs_v3(0.0f, 0.0f, 0.0f);
}

/* One damped Jacobi update of vertex v: x_v + omega Dinv (b_v - (A x)_v), 0 out of the solve; Ax
 * is (A x)_v. Without branches (the mask a select), so that a CPU loop over vertices vectorizes. */
SIM_HD static inline cs_vec3 cs_im_jacobi(const cs_im_level *L, int32_t v, cs_vec3 x, cs_vec3 b, cs_vec3 Ax)
{
    const cs_vec3 r = cs_add(x, cs_scale(cs_im_sym_mul(L->Dinv + v, L->S, cs_sub(b, Ax)), CS_IM_OMEGA));
    return L->mask[v] != 0.0f ? r : cs_v3(0.0f, 0.0f, 0.0f);
}

/* The coarse level's size along an axis of n fine vertices. */
SIM_HD static inline int32_t cs_im_coarse(int32_t n) { return (n + 1) / 2; }

/* Floats a level of k vertices takes: D, Dinv and the four forward blocks (CS_IM_SYM rows of
 * cs_im_stride(k) each), the mask, and the V-cycle's three vectors (right side, solution, scratch: 3
 * a vertex). */
static inline size_t cs_im_level_floats(size_t k) { return CS_IM_SYM * 6 * cs_im_stride(k) + 10 * k; }

/* Carves a level of k vertices out of a workspace block at m, in the order both backends use
 * (cs_im_level_floats(k): D, Dinv, the four forward blocks, the mask, b, x, t); returns the
 * block past it. Host code: the backends lay out their workspaces with it. */
static inline float *cs_im_carve_level(float *m, size_t k, float **D, float **Dinv, float *F[4], float **mask,
                                       float **b, float **x, float **t)
{
    const size_t S = cs_im_stride(k);
    *D = m, m += CS_IM_SYM * S;
    *Dinv = m, m += CS_IM_SYM * S;
    for (int q = 0; q < 4; q++) F[q] = m, m += CS_IM_SYM * S;
    *mask = m, m += k;
    *b = m, m += 3 * k;
    *x = m, m += 3 * k;
    *t = m, m += 3 * k;
    return m;
}

/* The hierarchy of an nx x ny grid: each level's size into lx[], ly[] (CS_IM_MAX_LEVELS slots),
 * halving while either side is above CS_IM_COARSEST; returns the number of levels. */
SIM_HD static inline int cs_im_levels(int32_t nx, int32_t ny, int32_t *lx, int32_t *ly)
{
    int L = 0;
    for (;;) {
        lx[L] = nx, ly[L] = ny;
        L++;
        if (L == CS_IM_MAX_LEVELS || (nx <= CS_IM_COARSEST && ny <= CS_IM_COARSEST)) return L;
        nx = cs_im_coarse(nx), ny = cs_im_coarse(ny);
    }
}

/* The Galerkin product's row of coarse vertex (I, J) of level C from the fine level L (2 x 2
 * aggregation): D_C = the sum of the aggregate's diagonal blocks and of the blocks coupling two of
 * its vertices (both ways), F_C,t = the sum of the blocks coupling the aggregate to aggregate
 * (I, J) + fwd(t) - the fine forward blocks from this aggregate, then the fine backward ones into
 * it (transposed) - each in a fixed order of fine vertex, then direction. Writes D and F[t]
 * (the coarse arrays + the coarse vertex; Sc the coarse level's vertex count) and the coarse
 * mask; an empty aggregate gets the identity and mask 0. */
SIM_HD static inline void cs_im_galerkin(const cs_im_level *L, int32_t I, int32_t J, float *D, float *F[4],
                                         size_t Sc, float *mask)
{
    const int32_t nx = L->nx, ny = L->ny;
    const size_t S = L->S;
    cs_mat3 d = cs_m3_zero(), f[4];
    for (int t = 0; t < 4; t++) f[t] = cs_m3_zero();
    float any = 0.0f;
    for (int a = 0; a < 4; a++) {
        const int32_t i = 2 * I + (a & 1), j = 2 * J + (a >> 1);
        if (i >= nx || j >= ny) continue;
        const int32_t v = j * nx + i;
        if (L->mask[v] == 0.0f) continue;
        any = 1.0f;
        const cs_mat3 Dv = cs_im_sym_get(L->D + v, S);
        cs_m3_addto(&d, &Dv);
        for (int s = 0; s < 4; s++) {
            const int32_t ii = i + cs_im_fwd_di(s), jj = j + cs_im_fwd_dj(s);
            if (ii < 0 || ii >= nx || jj >= ny || L->mask[jj * nx + ii] == 0.0f) continue;
            const cs_mat3 Bv = cs_im_sym_get(L->F[s] + v, S), *B = &Bv;
            const int32_t dI = ii / 2 - I, dJ = jj / 2 - J;
            if (dI == 0 && dJ == 0) { /* within the aggregate: both ways */
                cs_m3_addto(&d, B);
                cs_m3_addto_t(&d, B);
                continue;
            }
            for (int t = 0; t < 4; t++)
                if (dI == cs_im_fwd_di(t) && dJ == cs_im_fwd_dj(t)) cs_m3_addto(&f[t], B);
        }
    }
    /* fine backward blocks from this aggregate into a forward neighbour aggregate: the fine block
     * A(a, b) with a here and b = a - fwd(s) there is F_s(b)^T */
    for (int a = 0; a < 4; a++) {
        const int32_t i = 2 * I + (a & 1), j = 2 * J + (a >> 1);
        if (i >= nx || j >= ny || L->mask[j * nx + i] == 0.0f) continue;
        for (int s = 0; s < 4; s++) {
            const int32_t ii = i - cs_im_fwd_di(s), jj = j - cs_im_fwd_dj(s);
            if (ii < 0 || ii >= nx || jj < 0) continue;
            const int32_t q = jj * nx + ii;
            if (L->mask[q] == 0.0f) continue;
            const int32_t dI = ii / 2 - I, dJ = jj / 2 - J;
            if (dI == 0 && dJ == 0) continue; /* counted above from q's side */
            for (int t = 0; t < 4; t++)
                if (dI == cs_im_fwd_di(t) && dJ == cs_im_fwd_dj(t)) {
                    const cs_mat3 Bq = cs_im_sym_get(L->F[s] + q, S);
                    cs_m3_addto_t(&f[t], &Bq);
                }
        }
    }
    if (any == 0.0f) d = cs_m3_diag(1.0f);
    cs_im_sym_put(D, Sc, &d);
    for (int t = 0; t < 4; t++) {
        if (any == 0.0f) f[t] = cs_m3_zero();
        cs_im_sym_put(F[t], Sc, &f[t]);
    }
    *mask = any;
}

/* Whether coarse vertex (I, J) of a level over an nx x ny fine grid is inner for
 * cs_im_galerkin_inner: every fine vertex its product reads lies on the grid (columns 2I - 1 ..
 * 2I + 2, rows 2J .. 2J + 2). */
SIM_HD static inline int cs_im_galerkin_is_inner(int32_t nx, int32_t ny, int32_t I, int32_t J)
{
    return I >= 1 && 2 * I + 2 <= nx - 1 && 2 * J + 2 <= ny - 1;
}

/* cs_im_galerkin for an inner coarse vertex (cs_im_galerkin_is_inner): the same sums in the same
 * order, the branches of the general loops resolved for the 2 x 2 aggregate (which fine block
 * couples which aggregates is fixed there), a mask a select after the sum, and the symmetric
 * blocks' six stored elements only (each of the nine takes the same sums as its mirror), so that a
 * CPU loop over a row's coarse vertices vectorizes. The same bits as cs_im_galerkin
 * (tests/unit/test_implicit.c). Fine vertices v0 = (2I, 2J), v1 = v0 + 1, v2 = v0 + nx, v3 = v2 + 1. */
SIM_HD static inline CS_IM_FORCE_INLINE void cs_im_galerkin_inner(const cs_im_level *L, int32_t I, int32_t J,
                                                                 float *D, float *F[4], size_t Sc, float *mask)
{
    const int32_t nx = L->nx;
    const size_t S = L->S;
    const int32_t v0 = 2 * J * nx + 2 * I, v1 = v0 + 1, v2 = v0 + nx, v3 = v2 + 1;
    const float *m = L->mask;
    const int m0 = m[v0] != 0.0f, m1 = m[v1] != 0.0f, m2 = m[v2] != 0.0f, m3 = m[v3] != 0.0f;
    float d[6], f0[6], f1[6], f2[6], f3[6];
    for (int e = 0; e < 6; e++) d[e] = f0[e] = f1[e] = f2[e] = f3[e] = 0.0f;
    /* acc += blk[e S] where on (the fine blocks' element e); twice: B and its transpose */
#define CS_IM_ADD(acc, blk, on)                                                                    \
    for (int e = 0; e < 6; e++) {                                                                  \
        const float t_ = acc[e] + (blk)[(size_t)e * S];                                            \
        acc[e] = (on) ? t_ : acc[e];                                                               \
    }
#define CS_IM_ADD2(acc, blk, on)                                                                   \
    for (int e = 0; e < 6; e++) {                                                                  \
        const float b_ = (blk)[(size_t)e * S], t_ = (acc[e] + b_) + b_;                            \
        acc[e] = (on) ? t_ : acc[e];                                                               \
    }
    /* fine vertex 0 (2I, 2J): its blocks to v1, v2, v3 lie within the aggregate */
    CS_IM_ADD(d, L->D + v0, m0)
    CS_IM_ADD2(d, L->F[0] + v0, m0 && m1)
    CS_IM_ADD2(d, L->F[1] + v0, m0 && m2)
    CS_IM_ADD2(d, L->F[2] + v0, m0 && m3)
    /* fine vertex 1 (2I + 1, 2J): to (2I + 2, 2J) and (2I + 2, 2J + 1) in aggregate (I + 1, J) */
    CS_IM_ADD(d, L->D + v1, m1)
    CS_IM_ADD(f0, L->F[0] + v1, m1 && m[v1 + 1] != 0.0f)
    CS_IM_ADD2(d, L->F[1] + v1, m1 && m3)
    CS_IM_ADD(f0, L->F[2] + v1, m1 && m[v1 + nx + 1] != 0.0f)
    CS_IM_ADD2(d, L->F[3] + v1, m1 && m2)
    /* fine vertex 2 (2I, 2J + 1): up into (I, J + 1), and (2I - 1, 2J + 2) into (I - 1, J + 1) */
    CS_IM_ADD(d, L->D + v2, m2)
    CS_IM_ADD2(d, L->F[0] + v2, m2 && m3)
    CS_IM_ADD(f1, L->F[1] + v2, m2 && m[v2 + nx] != 0.0f)
    CS_IM_ADD(f1, L->F[2] + v2, m2 && m[v2 + nx + 1] != 0.0f)
    CS_IM_ADD(f3, L->F[3] + v2, m2 && m[v2 + nx - 1] != 0.0f)
    /* fine vertex 3 (2I + 1, 2J + 1) */
    CS_IM_ADD(d, L->D + v3, m3)
    CS_IM_ADD(f0, L->F[0] + v3, m3 && m[v3 + 1] != 0.0f)
    CS_IM_ADD(f1, L->F[1] + v3, m3 && m[v3 + nx] != 0.0f)
    CS_IM_ADD(f2, L->F[2] + v3, m3 && m[v3 + nx + 1] != 0.0f)
    CS_IM_ADD(f1, L->F[3] + v3, m3 && m[v3 + nx - 1] != 0.0f)
    /* the one backward block into a forward aggregate: (2I + 2, 2J)'s block to (2I + 1, 2J + 1),
     * transposed (symmetric: the same elements) */
    CS_IM_ADD(f0, L->F[3] + (v0 + 2), m3 && m[v0 + 2] != 0.0f)
#undef CS_IM_ADD
#undef CS_IM_ADD2
    const int any = m0 || m1 || m2 || m3;
    const float id[6] = {1.0f, 0.0f, 0.0f, 1.0f, 0.0f, 1.0f};
    for (int e = 0; e < 6; e++) {
        D[(size_t)e * Sc] = any ? d[e] : id[e];
        F[0][(size_t)e * Sc] = any ? f0[e] : 0.0f;
        F[1][(size_t)e * Sc] = any ? f1[e] : 0.0f;
        F[2][(size_t)e * Sc] = any ? f2[e] : 0.0f;
        F[3][(size_t)e * Sc] = any ? f3[e] : 0.0f;
    }
    *mask = any ? 1.0f : 0.0f;
}

/* Restriction (the sum over the aggregate, in its fixed order) of a fine vector r at coarse vertex
 * (I, J). */
SIM_HD static inline cs_vec3 cs_im_restrict(const cs_im_level *L, const float *r, int32_t I, int32_t J)
{
    cs_vec3 s = cs_v3(0.0f, 0.0f, 0.0f);
    for (int a = 0; a < 4; a++) {
        const int32_t i = 2 * I + (a & 1), j = 2 * J + (a >> 1);
        if (i >= L->nx || j >= L->ny) continue;
        const int32_t v = j * L->nx + i;
        if (L->mask[v] != 0.0f) s = cs_add(s, cs_v3_from(r + 3 * (size_t)v));
    }
    return s;
}

/* ---- fixed-order sums ----
 * A sum over the vertices of a level-0 grid is taken as the rock partials are (physics.h): per
 * chunk (a row's CS_CHUNK columns) by cs_tree_sum's tree, then the chunks in order, in groups of
 * CS_CHUNK_GROUP. The terms of vertex v of a dot product: a.x b.x + a.y b.y + a.z b.z. */
SIM_HD static inline float cs_im_dot3(const float *a, const float *b, int32_t v)
{
    const size_t o = 3 * (size_t)v;
    return a[o] * b[o] + a[o + 1] * b[o + 1] + a[o + 2] * b[o + 2];
}

/* The total of per-chunk partials, chunk by chunk in groups (cs_rock_group_sum's order). */
SIM_HD static inline float cs_im_chunk_total(const float *partials, int32_t nchunks)
{
    float total = 0.0f;
    for (int32_t g = 0; g < nchunks; g += CS_CHUNK_GROUP) {
        const int32_t e = g + CS_CHUNK_GROUP < nchunks ? g + CS_CHUNK_GROUP : nchunks;
        float s = 0.0f;
        for (int32_t c = g; c < e; c++) s += partials[c];
        total += s;
    }
    return total;
}

/* What float rounding alone leaves of a residual: positions of `reach` metres carry an ulp of
 * 2^-23 reach, which a vertex's springs turn into forces of about k ulp; measured, the residual of
 * the default cloth stops falling at about a tenth of 4 (k_structural + k_shear + k_bend) ulp
 * sqrt(n) (6e-3 N at 64 x 64). Newton stops there: iterating below it only stirs rounding. */
SIM_HD static inline float cs_im_float_floor(const cs_phys *p, float reach)
{
    return 1.2e-8f * reach * 4.0f * (p->k[CS_SX] + p->k[CS_D1] + p->k[CS_BX]) * sqrtf((float)p->n);
}

/* Whether Newton takes another iteration, in both backends' loops: k iterations taken, r the
 * residual now, r0 the first, prev the one before the last iteration, rounding
 * cs_im_float_floor. It stops at solver_iterations, at the tolerance, at rounding's floor, or once
 * an iteration no longer halves the residual (the floor, where the estimate is low). */
SIM_HD static inline int cs_im_newton_more(const cs_phys *p, int k, float r, float r0, float prev, float rounding)
{
    return k < p->solver_iterations && r > p->solver_tolerance * r0 && r > rounding && r < 0.5f * prev;
}

/* Where a Newton iteration's conjugate gradients stop, at residual r (r0 the first): a twentieth
 * of r, or half the tolerance of r0 where that is more. */
SIM_HD static inline float cs_im_cg_target(const cs_phys *p, float r0, float r)
{
    const float aim = 0.5f * p->solver_tolerance * r0, step = 0.05f * r;
    return aim > step ? aim : step;
}

/* The largest coordinate of x and r (for cs_im_float_floor's reach; max is exact in any order). */
SIM_HD static inline float cs_im_reach(cs_vec3 x, float r)
{
    const float ax = fabsf(x.x) > fabsf(x.y) ? fabsf(x.x) : fabsf(x.y), az = fabsf(x.z);
    r = ax > r ? ax : r;
    return az > r ? az : r;
}

/* The phys of a part of a substep, of length h: its own step, and plasticity's share of it. Both
 * backends' parts step with it. */
SIM_HD static inline cs_phys cs_im_part_phys(const cs_phys *p, float h)
{
    cs_phys P = *p;
    P.dt = h, P.hdt = 0.5f * h;
    if (P.plastic_rate > 0.0f) P.plastic_f = P.plastic_rate * h < 1.0f ? P.plastic_rate * h : 1.0f;
    return P;
}

/* The parts a substep h is cut into so that nothing closes on a rock by more than cs_im_depth in
 * one (MODEL.md, "Parts"): for the largest closing rate of cs_im_closing (1/s), at most most. */
SIM_HD static inline int32_t cs_im_splits(float rate, float h, int32_t most)
{
    const float k = rate * h;
    if (!(k > 1.0f)) return 1;
    return k >= (float)most ? most : (int32_t)k + 1;
}

#endif
