/* clothsim/selfcontact.h - cloth self-collision (self_collision, self_thickness; kernels/MODEL.md,
 * "Self-collision"): SIM_HD functions that the CPU backend loops over the grid.
 *
 * After each substep (each part under implicit_euler) the cloth has moved from x0 (the substep's
 * start, free of crossings) to x1. Two passes, each one thread per vertex, gathering only:
 *
 * 1. Repulsion (cs_sc_repel). Vertex-triangle and edge-edge pairs closer at x1 than
 *    self_thickness push apart: the point and the triangle's corners (by its barycentric weights),
 *    or the two edges' ends (by the closest points' segment weights), each by its inverse mass,
 *    move apart along the pair's normal until they are self_thickness apart, and their approach
 *    along it stops (inelastic: momentum kept, no energy added). The normal is turned to the side
 *    the pair was on at x0, so a pair the step took through each other is pushed back across.
 *    Left out: pairs within CS_SC_RINGS rings of each other in the grid, and pairs closer at rest
 *    than the thickness. Each vertex averages what its pairs ask of it (Jacobi), each weighted by
 *    the vertex's part in the pair (1 as the point, else its barycentric or segment weight),
 *    summed in the order of the pairs' keys (cs_sc_pair_key, cs_sc_ee_key), so whichever list
 *    found them gives the same bits.
 *
 * 2. The bound (cs_sc_limit). Every vertex-triangle pair and every edge-edge pair that shares no
 *    vertex, intact triangles and their edges only, as close at x0 as r = self_thickness + 2 M /
 *    CS_SC_GAMMA (M the largest displacement of any vertex in the substep: a pair further apart
 *    cannot meet, its vertices' motion relative to each other being at most 2 M) is safe while the
 *    largest displacement of one of its vertices relative to another of them stays under
 *    CS_SC_GAMMA times its distance at x0, less a room for rounding (cs_sc_round_margin; its
 *    distance then changes too slowly to reach zero),
 *    or while a direction keeps its two sides apart all along their straight paths (cs_sc_safe,
 *    cs_sc_apart_along: layers sliding over each other, or pushed apart, however near): its
 *    closest points then never meet. An unsafe pair's vertices are cut back, each to half of
 *    CS_SC_GAMMA of that distance less the room (then no two of them move apart by more than
 *    that); sweeps repeat
 *    until every pair is safe (a vertex's cut only ever grows, so they end). Two triangles that
 *    share no vertex cross only after such a pair met (a vertex through a face, or an edge
 *    through an edge), so none cross: the guarantee needs no continuous collision detection.
 *    The cut vertex's velocity is scaled as its displacement was.
 *
 * The broad phase: vertices in a uniform hash grid of cells as large as the farthest a pair's
 * vertex can lie from the vertex that gathers it (r plus twice the longest edge), built by a
 * counting sort in vertex order, so the order every vertex meets its candidates in is fixed. */
#ifndef CLOTHSIM_SELFCONTACT_H
#define CLOTHSIM_SELFCONTACT_H

#include "clothsim/physics.h"

/* A pair is safe while its vertices move relative to each other by less than this fraction of
 * its distance (the rest is left for rounding). */
#define CS_SC_GAMMA 0.9f
/* Pairs within this many rings of each other in the grid do not repel. */
#define CS_SC_RINGS 2
/* Sweeps of the bound before every pair near enough is cut outright (each sweep is exact). */
#define CS_SC_SWEEPS 16

SIM_HD static inline float cs_sc_min(float a, float b) { return a < b ? a : b; }
SIM_HD static inline float cs_sc_max(float a, float b) { return a > b ? a : b; }

/* The hash grid: start[k] .. start[k + 1] index ids (vertices by cell key, in vertex order);
 * cc[3 v .. 3 v + 2] is vertex v's cell (cs_sc_coord of each coordinate). */
typedef struct cs_sc_grid {
    const int32_t *start, *ids, *cc;
    uint32_t mask; /* table size - 1 (a power of two) */
    float cell;    /* cell size (m) */
} cs_sc_grid;

/* The cell coordinate of a position along an axis (clamped far beyond any cloth). */
SIM_HD static inline int32_t cs_sc_coord(float x, float cell)
{
    const float c = floorf(x / cell);
    return c < -1e9f ? -1000000000 : c > 1e9f ? 1000000000 : (int32_t)c;
}

SIM_HD static inline uint32_t cs_sc_key(int32_t i, int32_t j, int32_t k, uint32_t mask)
{
    return (((uint32_t)i * 73856093u) ^ ((uint32_t)j * 19349663u) ^ ((uint32_t)k * 83492791u)) & mask;
}

/* Vertex v's cell into cc[3 v ..] and its key. */
SIM_HD static inline uint32_t cs_sc_cell_of(cs_vec3 x, float cell, uint32_t mask, int32_t *cc)
{
    cc[0] = cs_sc_coord(x.x, cell), cc[1] = cs_sc_coord(x.y, cell), cc[2] = cs_sc_coord(x.z, cell);
    return cs_sc_key(cc[0], cc[1], cc[2], mask);
}

/* The counting sort: key[v] of every vertex, then start (mask + 2 entries) and ids. One thread. */
SIM_HD static inline void cs_sc_sort(int32_t n, const uint32_t *key, uint32_t mask, int32_t *start, int32_t *ids)
{
    for (uint32_t k = 0; k <= mask + 1; k++) start[k] = 0;
    for (int32_t v = 0; v < n; v++) start[key[v] + 1]++;
    for (uint32_t k = 0; k <= mask; k++) start[k + 1] += start[k];
    /* fill in vertex order: start[k] runs ahead as its cell fills, then is set back */
    for (int32_t v = 0; v < n; v++) ids[start[key[v]]++] = v;
    for (uint32_t k = mask + 1; k > 0; k--) start[k] = start[k - 1];
    start[0] = 0;
}

/* Distance from p to triangle a b c, and the barycentric weights of its closest point. */
SIM_HD static inline float cs_sc_point_tri(cs_vec3 p, cs_vec3 a, cs_vec3 b, cs_vec3 c, float w[3])
{
    cs_closest_on_triangle(p, a, b, c, w);
    const cs_vec3 q = cs_tri_point(a, b, c, w);
    return cs_len(cs_sub(p, q));
}

/* The point of segment p0 p1 at parameter s. */
SIM_HD static inline cs_vec3 cs_sc_seg_point(cs_vec3 p0, cs_vec3 p1, float s)
{
    return cs_add(p0, cs_scale(cs_sub(p1, p0), s));
}

/* Distance between segments p0 p1 and q0 q1 (closest points by clamped parameters, then each
 * re-projected once: exact for non-parallel segments, and for parallel ones a pair of points at
 * the least distance). */
SIM_HD static inline float cs_sc_seg_seg_st(cs_vec3 p0, cs_vec3 p1, cs_vec3 q0, cs_vec3 q1, float *ps, float *pt)
{
    const cs_vec3 d1 = cs_sub(p1, p0), d2 = cs_sub(q1, q0), r = cs_sub(p0, q0);
    const float a = cs_dot(d1, d1), e = cs_dot(d2, d2), f = cs_dot(d2, r);
    float s = 0.0f, t = 0.0f;
    *ps = 0.0f, *pt = 0.0f;
    if (!(a > 1e-20f) && !(e > 1e-20f)) return cs_len(r);
    if (!(a > 1e-20f)) {
        t = cs_sc_min(cs_sc_max(f / e, 0.0f), 1.0f);
    } else {
        const float c = cs_dot(d1, r);
        if (!(e > 1e-20f)) {
            s = cs_sc_min(cs_sc_max(-c / a, 0.0f), 1.0f);
        } else {
            const float b = cs_dot(d1, d2), den = a * e - b * b;
            s = den > 1e-12f * a * e ? cs_sc_min(cs_sc_max((b * f - c * e) / den, 0.0f), 1.0f) : 0.0f;
            t = (b * s + f) / e;
            if (t < 0.0f) {
                t = 0.0f;
                s = cs_sc_min(cs_sc_max(-c / a, 0.0f), 1.0f);
            } else if (t > 1.0f) {
                t = 1.0f;
                s = cs_sc_min(cs_sc_max((b - c) / a, 0.0f), 1.0f);
            }
        }
    }
    *ps = s, *pt = t;
    const cs_vec3 cp = cs_sc_seg_point(p0, p1, s), cq = cs_sc_seg_point(q0, q1, t);
    return cs_len(cs_sub(cp, cq));
}

SIM_HD static inline float cs_sc_seg_seg(cs_vec3 p0, cs_vec3 p1, cs_vec3 q0, cs_vec3 q1)
{
    float s, t;
    return cs_sc_seg_seg_st(p0, p1, q0, q1, &s, &t);
}

/* The intact triangles of quad (i, j) as vertex ids (canonical order, physics.h), into t[f];
 * returns the bits (1 A, 2 B). */
