/* clothsim/physics.h - the force math of kernels/MODEL.md, written once.
 *
 * Every function here is SIM_HD: plain C under a C compiler, __host__ __device__ under nvcc. The
 * CPU backend loops over them and the CUDA kernels call them unchanged, so both backends do the
 * same arithmetic in the same order (built with -ffp-contract=off / -fmad=false they agree bit for
 * bit). Rules for this file: no libc beyond sqrtf, no globals, no fminf/fmaxf (their NaN handling
 * would hide a NaN), plain structs only.
 *
 * Sign conventions: a spring force is computed from d = xj - xi, so evaluating a spring from its
 * other end gives exactly the negated force; a contact law takes the normal pointing from the
 * other body toward the one receiving the force, and the relative velocity of that body's contact
 * point. These make action and reaction bitwise opposite. */
#ifndef CLOTHSIM_PHYSICS_H
#define CLOTHSIM_PHYSICS_H

#include <math.h>
#include <stddef.h>
#include <stdint.h>

#include "clothsim/params.h"

/* Functions below are written `SIM_HD static inline`: host and device code under nvcc. */
#ifdef __CUDACC__
#define SIM_HD __host__ __device__
#else
#define SIM_HD
#endif

/* Below this length a spring, a contact normal or a tangential velocity has no direction. */
#define CS_MIN_LEN 1e-9f
/* Rest length of a torn spring, or of one that the grid does not have (at a border). */
#define CS_TORN (-1.0f)
/* Chunks: each row of the grid is cut into segments of CS_CHUNK vertices (the last one shorter),
 * numbered row by row: chunk c = j nseg + s covers columns s CS_CHUNK .. of row j. Rock forces from
 * the cloth are summed per chunk with the fixed pairwise tree of cs_tree_sum (missing vertices
 * count as +0), then chunk by chunk in index order. Both backends use these chunks. */
#define CS_CHUNK 256

typedef struct cs_vec3 {
    float x, y, z;
} cs_vec3;

SIM_HD static inline cs_vec3 cs_v3(float x, float y, float z)
{
    cs_vec3 r;
    r.x = x;
    r.y = y;
    r.z = z;
    return r;
}
SIM_HD static inline cs_vec3 cs_add(cs_vec3 a, cs_vec3 b) { return cs_v3(a.x + b.x, a.y + b.y, a.z + b.z); }
SIM_HD static inline cs_vec3 cs_sub(cs_vec3 a, cs_vec3 b) { return cs_v3(a.x - b.x, a.y - b.y, a.z - b.z); }
SIM_HD static inline cs_vec3 cs_scale(cs_vec3 a, float s) { return cs_v3(a.x * s, a.y * s, a.z * s); }
SIM_HD static inline cs_vec3 cs_neg(cs_vec3 a) { return cs_v3(-a.x, -a.y, -a.z); }
SIM_HD static inline float cs_dot(cs_vec3 a, cs_vec3 b) { return a.x * b.x + a.y * b.y + a.z * b.z; }
SIM_HD static inline float cs_len(cs_vec3 a) { return sqrtf(cs_dot(a, a)); }
SIM_HD static inline cs_vec3 cs_cross(cs_vec3 a, cs_vec3 b)
{
    return cs_v3(a.y * b.z - a.z * b.y, a.z * b.x - a.x * b.z, a.x * b.y - a.y * b.x);
}
SIM_HD static inline cs_vec3 cs_v3_from(const float *a) { return cs_v3(a[0], a[1], a[2]); }

/* Spring types, each owned by its lower-index end (i, j) and reaching (i + di, j + dj). */
enum { CS_SX, CS_SY, CS_D1, CS_D2, CS_BX, CS_BY, CS_NTYPES };
#define CS_SPRING_TYPES(X) X(CS_SX, 1, 0) X(CS_SY, 0, 1) X(CS_D1, 1, 1) X(CS_D2, -1, 1) X(CS_BX, 2, 0) X(CS_BY, 0, 2)

/* The grid's far-end rule: the spring of vertex (i, j) reaching (i + di, j + dj) exists when its far
 * end is on the nx x ny grid (the spring types' dj is never negative). */
SIM_HD static inline int cs_far_end_on_grid(int32_t nx, int32_t ny, int32_t i, int32_t j, int di, int dj)
{
    return i + di >= 0 && i + di < nx && j + dj < ny;
}

/* The fixed order in which every backend sums the 12 springs of a vertex: X(type, di, dj, fwd)
 * for the neighbour at (i + di, j + dj); fwd = 1 when the vertex owns the spring (its rest length
 * is L0[type][v]), 0 when the neighbour does (L0[type][v + di + dj nx]). */
#define CS_SPRING_SLOTS(X)                                                                          \
    X(CS_SX, 1, 0, 1) X(CS_SX, -1, 0, 0) X(CS_SY, 0, 1, 1) X(CS_SY, 0, -1, 0) X(CS_D1, 1, 1, 1)    \
    X(CS_D1, -1, -1, 0) X(CS_D2, -1, 1, 1) X(CS_D2, 1, -1, 0) X(CS_BX, 2, 0, 1) X(CS_BX, -2, 0, 0) \
    X(CS_BY, 0, 2, 1) X(CS_BY, 0, -2, 0)

/* What the force functions read: the live parameters in the form the kernels use, plus the
 * scene's derived constants. Filled by the core (cs_phys_from in the core), copied as is to a
 * device. */
typedef struct cs_phys {
    int32_t nx, ny, n;
    int32_t nseg, nchunks;       /* chunks per row, chunks in all (ny nseg) */
    float k[CS_NTYPES];          /* stiffness per spring type */
    float c_spring, mass, inv_mass, drag;
    cs_vec3 gravity, wind;
    float k_contact, c_contact, c_tangent, mu, contact_offset;
    float face_area;             /* a render triangle's rest area, hx hy / 2 */
    int32_t friction;            /* cs_friction */
    int32_t contact_model;       /* cs_contact_model */
    float max_sep;               /* max_depenetration_speed; 3e38 when 0 (no cap) */
    float k_rock, c_rock, mu_rock;
    int32_t ground;
    float ground_z;
    float dt, hdt;               /* substep and half substep */
    float plastic_yield, tear_strain, plastic_f;
    int32_t strain_on;           /* plastic_yield > 0 or tear_strain > 0 */
    int32_t integrator;          /* cs_integrator */
    float grab_speed;
    /* implicit_euler (implicit.h) */
    float plastic_rate;          /* 1/s, so that a substep cut in parts flows the same per second */
    float rock_dt;               /* the longest stable step of a rock contact (rocks sub-cycle to it) */
    int32_t solver_iterations, cg_iterations;
    float solver_tolerance;
    int32_t most_splits;         /* parts a substep may be cut into for contact (max_substeps / substeps) */
    /* self_collision (selfcontact.h) */
    int32_t self_on;
    float self_thickness, self_hx, self_hy; /* and the grid's spacing at rest */
} cs_phys;

