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
    int32_t friction;            /* cs_friction */
    float k_rock, c_rock, mu_rock;
    int32_t ground;
    float ground_z;
    float dt, hdt;               /* substep and half substep */
    float plastic_yield, tear_strain, plastic_f;
    int32_t strain_on;           /* plastic_yield > 0 or tear_strain > 0 */
    int32_t integrator;          /* cs_integrator */
    float grab_speed;
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
 * other's; Ro: resultant of the non-contact forces on this body (resultant model only).
 * Fn = max(0, k delta - c vn) n; friction per model (MODEL.md, Rocks). */
SIM_HD static inline cs_vec3 cs_contact_law(cs_vec3 n, float delta, cs_vec3 vrel, float k, float c, float mu,
                                            float ct, int32_t model, cs_vec3 Ro)
{
    const float vn = cs_dot(vrel, n);
    float fn = k * delta - c * vn;
    fn = fn > 0.0f ? fn : 0.0f;
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
    *F = cs_contact_law(n, delta, vrel, p->k_contact, p->c_contact, p->mu, p->c_tangent, p->friction, Ro);
    *arm = rr;
    return 1;
}

/* Contact of a cloth vertex with the ground plane (when on). */
SIM_HD static inline int cs_vertex_ground_contact(cs_vec3 xi, cs_vec3 vi, cs_vec3 Ro, const cs_phys *p, cs_vec3 *F)
{
    const float delta = p->ground_z + p->contact_offset - xi.z;
    if (!(p->ground && delta > 0.0f)) return 0;
    *F = cs_contact_law(cs_v3(0.0f, 0.0f, 1.0f), delta, vi, p->k_contact, p->c_contact, p->mu, p->c_tangent,
                        p->friction, Ro);
    return 1;
}

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
    *F = cs_contact_law(cs_neg(n), delta, vrel, p->k_rock, p->c_rock, p->mu_rock, p->c_tangent,
                        CS_FRICTION_COULOMB_VISCOUS, cs_v3(0.0f, 0.0f, 0.0f));
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
    *F = cs_contact_law(n, delta, vrel, p->k_rock, p->c_rock, p->mu_rock, p->c_tangent, CS_FRICTION_COULOMB_VISCOUS,
                        cs_v3(0.0f, 0.0f, 0.0f));
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

/* Total force and torque on rock r: the cloth's (the group sums of cs_rock_group_sum, in group
 * order), then the other rocks in index order, the ground, gravity. */
SIM_HD static inline void cs_rock_force(const cs_rock_state *rocks, int32_t nr, int32_t r, const float *partials,
                                        int32_t nchunks, const cs_phys *p, cs_vec3 *F_out, cs_vec3 *T_out)
{
    cs_vec3 F = cs_v3(0.0f, 0.0f, 0.0f), T = cs_v3(0.0f, 0.0f, 0.0f), f, t;
    for (int32_t g = 0; g < nchunks; g += CS_CHUNK_GROUP) {
        cs_rock_group_sum(partials, nr, r, g, g + CS_CHUNK_GROUP < nchunks ? g + CS_CHUNK_GROUP : nchunks, &f, &t);
        F = cs_add(F, f);
        T = cs_add(T, t);
    }
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