SIM_HD static inline int32_t cs_sc_quad_tris(const float *L0, int32_t nx, int32_t ny, int32_t i, int32_t j,
                                             int32_t t[2][3])
{
    const int32_t faces = cs_quad_faces(L0, nx, ny, i, j), v00 = j * nx + i;
    t[0][0] = v00, t[0][1] = v00 + 1, t[0][2] = v00 + nx + 1;
    t[1][0] = v00, t[1][1] = v00 + nx + 1, t[1][2] = v00 + nx;
    return faces;
}

/* Edge k (0 x, 1 y, 2 diagonal) of vertex (i, j) to (i+1, j), (i, j+1), (i+1, j+1): there while a
 * triangle it bounds is intact (A(i,j) or B(i,j-1); B(i,j) or A(i-1,j); A(i,j) or B(i,j)). */
SIM_HD static inline int cs_sc_edge_on(const float *L0, int32_t nx, int32_t ny, int32_t i, int32_t j, int k)
{
    if (k == 0) return (cs_quad_faces(L0, nx, ny, i, j) & 1) | (cs_quad_faces(L0, nx, ny, i, j - 1) >> 1);
    if (k == 1) return (cs_quad_faces(L0, nx, ny, i, j) >> 1) | (cs_quad_faces(L0, nx, ny, i - 1, j) & 1);
    return cs_quad_faces(L0, nx, ny, i, j) != 0;
}

/* Grid (Chebyshev) distance between vertices a and b. */
SIM_HD static inline int32_t cs_sc_rings(int32_t nx, int32_t a, int32_t b)
{
    const int32_t di = a % nx - b % nx, dj = a / nx - b / nx;
    const int32_t ai = di < 0 ? -di : di, aj = dj < 0 ? -dj : dj;
    return ai > aj ? ai : aj;
}

/* Distance at rest between vertices a and b (the scene's spacing hx, hy). */
SIM_HD static inline float cs_sc_rest(int32_t nx, float hx, float hy, int32_t a, int32_t b)
{
    const float di = (float)(a % nx - b % nx) * hx, dj = (float)(a / nx - b / nx) * hy;
    return sqrtf(di * di + dj * dj);
}

/* Whether point p and triangle t repel (neither near in the grid nor closer at rest than the
 * thickness). */
SIM_HD static inline int cs_sc_repels(const cs_phys *ph, int32_t p, const int32_t t[3])
{
    for (int q = 0; q < 3; q++) {
        if (cs_sc_rings(ph->nx, p, t[q]) <= CS_SC_RINGS) return 0;
        if (cs_sc_rest(ph->nx, ph->self_hx, ph->self_hy, p, t[q]) < ph->self_thickness) return 0;
    }
    return 1;
}

SIM_HD static inline cs_vec3 cs_sc_at(const float *x, const float *y, const float *z, int32_t v)
{
    return cs_v3(x[v], y[v], z[v]);
}


/* The vertices within reach of a gatherer at x0 (XV its position), from every cell the reach spans
 * (each met once: an entry is taken only in its own cell, whatever cell shares its key; when the
 * reach spans more cells than the table has keys, every vertex of the grid in its order instead,
 * so that a far reach costs at most a pass over the cloth); the body is the trailing arguments
 * (commas and all). */
#define CS_SC_FOR_WITHIN(G, X0, Y0, Z0, XV, REACH, W, ...)                                                 \
    do {                                                                                                   \
        const float rc_ = (REACH);                                                                         \
        const int32_t il_ = cs_sc_coord((XV).x - rc_, (G)->cell), ih_ = cs_sc_coord((XV).x + rc_, (G)->cell), \
                      jl_ = cs_sc_coord((XV).y - rc_, (G)->cell), jh_ = cs_sc_coord((XV).y + rc_, (G)->cell), \
                      kl_ = cs_sc_coord((XV).z - rc_, (G)->cell), kh_ = cs_sc_coord((XV).z + rc_, (G)->cell); \
        const double span_ = ((double)ih_ - il_ + 1.0) * ((double)jh_ - jl_ + 1.0) * ((double)kh_ - kl_ + 1.0); \
        if (span_ > (double)(G)->mask + 1.0) {                                                             \
            for (int32_t e_ = 0; e_ < (G)->start[(G)->mask + 1]; e_++) {                                   \
                const int32_t W = (G)->ids[e_];                                                            \
                const cs_vec3 rw_ = cs_sub(cs_sc_at(X0, Y0, Z0, W), XV);                                    \
                if (!(cs_dot(rw_, rw_) < rc_ * rc_)) continue;                                             \
                __VA_ARGS__                                                                                \
            }                                                                                              \
        } else {                                                                                           \
            for (int32_t ck_ = kl_; ck_ <= kh_; ck_++)                                                     \
                for (int32_t cj_ = jl_; cj_ <= jh_; cj_++)                                                 \
                    for (int32_t ci_ = il_; ci_ <= ih_; ci_++) {                                           \
                        const uint32_t key_ = cs_sc_key(ci_, cj_, ck_, (G)->mask);                         \
                        for (int32_t e_ = (G)->start[key_]; e_ < (G)->start[key_ + 1]; e_++) {             \
                            const int32_t W = (G)->ids[e_];                                                \
                            const int32_t *cw_ = (G)->cc + 3 * (size_t)W;                                  \
                            if (cw_[0] != ci_ || cw_[1] != cj_ || cw_[2] != ck_) continue;                 \
                            const cs_vec3 rw_ = cs_sub(cs_sc_at(X0, Y0, Z0, W), XV);                        \
                            if (!(cs_dot(rw_, rw_) < rc_ * rc_)) continue;                                 \
                            __VA_ARGS__                                                                    \
                        }                                                                                  \
                    }                                                                                      \
        }                                                                                                  \
    } while (0)

/* A lower bound of the distance from p to the triangle or segment of corners c[0..k): how far p
 * lies outside their box (cheap; exact distances only where this is below the pairs' reach). */
SIM_HD static inline float cs_sc_box_gap(cs_vec3 p, const cs_vec3 *c, int k)
{
    cs_vec3 lo = c[0], hi = c[0];
    for (int q = 1; q < k; q++) {
        lo = cs_v3(cs_sc_min(lo.x, c[q].x), cs_sc_min(lo.y, c[q].y), cs_sc_min(lo.z, c[q].z));
        hi = cs_v3(cs_sc_max(hi.x, c[q].x), cs_sc_max(hi.y, c[q].y), cs_sc_max(hi.z, c[q].z));
    }
    const float gx = cs_sc_max(cs_sc_max(lo.x - p.x, p.x - hi.x), 0.0f), gy = cs_sc_max(cs_sc_max(lo.y - p.y, p.y - hi.y), 0.0f),
                gz = cs_sc_max(cs_sc_max(lo.z - p.z, p.z - hi.z), 0.0f);
    return sqrtf(gx * gx + gy * gy + gz * gz);
}

/* The gap between the boxes of segments a0 a1 and b0 b1 (a lower bound of their distance). */
SIM_HD static inline float cs_sc_seg_gap(cs_vec3 a0, cs_vec3 a1, cs_vec3 b0, cs_vec3 b1)
{
    const float gx = cs_sc_max(cs_sc_max(cs_sc_min(a0.x, a1.x) - cs_sc_max(b0.x, b1.x), cs_sc_min(b0.x, b1.x) - cs_sc_max(a0.x, a1.x)), 0.0f);
    const float gy = cs_sc_max(cs_sc_max(cs_sc_min(a0.y, a1.y) - cs_sc_max(b0.y, b1.y), cs_sc_min(b0.y, b1.y) - cs_sc_max(a0.y, a1.y)), 0.0f);
    const float gz = cs_sc_max(cs_sc_max(cs_sc_min(a0.z, a1.z) - cs_sc_max(b0.z, b1.z), cs_sc_min(b0.z, b1.z) - cs_sc_max(a0.z, a1.z)), 0.0f);
    return sqrtf(gx * gx + gy * gy + gz * gz);
}

/* The centre of a box of displacements (lo, hi: their least and largest components): two vertices
 * move apart by at most twice the farthest any moves from it, whatever the cloth's motion as a
 * whole. */
SIM_HD static inline cs_vec3 cs_sc_centre(const float lo[3], const float hi[3])
{
    return cs_v3(0.5f * (lo[0] + hi[0]), 0.5f * (lo[1] + hi[1]), 0.5f * (lo[2] + hi[2]));
}

/* Whether candidate u, dist from v, may be in a pair closer than rad: a triangle with corner u
 * (or v) lies within the longest edge L of it (vertex-triangle), an edge from u or v within its
 * length (edge-edge, la + lb for the two). The 1 % and 1 um only leave room for rounding: what is
 * skipped could never pass the exact tests. */
SIM_HD static inline int cs_sc_may(float dist, float rad, float span)
{
    return dist < 1.01f * rad + span + 1e-6f;
}