/* A rock as the kernels see it. Kinematic rocks have inv_mass = inv_inertia = 0. */
typedef struct cs_rock_state {
    cs_vec3 x, v, w;             /* position, velocity, angular velocity */
    cs_vec3 a, alpha;            /* linear and angular acceleration (part of the state) */
    float q[4];                  /* orientation quaternion x, y, z, w */
    float radius, density, mass, inv_mass, inertia, inv_inertia;
    uint32_t id;
    int32_t kinematic;
} cs_rock_state;

/* Force on vertex i from the spring to j (rest length L0, stiffness k, damping c):
 * k (|d| - L0) u + c ((vj - vi) . u) u with d = xj - xi, u = d/|d|; zero for a torn spring
 * (L0 <= 0) and below CS_MIN_LEN. Written without branches so a CPU loop over it vectorizes:
 * the masks multiply, and the division never sees zero. *len receives |d|. */
SIM_HD static inline cs_vec3 cs_spring_force(cs_vec3 xi, cs_vec3 vi, cs_vec3 xj, cs_vec3 vj, float L0, float k,
                                             float c, float *len)
{
    const cs_vec3 d = cs_sub(xj, xi);
    const cs_vec3 dv = cs_sub(vj, vi);
    const float l = sqrtf(cs_dot(d, d));
    const float on = (float)(l > CS_MIN_LEN) * (float)(L0 > 0.0f);
    const float inv = on / (l + (float)(l <= CS_MIN_LEN));
    const float s = k * (l - L0) + c * (cs_dot(dv, d) * inv);
    *len = l;
    return cs_scale(d, s * inv);
}

/* Potential energy 1/2 k (|d| - L0)^2 of an intact spring; 0 for a torn one. */
SIM_HD static inline float cs_spring_energy(cs_vec3 xi, cs_vec3 xj, float L0, float k)
{
    const float e = cs_len(cs_sub(xj, xi)) - L0;
    return L0 > 0.0f ? 0.5f * k * e * e : 0.0f;
}

/* New rest length of a spring of current length len after a substep (MODEL.md: tear past
 * tear_strain, else plastic flow past plastic_yield, tension only). Branch-free selects. */
SIM_HD static inline float cs_strain_update(float len, float L0, const cs_phys *p)
{
    const float e = (len - L0) / L0;
    const float flowed = L0 + p->plastic_f * (len - L0);
    float r = (p->plastic_yield > 0.0f && e > p->plastic_yield) ? flowed : L0;
    r = (p->tear_strain > 0.0f && e > p->tear_strain) ? CS_TORN : r;
    return L0 > 0.0f ? r : L0;
}

/* Gravity and air drag on a cloth vertex: m (g - drag (v - wind)). */
SIM_HD static inline cs_vec3 cs_air_gravity(cs_vec3 vi, const cs_phys *p)
{
    return cs_scale(cs_sub(p->gravity, cs_scale(cs_sub(vi, p->wind), p->drag)), p->mass);
}

/* The penalty contact law shared by every contact. n: unit normal from the other body toward
 * this one; delta > 0: penetration; vrel: velocity of this body's contact point relative to the
 * other's; Ro: resultant of the non-contact forces on this body (resultant model only); vmax:
 * max_depenetration_speed. Fn = max(0, k delta - c vn) n, and 0 while the bodies already separate
 * faster than vmax (vn > vmax), so that no overlap throws them apart faster than that; friction
 * per model (MODEL.md, Rocks). */
SIM_HD static inline cs_vec3 cs_contact_law(cs_vec3 n, float delta, cs_vec3 vrel, float k, float c, float mu,
                                            float ct, int32_t model, cs_vec3 Ro, float vmax)
{
    const float vn = cs_dot(vrel, n);
    float fn = k * delta - c * vn;
    fn = fn > 0.0f && vn <= vmax ? fn : 0.0f;
    cs_vec3 F = cs_scale(n, fn);
    if (model == CS_FRICTION_COULOMB_VISCOUS) {
        const cs_vec3 vt = cs_sub(vrel, cs_scale(n, vn));
        const float vt_len = cs_len(vt);
        if (vt_len >= CS_MIN_LEN) {
            const float a = mu * fn, b = ct * vt_len;
            const float ft = a < b ? a : b;
            F = cs_add(F, cs_scale(vt, -ft / vt_len));
        }
    } else {
        const float ron = cs_dot(Ro, n);
        if (ron < 0.0f) {
            const cs_vec3 rot = cs_sub(Ro, cs_scale(n, ron));
            const float rot_len = cs_len(rot);
            if (rot_len >= CS_MIN_LEN) {
                const float b = mu * -ron;
                const float ft = rot_len < b ? rot_len : b;
                F = cs_add(F, cs_scale(rot, -ft / rot_len));
            }
        }
    }
    return F;
}

/* Contact of cloth vertex (xi, vi) with rock r. Returns 1 and the force on the vertex in *F
 * (the rock receives -*F and the torque rr x -*F, rr = *arm) when they touch. */
SIM_HD static inline int cs_vertex_rock_contact(cs_vec3 xi, cs_vec3 vi, cs_vec3 Ro, const cs_rock_state *r,
                                                const cs_phys *p, cs_vec3 *F, cs_vec3 *arm)
{
    const cs_vec3 rr = cs_sub(xi, r->x);
    const float len = cs_len(rr);
    const float delta = r->radius + p->contact_offset - len;
    if (!(delta > 0.0f && len > CS_MIN_LEN)) return 0;
    const cs_vec3 n = cs_scale(rr, 1.0f / len);
    const cs_vec3 vrel = cs_sub(vi, cs_add(r->v, cs_cross(r->w, rr)));
    *F = cs_contact_law(n, delta, vrel, p->k_contact, p->c_contact, p->mu, p->c_tangent, p->friction, Ro, p->max_sep);
    *arm = rr;
    return 1;
}

