/* read.c - reading the state: vertex arrays, rest lengths and torn springs, energy, state hash. */
#include <string.h>

#include "sim_internal.h"

static cs_status read3(cs_sim *sim, const float *a, const float *b, const float *c, float *xyz, size_t n_floats,
                       const char *what)
{
    if (!xyz) return cs_fail(sim, CS_E_INVALID, NULL, "%s buffer is NULL", what);
    const size_t n = (size_t)sim->state.n;
    if (n_floats < 3 * n) return cs_fail(sim, CS_E_INVALID, NULL, "%s buffer holds %zu floats, %zu needed", what, n_floats, 3 * n);
    for (size_t v = 0; v < n; v++) {
        xyz[3 * v] = a[v];
        xyz[3 * v + 1] = b[v];
        xyz[3 * v + 2] = c[v];
    }
    cs_ok(sim);
    return CS_OK;
}

cs_status cs_read_positions(cs_sim *sim, float *xyz, size_t n_floats)
{
    if (!sim) return CS_E_INVALID;
    const cs_status st = cs_sim_sync(sim, CS_SYNC_POSITIONS);
    if (st != CS_OK) return st;
    return read3(sim, sim->state.x, sim->state.y, sim->state.z, xyz, n_floats, "positions");
}

cs_status cs_read_velocities(cs_sim *sim, float *xyz, size_t n_floats)
{
    if (!sim) return CS_E_INVALID;
    const cs_status st = cs_sim_sync(sim, CS_SYNC_VELOCITIES);
    if (st != CS_OK) return st;
    return read3(sim, sim->state.vx, sim->state.vy, sim->state.vz, xyz, n_floats, "velocities");
}

cs_status cs_read_rest_lengths(cs_sim *sim, float *out, size_t n_floats)
{
    if (!sim) return CS_E_INVALID;
    const size_t need = (size_t)sim->state.n * CS_NTYPES;
    if (!out || n_floats < need) return cs_fail(sim, CS_E_INVALID, NULL, "rest-length buffer must hold %zu floats", need);
    const cs_status st = cs_sim_sync(sim, CS_SYNC_REST);
    if (st != CS_OK) return st;
    memcpy(out, sim->state.L0, need * sizeof(float));
    cs_ok(sim);
    return CS_OK;
}

int64_t cs_torn_list(int32_t nx, int32_t ny, const float *L0, uint32_t *ids, size_t cap)
{
    const int32_t n = nx * ny;
    int64_t torn = 0;
    for (int t = 0; t < CS_NTYPES; t++) {
        for (int32_t v = 0; v < n; v++) {
            if (L0[(size_t)t * n + v] <= 0.0f && cs_spring_exists(nx, ny, t, v)) {
                if (ids && (size_t)torn < cap) ids[torn] = (uint32_t)t * (uint32_t)n + (uint32_t)v;
                torn++;
            }
        }
    }
    return torn;
}

int64_t cs_read_torn(cs_sim *sim, uint32_t *ids, size_t cap)
{
    if (!sim || cs_sim_sync(sim, CS_SYNC_REST) != CS_OK) return 0;
    return cs_torn_list(sim->model.scene.nx, sim->model.scene.ny, sim->state.L0, ids, cap);
}

cs_status cs_read_strain(cs_sim *sim, float *out, size_t n_floats)
{
    if (!sim) return CS_E_INVALID;
    const int32_t nx = sim->model.scene.nx, ny = sim->model.scene.ny, n = sim->state.n;
    if (!out || n_floats < (size_t)n) return cs_fail(sim, CS_E_INVALID, NULL, "strain buffer must hold %d floats", (int)n);
    const cs_status st = cs_sim_sync(sim, CS_SYNC_ALL);
    if (st != CS_OK) return st;
    const cs_state *s = &sim->state;
    memset(out, 0, sizeof(float) * (size_t)n);
    for (int t = CS_SX; t <= CS_SY; t++) {
        for (int32_t v = 0; v < n; v++) {
            const float L0 = s->L0[(size_t)t * n + v];
            const int32_t o = cs_spring_far_end(nx, ny, t, v);
            if (o < 0 || !(L0 > 0.0f)) continue; /* off the grid, or torn */
            const float e = (cs_len(cs_v3(s->x[o] - s->x[v], s->y[o] - s->y[v], s->z[o] - s->z[v])) - L0) / L0;
            if (e > out[v]) out[v] = e;
            if (e > out[o]) out[o] = e;
        }
    }
    cs_ok(sim);
    return CS_OK;
}