/* Under implicit_euler a substep is cut into parts (as for rocks: implicit.h, cs_im_splits) so that
 * no vertex of a pair that may touch within the substep moves more than this fraction of
 * self_thickness in one about the cloth's common motion: the repulsion after each part then meets
 * layers before the bound has to stop them. (At twice and four times the thickness the folding
 * test still did not cross, but its layers at rest came to 1.97 and 0.82 mm, against 3.79 mm at
 * one: MODEL.md.) */
#define CS_SC_PART 1.0f

/* Vertex q's speed about a centre cv (the centre of the velocities' box), with gravity's |g| h
 * (as cs_sc_near_speed counts it): two vertices close at most at the sum of theirs. */
SIM_HD static inline float cs_sc_speed(const cs_phys *ph, const float *vx, const float *vy, const float *vz, int32_t q,
                                       cs_vec3 cv, float h)
{
    return cs_len(cs_sub(cs_sc_at(vx, vy, vz, q), cv)) + cs_len(ph->gravity) * h;
}

/* ---- 1. repulsion ---- */

/* What one vertex-triangle pair asks of vertex v (v is point p or a corner of t): the position and
 * velocity changes dx, dv (added); 1 when the pair touches. x1..v*: the state's arrays after the
 * substep, w the inverse masses (0 pinned or grabbed), o* the positions at x0. */
SIM_HD static inline int cs_sc_pair_push(const cs_phys *ph, const float *x, const float *y, const float *z,
                                         const float *vx, const float *vy, const float *vz, const float *w,
                                         const float *ox, const float *oy, const float *oz, int32_t p,
                                         const int32_t t[3], int32_t v, cs_vec3 *dx, cs_vec3 *dv, float *wsum)
{
    const cs_vec3 xp = cs_sc_at(x, y, z, p), a = cs_sc_at(x, y, z, t[0]), b = cs_sc_at(x, y, z, t[1]),
                  c = cs_sc_at(x, y, z, t[2]);
    float bw[3];
    const float d = cs_sc_point_tri(xp, a, b, c, bw);
    if (!(d < ph->self_thickness)) return 0;
    const cs_vec3 q = cs_tri_point(a, b, c, bw);
    cs_vec3 n;
    if (d > 1e-9f) {
        n = cs_scale(cs_sub(xp, q), 1.0f / d);
    } else { /* on the face: its normal (its winding decides the side) */
        n = cs_cross(cs_sub(b, a), cs_sub(c, a));
        const float l = cs_len(n);
        if (!(l > 0.0f)) return 0;
        n = cs_scale(n, 1.0f / l);
    }
    /* the side the point was on at x0 (the same closest point): one the step took it through
     * is pushed back across, not further */
    const cs_vec3 r0 = cs_sub(cs_sc_at(ox, oy, oz, p), cs_tri_point(cs_sc_at(ox, oy, oz, t[0]), cs_sc_at(ox, oy, oz, t[1]),
                                                                 cs_sc_at(ox, oy, oz, t[2]), bw));
    const int through = cs_dot(n, r0) < 0.0f;
    if (through) n = cs_scale(n, -1.0f);
    const float wp = w[p];
    float den = wp;
    for (int k = 0; k < 3; k++) den += bw[k] * bw[k] * w[t[k]];
    if (!(den > 0.0f)) return 0;
    /* the separation along n still missing, and the approach along it */
    const float gap = (ph->self_thickness + (through ? d : -d)) / den;
    cs_vec3 vq = cs_v3(0.0f, 0.0f, 0.0f);
    for (int k = 0; k < 3; k++) vq = cs_add(vq, cs_scale(cs_sc_at(vx, vy, vz, t[k]), bw[k]));
    const float vn = cs_dot(cs_sub(cs_sc_at(vx, vy, vz, p), vq), n);
    const float stop = vn < 0.0f ? -vn / den : 0.0f;
    float share = 0.0f, part = 0.0f;
    if (v == p) share = wp, part = 1.0f;
    for (int k = 0; k < 3; k++)
        if (t[k] == v) share = -bw[k] * w[v], part = bw[k];
    *dx = cs_add(*dx, cs_scale(n, gap * share * part));
    *dv = cs_add(*dv, cs_scale(n, stop * share * part));
    *wsum += part;
    return 1;
}

/* Render edge id 3 o + k: edge k (cs_sc_edge_on) of its lower end o; its ends into e. */
SIM_HD static inline void cs_sc_edge_ends(const cs_phys *ph, int32_t id, int32_t e[2])
{
    const int32_t o = id / 3, k = id % 3;
    e[0] = o;
    e[1] = k == 0 ? o + 1 : k == 1 ? o + ph->nx : o + ph->nx + 1;
}

/* Whether edges a and b repel (no ends within CS_SC_RINGS rings, none closer at rest than the
 * thickness; so they share no vertex). */
SIM_HD static inline int cs_sc_ee_repels(const cs_phys *ph, const int32_t a[2], const int32_t b[2])
{
    for (int i = 0; i < 2; i++)
        for (int k = 0; k < 2; k++) {
            if (cs_sc_rings(ph->nx, a[i], b[k]) <= CS_SC_RINGS) return 0;
            if (cs_sc_rest(ph->nx, ph->self_hx, ph->self_hy, a[i], b[k]) < ph->self_thickness) return 0;
        }
    return 1;
}

/* What one edge-edge pair (a, b: a's id the lower) asks of vertex v, as cs_sc_pair_push: the
 * closest points pushed apart to self_thickness and their approach stopped, each end by its
 * segment weight and inverse mass. */
SIM_HD static inline int cs_sc_edge_push(const cs_phys *ph, const float *x, const float *y, const float *z,
                                         const float *vx, const float *vy, const float *vz, const float *w,
                                         const float *ox, const float *oy, const float *oz, const int32_t a[2],
                                         const int32_t b[2], int32_t v, cs_vec3 *dx, cs_vec3 *dv, float *wsum)
{
    const cs_vec3 a0 = cs_sc_at(x, y, z, a[0]), a1 = cs_sc_at(x, y, z, a[1]), b0 = cs_sc_at(x, y, z, b[0]),
                  b1 = cs_sc_at(x, y, z, b[1]);
    float ps, pt;
    const float d = cs_sc_seg_seg_st(a0, a1, b0, b1, &ps, &pt);
    if (!(d < ph->self_thickness)) return 0;
    const cs_vec3 cp = cs_sc_seg_point(a0, a1, ps), cq = cs_sc_seg_point(b0, b1, pt);
    cs_vec3 n;
    if (d > 1e-9f) {
        n = cs_scale(cs_sub(cp, cq), 1.0f / d);
    } else { /* crossing exactly: across both edges */
        n = cs_cross(cs_sub(a1, a0), cs_sub(b1, b0));
        const float l = cs_len(n);
        if (!(l > 0.0f)) return 0;
        n = cs_scale(n, 1.0f / l);
    }
    const float wt[4] = {1.0f - ps, ps, -(1.0f - pt), -pt};
    const int32_t id[4] = {a[0], a[1], b[0], b[1]};
    /* the side edge a was on at x0 (the same closest points): pushed back across if the step
     * took it through */
    cs_vec3 r0 = cs_v3(0.0f, 0.0f, 0.0f);
    for (int k = 0; k < 4; k++) r0 = cs_add(r0, cs_scale(cs_sc_at(ox, oy, oz, id[k]), wt[k]));
    const int through = cs_dot(n, r0) < 0.0f;
    if (through) n = cs_scale(n, -1.0f);
    float den = 0.0f;
    cs_vec3 vr = cs_v3(0.0f, 0.0f, 0.0f);
    for (int k = 0; k < 4; k++) {
        den += wt[k] * wt[k] * w[id[k]];
        vr = cs_add(vr, cs_scale(cs_sc_at(vx, vy, vz, id[k]), wt[k]));
    }
    if (!(den > 0.0f)) return 0;
    const float gap = (ph->self_thickness + (through ? d : -d)) / den, vn = cs_dot(vr, n),
                stop = vn < 0.0f ? -vn / den : 0.0f;
    float share = 0.0f, part = 0.0f;
    for (int k = 0; k < 4; k++)
        if (id[k] == v) share = wt[k] * w[v], part = wt[k] < 0.0f ? -wt[k] : wt[k];
    *dx = cs_add(*dx, cs_scale(n, gap * share * part));
    *dv = cs_add(*dv, cs_scale(n, stop * share * part));
    *wsum += part;
    return 1;
}

/* Vertex v's own part of every pair it is in: its intact triangles (canonical corners, their
 * positions and slots) and its spokes that bound one (as edge ids, and their lengths). */
typedef struct cs_sc_ring {
    int32_t tri[6][3], slot[6], spoke[6];
    cs_vec3 c[6][3];
    float slen[6];
    int ntri, nspoke;
} cs_sc_ring;