/* Contact of a cloth vertex with the ground plane (when on). */
SIM_HD static inline int cs_vertex_ground_contact(cs_vec3 xi, cs_vec3 vi, cs_vec3 Ro, const cs_phys *p, cs_vec3 *F)
{
    const float delta = p->ground_z + p->contact_offset - xi.z;
    if (!(p->ground && delta > 0.0f)) return 0;
    *F = cs_contact_law(cs_v3(0.0f, 0.0f, 1.0f), delta, vi, p->k_contact, p->c_contact, p->mu, p->c_tangent,
                        p->friction, Ro, p->max_sep);
    return 1;
}

/* ---- surface contact (contact_model surface) ----
 *
 * The cloth's surface is its intact render triangles: each grid quad (i, j) .. (i+1, j+1) is split
 * on its +x+y diagonal into A = (v00, v10, v11) and B = (v00, v11, v01); a triangle is there while
 * its three springs (two structural, the CS_D1 shear) are intact. An edge is interior when both its
 * triangles are there. A rock (centre c, reach R' = R + contact_offset) meets it in three parts.
 *
 * 1. Elastic: the gradient of a contact potential built from closest points. For a closed feature
 *    X (a triangle, an edge segment, a vertex) let p_X be its point closest to c, delta_X =
 *    R' - |c - p_X| and f_X = 1/2 k_contact delta_X^2 (0 when delta_X <= 0);
 *
 *      U = sum over triangles f_T - sum over interior edges (1 - G_E) f_E + sum over vertices n_V f_V
 *
 *    with n_V = 1 - (triangles at V) + (interior edges at V) (1 inside the cloth, 0 on its border)
 *    and G_E = smoothstep(min(lambda_1, lambda_2) / CS_MERGE), lambda_i the barycentric weight,
 *    across E, of the foot of c on the plane of E's triangle i (positive on that triangle's side).
 *    With every G_E = 0 the sum is the Euler integral of the surface within reach (each feature
 *    meets every ball round c in a convex set, so inclusion-exclusion over the features counts the
 *    connected pieces at each depth): on a flat cloth it is exactly one contact, 1/2 k delta^2 at
 *    the foot of c, wherever c is (the triangles around the one under c, whose closest points lie
 *    on shared edges and vertices, cancel against them); a ridge or a vertex under c is one
 *    contact too. G_E lifts an edge's subtraction where both its triangles' feet lie well inside
 *    them, so a fold toward the rock with two distinct minima counts two, and a cloth wrapped
 *    round a rock pushes with each of its triangles. U is continuous in every position: nothing
 *    appears or vanishes while pressed in. Term X of weight w (+1, -(1 - G_E), n_V) pushes with
 *    w k delta_X along (p_X - c), shared among X's vertices by p_X's barycentric weights b, and
 *    the rock takes the opposite (through its centre: no torque). The weights' own gradient
 *    (f_E dG_E/dx) is left out: it only acts where two minima merge, and counting it would make
 *    the contact stiffer there than the stability guard allows for.
 *
 * 2. Dissipation, at each vertex from its net elastic contact force E (direction n = E / |E|)
 *    and net contact weight W = sum of w b (cs_surface_vertex_law): fn = max(0, |E| -
 *    c_contact W vn), none while separating faster than max_depenetration_speed; friction per
 *    model: coulomb_viscous min(mu fn, c_tangent W |vt|) against vt, resultant min(|Rot|, mu |Ron|)
 *    min(W, 1) against Rot while Ro . n < 0. Applied per vertex, these only ever take energy
 *    away (per term, a negative weight would turn damping into anti-damping).
 *
 * 3. Velocity level (free vertices): the vertex's drift velocity over the next substep is
 *    predicted from its total force; an approach toward the rock's surface along n is cancelled
 *    within that substep (a force m' (-vn) / dt, m' the vertex's mass against its share of the
 *    rock's, cs_surface_max_touch), with Coulomb friction mu (-vn) on the tangential velocity. So a light vertex cannot be pushed deeper into the contact layer by a heavy or fast
 *    rock: the rock carries it along and the cloth's tension, transmitted by these forces, stops
 *    the rock. Inelastic, deadbeat (it removes the approach in one substep, never more), so it
 *    adds nothing to the stiffness the stability guard counts.
 *
 * Gather: a vertex computes its part from its 1-ring (cs_ring): one thread per vertex, no
 * atomics. It adds its shares in a fixed order (its vertex term, spoke edges 1-6, triangles 1-6),
 * then its own law; the reactions on the rock of the terms it owns (its vertex, spoke edges 1-3,
 * triangles 1-2: each term has one owner) and of its own law go into its lane of the chunk tree.
 * Each term is computed from its feature's vertices in a canonical order, so every vertex that
 * shares it computes the same bits. */

/* Slots of a vertex's ring: 0 the vertex (i, j), then its six render-edge neighbours counter-
 * clockwise: 1 (i+1, j), 2 (i+1, j+1), 3 (i, j+1), 4 (i-1, j), 5 (i-1, j-1), 6 (i, j-1). Triangle k
 * (1..6) is (0, k, k+1), wrapping 6 to 1; spoke edge k joins slots 0 and k and lies between
 * triangles k-1 and k. (The tables are functions: a CUDA kernel cannot read host arrays.) */
#define CS_RING 7
#ifndef CS_NO_VL
#define CS_NO_VL 0
#endif
SIM_HD static inline int cs_ring_di(int k)
{
    return (int)((0x1069u >> (2 * k)) & 3u) - 1; /* 0, 1, 1, 0, -1, -1, 0 */
}
SIM_HD static inline int cs_ring_dj(int k)
{
    return (int)((0x1a5u >> (2 * k)) & 3u) - 1; /* 0, 0, 1, 1, 0, -1, -1 */
}
/* Slot q (0..2) of ring triangle f (0..5, triangle f+1) in canonical order (A: v00 v10 v11,
 * B: v00 v11 v01): A(i, j) 0 1 2, B(i, j) 0 2 3, A(i-1, j) 4 0 3, B(i-1, j-1) 5 0 4, A(i-1, j-1)
 * 5 6 0, B(i, j-1) 6 1 0 (3 bits each, f major). */
SIM_HD static inline int cs_ring_face(int f, int q)
{
    return (int)((0x1c3582b11a088ull >> (3 * (3 * f + q))) & 7ull);
}
/* Width of G's ramp, in barycentric units. */
#define CS_MERGE 0.3f

typedef struct cs_ring {
    cs_vec3 x[CS_RING]; /* positions of the slots */
    cs_vec3 v;          /* the vertex's velocity */
    cs_vec3 ro;         /* and its non-contact resultant (resultant friction only; else anything) */
    int32_t faces;      /* bit k-1: triangle k intact */
} cs_ring;

