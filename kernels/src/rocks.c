/* rocks.c - adding, changing and removing rocks. A rock list change goes through the stability
 * guard (a light rock on stiff contact may need more substeps) before it is adopted. Ids run from 1
 * to CS_ROCK_ID_MAX within a scene; the next one is kept in the state (and its snapshots). */
#include <math.h>
#include <stdlib.h>
#include <string.h>

#include "sim_internal.h"

void cs_rock_def_default(cs_rock_def *def)
{
    memset(def, 0, sizeof *def);
    def->orientation[3] = 1.0f;
    def->radius = 0.1f;
    def->density = 2500.0f;
}

/* Where a rock's surface meets the cloth's at a placement: the distance from its centre to the
 * nearest point of the cloth's surface (its intact triangles; its vertices in the vertex model),
 * and the vertex nearest to that point. */
static float cloth_distance(const cs_sim *sim, cs_vec3 c, int32_t *near)
{
    const cs_state *s = &sim->state;
    const int32_t nx = sim->model.phys.nx, ny = sim->model.phys.ny;
    float best = 3.0e38f;
    *near = -1;
    if (sim->model.params.contact_model == CS_CONTACT_VERTEX) {
        for (int32_t v = 0; v < s->n; v++) {
            const float d = cs_len(cs_sub(cs_v3(s->x[v], s->y[v], s->z[v]), c));
            if (d < best) best = d, *near = v;
        }
        return best;
    }
    int32_t t[3];
    for (int64_t k = 0; cs_next_triangle(s->L0, nx, ny, &k, t);) {
        cs_vec3 x[3];
        for (int q = 0; q < 3; q++) x[q] = cs_v3(s->x[t[q]], s->y[t[q]], s->z[t[q]]);
        float w[3];
        cs_closest_on_triangle(c, x[0], x[1], x[2], w);
        const cs_vec3 p = cs_tri_point(x[0], x[1], x[2], w);
        const float d = cs_len(cs_sub(p, c));
        if (d < best) best = d, *near = t[w[0] >= w[1] ? (w[0] >= w[2] ? 0 : 2) : (w[1] >= w[2] ? 1 : 2)];
    }
    return best;
}

/* Refuses a placement of rock r (index skip in the list, -1 for a new one) that overlaps another
 * rock or holds part of the cloth's surface inside it, by more than placement_overlap. */
static cs_status check_overlap(cs_sim *sim, const cs_rock_state *r, int32_t skip, const char *param)
{
    const cs_state *s = &sim->state;
    for (int32_t k = 0; k < s->n_rocks; k++) {
        if (k == skip) continue;
        const cs_rock_state *o = &s->rocks[k];
        const float gap = cs_len(cs_sub(o->x, r->x)) - (o->radius + r->radius);
        if (gap < -sim->model.params.placement_overlap)
            return cs_fail(sim, CS_E_OVERLAP, param, "the rock would overlap rock %u (by %.3g m): place it clear of it",
                           (unsigned)o->id, (double)-gap);
    }
    int32_t near;
    const float d = cloth_distance(sim, r->x, &near);
    if (d < r->radius - sim->model.params.placement_overlap)
        return cs_fail(sim, CS_E_OVERLAP, param,
                       "the rock would hold the cloth %.3g m inside it, near vertex %d (the cloth may come at most "
                       "contact_offset, %.3g m, into its contact layer): place it clear of the cloth",
                       (double)(r->radius - d), (int)near, (double)sim->model.params.contact_offset);
    return CS_OK;
}

static cs_status check_vec(cs_sim *sim, const char *name, const float *v, int n, float most)
{
    for (int i = 0; i < n; i++) {
        if (!isfinite(v[i])) return cs_fail(sim, CS_E_INVALID, name, "%s must be finite numbers", name);
        if (fabsf(v[i]) > most) return cs_fail(sim, CS_E_RANGE, name, "%s components must be within +-%g", name, most);
    }
    return CS_OK;
}

static cs_status check_def(cs_sim *sim, const cs_rock_def *d)
{
    cs_status st;
    if (!d) return cs_fail(sim, CS_E_INVALID, NULL, "rock is NULL");
    if ((st = check_vec(sim, "position", d->position, 3, 1e6f)) != CS_OK) return st;
    if ((st = check_vec(sim, "velocity", d->velocity, 3, 1e4f)) != CS_OK) return st;
    if ((st = check_vec(sim, "angular_velocity", d->angular_velocity, 3, 1e5f)) != CS_OK) return st;
    if ((st = check_vec(sim, "orientation", d->orientation, 4, 1e6f)) != CS_OK) return st;
    const float *q = d->orientation;
    if (!(q[0] * q[0] + q[1] * q[1] + q[2] * q[2] + q[3] * q[3] > 1e-12f))
        return cs_fail(sim, CS_E_INVALID, "orientation", "orientation must be a non-zero quaternion");
    if (!(isfinite(d->radius) && d->radius >= 1e-3f && d->radius <= 1e3f))
        return cs_fail(sim, CS_E_RANGE, "radius", "radius must be between 0.001 and 1000 m");
    if (!(isfinite(d->density) && d->density >= 1e-3f && d->density <= 1e6f))
        return cs_fail(sim, CS_E_RANGE, "density", "density must be between 0.001 and 1e6 kg/m^3");
    return CS_OK;
}