SIM_HD static inline void cs_sc_ring_of(const cs_phys *ph, const float *L0, const float *x, const float *y,
                                        const float *z, int32_t v, cs_sc_ring *g)
{
    const int32_t nx = ph->nx, ny = ph->ny, vi = v % nx, vj = v / nx;
    g->ntri = g->nspoke = 0;
    for (int qj = vj - 1; qj <= vj; qj++)
        for (int qi = vi - 1; qi <= vi; qi++) {
            int32_t t[2][3];
            const int32_t f = cs_sc_quad_tris(L0, nx, ny, qi, qj, t);
            for (int k = 0; k < 2; k++)
                if ((f >> k) & 1 && (t[k][0] == v || t[k][1] == v || t[k][2] == v)) {
                    for (int q = 0; q < 3; q++) {
                        g->tri[g->ntri][q] = t[k][q];
                        g->c[g->ntri][q] = cs_sc_at(x, y, z, t[k][q]);
                    }
                    g->slot[g->ntri++] = 2 * (qj * (nx - 1) + qi) + k;
                }
        }
    for (int k = 1; k < CS_RING; k++) {
        const int32_t ui = vi + cs_ring_di(k), uj = vj + cs_ring_dj(k);
        if (ui < 0 || ui >= nx || uj < 0 || uj >= ny) continue;
        const int32_t lo = k <= 3 ? v : uj * nx + ui; /* the edge's owner: its lower end */
        const int e = cs_ring_di(k) != 0 && cs_ring_dj(k) != 0 ? 2 : cs_ring_di(k) != 0 ? 0 : 1;
        if (!cs_sc_edge_on(L0, nx, ny, lo % nx, lo / nx, e)) continue;
        g->slen[g->nspoke] = cs_len(cs_sub(cs_sc_at(x, y, z, uj * nx + ui), cs_sc_at(x, y, z, v)));
        g->spoke[g->nspoke++] = 3 * lo + e;
    }
}

/* A vertex-triangle pair as one sortable key: the point's id, then the triangle's slot (2 per quad,
 * physics.h's canonical A then B), so that every list is summed in the same order. */
SIM_HD static inline int64_t cs_sc_pair_key(const cs_phys *ph, int32_t p, int32_t slot)
{
    return (int64_t)p * (2 * (int64_t)(ph->nx - 1) * (ph->ny - 1)) + slot;
}

/* Edge-edge keys follow every vertex-triangle key: base + lower id 3 n + higher id. */
SIM_HD static inline int64_t cs_sc_ee_base(const cs_phys *ph)
{
    return (int64_t)ph->n * (2 * (int64_t)(ph->nx - 1) * (ph->ny - 1));
}

SIM_HD static inline int64_t cs_sc_ee_key(const cs_phys *ph, int32_t ea, int32_t eb)
{
    const int32_t lo = ea < eb ? ea : eb, hi = ea < eb ? eb : ea;
    return cs_sc_ee_base(ph) + (int64_t)lo * (3 * (int64_t)ph->n) + hi;
}

SIM_HD static inline void cs_sc_key_pair(const cs_phys *ph, int64_t key, int32_t *p, int32_t t[3])
{
    const int64_t slots = 2 * (int64_t)(ph->nx - 1) * (ph->ny - 1);
    *p = (int32_t)(key / slots);
    const int32_t slot = (int32_t)(key % slots), q = slot >> 1, f = slot & 1, nq = ph->nx - 1;
    const int32_t v00 = (q / nq) * ph->nx + q % nq;
    t[0] = v00;
    t[1] = f ? v00 + ph->nx + 1 : v00 + 1;
    t[2] = f ? v00 + ph->nx : v00 + ph->nx + 1;
}

/* A list's key back to its pair: an edge-edge pair's edges into a, b (returns 1), a vertex-triangle
 * pair's point and triangle into p, t (returns 0). */
SIM_HD static inline int cs_sc_key_decode(const cs_phys *ph, int64_t key, int32_t *p, int32_t t[3], int32_t a[2],
                                          int32_t b[2])
{
    const int64_t base = cs_sc_ee_base(ph), edges = 3 * (int64_t)ph->n;
    if (key < base) {
        cs_sc_key_pair(ph, key, p, t);
        return 0;
    }
    cs_sc_edge_ends(ph, (int32_t)((key - base) / edges), a);
    cs_sc_edge_ends(ph, (int32_t)((key - base) % edges), b);
    return 1;
}

/* Adds key to the sorted list keys[0..*n), which has room for cap: past it the key is only
 * counted (*n says how many the list needs; its keys are then not all there). */
SIM_HD static inline void cs_sc_list_add(int64_t *keys, int32_t cap, int32_t *n, int64_t key)
{
    int32_t k = (*n)++;
    if (k >= cap) return;
    while (k > 0 && keys[k - 1] > key) {
        keys[k] = keys[k - 1];
        k--;
    }
    keys[k] = key;
}

/* How many rings apart in the grid vertices (vi, vj) and (ui, uj) lie (the larger of the two index
 * distances). */
SIM_HD static inline int32_t cs_sc_rings_apart(int32_t vi, int32_t vj, int32_t ui, int32_t uj)
{
    const int32_t di = ui > vi ? ui - vi : vi - ui, dj = uj > vj ? uj - vj : vj - uj;
    return di > dj ? di : dj;
}

/* Vertex v's repelling pairs closer than rad at x0 - vertex-triangle (cs_sc_repels) as the point
 * (the triangles of its candidates) and as a corner (its six triangles against its candidates),
 * edge-edge (cs_sc_ee_repels) through its spokes - into keys (room for cap), sorted; returns how
 * many there are: more than cap, and the caller makes room and asks again. Candidates within
 * reach: rad plus twice the longest edge. */
SIM_HD static inline int32_t cs_sc_pairs(const cs_phys *ph, const cs_sc_grid *G, const float *L0, const float *x0,
                                         const float *y0, const float *z0, float reach, float rad, int32_t v,
                                         int64_t *keys, int32_t cap)
{
    const int32_t nx = ph->nx, ny = ph->ny, vi = v % nx, vj = v / nx;
    const cs_vec3 xv = cs_sc_at(x0, y0, z0, v);
    /* a candidate more than 2 CS_SC_RINGS rings away repels with every pair it is in (their vertices
     * lie more than CS_SC_RINGS rings apart), unless the thickness spans that many rings at rest */
    const float h = ph->self_hx < ph->self_hy ? ph->self_hx : ph->self_hy;
    const int fine = ph->self_thickness > (float)(CS_SC_RINGS + 1) * h;
    const float L = 0.5f * (reach - rad); /* the longest edge */
    int32_t n = 0;
    cs_sc_ring g;
    cs_sc_ring_of(ph, L0, x0, y0, z0, v, &g);
    CS_SC_FOR_WITHIN(G, x0, y0, z0, xv, reach, u, {
        if (u != v) {
            float bw[3];
            int32_t t[2][3];
            const int32_t ui = u % nx, uj = u / nx, f = cs_sc_quad_tris(L0, nx, ny, ui, uj, t);
            const int32_t rings = cs_sc_rings_apart(vi, vj, ui, uj);
            /* u and v are both in every pair they could share here: within CS_SC_RINGS, none repels */
            if (rings <= CS_SC_RINGS) continue;
            const int far = !fine && rings > 2 * CS_SC_RINGS;
            const cs_vec3 xu = cs_sc_at(x0, y0, z0, u);
            const float D = cs_len(cs_sub(xu, xv)), vf = cs_sc_may(D, rad, L);
            for (int k = 0; k < 2 && vf; k++) {
                if (!((f >> k) & 1)) continue;
                const cs_vec3 c[3] = {cs_sc_at(x0, y0, z0, t[k][0]), cs_sc_at(x0, y0, z0, t[k][1]),
                                      cs_sc_at(x0, y0, z0, t[k][2])};
                if (!(cs_sc_box_gap(xv, c, 3) < rad) || !(far || cs_sc_repels(ph, v, t[k]))) continue;
                if (cs_sc_point_tri(xv, c[0], c[1], c[2], bw) < rad)
                    cs_sc_list_add(keys, cap, &n, cs_sc_pair_key(ph, v, 2 * (uj * (nx - 1) + ui) + k));
            }
            for (int k = 0; k < g.ntri && vf; k++) {
                if (!(cs_sc_box_gap(xu, g.c[k], 3) < rad) || !(far || cs_sc_repels(ph, u, g.tri[k]))) continue;
                if (cs_sc_point_tri(xu, g.c[k][0], g.c[k][1], g.c[k][2], bw) < rad)
                    cs_sc_list_add(keys, cap, &n, cs_sc_pair_key(ph, u, g.slot[k]));
            }
            /* v's spokes against the edges u owns */
            for (int e = 0; e < 3; e++) {
                if ((e != 1 && ui + 1 >= nx) || (e != 0 && uj + 1 >= ny) || !cs_sc_edge_on(L0, nx, ny, ui, uj, e))
                    continue;
                int32_t b[2];
                cs_sc_edge_ends(ph, 3 * u + e, b);
                const cs_vec3 b0 = cs_sc_at(x0, y0, z0, b[0]), b1 = cs_sc_at(x0, y0, z0, b[1]);
                const float lb = cs_len(cs_sub(b1, b0));
                for (int k = 0; k < g.nspoke; k++) {
                    if (!cs_sc_may(D, rad, lb + g.slen[k])) continue;
                    int32_t a[2];
                    cs_sc_edge_ends(ph, g.spoke[k], a);
                    const cs_vec3 a0 = cs_sc_at(x0, y0, z0, a[0]), a1 = cs_sc_at(x0, y0, z0, a[1]);
                    if (!(cs_sc_seg_gap(a0, a1, b0, b1) < rad) || !(far || cs_sc_ee_repels(ph, a, b))) continue;
                    if (cs_sc_seg_seg(a0, a1, b0, b1) < rad)
                        cs_sc_list_add(keys, cap, &n, cs_sc_ee_key(ph, g.spoke[k], 3 * u + e));
                }
            }
        }
    });
    (void)ny;
    return n;
}