/* The intact triangles of grid quad (qi, qj): bit 0 A, bit 1 B; 0 off the grid. L0: the
 * type-major rest lengths (CS_TORN where torn or absent). A needs the structural x spring of v00,
 * the structural y of v10 and the diagonal; B the diagonal, the structural x of v01 and the
 * structural y of v00. */
SIM_HD static inline int32_t cs_quad_faces(const float *L0, int32_t nx, int32_t ny, int32_t qi, int32_t qj)
{
    if ((qi < 0) | (qj < 0) | (qi + 1 >= nx) | (qj + 1 >= ny)) return 0;
    const size_t n = (size_t)nx * (size_t)ny, q = (size_t)qj * (size_t)nx + (size_t)qi;
    const float *sx = L0 + CS_SX * n, *sy = L0 + CS_SY * n, *d1 = L0 + CS_D1 * n;
    const int32_t d = d1[q] > 0.0f;
    const int32_t a = d & (sx[q] > 0.0f) & (sy[q + 1] > 0.0f);
    const int32_t b = d & (sx[q + (size_t)nx] > 0.0f) & (sy[q] > 0.0f);
    return a | b << 1;
}

/* The intact render triangles of the whole cloth, as (t[0], t[1], t[2]) vertex ids in canonical
 * order (A: v00 v10 v11, B: v00 v11 v01), quad by quad, row by row: for (k = 0; cs_next_triangle(
 * L0, nx, ny, &k, t);). k counts the grid's triangle slots (2 per quad). */
SIM_HD static inline int cs_next_triangle(const float *L0, int32_t nx, int32_t ny, int64_t *k, int32_t t[3])
{
    const int64_t slots = 2 * (int64_t)(nx - 1) * (int64_t)(ny - 1);
    for (; *k < slots; (*k)++) {
        const int32_t q = (int32_t)(*k >> 1), f = (int32_t)(*k & 1), i = q % (nx - 1), j = q / (nx - 1);
        if (!((cs_quad_faces(L0, nx, ny, i, j) >> f) & 1)) continue;
        const int32_t v00 = j * nx + i;
        t[0] = v00;
        t[1] = f ? v00 + nx + 1 : v00 + 1;
        t[2] = f ? v00 + nx : v00 + nx + 1;
        (*k)++;
        return 1;
    }
    return 0;
}

/* The intact triangles of the ring of vertex (i, j), as cs_ring.faces: 1 A(i, j), 2 B(i, j),
 * 3 A(i-1, j), 4 B(i-1, j-1), 5 A(i-1, j-1), 6 B(i, j-1). */
SIM_HD static inline int32_t cs_ring_faces(const float *L0, int32_t nx, int32_t ny, int32_t i, int32_t j)
{
    const int32_t q0 = cs_quad_faces(L0, nx, ny, i, j), q1 = cs_quad_faces(L0, nx, ny, i - 1, j);
    const int32_t q2 = cs_quad_faces(L0, nx, ny, i - 1, j - 1), q3 = cs_quad_faces(L0, nx, ny, i, j - 1);
    return q0 | (q1 & 1) << 2 | (q2 >> 1) << 3 | (q2 & 1) << 4 | (q3 >> 1) << 5;
}

/* The set bits of a 6-bit mask. */
SIM_HD static inline int cs_popcount6(int32_t m)
{
    m = (m & 0x15) + ((m >> 1) & 0x15);
    m = (m & 0x33) + ((m >> 2) & 0x33);
    return (m & 0x0f) + ((m >> 4) & 0x0f);
}

/* Barycentric weights (of a, b, o) of the point of triangle a b o closest to c: the foot of c on
 * the plane when it falls inside, else the closest point of the nearest edge or vertex. */
SIM_HD static inline void cs_closest_on_triangle(cs_vec3 c, cs_vec3 a, cs_vec3 b, cs_vec3 o, float w[3])
{
    const cs_vec3 ab = cs_sub(b, a), ao = cs_sub(o, a), ac = cs_sub(c, a);
    const float d1 = cs_dot(ab, ac), d2 = cs_dot(ao, ac);
    w[0] = 1.0f, w[1] = 0.0f, w[2] = 0.0f;
    if (d1 <= 0.0f && d2 <= 0.0f) return; /* beyond a */
    const cs_vec3 bc = cs_sub(c, b);
    const float d3 = cs_dot(ab, bc), d4 = cs_dot(ao, bc);
    if (d3 >= 0.0f && d4 <= d3) { /* beyond b */
        w[0] = 0.0f, w[1] = 1.0f;
        return;
    }
    const float vo = d1 * d4 - d3 * d2;
    if (vo <= 0.0f && d1 >= 0.0f && d3 <= 0.0f) { /* on edge ab */
        const float t = d1 / (d1 - d3);
        w[0] = 1.0f - t, w[1] = t;
        return;
    }
    const cs_vec3 oc = cs_sub(c, o);
    const float d5 = cs_dot(ab, oc), d6 = cs_dot(ao, oc);
    if (d6 >= 0.0f && d5 <= d6) { /* beyond o */
        w[0] = 0.0f, w[2] = 1.0f;
        return;
    }
    const float vb = d5 * d2 - d1 * d6;
    if (vb <= 0.0f && d2 >= 0.0f && d6 <= 0.0f) { /* on edge ao */
        const float t = d2 / (d2 - d6);
        w[0] = 1.0f - t, w[2] = t;
        return;
    }
    const float va = d3 * d6 - d5 * d4;
    if (va <= 0.0f && d4 - d3 >= 0.0f && d5 - d6 >= 0.0f) { /* on edge bo */
        const float t = (d4 - d3) / ((d4 - d3) + (d5 - d6));
        w[0] = 0.0f, w[1] = 1.0f - t, w[2] = t;
        return;
    }
    const float den = va + vb + vo;
    if (!(den > 0.0f)) return; /* degenerate: keep vertex a */
    const float inv = 1.0f / den;
    w[1] = vb * inv, w[2] = vo * inv, w[0] = 1.0f - w[1] - w[2];
}

/* The point of triangle a b o with barycentric weights w. */
SIM_HD static inline cs_vec3 cs_tri_point(cs_vec3 a, cs_vec3 b, cs_vec3 o, const float w[3])
{
    return cs_add(cs_add(cs_scale(a, w[0]), cs_scale(b, w[1])), cs_scale(o, w[2]));
}