cs_status cs_energy_get(cs_sim *sim, cs_energy *out)
{
    if (!sim || !out) return sim ? cs_fail(sim, CS_E_INVALID, NULL, "out is NULL") : CS_E_INVALID;
    const cs_status st = cs_sim_sync(sim, CS_SYNC_POSITIONS | CS_SYNC_VELOCITIES | CS_SYNC_REST | CS_SYNC_ROCKS);
    if (st != CS_OK) return st;
    const cs_state *s = &sim->state;
    const cs_phys *p = &sim->model.phys;
    const int32_t nx = p->nx, ny = p->ny, n = p->n;
    double ke = 0, pe = 0, ge = 0;
    const double gx = p->gravity.x, gy = p->gravity.y, gz = p->gravity.z, m = p->mass;
    for (int32_t v = 0; v < n; v++) {
        ke += 0.5 * m * ((double)s->vx[v] * s->vx[v] + (double)s->vy[v] * s->vy[v] + (double)s->vz[v] * s->vz[v]);
        ge -= m * (gx * s->x[v] + gy * s->y[v] + gz * s->z[v]);
        for (int t = 0; t < CS_NTYPES; t++) {
            const int32_t o = cs_spring_far_end(nx, ny, t, v);
            if (o < 0) continue;
            pe += cs_spring_energy(cs_v3(s->x[v], s->y[v], s->z[v]), cs_v3(s->x[o], s->y[o], s->z[o]),
                                   s->L0[(size_t)t * n + v], p->k[t]);
        }
    }
    for (int32_t r = 0; r < s->n_rocks; r++) {
        const cs_rock_state *k = &s->rocks[r];
        ke += 0.5 * k->mass * ((double)k->v.x * k->v.x + (double)k->v.y * k->v.y + (double)k->v.z * k->v.z);
        ke += 0.5 * k->inertia * ((double)k->w.x * k->w.x + (double)k->w.y * k->w.y + (double)k->w.z * k->w.z);
        ge -= k->mass * (gx * k->x.x + gy * k->x.y + gz * k->x.z);
    }
    out->kinetic = ke;
    out->spring = pe;
    out->gravity = ge;
    out->total = ke + pe + ge;
    cs_ok(sim);
    return CS_OK;
}

/* ---- FNV-1a 64 ---- */

#define CS_FNV_PRIME 0x100000001b3ull

uint64_t cs_fnv1a(uint64_t h, const void *data, size_t len)
{
    const unsigned char *b = data;
    for (size_t i = 0; i < len; i++) {
        h ^= b[i];
        h *= CS_FNV_PRIME;
    }
    return h;
}

/* 32-bit words hashed as their little-endian bytes, whatever the host's order. */
static uint64_t hash_u32(uint64_t h, uint32_t u)
{
    const unsigned char b[4] = {(unsigned char)u, (unsigned char)(u >> 8), (unsigned char)(u >> 16),
                                (unsigned char)(u >> 24)};
    return cs_fnv1a(h, b, 4);
}

static uint64_t hash_floats(uint64_t h, const float *f, size_t n)
{
    for (size_t i = 0; i < n; i++) {
        uint32_t u;
        memcpy(&u, &f[i], 4);
        h = hash_u32(h, u);
    }
    return h;
}

uint64_t cs_state_hash(cs_sim *sim)
{
    if (!sim || cs_sim_sync(sim, CS_SYNC_ALL) != CS_OK) return 0;
    const cs_state *s = &sim->state;
    const size_t n = (size_t)s->n;
    uint64_t h = CS_FNV_OFFSET;
    const float *arrays[] = {s->x, s->y, s->z, s->vx, s->vy, s->vz, s->ax, s->ay, s->az};
    for (int a = 0; a < 9; a++) h = hash_floats(h, arrays[a], n);
    h = hash_floats(h, s->L0, n * CS_NTYPES);
    for (int32_t r = 0; r < s->n_rocks; r++) {
        const cs_rock_state *k = &s->rocks[r];
        h = hash_u32(hash_u32(h, k->id), (uint32_t)k->kinematic);
        const float f[] = {k->x.x, k->x.y, k->x.z, k->v.x, k->v.y, k->v.z, k->w.x, k->w.y, k->w.z,
                           k->a.x, k->a.y, k->a.z, k->alpha.x, k->alpha.y, k->alpha.z, k->q[0], k->q[1], k->q[2],
                           k->q[3], k->radius, k->density};
        h = hash_floats(h, f, sizeof f / sizeof f[0]);
    }
    return h;
}

void cs_hash_hex(uint64_t hash, char out[17])
{
    static const char hex[] = "0123456789abcdef";
    for (int i = 15; i >= 0; i--) {
        out[i] = hex[hash & 15];
        hash >>= 4;
    }
    out[16] = '\0';
}