/* Vertex v's repulsion from its list of pairs (keys[0..n), sorted): what the pairs that touch at
 * x1 ask of it, averaged (each weighted by v's part in the pair), into *dx, *dv. Returns the pairs
 * that touch. */
SIM_HD static inline int32_t cs_sc_repel(const cs_phys *ph, const float *x, const float *y, const float *z,
                                         const float *vx, const float *vy, const float *vz, const float *w,
                                         const float *ox, const float *oy, const float *oz, const int64_t *keys,
                                         int32_t n, int32_t v, cs_vec3 *dx, cs_vec3 *dv)
{
    cs_vec3 sx = cs_v3(0.0f, 0.0f, 0.0f), sv = sx;
    int32_t touching = 0;
    float wsum = 0.0f;
    for (int32_t k = 0; k < n; k++) {
        int32_t p, t[3], a[2], b[2];
        if (cs_sc_key_decode(ph, keys[k], &p, t, a, b))
            touching += cs_sc_edge_push(ph, x, y, z, vx, vy, vz, w, ox, oy, oz, a, b, v, &sx, &sv, &wsum);
        else
            touching += cs_sc_pair_push(ph, x, y, z, vx, vy, vz, w, ox, oy, oz, p, t, v, &sx, &sv, &wsum);
    }
    if (wsum > 0.0f) { /* (some pair touched) */
        const float inv = 1.0f / wsum;
        *dx = cs_scale(sx, inv);
        *dv = cs_scale(sv, inv);
    }
    return touching;
}

/* How far apart at x a repelling pair may lie and still pass cs_sc_near_speed's test within h when
 * no vertex's cs_sc_speed (about any one centre) passes Vm: two sides closing at most at 2 Vm, with
 * room for the rounding of a distance computed from the other end. */
SIM_HD static inline float cs_sc_near_reach(float thick, float h, float Vm)
{
    return 1.05f * (thick + 1.01f * h * 2.0f * Vm) + 1e-5f;
}

/* The fastest that the two sides of one of vertex v's repelling pairs (keys[0..n), any order) close
 * on each other, among the pairs that may touch within h: the largest relative speed of a vertex
 * of one side and one of the other, with gravity's |g| h (a layer held up by the ground, a rock or
 * a pin does not follow gravity while the one above it does), for the pairs closer at x than the
 * thickness plus that speed's reach in h (1 % and 1 um for rounding). 0 where none may: the parts
 * of a substep (cs_im_splits of this over CS_SC_PART self_thickness) are cut only for layers that
 * can meet in it, whatever the rest of the cloth does. Such a pair lies within cs_sc_near_reach of
 * its vertices for the fastest cs_sc_speed about any centre. */
SIM_HD static inline float cs_sc_near_speed(const cs_phys *ph, const float *x, const float *y, const float *z,
                                            const float *vx, const float *vy, const float *vz, float h,
                                            const int64_t *keys, int32_t n)
{
    const float gh = cs_len(ph->gravity) * h;
    float most = 0.0f;
    for (int32_t k = 0; k < n; k++) {
        int32_t q[4], t[3], a[2], b[2], na;
        float dist;
        if (cs_sc_key_decode(ph, keys[k], &q[0], t, a, b)) {
            q[0] = a[0], q[1] = a[1], q[2] = b[0], q[3] = b[1], na = 2;
            dist = cs_sc_seg_seg(cs_sc_at(x, y, z, a[0]), cs_sc_at(x, y, z, a[1]), cs_sc_at(x, y, z, b[0]),
                                 cs_sc_at(x, y, z, b[1]));
        } else {
            float bw[3];
            q[1] = t[0], q[2] = t[1], q[3] = t[2], na = 1;
            dist = cs_sc_point_tri(cs_sc_at(x, y, z, q[0]), cs_sc_at(x, y, z, t[0]), cs_sc_at(x, y, z, t[1]),
                                   cs_sc_at(x, y, z, t[2]), bw);
        }
        float V = 0.0f;
        for (int i = 0; i < na; i++)
            for (int j = na; j < 4; j++) {
                const float l = cs_len(cs_sub(cs_sc_at(vx, vy, vz, q[i]), cs_sc_at(vx, vy, vz, q[j])));
                V = l > V ? l : V;
            }
        V += gh;
        if (dist < ph->self_thickness + 1.01f * h * V + 1e-6f) most = V > most ? V : most;
    }
    return most;
}

/* ---- 2. the bound ---- */


/* The largest displacement of one of a pair's vertices relative to another of its other side:
 * side a (na vertices) against side b (nb), with each vertex's displacement s d. */
SIM_HD static inline float cs_sc_relative(const int32_t *a, int na, const int32_t *b, int nb, const float *dx,
                                          const float *dy, const float *dz, const float *s)
{
    float m = 0.0f;
    for (int i = 0; i < na; i++)
        for (int k = 0; k < nb; k++) {
            const float si = s[a[i]], sk = s[b[k]];
            const cs_vec3 r = cs_sub(cs_scale(cs_sc_at(dx, dy, dz, a[i]), si), cs_scale(cs_sc_at(dx, dy, dz, b[k]), sk));
            const float l = cs_len(r);
            m = l > m ? l : m;
        }
    return m;
}

/* Whether direction n keeps the pair's sides apart all along the straight paths from x0 to
 * x0 + s d: side a its first na of the four vertices q, side b the rest. Along n, side a's
 * farthest reach (the largest n . x of its vertices, a maximum of functions linear in time) is
 * convex in time and side b's nearest (the least) concave, so the gap between them is concave:
 * when it is positive at both ends it is positive all the way, and the two convex hulls (the
 * vertex and the triangle, or the two edges) never meet, however close they start or whichever
 * way they slide. In double, from the floats: the margin 1e-6 |n|_1 max|x| covers the positions'
 * rounding (x1 is x0 + s d within 2 ulps of its largest coordinate) and the products'. Either
 * sign of n will do. */
SIM_HD static inline int cs_sc_apart_along(const double n[3], const double X[4][3], const double E[4][3], int na)
{
    double lo[2][2], hi[2][2], big = 0.0; /* [end][side]: the least and largest n . x */
    for (int e = 0; e < 2; e++) {
        const double(*P)[3] = e ? E : X;
        for (int k = 0; k < 4; k++) {
            const double d = n[0] * P[k][0] + n[1] * P[k][1] + n[2] * P[k][2];
            const int side = k >= na;
            if (k == 0 || k == na) lo[e][side] = hi[e][side] = d;
            lo[e][side] = d < lo[e][side] ? d : lo[e][side];
            hi[e][side] = d > hi[e][side] ? d : hi[e][side];
            for (int c = 0; c < 3; c++) {
                const double a = P[k][c] < 0.0 ? -P[k][c] : P[k][c];
                big = a > big ? a : big;
            }
        }
    }
    const double n1 = (n[0] < 0.0 ? -n[0] : n[0]) + (n[1] < 0.0 ? -n[1] : n[1]) + (n[2] < 0.0 ? -n[2] : n[2]);
    const double m = 1e-6 * n1 * big;
    if (!(m > 0.0)) return 0;
    return (lo[0][1] - hi[0][0] > m && lo[1][1] - hi[1][0] > m) || (lo[0][0] - hi[0][1] > m && lo[1][0] - hi[1][1] > m);
}

/* The rounding a pair's first test leaves room for: 2e-6 of the largest coordinate of its four
 * vertices at x0 and at x0 + s d, at most half the thickness (so a pair beyond its reach,
 * cs_sc_pair_reach, stays safe: which list a pair came from never shows; the room covers the
 * rounding while the cloth lies within 2.5e5 thicknesses of the origin, 1.25 km at the default). Each vertex ends within 2 ulps of its largest coordinate of
 * x0 + s d (x0 + fl(s d) rounded, and x0 + d is not x exactly), and its distance at x0 is
 * computed in float from coordinates of that size: a pair a few ulps apart can cross by rounding
 * alone however little it moves (the head-on test's grabbed corner, pressed onto the sheet part
 * after part, came to 0.24 um of it on a cloth 0.5 m from the origin and went through, with a
 * relative motion of 0.21 um: build machine, 2026-12-07). */