/* Weight of b (a's is 1 minus it) of the point of segment a b closest to c. */
SIM_HD static inline float cs_closest_on_segment(cs_vec3 c, cs_vec3 a, cs_vec3 b)
{
    const cs_vec3 e = cs_sub(b, a);
    const float ee = cs_dot(e, e), t = cs_dot(cs_sub(c, a), e);
    if (!(t > 0.0f) || !(ee > 0.0f)) return 0.0f;
    return t >= ee ? 1.0f : t / ee;
}

/* The barycentric weight of o of the foot of c on the plane of triangle a b o: positive on o's
 * side of line ab (a, b in the edge's canonical order); 0 for a degenerate triangle. It is
 * ((b - a) x (c - a)) . ((b - a) x (o - a)) / |(b - a) x (o - a)|^2, written with dot products. */
SIM_HD static inline float cs_foot_weight(cs_vec3 a, cs_vec3 b, cs_vec3 o, cs_vec3 c)
{
    const cs_vec3 e = cs_sub(b, a), u = cs_sub(c, a), w = cs_sub(o, a);
    const float P = cs_dot(e, e), Q = cs_dot(e, u), R = cs_dot(e, w), X = cs_dot(u, w), T = cs_dot(w, w);
    const float num = P * X - Q * R, den = P * T - R * R;
    return den > 1e-30f ? num / den : 0.0f;
}

/* smoothstep(u / CS_MERGE): 0 up to 0, 1 from CS_MERGE on. */
SIM_HD static inline float cs_merge_ramp(float u)
{
    const float t = u * (1.0f / CS_MERGE);
    return t >= 1.0f ? 1.0f : t <= 0.0f ? 0.0f : t * t * (3.0f - 2.0f * t);
}

/* What a vertex gathers from one rock's surface contact. */
typedef struct cs_surface_out {
    cs_vec3 share;      /* the force on the vertex: elastic, damping and friction */
    cs_vec3 force;      /* force on the rock from the terms it owns and its own dissipation */
    cs_vec3 torque;     /* and their torque about the rock's centre */
    float energy;       /* the part of U of the terms it owns */
    float depth;        /* deepest delta of the triangles and vertex it owns (0 when none) */
    int32_t touches;    /* terms within reach it takes a share of */
    int32_t owns;       /* terms within reach it owns, plus 1 for its own law when it touches: its
                           lane of the rock's sum is written when this is not 0 */
    cs_vec3 E;          /* its net elastic contact force and net contact weight (the vertex law's */
    float weight;       /* inputs; implicit_euler linearises the contact with them) */
} cs_surface_out;

/* The working sums of one gather: the elastic force on the vertex and its net contact weight. */
typedef struct cs_surface_acc {
    cs_vec3 E;          /* sum of w b k delta n over the terms at this vertex */
    float weight;       /* sum of w b */
} cs_surface_acc;

/* One term of weight w at point p (b: this vertex's barycentric weight there, 0 when p is not on
 * it): the elastic force w k delta n, n from c toward p, within reach (the vertex law's test). */
SIM_HD static inline void cs_surface_term(cs_surface_out *o, cs_surface_acc *acc, cs_vec3 p, float w, float b, int own,
                                          const cs_rock_state *r, const cs_phys *ph)
{
    const cs_vec3 rr = cs_sub(p, r->x);
    const float len = cs_len(rr);
    const float delta = r->radius + ph->contact_offset - len;
    if (!(delta > 0.0f && len > CS_MIN_LEN)) return;
    const cs_vec3 F = cs_scale(rr, w * ph->k_contact * delta / len);
    if (b != 0.0f) {
        acc->E = cs_add(acc->E, cs_scale(F, b));
        acc->weight += w * b;
        o->touches++;
    }
    if (own) {
        o->force = cs_sub(o->force, F); /* through the centre: no torque */
        o->energy += w * 0.5f * ph->k_contact * delta * delta;
        if (w > 0.0f) o->depth = delta > o->depth ? delta : o->depth;
        o->owns++;
    }
}

/* Spoke edge k (1..6, slots 0 and k, in canonical order: slot 0 first for k <= 3) between ring
 * triangles k-1 and k, whose vertices off the edge are slots k-1 and k+1 (wrapping 0 to 6 and 7
 * to 1): the term -(1 - G) at the edge's closest point. */
SIM_HD static inline void cs_surface_edge(cs_surface_out *o, cs_surface_acc *acc, const cs_ring *g, int k,
                                          const cs_rock_state *r, const cs_phys *ph)
{
    const cs_vec3 c = r->x;
    const int ea = k <= 3 ? 0 : k, eb = k <= 3 ? k : 0;
    const float wb = cs_closest_on_segment(c, g->x[ea], g->x[eb]), wa = 1.0f - wb;
    const cs_vec3 p = cs_add(cs_scale(g->x[ea], wa), cs_scale(g->x[eb], wb));
    if (!(r->radius + ph->contact_offset - cs_len(cs_sub(p, c)) > 0.0f)) return; /* out of reach */
    /* the foot weight, across the edge, of each triangle's vertex off it */
    const float l1 = cs_foot_weight(g->x[ea], g->x[eb], g->x[k == 1 ? 6 : k - 1], c);
    const float l2 = cs_foot_weight(g->x[ea], g->x[eb], g->x[k == 6 ? 1 : k + 1], c);
    const float G = cs_merge_ramp(l1 < l2 ? l1 : l2);
    if (G >= 1.0f) return;
    cs_surface_term(o, acc, p, -(1.0f - G), ea == 0 ? wa : wb, k <= 3, r, ph);
}

/* The most cloth vertices rock r can touch at once, for its share of the velocity level: the
 * area of its contact sphere over a rest triangle's, plus the three of one triangle (a rock
 * smaller than the grid meets a single face). Each vertex cancels its approach against 1/N of
 * the rock's mass, m M/N / (m + M/N): with N vertices at once that is exactly a perfectly
 * inelastic collision of them all with the rock, with fewer it is less, so the velocity level
 * never throws a light rock back (a heavy one moves the vertex with it: m M/N >> m). The
 * stability guard counts the same vertices' contact stiffness. */
SIM_HD static inline float cs_surface_max_touch(const cs_rock_state *r, const cs_phys *p)
{
    const float reach = r->radius + p->contact_offset;
    return floorf(4.0f * 3.14159265f * reach * reach / p->face_area) + 3.0f;
}