static void def_to_state(const cs_rock_def *d, cs_rock_state *r)
{
    const float *q = d->orientation;
    const float inv = 1.0f / sqrtf(q[0] * q[0] + q[1] * q[1] + q[2] * q[2] + q[3] * q[3]);
    r->x = cs_v3_from(d->position);
    r->v = cs_v3_from(d->velocity);
    r->w = cs_v3_from(d->angular_velocity);
    r->a = r->alpha = cs_v3(0.0f, 0.0f, 0.0f);
    for (int i = 0; i < 4; i++) r->q[i] = q[i] * inv;
    r->radius = d->radius;
    r->density = d->density;
    r->kinematic = d->kinematic ? 1 : 0;
    cs_rock_mass(r);
}

static void state_to_rock(const cs_rock_state *r, cs_rock *out)
{
    memset(out, 0, sizeof *out);
    out->id = r->id;
    out->def.position[0] = r->x.x, out->def.position[1] = r->x.y, out->def.position[2] = r->x.z;
    out->def.velocity[0] = r->v.x, out->def.velocity[1] = r->v.y, out->def.velocity[2] = r->v.z;
    out->def.angular_velocity[0] = r->w.x, out->def.angular_velocity[1] = r->w.y, out->def.angular_velocity[2] = r->w.z;
    memcpy(out->def.orientation, r->q, sizeof r->q);
    out->def.radius = r->radius;
    out->def.density = r->density;
    out->def.kinematic = r->kinematic != 0;
    out->mass = r->mass;
    out->inertia = r->inertia;
}

static int32_t find(const cs_sim *sim, uint32_t id)
{
    for (int32_t r = 0; r < sim->state.n_rocks; r++)
        if (sim->state.rocks[r].id == id) return r;
    return -1;
}

static cs_status not_found(cs_sim *sim, uint32_t id)
{
    return cs_fail(sim, CS_E_NOT_FOUND, "id", "no rock with id %u", (unsigned)id);
}

/* Adopts a new rock list (already guarded): swaps it in, hands it to the backend. */
static cs_status adopt(cs_sim *sim, cs_rock_state *rocks, int32_t n, int32_t cap)
{
    free(sim->state.rocks);
    sim->state.rocks = rocks;
    sim->state.n_rocks = n;
    sim->state.rock_cap = cap;
    const cs_status st = cs_sim_commit(sim);
    if (st == CS_OK) cs_ok(sim);
    return st;
}

/* A copy of the rock list with room for one more. */
static cs_rock_state *copy_rocks(cs_sim *sim, int32_t *cap)
{
    *cap = sim->state.n_rocks + 1;
    cs_rock_state *r = malloc(sizeof *r * (size_t)*cap);
    if (r && sim->state.n_rocks) memcpy(r, sim->state.rocks, sizeof *r * (size_t)sim->state.n_rocks);
    return r;
}

cs_status cs_rock_add(cs_sim *sim, const cs_rock_def *def, uint32_t *id)
{
    if (!sim) return CS_E_INVALID;
    cs_status st = check_def(sim, def);
    if (st != CS_OK) return st;
    if (sim->state.n_rocks >= sim->rock_limit)
        return cs_fail(sim, CS_E_LIMIT, "max_rocks", "the simulation already holds max_rocks (%d) rocks",
                       (int)sim->rock_limit);
    if (sim->state.next_rock_id > CS_ROCK_ID_MAX)
        return cs_fail(sim, CS_E_LIMIT, "id",
                       "rock ids are used up (the last one given was %u): rebuild the scene to start again from 1",
                       CS_ROCK_ID_MAX);
    if ((st = cs_sim_sync(sim, CS_SYNC_ALL)) != CS_OK) return st;
    int32_t cap;
    cs_rock_state *rocks = copy_rocks(sim, &cap);
    if (!rocks) return cs_fail(sim, CS_E_NOMEM, NULL, "out of memory");
    cs_rock_state *r = &rocks[sim->state.n_rocks];
    memset(r, 0, sizeof *r);
    def_to_state(def, r);
    r->id = sim->state.next_rock_id;
    if ((st = check_overlap(sim, r, -1, "position")) != CS_OK) {
        free(rocks);
        return st;
    }
    if ((st = cs_sim_reguard(sim, rocks, sim->state.n_rocks + 1, "radius")) != CS_OK) {
        free(rocks);
        return st;
    }
    sim->state.next_rock_id++;
    if (id) *id = r->id;
    return adopt(sim, rocks, sim->state.n_rocks + 1, cap);
}