SIM_HD static inline float cs_sc_round_margin(const int32_t q[4], const float *x0, const float *y0, const float *z0,
                                              const float *dx, const float *dy, const float *dz, const float *s,
                                              float thick)
{
    float big = 0.0f;
    for (int k = 0; k < 4; k++) {
        const int32_t v = q[k];
        const cs_vec3 a = cs_sc_at(x0, y0, z0, v), b = cs_add(a, cs_scale(cs_sc_at(dx, dy, dz, v), s[v]));
        const float c[6] = {a.x, a.y, a.z, b.x, b.y, b.z};
        for (int i = 0; i < 6; i++) {
            const float u = c[i] < 0.0f ? -c[i] : c[i];
            big = u > big ? u : big;
        }
    }
    const float m = 2e-6f * big;
    return m < 0.5f * thick ? m : 0.5f * thick;
}

/* Whether a pair (its four vertices q, side a the first na) is safe for the displacements s d:
 * its vertices move relative to one another by less than CS_SC_GAMMA of dist, its distance at x0,
 * less m (cs_sc_round_margin; the distance then changes no faster than that, so it cannot reach
 * zero), or - only if not,
 * as it costs more - one of the directions dir (the pair's normal at x0 from its closest points,
 * and the triangle's normal or the edges' cross product there) keeps them apart all along
 * (cs_sc_apart_along): layers that slide over each other, or that the repulsion pushes apart,
 * however near they are. */
SIM_HD static inline int cs_sc_safe(const int32_t q[4], int na, float dist, float m, cs_vec3 dir,
                                    const float *x0, const float *y0, const float *z0, const float *dx,
                                    const float *dy, const float *dz, const float *s)
{
    if (cs_sc_relative(q, na, q + na, 4 - na, dx, dy, dz, s) < CS_SC_GAMMA * dist - m) return 1;
    double X[4][3], E[4][3];
    for (int k = 0; k < 4; k++) {
        const int32_t v = q[k];
        const double sv = (double)s[v]; /* s d is exact in double */
        X[k][0] = x0[v], X[k][1] = y0[v], X[k][2] = z0[v];
        E[k][0] = X[k][0] + sv * (double)dx[v], E[k][1] = X[k][1] + sv * (double)dy[v];
        E[k][2] = X[k][2] + sv * (double)dz[v];
    }
    const double n0[3] = {dir.x, dir.y, dir.z};
    if (cs_sc_apart_along(n0, X, E, na)) return 1;
    /* the triangle's normal (na 1: q1 q2 x q1 q3), or the two edges' cross product (na 2: q0 q1 x
     * q2 q3) */
    const int u0 = na == 1 ? 1 : 0, w0 = na == 1 ? 1 : 2;
    double u[3], w[3];
    for (int c = 0; c < 3; c++) u[c] = X[u0 + 1][c] - X[u0][c], w[c] = X[3][c] - X[w0][c];
    const double n1[3] = {u[1] * w[2] - u[2] * w[1], u[2] * w[0] - u[0] * w[2], u[0] * w[1] - u[1] * w[0]};
    return cs_sc_apart_along(n1, X, E, na);
}

/* Vertex v's cut for a pair (dist its distance at x0, m cs_sc_round_margin): 1 while the pair is
 * safe, else the largest scale that keeps v within half of CS_SC_GAMMA dist - m, and 0 when that
 * is not positive (the vertex then stays at x0 exactly: x0 + 0 d is x0). */
SIM_HD static inline float cs_sc_pair_cut(int safe, float dist, float m, const float *dx, const float *dy,
                                          const float *dz, int32_t v)
{
    if (safe) return 1.0f;
    const float l = cs_len(cs_sc_at(dx, dy, dz, v)), lim = 0.5f * (CS_SC_GAMMA * dist - m);
    if (!(lim > 0.0f)) return 0.0f;
    return l > lim ? lim / l : 1.0f;
}


/* The distance at x0 within which a pair whose vertices move by at most E relative to one another
 * may be unsafe: beyond it they move by less than CS_SC_GAMMA of their distance (1 % and 1 um for
 * rounding), so the pair is safe; the thickness is the room every pair gets (the repulsion's). A
 * pair's vertices move relative to one another by at most the farthest any of one side's moves
 * from a point c plus the farthest of the other side's (|d_i - d_k| <= |d_i - c| + |d_k - c|,
 * whatever c: the spreads about it). */
SIM_HD static inline float cs_sc_pair_reach(float thick, float E)
{
    return thick + 1.01f * E / CS_SC_GAMMA + 1e-6f;
}

/* Vertex-triangle pair (point p, triangle t; canonical corners) if it lies within r at x0: vertex
 * v's cut for it into *cut and its distance into *dmin (each the least kept); returns 1 then. */
SIM_HD static inline int cs_sc_vf_cut(const float *x0, const float *y0, const float *z0, const float *dx,
                                      const float *dy, const float *dz, const float *s, int32_t p,
                                      const int32_t t[3], float r, float thick, int32_t v, int outright, float *cut,
                                      float *dmin)
{
    float bw[3];
    const cs_vec3 xp = cs_sc_at(x0, y0, z0, p), a = cs_sc_at(x0, y0, z0, t[0]), b = cs_sc_at(x0, y0, z0, t[1]),
                  c = cs_sc_at(x0, y0, z0, t[2]);
    const float d = cs_sc_point_tri(xp, a, b, c, bw);
    if (!(d < r)) return 0;
    const int32_t q[4] = {p, t[0], t[1], t[2]};
    const cs_vec3 dir = cs_sub(xp, cs_tri_point(a, b, c, bw));
    const float m = cs_sc_round_margin(q, x0, y0, z0, dx, dy, dz, s, thick);
    const int safe = !outright && cs_sc_safe(q, 1, d, m, dir, x0, y0, z0, dx, dy, dz, s);
    const float cv = cs_sc_pair_cut(safe, d, m, dx, dy, dz, v);
    *cut = cv < *cut ? cv : *cut;
    *dmin = d < *dmin ? d : *dmin;
    return 1;
}

/* The same for the edge-edge pair a, b (each from its lower end), taken in a canonical order (the
 * edge with the lower first vertex first), so every vertex of the pair computes the same bits. */
SIM_HD static inline int cs_sc_ee_cut(const float *x0, const float *y0, const float *z0, const float *dx,
                                      const float *dy, const float *dz, const float *s, const int32_t a[2],
                                      const int32_t b[2], float r, float thick, int32_t v, int outright, float *cut,
                                      float *dmin)
{
    const int swap = b[0] < a[0];
    const int32_t *ea = swap ? b : a, *eb = swap ? a : b;
    const cs_vec3 a0 = cs_sc_at(x0, y0, z0, ea[0]), a1 = cs_sc_at(x0, y0, z0, ea[1]), b0 = cs_sc_at(x0, y0, z0, eb[0]),
                  b1 = cs_sc_at(x0, y0, z0, eb[1]);
    float ps, pt;
    const float d = cs_sc_seg_seg_st(a0, a1, b0, b1, &ps, &pt);
    if (!(d < r)) return 0;
    const int32_t q[4] = {ea[0], ea[1], eb[0], eb[1]};
    const cs_vec3 dir = cs_sub(cs_sc_seg_point(a0, a1, ps), cs_sc_seg_point(b0, b1, pt));
    const float m = cs_sc_round_margin(q, x0, y0, z0, dx, dy, dz, s, thick);
    const int safe = !outright && cs_sc_safe(q, 2, d, m, dir, x0, y0, z0, dx, dy, dz, s);
    const float cv = cs_sc_pair_cut(safe, d, m, dx, dy, dz, v);
    *cut = cv < *cut ? cv : *cut;
    *dmin = d < *dmin ? d : *dmin;
    return 1;
}

/* Appends key to keys (room for cap; past it only counted). */
SIM_HD static inline void cs_sc_keep(int64_t *keys, int32_t cap, int32_t *n, int64_t key)
{
    if (keys && *n < cap) keys[*n] = key;
    (*n)++;
}

/* cs_sc_keep, with the pair's distance d beside its key. */
SIM_HD static inline void cs_sc_keep_at(int64_t *keys, float *dists, int32_t cap, int32_t *n, int64_t key, float d)
{
    if (keys && *n < cap) keys[*n] = key, dists[*n] = d;
    (*n)++;
}

/* Vertex v's scale after one sweep: the least of its scale s[v] and the cuts of every pair it
 * belongs to (vertex-triangle as the point or a corner, edge-edge through its six spokes) that
 * lies within r at x0 and shares no vertex (outright: cut every such pair, safe or not). d*: the
 * substep's displacements (x1 - x0). Also the least distance at x0 of those pairs into *dall (r
 * where none), and with keys (room for cap) the pairs themselves (cs_sc_pair_key, cs_sc_ee_key;
 * *nkeys says how many there are, past cap too). */