/* The vertex's contact force from its net elastic contact force E and net weight W (the
 * surface model's per-vertex law, see above): along n = E/|E|, with vrel the vertex's velocity
 * relative to the rock's surface there,
 *   - penalty: fn = max(0, |E| - c_contact W vn), 0 while separating faster than
 *     max_depenetration_speed; friction per model: coulomb_viscous min(mu fn, c_tangent W |vt|)
 *     against vt; resultant min(|Rot|, mu |Ron|) min(W, 1) against Rot while Ro . n < 0 (Ro the
 *     vertex's own non-contact resultant);
 *   - velocity level (free vertices only): with Fsum the vertex's total force so far (its
 *     non-contact resultant and the contacts before this one) plus the penalty force, the
 *     velocity it would move with, vi + dt Fsum / m, is predicted; an approach toward the rock
 *     along n (vn < 0) is cancelled by the force m' (-vn) / dt (m' as above), and the tangential velocity reduced
 *     by up to mu (-vn) (Coulomb friction of that normal impulse) by a further force. So a vertex
 *     never moves deeper into a rock's contact layer, however heavy or fast the rock. */
SIM_HD static inline cs_vec3 cs_surface_vertex_law(cs_vec3 E, float W, cs_vec3 vi, cs_vec3 Ro, cs_vec3 Fsum, float free,
                                                   const cs_rock_state *r, const cs_phys *p, cs_vec3 *arm)
{
    const float e = cs_len(E);
    *arm = cs_v3(0.0f, 0.0f, 0.0f);
    if (!(e > 0.0f)) return E;
    const cs_vec3 n = cs_scale(E, 1.0f / e);
    const float w = W > 0.0f ? W : 0.0f;
    /* the rock's surface where it meets the vertex's contact: R n from its centre */
    *arm = cs_scale(n, r->radius);
    const cs_vec3 vsurf = cs_add(r->v, cs_cross(r->w, *arm));
    const cs_vec3 vrel = cs_sub(vi, vsurf);
    const float vn = cs_dot(vrel, n);
    float fn = e - p->c_contact * w * vn;
    fn = fn > 0.0f && vn <= p->max_sep ? fn : 0.0f;
    cs_vec3 F = cs_scale(n, fn);
    if (p->friction == CS_FRICTION_COULOMB_VISCOUS) {
        const cs_vec3 vt = cs_sub(vrel, cs_scale(n, vn));
        const float vt_len = cs_len(vt);
        if (vt_len >= CS_MIN_LEN) {
            const float a = p->mu * fn, b = p->c_tangent * w * vt_len;
            const float ft = a < b ? a : b;
            F = cs_add(F, cs_scale(vt, -ft / vt_len));
        }
    } else {
        const float ron = cs_dot(Ro, n);
        if (ron < 0.0f && fn > 0.0f) {
            const cs_vec3 rot = cs_sub(Ro, cs_scale(n, ron));
            const float rot_len = cs_len(rot);
            if (rot_len >= CS_MIN_LEN) {
                const float b = p->mu * -ron, s = w < 1.0f ? w : 1.0f;
                const float ft = (rot_len < b ? rot_len : b) * s;
                F = cs_add(F, cs_scale(rot, -ft / rot_len));
            }
        }
    }
    if (free > 0.0f && !CS_NO_VL) {
        /* the velocity the vertex would drift with, relative to the rock's surface now */
        const cs_vec3 pred = cs_sub(cs_add(vi, cs_scale(cs_add(Fsum, F), p->dt * p->inv_mass)), vsurf);
        const float pn = cs_dot(pred, n);
        if (pn < 0.0f) {
            /* the vertex's mass against its share of the rock's (cs_surface_max_touch) */
            const float m_dt = 1.0f / ((p->inv_mass + cs_surface_max_touch(r, p) * r->inv_mass) * p->dt);
            F = cs_add(F, cs_scale(n, -pn * m_dt));
            const cs_vec3 pt = cs_sub(pred, cs_scale(n, pn));
            const float pt_len = cs_len(pt), cap = p->mu * -pn;
            if (pt_len >= CS_MIN_LEN) F = cs_add(F, cs_scale(pt, -(pt_len < cap ? pt_len : cap) * m_dt / pt_len));
        }
    }
    return F;
}

/* How far from a rock's centre a triangle may lie and still take part: its reach R + offset plus
 * more than float rounding of a closest point can amount to. An edge lies on its two triangles
 * and a vertex on all of its, so a term whose triangles are all farther than this is out of reach
 * too: it is skipped (every vertex that shares it decides so from the same bits). */
SIM_HD static inline float cs_surface_lim(const cs_rock_state *r, const cs_phys *ph)
{
    const cs_vec3 c = r->x;
    return r->radius + ph->contact_offset + 1e-4f + 1e-6f * (fabsf(c.x) + fabsf(c.y) + fabsf(c.z));
}

/* Triangle (a, b, o) in canonical order (cs_ring_face): its point *p closest to c, the
 * barycentric weights w of that point, and whether it lies within lim of c. Every vertex of the
 * triangle computes the same bits. */
SIM_HD static inline int cs_surface_triangle(cs_vec3 c, cs_vec3 a, cs_vec3 b, cs_vec3 o, float lim, cs_vec3 *p,
                                             float w[3])
{
    cs_closest_on_triangle(c, a, b, o, w);
    *p = cs_tri_point(a, b, o, w);
    const cs_vec3 d = cs_sub(*p, c);
    return cs_dot(d, d) <= lim * lim;
}

/* The weight of ring slot 0 among the canonical weights w of ring triangle f: slot 0 is first in
 * triangles 1 and 2, second in 3 and 4, third in 5 and 6 (cs_ring_face). */
SIM_HD static inline float cs_ring_own_weight(int f, const float w[3]) { return w[f >> 1]; }

/* The rest of the gather (below) once the ring's intact triangles are found: tp[f] the closest
 * point of triangle f, tw[f] the vertex's weight there, bit f of in whether it is within lim
 * (cs_surface_triangle). A backend that computes each triangle once for its three vertices calls
 * this; cs_surface_gather is both parts. */