cs_status cs_rock_get(cs_sim *sim, uint32_t id, cs_rock *out)
{
    if (!sim || !out) return sim ? cs_fail(sim, CS_E_INVALID, NULL, "out is NULL") : CS_E_INVALID;
    const int32_t r = find(sim, id);
    if (r < 0) return not_found(sim, id);
    const cs_status st = cs_sim_sync(sim, CS_SYNC_ROCKS);
    if (st != CS_OK) return st;
    state_to_rock(&sim->state.rocks[r], out);
    cs_ok(sim);
    return CS_OK;
}

cs_status cs_rock_set(cs_sim *sim, uint32_t id, const cs_rock_def *def)
{
    if (!sim) return CS_E_INVALID;
    const int32_t r = find(sim, id);
    if (r < 0) return not_found(sim, id);
    cs_status st = check_def(sim, def);
    if (st != CS_OK) return st;
    if ((st = cs_sim_sync(sim, CS_SYNC_ALL)) != CS_OK) return st;
    int32_t cap;
    cs_rock_state *rocks = copy_rocks(sim, &cap);
    if (!rocks) return cs_fail(sim, CS_E_NOMEM, NULL, "out of memory");
    const cs_rock_state was = rocks[r];
    def_to_state(def, &rocks[r]);
    rocks[r].id = was.id;
    const int moved = memcmp(&was.x, &rocks[r].x, sizeof was.x) != 0 || was.radius != rocks[r].radius;
    if (moved && (st = check_overlap(sim, &rocks[r], r, was.radius != rocks[r].radius ? "radius" : "position")) != CS_OK) {
        free(rocks);
        return st;
    }
    if ((st = cs_sim_reguard(sim, rocks, sim->state.n_rocks, "radius")) != CS_OK) {
        free(rocks);
        return st;
    }
    return adopt(sim, rocks, sim->state.n_rocks, cap);
}

cs_status cs_rock_remove(cs_sim *sim, uint32_t id)
{
    if (!sim) return CS_E_INVALID;
    const int32_t r = find(sim, id);
    if (r < 0) return not_found(sim, id);
    cs_status st = cs_sim_sync(sim, CS_SYNC_ALL);
    if (st != CS_OK) return st;
    int32_t cap;
    cs_rock_state *rocks = copy_rocks(sim, &cap);
    if (!rocks) return cs_fail(sim, CS_E_NOMEM, NULL, "out of memory");
    const int32_t n = sim->state.n_rocks - 1;
    memmove(&rocks[r], &rocks[r + 1], sizeof *rocks * (size_t)(n - r));
    /* Fewer rocks never need more substeps, but the effective count may now drop. */
    if ((st = cs_sim_reguard(sim, rocks, n, NULL)) != CS_OK) {
        free(rocks);
        return st;
    }
    return adopt(sim, rocks, n, cap);
}

int32_t cs_rock_clear(cs_sim *sim)
{
    if (!sim) return 0;
    const int32_t n = sim->state.n_rocks;
    if (cs_sim_sync(sim, CS_SYNC_ALL) != CS_OK) return 0;
    if (cs_sim_reguard(sim, NULL, 0, NULL) != CS_OK) return 0;
    if (adopt(sim, NULL, 0, 0) != CS_OK) return 0;
    return n;
}

int32_t cs_rock_count(const cs_sim *sim) { return sim ? sim->state.n_rocks : 0; }

cs_status cs_rock_at(cs_sim *sim, int32_t index, cs_rock *out)
{
    if (!sim || !out) return sim ? cs_fail(sim, CS_E_INVALID, NULL, "out is NULL") : CS_E_INVALID;
    if (index < 0 || index >= sim->state.n_rocks)
        return cs_fail(sim, CS_E_RANGE, "index", "rock index %d is not in 0..%d", (int)index, (int)sim->state.n_rocks - 1);
    const cs_status st = cs_sim_sync(sim, CS_SYNC_ROCKS);
    if (st != CS_OK) return st;
    state_to_rock(&sim->state.rocks[index], out);
    cs_ok(sim);
    return CS_OK;
}