SIM_HD static inline float cs_sc_limit(const cs_phys *ph, const cs_sc_grid *G, const float *L0, const float *x0,
                                       const float *y0, const float *z0, const float *dx, const float *dy,
                                       const float *dz, const float *s, float r, float reach, int32_t v,
                                       int outright, float *dall, int64_t *keys, int32_t cap, int32_t *nkeys)
{
    const int32_t nx = ph->nx, ny = ph->ny;
    const cs_vec3 xv = cs_sc_at(x0, y0, z0, v);
    float cut = s[v], dmin = r;
    const float L = 0.5f * (reach - r); /* the longest edge */
    cs_sc_ring g;
    cs_sc_ring_of(ph, L0, x0, y0, z0, v, &g);
    *nkeys = 0;
    CS_SC_FOR_WITHIN(G, x0, y0, z0, xv, reach, u, {
        if (u != v) {
            const cs_vec3 xu = cs_sc_at(x0, y0, z0, u);
            int32_t t[2][3];
            const int32_t ui = u % nx, uj = u / nx, f = cs_sc_quad_tris(L0, nx, ny, ui, uj, t);
            const float D = cs_len(cs_sub(xu, xv));
            const int vf = cs_sc_may(D, r, L);
            /* v against the triangles u owns */
            for (int k = 0; k < 2 && vf; k++) {
                if (!((f >> k) & 1) || t[k][0] == v || t[k][1] == v || t[k][2] == v) continue;
                const cs_vec3 c[3] = {cs_sc_at(x0, y0, z0, t[k][0]), cs_sc_at(x0, y0, z0, t[k][1]),
                                      cs_sc_at(x0, y0, z0, t[k][2])};
                if (cs_sc_box_gap(xv, c, 3) < r &&
                    cs_sc_vf_cut(x0, y0, z0, dx, dy, dz, s, v, t[k], r, ph->self_thickness, v, outright, &cut, &dmin))
                    cs_sc_keep(keys, cap, nkeys, cs_sc_pair_key(ph, v, 2 * (uj * (nx - 1) + ui) + k));
            }
            /* u against v's triangles */
            for (int k = 0; k < g.ntri && vf; k++) {
                if (g.tri[k][0] == u || g.tri[k][1] == u || g.tri[k][2] == u) continue;
                if (cs_sc_box_gap(xu, g.c[k], 3) < r &&
                    cs_sc_vf_cut(x0, y0, z0, dx, dy, dz, s, u, g.tri[k], r, ph->self_thickness, v, outright, &cut, &dmin))
                    cs_sc_keep(keys, cap, nkeys, cs_sc_pair_key(ph, u, g.slot[k]));
            }
            /* v's spokes against the edges u owns */
            for (int e = 0; e < 3; e++) {
                if ((e != 1 && ui + 1 >= nx) || (e != 0 && uj + 1 >= ny)) continue;
                const int32_t z1 = e == 0 ? u + 1 : e == 1 ? u + nx : u + nx + 1;
                if (z1 == v || !cs_sc_edge_on(L0, nx, ny, ui, uj, e)) continue;
                const cs_vec3 xz = cs_sc_at(x0, y0, z0, z1);
                const float lb = cs_len(cs_sub(xz, xu));
                for (int k = 0; k < g.nspoke; k++) {
                    if (!cs_sc_may(D, r, lb + g.slen[k])) continue;
                    int32_t ea[2];
                    cs_sc_edge_ends(ph, g.spoke[k], ea);
                    const int32_t o = ea[0] == v ? ea[1] : ea[0], eb[2] = {u, z1};
                    if (o == u || o == z1) continue;
                    if (cs_sc_seg_gap(xv, cs_sc_at(x0, y0, z0, o), xu, xz) < r &&
                        cs_sc_ee_cut(x0, y0, z0, dx, dy, dz, s, ea, eb, r, ph->self_thickness, v, outright, &cut, &dmin))
                        cs_sc_keep(keys, cap, nkeys, cs_sc_ee_key(ph, g.spoke[k], 3 * u + e));
                }
            }
        }
    });
    *dall = dmin;
    return cut;
}

/* What vertex v owns that is intact, as bits for cs_sc_found: 1 its quad's triangle A, 2 B, 4 << e
 * its edge e (cs_sc_edge_on, 0 where it would leave the grid). */
SIM_HD static inline uint8_t cs_sc_intact(const float *L0, int32_t nx, int32_t ny, int32_t v)
{
    const int32_t i = v % nx, j = v / nx;
    int bits = cs_quad_faces(L0, nx, ny, i, j);
    for (int e = 0; e < 3; e++)
        if (!((e != 1 && i + 1 >= nx) || (e != 0 && j + 1 >= ny)) && cs_sc_edge_on(L0, nx, ny, i, j, e)) bits |= 4 << e;
    return (uint8_t)bits;
}

/* How far vertex v's own primitives (its quad's triangles, its edges: physics.h's quad) reach from
 * it at x: the longest of its three edges to the right, up and diagonally - with L0 the intact
 * ones only, without it intact or not. */
SIM_HD static inline float cs_sc_own_reach(const cs_phys *ph, const float *L0, const float *x, const float *y,
                                           const float *z, int32_t v)
{
    const int32_t nx = ph->nx, ny = ph->ny, i = v % nx, j = v / nx;
    const cs_vec3 xv = cs_sc_at(x, y, z, v);
    float m = 0.0f;
    for (int e = 0; e < 3; e++) {
        if ((e != 1 && i + 1 >= nx) || (e != 0 && j + 1 >= ny) || (L0 && !cs_sc_edge_on(L0, nx, ny, i, j, e))) continue;
        const int32_t o = e == 0 ? v + 1 : e == 1 ? v + nx : v + nx + 1;
        m = cs_sc_max(m, cs_len(cs_sub(cs_sc_at(x, y, z, o), xv)));
    }
    return m;
}

/* Whether vertex f finds the pairs it owns with vertex u (cs_sc_found): the one of the two whose
 * spread eh is the larger does, the lower id on a tie. */
SIM_HD static inline int cs_sc_finds(const float *eh, int32_t f, int32_t u)
{
    return eh[f] > eh[u] || (eh[f] == eh[u] && f < u);
}

/* The box of vertex v's quad at x (its corners v, v + 1, v + nx, v + nx + 1 where they lie in the
 * grid: every primitive v owns, physics.h's quad) into b: lowest x y z, then highest. */
SIM_HD static inline void cs_sc_quad_box(const cs_phys *ph, const float *x, const float *y, const float *z, int32_t v,
                                         float b[6])
{
    const int32_t nx = ph->nx, i = v % nx, j = v / nx;
    const cs_vec3 p = cs_sc_at(x, y, z, v);
    b[0] = b[3] = p.x, b[1] = b[4] = p.y, b[2] = b[5] = p.z;
    for (int k = 1; k < 4; k++) {
        const int32_t di = k & 1, dj = k >> 1;
        if (i + di >= nx || j + dj >= ph->ny) continue;
        const cs_vec3 q = cs_sc_at(x, y, z, v + dj * nx + di);
        const float c[3] = {q.x, q.y, q.z};
        for (int a = 0; a < 3; a++) b[a] = c[a] < b[a] ? c[a] : b[a], b[3 + a] = c[a] > b[3 + a] ? c[a] : b[3 + a];
    }
}

/* The distance between two boxes (cs_sc_quad_box): no point of one lies nearer a point of the
 * other. */
SIM_HD static inline float cs_sc_boxes_gap(const float *a, const float *b)
{
    float s = 0.0f;
    for (int c = 0; c < 3; c++) {
        const float p = b[c] - a[3 + c], q = a[c] - b[3 + c], g = p > q ? p : q;
        s += g > 0.0f ? g * g : 0.0f;
    }
    return sqrtf(s);
}

/* The windows of the ring bound (cs_sc_ring_spread): the largest neighbour difference within
 * 2, 4, 8 and 16 rings of each vertex. */
#define CS_SC_WINDOWS 4
SIM_HD static inline int32_t cs_sc_window(int k) { return 2 << k; }

/* The farthest a pair's vertices may move relative to one another, E (the spreads' bound, about one
 * centre), or where its owners v and u lie within a window of rings less one of each other the
 * smaller of it and its ring bound. Every vertex of a pair lies within one ring of its owner (the
 * quad's corners) and so within rho + 1 rings (rho the owners' distance in rings) of every vertex
 * of the other side, along a path of king's moves inside the window of radius rho + 1 about either
 * owner; each move changes the displacement by at most the moving vertex's largest difference to
 * a neighbour (g). gh[k n + q]: the largest g within cs_sc_window(k) rings of q; ga is added to
 * the ring bound (gravity's reach in a substep, where the bound is of speeds). */
SIM_HD static inline float cs_sc_ring_spread(const float *gh, float ga, int32_t n, int32_t v, int32_t vi, int32_t vj,
                                             int32_t u, int32_t ui, int32_t uj, float E)
{
    const int32_t rho = cs_sc_rings_apart(vi, vj, ui, uj);
    for (int k = 0; k < CS_SC_WINDOWS; k++) {
        if (rho + 1 > cs_sc_window(k)) continue;
        const float *g = gh + (size_t)k * (size_t)n, G = g[v] < g[u] ? g[v] : g[u], R = (float)(rho + 1) * G + ga;
        return R < E ? R : E;
    }
    return E;
}