SIM_HD static inline void cs_surface_gather_tris(const cs_ring *g, const cs_vec3 tp[6], const float tw[6], int32_t in,
                                                 const cs_rock_state *r, const cs_phys *ph, cs_vec3 Fsum, float free,
                                                 cs_surface_out *o)
{
    const cs_vec3 zero = cs_v3(0.0f, 0.0f, 0.0f);
    cs_surface_acc acc;
    acc.E = zero;
    acc.weight = 0.0f;
    o->share = o->force = o->torque = zero;
    o->energy = o->depth = 0.0f;
    o->touches = o->owns = 0;
    o->E = zero;
    o->weight = 0.0f;
    const int32_t fm = g->faces;
    in &= fm;
    if (!in) return; /* a vertex near, not at, a contact (most of those a culling box lets through) */
    /* Spoke k lies between triangles k-1 and k: bits k-2 (mod 6) and k-1. Interior spokes are
     * those with both; bit k-1 of ie. The vertex term: n_V = 1 - triangles + interior edges. */
    const int32_t rot = ((fm << 1) | (fm >> 5)) & 63, ie = fm & rot, near = (in | ((in << 1) | (in >> 5))) & 63;
    const int nv = 1 - cs_popcount6(fm) + cs_popcount6(ie);
    if (nv != 0) cs_surface_term(o, &acc, g->x[0], (float)nv, 1.0f, 1, r, ph);
    /* Spoke edges: the interior ones with a triangle within reach. */
    const int32_t edges = ie & near;
    for (int k = 1; k <= 6; k++)
        if ((edges >> (k - 1)) & 1) cs_surface_edge(o, &acc, g, k, r, ph);
    /* Triangles: at their closest points. */
    for (int f = 0; f < 6; f++)
        if ((in >> f) & 1) cs_surface_term(o, &acc, tp[f], 1.0f, tw[f], f <= 1, r, ph);
    /* Dissipation and the separation cap, at the vertex from its net elastic force; the vertex
     * owns the reaction of what it adds or removes. */
    if (!o->touches) return;
    o->E = acc.E;
    o->weight = acc.weight;
    cs_vec3 arm;
    const cs_vec3 F = cs_surface_vertex_law(acc.E, acc.weight, g->v, g->ro, Fsum, free, r, ph, &arm);
    const cs_vec3 D = cs_sub(F, acc.E);
    o->share = F;
    o->force = cs_sub(o->force, D);
    o->torque = cs_cross(arm, cs_neg(D)); /* at the rock's surface: the work done there is D . vrel */
    o->owns++; /* the reaction of its own law */
}

/* Vertex g->x[0]'s part in rock r's surface contact (the rules above), into *o. Fsum: the force
 * on the vertex so far (non-contact resultant and earlier rocks' contacts); free: its w (1 free,
 * 0 pinned or grabbed). */
SIM_HD static inline void cs_surface_gather(const cs_ring *g, const cs_rock_state *r, const cs_phys *ph, cs_vec3 Fsum,
                                            float free, cs_surface_out *o)
{
    const float lim = cs_surface_lim(r, ph);
    cs_vec3 tp[6];
    float tw[6];
    int32_t in = 0; /* bit f: triangle f within lim */
    for (int f = 0; f < 6; f++) {
        tp[f] = cs_v3(0.0f, 0.0f, 0.0f);
        tw[f] = 0.0f;
        if (!((g->faces >> f) & 1)) continue;
        float w[3];
        in |= cs_surface_triangle(r->x, g->x[cs_ring_face(f, 0)], g->x[cs_ring_face(f, 1)], g->x[cs_ring_face(f, 2)],
                                  lim, &tp[f], w)
              << f;
        tw[f] = cs_ring_own_weight(f, w);
    }
    cs_surface_gather_tris(g, tp, tw, in, r, ph, Fsum, free, o);
}

/* Reduced mass 1 / (1/Ma + 1/Mb) from the inverse masses (0 for a kinematic rock or the ground);
 * 0 when neither body moves. */
SIM_HD static inline float cs_reduced_mass(float inv_a, float inv_b)
{
    const float s = inv_a + inv_b;
    return s > 0.0f ? 1.0f / s : 0.0f;
}

/* Rock contacts are scaled by the reduced mass mr of the pair: stiffness k_rock mr, normal and
 * tangential damping c_rock mr, so that every rock contact has the same natural frequency
 * sqrt(k_rock) and damping ratio c_rock / (2 sqrt(k_rock)) whatever the rocks weigh: a 40 kg rock
 * sinks into the ground as little as a 10 g one (g / k_rock at rest, v / sqrt(k_rock) at impact),
 * and no rock limits the time step more than another. */

/* Contact of rock a with rock b: the force and torque on a. */
SIM_HD static inline int cs_rock_pair_contact(const cs_rock_state *a, const cs_rock_state *b, const cs_phys *p,
                                              cs_vec3 *F, cs_vec3 *T)
{
    const cs_vec3 d = cs_sub(b->x, a->x);
    const float len = cs_len(d);
    const float delta = a->radius + b->radius - len;
    if (!(delta > 0.0f && len > CS_MIN_LEN)) return 0;
    const cs_vec3 n = cs_scale(d, 1.0f / len); /* from a to b */
    const cs_vec3 arm_a = cs_scale(n, a->radius);
    const cs_vec3 arm_b = cs_scale(n, -b->radius);
    const cs_vec3 vrel = cs_sub(cs_add(a->v, cs_cross(a->w, arm_a)), cs_add(b->v, cs_cross(b->w, arm_b)));
    const float mr = cs_reduced_mass(a->inv_mass, b->inv_mass), c = p->c_rock * mr;
    *F = cs_contact_law(cs_neg(n), delta, vrel, p->k_rock * mr, c, p->mu_rock, c, CS_FRICTION_COULOMB_VISCOUS,
                        cs_v3(0.0f, 0.0f, 0.0f), p->max_sep);
    *T = cs_cross(arm_a, *F);
    return 1;
}

/* Contact of a rock with the ground: the force and torque on the rock. */
SIM_HD static inline int cs_rock_ground_contact(const cs_rock_state *a, const cs_phys *p, cs_vec3 *F, cs_vec3 *T)
{
    const float delta = p->ground_z + a->radius - a->x.z;
    if (!(p->ground && delta > 0.0f)) return 0;
    const cs_vec3 n = cs_v3(0.0f, 0.0f, 1.0f);
    const cs_vec3 arm = cs_v3(0.0f, 0.0f, -a->radius);
    const cs_vec3 vrel = cs_add(a->v, cs_cross(a->w, arm));
    const float mr = cs_reduced_mass(a->inv_mass, 0.0f), c = p->c_rock * mr;
    *F = cs_contact_law(n, delta, vrel, p->k_rock * mr, c, p->mu_rock, c, CS_FRICTION_COULOMB_VISCOUS,
                        cs_v3(0.0f, 0.0f, 0.0f), p->max_sep);
    *T = cs_cross(arm, *F);
    return 1;
}