/* The pairs vertex v finds within their reach at x0, for every pass whose spreads stay within eh
 * and whose neighbour differences stay within those gh was taken from. A pair has two owners - a
 * vertex-triangle pair its point and the triangle's lower-left corner (physics.h's quad), an
 * edge-edge pair each edge's lower end - and eh[q] bounds how far q and the far ends of its own
 * edges and triangles move from a centre, so the pair's vertices move relative to one another by
 * at most eh[a] + eh[b], and where its owners lie within a window of rings of each other by at
 * most their ring bound (cs_sc_ring_spread, gh and ga: the layers of one smooth sheet barely move
 * relative to one another, however far the sheet moves about the cloth's centre). The pair can
 * pass cs_sc_vf_cut's or cs_sc_ee_cut's reach only within cs_sc_pair_reach(thickness, the smaller
 * bound) of the other owner's primitive. Each pair is found once, by the owner that cs_sc_finds
 * picks, among the owners whose quad's box (qb: every primitive an owner has lies in it,
 * cs_sc_quad_box at x0) lies within that reach of its own: a vertex that barely moves looks about
 * it, one that moves far looks far, and a pair between them is found from the far one. The
 * candidates come from G, a grid of the boxes' centres (qc: x, y, z, each n, then each box's
 * radius about its centre, n), within the finder's reach (2 eh[v]) and the two radii (Qm the
 * largest). extra widens every reach (the room for the cloth to move before the lists are found
 * again). Every pair that shares no vertex, grid neighbours included (the bound's; the repulsion
 * takes those that repel), of the primitives intact (cs_sc_intact of every vertex); ell (each
 * vertex's cs_sc_own_reach) skips a primitive early. Keys into keys and their distances at x0 into
 * dists (room for cap, unsorted); returns how many there are (past cap too). */
SIM_HD static inline int32_t cs_sc_found(const cs_phys *ph, const cs_sc_grid *G, const float *L0, const float *x0,
                                         const float *y0, const float *z0, const uint8_t *intact, const float *eh,
                                         const float *ell, const float *qb, const float *qc, float Qm,
                                         const float *gh, float ga, float extra,
                                         int32_t v, int64_t *keys, float *dists, int32_t cap)
{
    const int32_t nx = ph->nx, ny = ph->ny, vi = v % nx, vj = v / nx;
    const float th = ph->self_thickness, ev = eh[v];
    const cs_vec3 xv = cs_sc_at(x0, y0, z0, v);
    int32_t own[3], oe[3][2], nown = 0, n = 0; /* v's edges, their ends, the other end's position, */
    cs_vec3 xo[3], mo[3];                        /* the edge's middle and its length */
    float lo[3];
    for (int e = 0; e < 3; e++) {
        if (!((intact[v] >> (2 + e)) & 1)) continue;
        own[nown] = 3 * v + e;
        cs_sc_edge_ends(ph, own[nown], oe[nown]);
        xo[nown] = cs_sc_at(x0, y0, z0, oe[nown][1]);
        lo[nown] = cs_len(cs_sub(xo[nown], xv));
        mo[nown] = cs_scale(cs_add(xv, xo[nown]), 0.5f);
        nown++;
    }
    int32_t tv[2][3]; /* v's own triangles */
    cs_sc_quad_tris(L0, nx, ny, vi, vj, tv);
    const int32_t fv = intact[v] & 3;
    cs_vec3 cv[2][3];
    for (int k = 0; k < 2; k++)
        for (int q = 0; q < 3 && ((fv >> k) & 1); q++) cv[k][q] = cs_sc_at(x0, y0, z0, tv[k][q]);
    const float lv = ell[v], *qx = qc, *qy = qc + ph->n, *qz = qc + 2 * (size_t)ph->n, *qr = qc + 3 * (size_t)ph->n;
    const cs_vec3 mv = cs_sc_at(qx, qy, qz, v);
    /* (u's box lies within r of v's only where their centres lie within r and the two radii) */
    CS_SC_FOR_WITHIN(G, qx, qy, qz, mv, 1.01f * (cs_sc_pair_reach(th, 2.0f * ev) + extra + qr[v] + Qm) + 1e-6f, u, {
        const int32_t ui = u % nx, uj = u / nx;
        const float r = u != v && cs_sc_finds(eh, v, u)
                            ? cs_sc_pair_reach(th, cs_sc_ring_spread(gh, ga, ph->n, v, vi, vj, u, ui, uj, ev + eh[u])) + extra
                            : -1.0f;
        if (r > 0.0f && cs_sc_may(cs_sc_boxes_gap(qb + 6 * (size_t)v, qb + 6 * (size_t)u), r, 0.0f)) {
            const float lu = ell[u];
            const cs_vec3 xu = cs_sc_at(x0, y0, z0, u);
            const float D = cs_len(cs_sub(xu, xv));
            int32_t t[2][3];
            const int32_t u00 = uj * nx + ui, f = intact[u] & 3;
            t[0][0] = u00, t[0][1] = u00 + 1, t[0][2] = u00 + nx + 1;
            t[1][0] = u00, t[1][1] = u00 + nx + 1, t[1][2] = u00 + nx;
            float bw[3];
            for (int k = 0; k < 2 && cs_sc_may(D, r, lu); k++) { /* v against u's triangles */
                if (!((f >> k) & 1) || t[k][0] == v || t[k][1] == v || t[k][2] == v) continue;
                const cs_vec3 c[3] = {cs_sc_at(x0, y0, z0, t[k][0]), cs_sc_at(x0, y0, z0, t[k][1]),
                                      cs_sc_at(x0, y0, z0, t[k][2])};
                float d;
                if (cs_sc_box_gap(xv, c, 3) < r && (d = cs_sc_point_tri(xv, c[0], c[1], c[2], bw)) < r)
                    cs_sc_keep_at(keys, dists, cap, &n, cs_sc_pair_key(ph, v, 2 * (uj * (nx - 1) + ui) + k), d);
            }
            for (int k = 0; k < 2 && cs_sc_may(D, r, lv); k++) { /* u against v's triangles */
                if (!((fv >> k) & 1) || tv[k][0] == u || tv[k][1] == u || tv[k][2] == u) continue;
                float d;
                if (cs_sc_box_gap(xu, cv[k], 3) < r && (d = cs_sc_point_tri(xu, cv[k][0], cv[k][1], cv[k][2], bw)) < r)
                    cs_sc_keep_at(keys, dists, cap, &n, cs_sc_pair_key(ph, u, 2 * (vj * (nx - 1) + vi) + k), d);
            }
            for (int e = 0; e < 3; e++) { /* v's edges against u's */
                if (!((intact[u] >> (2 + e)) & 1)) continue;
                int32_t eb[2];
                cs_sc_edge_ends(ph, 3 * u + e, eb);
                if (eb[1] == v) continue;
                const cs_vec3 xz = cs_sc_at(x0, y0, z0, eb[1]), mu = cs_scale(cs_add(xu, xz), 0.5f);
                const float lb = cs_len(cs_sub(xz, xu));
                for (int k = 0; k < nown; k++) {
                    const int32_t *ea = oe[k];
                    /* (two segments lie no nearer than their middles less half their lengths) */
                    if (ea[1] == u || ea[1] == eb[1] || !cs_sc_may(cs_len(cs_sub(mu, mo[k])), r, 0.5f * (lb + lo[k])))
                        continue;
                    float d;
                    if (cs_sc_seg_gap(xv, xo[k], xu, xz) < r && (d = cs_sc_seg_seg(xv, xo[k], xu, xz)) < r)
                        cs_sc_keep_at(keys, dists, cap, &n, cs_sc_ee_key(ph, own[k], 3 * u + e), d);
                }
            }
        }
    });
    return n;
}

/* cs_sc_limit from a list of the pairs it kept (keys[0..n)) when that list holds every pair now
 * within r: the same cut (a least, in any order), and with dall the same least distance. */
SIM_HD static inline float cs_sc_limit_listed(const cs_phys *ph, const float *x0, const float *y0, const float *z0,
                                              const float *dx, const float *dy, const float *dz, const float *s,
                                              float r, int32_t v, int outright, const int64_t *keys, int32_t n,
                                              float *dall)
{
    float cut = s[v], dmin = r;
    for (int32_t k = 0; k < n; k++) {
        int32_t p, t[3], a[2], b[2];
        if (cs_sc_key_decode(ph, keys[k], &p, t, a, b))
            cs_sc_ee_cut(x0, y0, z0, dx, dy, dz, s, a, b, r, ph->self_thickness, v, outright, &cut, &dmin);
        else
            cs_sc_vf_cut(x0, y0, z0, dx, dy, dz, s, p, t, r, ph->self_thickness, v, outright, &cut, &dmin);
    }
    if (dall) *dall = dmin;
    return cut;
}

#endif