/* Sums CS_CHUNK values in place with the fixed pairwise tree buf[t] += buf[t + s] for
 * s = CS_CHUNK/2 .. 1 (the shape of a GPU block reduction); returns the sum in buf[0]. */
SIM_HD static inline float cs_tree_sum(float *buf)
{
    for (int s = CS_CHUNK / 2; s > 0; s >>= 1)
        for (int t = 0; t < s; t++) buf[t] += buf[t + s];
    return buf[0];
}

/* Chunks per group in the sum of a rock's chunk partials: chunks are summed in order within a
 * group, then the group sums in order - so a GPU may compute the groups in parallel and still
 * match a CPU that does both in one loop. */
#define CS_CHUNK_GROUP 64

/* The sum of rock r's partials (partials[(c nr + r) 6 + 0..5] = force, torque) over chunks
 * [c0, c1), in order: one group. */
SIM_HD static inline void cs_rock_group_sum(const float *partials, int32_t nr, int32_t r, int32_t c0, int32_t c1,
                                            cs_vec3 *F, cs_vec3 *T)
{
    cs_vec3 f = cs_v3(0.0f, 0.0f, 0.0f), t = f;
    for (int32_t c = c0; c < c1; c++) {
        const float *q = partials + ((size_t)c * (size_t)nr + (size_t)r) * 6;
        f = cs_add(f, cs_v3(q[0], q[1], q[2]));
        t = cs_add(t, cs_v3(q[3], q[4], q[5]));
    }
    *F = f;
    *T = t;
}

/* The cloth's force and torque on rock r: the group sums of cs_rock_group_sum, in group order. */
SIM_HD static inline void cs_rock_cloth_force(const float *partials, int32_t nr, int32_t r, int32_t nchunks,
                                              cs_vec3 *F_out, cs_vec3 *T_out)
{
    cs_vec3 F = cs_v3(0.0f, 0.0f, 0.0f), T = cs_v3(0.0f, 0.0f, 0.0f), f, t;
    for (int32_t g = 0; g < nchunks; g += CS_CHUNK_GROUP) {
        cs_rock_group_sum(partials, nr, r, g, g + CS_CHUNK_GROUP < nchunks ? g + CS_CHUNK_GROUP : nchunks, &f, &t);
        F = cs_add(F, f);
        T = cs_add(T, t);
    }
    *F_out = F;
    *T_out = T;
}

/* Total force and torque on rock r: the cloth's (the group sums of cs_rock_group_sum, in group
 * order), then the other rocks in index order, the ground, gravity. */
SIM_HD static inline void cs_rock_force(const cs_rock_state *rocks, int32_t nr, int32_t r, const float *partials,
                                        int32_t nchunks, const cs_phys *p, cs_vec3 *F_out, cs_vec3 *T_out)
{
    cs_vec3 F, T, f, t;
    cs_rock_cloth_force(partials, nr, r, nchunks, &F, &T);
    for (int32_t b = 0; b < nr; b++) {
        if (b != r && cs_rock_pair_contact(&rocks[r], &rocks[b], p, &f, &t)) {
            F = cs_add(F, f);
            T = cs_add(T, t);
        }
    }
    if (cs_rock_ground_contact(&rocks[r], p, &f, &t)) {
        F = cs_add(F, f);
        T = cs_add(T, t);
    }
    *F_out = cs_add(F, cs_scale(p->gravity, rocks[r].mass));
    *T_out = T;
}

/* Orientation update q += dt/2 (w, 0) (x) q, renormalised. */
SIM_HD static inline void cs_quat_integrate(float *q, cs_vec3 w, float dt)
{
    const float h = 0.5f * dt;
    const cs_vec3 qv = cs_v3(q[0], q[1], q[2]);
    const cs_vec3 dv = cs_add(cs_scale(w, q[3]), cs_cross(w, qv));
    const float dw = -cs_dot(w, qv);
    float x = q[0] + h * dv.x, y = q[1] + h * dv.y, z = q[2] + h * dv.z, s = q[3] + h * dw;
    const float inv = 1.0f / sqrtf(x * x + y * y + z * z + s * s);
    q[0] = x * inv;
    q[1] = y * inv;
    q[2] = z * inv;
    q[3] = s * inv;
}

/* Rock position step: x += dt v, orientation from w. */
SIM_HD static inline void cs_rock_drift(cs_rock_state *r, float dt)
{
    r->x = cs_add(r->x, cs_scale(r->v, dt));
    cs_quat_integrate(r->q, r->w, dt);
}

/* Rock velocity step by h with its stored accelerations. */
SIM_HD static inline void cs_rock_kick(cs_rock_state *r, float h)
{
    r->v = cs_add(r->v, cs_scale(r->a, h));
    r->w = cs_add(r->w, cs_scale(r->alpha, h));
}

/* Stores a rock's accelerations from its total force and torque (zero when kinematic). */
SIM_HD static inline void cs_rock_accel(cs_rock_state *r, cs_vec3 F, cs_vec3 T)
{
    r->a = cs_scale(F, r->inv_mass);
    r->alpha = cs_scale(T, r->inv_inertia);
}

/* Whether a rock's position, velocity, spin and orientation are finite (with rates, its linear and
 * angular accelerations too): what a step call checks (a huge spin makes the orientation NaN while
 * the rest stays finite), and a snapshot needs. */
SIM_HD static inline int cs_rock_finite(const cs_rock_state *r, int rates)
{
    int ok = isfinite(r->x.x) && isfinite(r->x.y) && isfinite(r->x.z) && isfinite(r->v.x) && isfinite(r->v.y) &&
             isfinite(r->v.z) && isfinite(r->w.x) && isfinite(r->w.y) && isfinite(r->w.z);
    for (int k = 0; k < 4; k++) ok = ok && isfinite(r->q[k]);
    if (rates)
        ok = ok && isfinite(r->a.x) && isfinite(r->a.y) && isfinite(r->a.z) && isfinite(r->alpha.x) &&
             isfinite(r->alpha.y) && isfinite(r->alpha.z);
    return ok;
}

/* Velocity that moves a grabbed vertex from x toward target by at most grab_speed dt. */
SIM_HD static inline cs_vec3 cs_grab_velocity(cs_vec3 x, cs_vec3 target, const cs_phys *p)
{
    cs_vec3 d = cs_sub(target, x);
    const float len = cs_len(d);
    const float most = p->grab_speed * p->dt;
    if (len > most) d = cs_scale(d, most / len);
    return cs_scale(d, 1.0f / p->dt);
}

#endif
