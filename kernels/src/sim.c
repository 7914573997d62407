/* sim.c - the simulation object: creation, scene and parameter changes, stepping, pins and grab.
 *
 * Every command follows one pattern: validate everything, compute the new model or state aside,
 * and only then adopt it, so a refused command changes nothing. After a command changes the host
 * state it is handed to the backend and the accelerations are recomputed from the current
 * positions and velocities (kernels/MODEL.md: a_n is refreshed whenever the state changes from outside). */
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "sim_internal.h"

cs_status cs_backend_fail(cs_sim *sim, cs_status st, const char *what)
{
    return cs_fail(sim, st, NULL, "the %s backend %s: %s", sim->backend->name, what, sim->backend->error(sim->ctx));
}

cs_status cs_sim_sync(cs_sim *sim, unsigned what)
{
    const unsigned need = what & sim->host_stale;
    if (!need) return CS_OK;
    const cs_status st = sim->backend->download(sim->ctx, &sim->model, &sim->state, need);
    if (st != CS_OK) return cs_backend_fail(sim, st, "could not hand the state back");
    sim->host_stale &= ~need;
    return CS_OK;
}

/* A device backend keeps its own copy: after it steps, the host copy is behind in every part;
 * after a refresh, in the accelerations (of the cloth and the rocks). */
static unsigned stale_after(const cs_sim *sim, unsigned parts) { return sim->backend != &cs_backend_cpu ? parts : 0; }

cs_status cs_sim_commit(cs_sim *sim)
{
    cs_status st = sim->backend->upload(sim->ctx, &sim->model, &sim->state);
    if (st == CS_OK) st = sim->backend->refresh(sim->ctx, &sim->model, &sim->state);
    if (st != CS_OK) return cs_backend_fail(sim, st, "failed to take the new state");
    sim->host_stale = stale_after(sim, CS_SYNC_ACCELERATIONS | CS_SYNC_ROCKS);
    return CS_OK;
}

static cs_status check_scene(cs_sim *sim, const cs_scene *scene)
{
    const char *bad = NULL;
    char why[200];
    if (cs_scene_validate(scene, &bad, why, sizeof why) != 0) return cs_fail(sim, CS_E_RANGE, bad, "%s", why);
    return cs_check_memory(sim, scene, &sim->model.params);
}

/* What the scene costs under params (the owner's cost function, else cs_scene_memory). */
static cs_status memory_of(const cs_sim *sim, const cs_scene *scene, const cs_params *params, uint64_t *bytes)
{
    uint64_t own;
    cs_status st = cs_scene_memory(scene, params, sim->rock_limit, &own);
    if (st == CS_OK && own > (uint64_t)SIZE_MAX / 2) st = CS_E_LIMIT;
    *bytes = own;
    if (st == CS_OK && sim->memory_cost) st = sim->memory_cost(scene, params, sim->rock_limit, sim->memory_ctx, bytes);
    return st;
}

cs_status cs_check_memory(cs_sim *sim, const cs_scene *scene, const cs_params *params)
{
    uint64_t bytes;
    if (memory_of(sim, scene, params, &bytes) != CS_OK)
        return cs_fail(sim, CS_E_LIMIT, "nx", "a %d x %d cloth is too large for this machine", (int)scene->nx,
                       (int)scene->ny);
    if (sim->memory_limit && bytes > sim->memory_limit)
        return cs_fail(sim, CS_E_LIMIT, "nx", "a %d x %d cloth needs %.0f MiB, more than the memory limit of %.0f MiB",
                       (int)scene->nx, (int)scene->ny, ceil((double)bytes / 1048576.0),
                       (double)sim->memory_limit / 1048576.0);
    return CS_OK;
}

/* A change of parameters that costs more memory than the ones in force (implicit_euler's workspace,
 * self_collision's) must fit the memory limit; it is blamed on self_collision when that turns on,
 * else on integrator. */
static cs_status check_params_memory(cs_sim *sim, const cs_params *params)
{
    if (!sim->memory_limit) return CS_OK;
    uint64_t now, then;
    const cs_scene *scene = &sim->model.scene;
    if (memory_of(sim, scene, params, &then) == CS_OK && memory_of(sim, scene, &sim->model.params, &now) == CS_OK &&
        (then <= now || then <= sim->memory_limit))
        return CS_OK;
    const int self = params->self_collision && !sim->model.params.self_collision;
    return cs_fail(sim, CS_E_LIMIT, self ? "self_collision" : "integrator",
                   "a %d x %d cloth with %s needs more than the memory limit of %.0f MiB", (int)scene->nx,
                   (int)scene->ny, self ? "self_collision" : "implicit_euler's workspace",
                   (double)sim->memory_limit / 1048576.0);
}

cs_status cs_sim_set_memory_limit(cs_sim *sim, uint64_t bytes, cs_cost_fn cost, void *ctx)
{
    if (!sim) return CS_E_INVALID;
    sim->memory_limit = bytes;
    sim->memory_cost = cost;
    sim->memory_ctx = ctx;
    cs_ok(sim);
    return CS_OK;
}

cs_status cs_sim_set_rock_limit(cs_sim *sim, int32_t rocks)
{
    if (!sim) return CS_E_INVALID;
    if (rocks < 1 || rocks > CS_MAX_ROCKS)
        return cs_fail(sim, CS_E_RANGE, "max_rocks", "the rock limit must be 1..%d (got %d)", CS_MAX_ROCKS, (int)rocks);
    sim->rock_limit = rocks;
    cs_ok(sim);
    return CS_OK;
}

int32_t cs_sim_rock_limit(const cs_sim *sim) { return sim ? sim->rock_limit : 0; }

static cs_status check_params(cs_sim *sim, const cs_params *p)
{
    const char *bad = NULL;
    char why[200];
    if (cs_params_validate(p, &bad, why, sizeof why) != 0) return cs_fail(sim, CS_E_RANGE, bad, "%s", why);
    return CS_OK;
}

/* Builds a fresh state for a scene and adopts it with the given parameters; on failure the old
 * state stays. */
static cs_status rebuild(cs_sim *sim, const cs_scene *scene, const cs_params *p)
{
    cs_combos combos;
    int32_t substeps;
    double dt_max;
    cs_guard_scene(&combos, scene);
    cs_status st = cs_guard_eval(sim, &combos, scene, p, NULL, 0, NULL, &substeps, &dt_max);
    if (st != CS_OK) return st;
    cs_state fresh;
    if (cs_state_alloc(&fresh, scene->nx * scene->ny) != CS_OK)
        return cs_fail(sim, CS_E_NOMEM, "nx", "out of memory for a %d x %d cloth", (int)scene->nx, (int)scene->ny);
    cs_scene_build(scene, &fresh);
    cs_model model = sim->model;
    cs_model_derive(&model, scene, p, substeps, dt_max);
    /* A failed upload leaves the backend's state as it was. A failed refresh leaves the new state
     * on the device: the old one goes back only if the host copy is current, else it is lost. */
    st = sim->backend->upload(sim->ctx, &model, &fresh);
    if (st != CS_OK) {
        cs_state_free(&fresh);
        return cs_backend_fail(sim, st, "could not take the new scene");
    }
    if ((st = sim->backend->refresh(sim->ctx, &model, &fresh)) != CS_OK) {
        cs_state_free(&fresh);
        if (!sim->state.x || sim->host_stale || sim->backend->upload(sim->ctx, &sim->model, &sim->state) != CS_OK)
            st = CS_E_DEVICE;
        return cs_backend_fail(sim, st, "could not take the new scene");
    }
    cs_state_free(&sim->state);
    sim->state = fresh;
    sim->model = model;
    sim->combos = combos;
    sim->host_stale = stale_after(sim, CS_SYNC_ACCELERATIONS | CS_SYNC_ROCKS);
    cs_sim_no_step_yet(sim);
    return CS_OK;
}

cs_status cs_sim_create(const cs_scene *scene, const cs_params *params, const char *backend, cs_sim **out,
                        char *err, size_t err_len)
{
    char scratch[8];
    if (!err || !err_len) err = scratch, err_len = sizeof scratch;
    err[0] = '\0';
    if (!out) {
        snprintf(err, err_len, "out is NULL");
        return CS_E_INVALID;
    }
    *out = NULL;
    cs_scene s;
    cs_params p;
    if (scene) s = *scene;
    else cs_scene_default(&s);
    if (params) p = *params;
    else cs_params_default(&p);

    cs_sim *sim = calloc(1, sizeof *sim);
    if (!sim) {
        snprintf(err, err_len, "out of memory");
        return CS_E_NOMEM;
    }
    sim->state.grab = -1;
    sim->rock_limit = CS_MAX_ROCKS;
    cs_ok(sim);
    cs_status st = cs_backend_pick(backend, &sim->backend, sim->backend_note, sizeof sim->backend_note);
    if (st != CS_OK) {
        snprintf(err, err_len, "%s", sim->backend_note);
        free(sim);
        return st;
    }
    char why[120];
    if (!cs_backend_covers(sim->backend, &p, why, sizeof why)) {
        if (backend && strcmp(backend, "auto") != 0) {
            snprintf(err, err_len, "%s", why);
            free(sim);
            return CS_E_BACKEND;
        }
        /* auto: the CPU backend has everything */
        sim->backend = &cs_backend_cpu;
        snprintf(sim->backend_note, sizeof sim->backend_note, "auto: %.120s; on the cpu backend", why);
    }
    st = sim->backend->create(&sim->ctx, err, err_len);
    if (st != CS_OK) {
        free(sim);
        return st;
    }
    st = check_scene(sim, &s);
    if (st == CS_OK) st = check_params(sim, &p);
    if (st == CS_OK) st = rebuild(sim, &s, &p);
    if (st != CS_OK) {
        snprintf(err, err_len, "%s", sim->err);
        cs_sim_destroy(sim);
        return st;
    }
    cs_ok(sim);
    *out = sim;
    return CS_OK;
}

void cs_sim_destroy(cs_sim *sim)
{
    if (!sim) return;
    if (sim->backend && sim->ctx) sim->backend->destroy(sim->ctx);
    cs_state_free(&sim->state);
    free(sim);
}

const char *cs_sim_error(const cs_sim *sim) { return sim ? sim->err : "sim is NULL"; }
const char *cs_sim_error_param(const cs_sim *sim) { return sim && sim->err_param ? sim->err_param : ""; }
const char *cs_sim_backend(const cs_sim *sim) { return sim->backend->name; }
const char *cs_sim_device(const cs_sim *sim) { return sim->backend->device(sim->ctx, &sim->model); }
const char *cs_sim_backend_note(const cs_sim *sim) { return sim->backend_note; }

cs_status cs_sim_backend_stats(cs_sim *sim, cs_backend_stats *out)
{
    if (!sim || !out) return sim ? cs_fail(sim, CS_E_INVALID, NULL, "out is NULL") : CS_E_INVALID;
    sim->backend->stats(sim->ctx, &sim->model, out);
    cs_ok(sim);
    return CS_OK;
}

cs_status cs_sim_cost(cs_sim *sim, const cs_backend *backend, cs_cost_model *out)
{
    if (!sim || !backend || !out) return sim ? cs_fail(sim, CS_E_INVALID, NULL, "backend or out is NULL") : CS_E_INVALID;
    backend->cost(&sim->model, sim->state.n_rocks, out);
    cs_ok(sim);
    return CS_OK;
}

cs_status cs_sim_set_threads(cs_sim *sim, int threads)
{
    if (!sim) return CS_E_INVALID;
    if (threads < 0 || threads > 256) return cs_fail(sim, CS_E_RANGE, NULL, "threads must be 0..256 (got %d)", threads);
    sim->model.threads = threads;
    cs_ok(sim);
    return CS_OK;
}

void cs_sim_scene(const cs_sim *sim, cs_scene *out) { *out = sim->model.scene; }
void cs_sim_params(const cs_sim *sim, cs_params *out) { *out = sim->model.params; }

cs_status cs_sim_set_scene(cs_sim *sim, const cs_scene *scene)
{
    if (!sim || !scene) return sim ? cs_fail(sim, CS_E_INVALID, NULL, "scene is NULL") : CS_E_INVALID;
    cs_status st = check_scene(sim, scene);
    if (st == CS_OK) st = rebuild(sim, scene, &sim->model.params);
    if (st == CS_OK) cs_ok(sim);
    return st;
}

cs_status cs_sim_reset(cs_sim *sim)
{
    if (!sim) return CS_E_INVALID;
    const cs_scene scene = sim->model.scene;
    return cs_sim_set_scene(sim, &scene);
}

/* The first parameter that differs between a and b, for blaming a refusal on it. */
static const char *first_change(const cs_params *a, const cs_params *b)
{
    for (size_t i = 0; i < cs_param_count(); i++) {
        const cs_param_info *p = cs_param_at(i);
        if (p->kind != CS_KIND_LIVE) continue;
        for (int c = 0; c < (p->type == CS_T_VEC3 ? 3 : 1); c++)
            if (cs_param_get(p, a, c) != cs_param_get(p, b, c)) return p->name;
    }
    return NULL;
}

cs_status cs_sim_set_params(cs_sim *sim, const cs_params *params)
{
    if (!sim || !params) return sim ? cs_fail(sim, CS_E_INVALID, NULL, "params is NULL") : CS_E_INVALID;
    cs_status st = check_params(sim, params);
    if (st != CS_OK) return st;
    char why[200];
    const char *lacks = cs_backend_lacks(sim->backend, params, why, sizeof why);
    if (lacks) return cs_fail(sim, CS_E_RANGE, lacks, "%s", why);
    if ((st = check_params_memory(sim, params)) != CS_OK) return st;
    int32_t substeps;
    double dt_max;
    st = cs_guard_eval(sim, &sim->combos, &sim->model.scene, params, sim->state.rocks, sim->state.n_rocks,
                       first_change(&sim->model.params, params), &substeps, &dt_max);
    if (st != CS_OK) return st;
    if ((st = cs_sim_sync(sim, CS_SYNC_ALL)) != CS_OK) return st;
    cs_model_derive(&sim->model, &sim->model.scene, params, substeps, dt_max);
    if ((st = cs_sim_commit(sim)) != CS_OK) return st;
    cs_ok(sim);
    return CS_OK;
}

cs_status cs_sim_reguard(cs_sim *sim, const cs_rock_state *rocks, int32_t n_rocks, const char *param)
{
    int32_t substeps;
    double dt_max;
    const cs_status st = cs_guard_eval(sim, &sim->combos, &sim->model.scene, &sim->model.params, rocks, n_rocks,
                                       param, &substeps, &dt_max);
    if (st == CS_OK) cs_model_derive(&sim->model, &sim->model.scene, &sim->model.params, substeps, dt_max);
    return st;
}

/* The checks of a step call, before anything runs. */
static cs_status step_check(cs_sim *sim, int64_t substeps)
{
    if (substeps < 0 || substeps > 1000000000)
        return cs_fail(sim, CS_E_RANGE, "substeps", "substeps must be 0..1e9 (got %lld)", (long long)substeps);
    if ((uint64_t)substeps > CS_STEP_MAX - sim->state.step)
        return cs_fail(sim, CS_E_LIMIT, "substeps", "the step count (%llu) would pass 2^63 - 1; rebuild the scene",
                       (unsigned long long)sim->state.step);
    return CS_OK;
}

/* The core's counters after a backend ran `now` substeps. */
static void step_account(cs_sim *sim, int32_t now, const cs_step_report *rep)
{
    sim->host_stale = stale_after(sim, CS_SYNC_ALL);
    sim->state.step += (uint64_t)now;
    /* One addition per substep: the clock reads the same however the substeps were split
     * into calls (a frame stepped in slices, a replay stepped in one go). */
    for (int32_t k = 0; k < now; k++) sim->state.time += sim->model.dt;
    sim->state.n_torn += rep->torn;
    sim->solver = rep->solver;
    sim->self = rep->self;
}

static cs_status nonfinite(cs_sim *sim)
{
    return cs_fail(sim, CS_E_NONFINITE, NULL, "the state became non-finite by step %llu",
                   (unsigned long long)sim->state.step);
}

#define STEP_CALL_MAX 100000 /* substeps one backend call runs at most */

cs_status cs_sim_step(cs_sim *sim, int64_t substeps)
{
    if (!sim) return CS_E_INVALID;
    cs_status st = step_check(sim, substeps);
    if (st != CS_OK) return st;
    cs_step_report total = {.finite = 1};
    while (substeps > 0 && total.finite) {
        const int32_t now = substeps > STEP_CALL_MAX ? STEP_CALL_MAX : (int32_t)substeps;
        cs_step_report rep = {.finite = 1};
        st = sim->backend->step(sim->ctx, &sim->model, &sim->state, now, &rep);
        if (st != CS_OK) return cs_backend_fail(sim, st, "failed while stepping");
        step_account(sim, now, &rep);
        total.finite = rep.finite;
        substeps -= now;
    }
    if (!total.finite) return nonfinite(sim);
    cs_ok(sim);
    return CS_OK;
}

/* Runs one round of a batch: the items of one backend, in one call where it has step_batch. */
static void batch_round(const cs_backend *b, cs_batch_item *items, int n)
{
    if (b->step_batch) {
        const cs_status st = b->step_batch(items, n);
        if (st == CS_OK) return;
        for (int k = 0; k < n; k++)
            if (items[k].status == CS_OK) items[k].status = st;
        return;
    }
    for (int k = 0; k < n; k++) items[k].status = b->step(items[k].ctx, items[k].m, items[k].s, items[k].substeps, &items[k].rep);
}

cs_status cs_sims_step(cs_sim *const *sims, size_t n, const int64_t *substeps, cs_status *each)
{
    if (!sims || !substeps || !each || n > CS_BATCH_MAX) return CS_E_INVALID;
    for (size_t k = 0; k < n; k++) {
        if (!sims[k]) return CS_E_INVALID;
        for (size_t j = 0; j < k; j++)
            if (sims[j] == sims[k]) return CS_E_INVALID; /* one simulation twice */
    }
    if (n == 0) return CS_OK;
    int64_t *left = malloc(n * sizeof *left);
    cs_batch_item *items = malloc(n * sizeof *items);
    size_t *of = malloc(n * sizeof *of);
    if (!left || !items || !of) {
        free(left);
        free(items);
        free(of);
        return CS_E_NOMEM;
    }
    for (size_t k = 0; k < n; k++) {
        each[k] = step_check(sims[k], substeps[k]);
        left[k] = each[k] == CS_OK ? substeps[k] : 0;
    }
    /* Rounds of at most STEP_CALL_MAX substeps each: the simulations left of the first one's
     * backend together, until none is left. */
    for (;;) {
        size_t first = 0;
        while (first < n && left[first] == 0) first++;
        if (first == n) break;
        const cs_backend *b = sims[first]->backend;
        int m = 0;
        for (size_t k = first; k < n; k++) {
            if (left[k] == 0 || sims[k]->backend != b) continue;
            cs_sim *s = sims[k];
            const int32_t now = left[k] > STEP_CALL_MAX ? STEP_CALL_MAX : (int32_t)left[k];
            items[m] = (cs_batch_item){s->ctx, &s->model, &s->state, now, {.finite = 1}, CS_OK};
            of[m++] = k;
        }
        batch_round(b, items, m);
        for (int j = 0; j < m; j++) {
            const size_t k = of[j];
            cs_sim *s = sims[k];
            if (items[j].status != CS_OK) {
                each[k] = cs_backend_fail(s, items[j].status, "failed while stepping");
                left[k] = 0;
                continue;
            }
            step_account(s, items[j].substeps, &items[j].rep);
            left[k] -= items[j].substeps;
            if (!items[j].rep.finite) {
                each[k] = nonfinite(s);
                left[k] = 0;
            }
        }
    }
    for (size_t k = 0; k < n; k++)
        if (each[k] == CS_OK) cs_ok(sims[k]);
    free(left);
    free(items);
    free(of);
    return CS_OK;
}

cs_status cs_sim_step_frames(cs_sim *sim, int64_t frames)
{
    if (!sim) return CS_E_INVALID;
    if (frames < 0 || frames > 1000000000 / sim->model.substeps)
        return cs_fail(sim, CS_E_RANGE, "frames", "frames must be 0..%d at %d substeps per frame (got %lld)",
                       1000000000 / (int)sim->model.substeps, (int)sim->model.substeps, (long long)frames);
    return cs_sim_step(sim, frames * sim->model.substeps);
}

static int64_t spring_total(int64_t nx, int64_t ny)
{
    const int64_t bx = nx > 2 ? (nx - 2) * ny : 0, by = ny > 2 ? nx * (ny - 2) : 0;
    return (nx - 1) * ny + nx * (ny - 1) + 2 * (nx - 1) * (ny - 1) + bx + by;
}

void cs_sim_info(const cs_sim *sim, cs_info *out)
{
    const cs_model *m = &sim->model;
    out->step = sim->state.step;
    out->time = sim->state.time;
    out->substeps = m->substeps;
    out->dt = m->dt;
    out->dt_max = m->dt_max;
    out->n_vertices = sim->state.n;
    out->n_torn = sim->state.n_torn;
    out->n_springs = (int32_t)(spring_total(m->scene.nx, m->scene.ny) - sim->state.n_torn);
    out->n_rocks = sim->state.n_rocks;
    out->solver = sim->solver;
    out->self = sim->self;
}

/* ---- pins and grab ---- */

cs_status cs_pins_preset(cs_sim *sim, cs_pins preset)
{
    if (!sim) return CS_E_INVALID;
    if ((unsigned)preset > CS_PINS_NONE) return cs_fail(sim, CS_E_RANGE, "preset", "unknown pins preset %d", (int)preset);
    cs_status st = cs_sim_sync(sim, CS_SYNC_ALL);
    if (st != CS_OK) return st;
    cs_state_apply_preset(&sim->model.scene, &sim->state, preset);
    if ((st = cs_sim_commit(sim)) != CS_OK) return st;
    cs_ok(sim);
    return CS_OK;
}

cs_status cs_pin(cs_sim *sim, const int32_t *vertices, size_t count, bool pinned)
{
    if (!sim) return CS_E_INVALID;
    if (count && !vertices) return cs_fail(sim, CS_E_INVALID, "vertices", "vertices is NULL");
    for (size_t k = 0; k < count; k++)
        if (vertices[k] < 0 || vertices[k] >= sim->state.n)
            return cs_fail(sim, CS_E_RANGE, "vertices", "vertex %lld is not in 0..%d", (long long)vertices[k],
                           (int)sim->state.n - 1);
    cs_status st = cs_sim_sync(sim, CS_SYNC_ALL);
    if (st != CS_OK) return st;
    for (size_t k = 0; k < count; k++) sim->state.pinned[vertices[k]] = pinned ? 1 : 0;
    cs_state_update_mask(&sim->state);
    if ((st = cs_sim_commit(sim)) != CS_OK) return st;
    cs_ok(sim);
    return CS_OK;
}

bool cs_is_pinned(const cs_sim *sim, int32_t vertex)
{
    return sim && vertex >= 0 && vertex < sim->state.n && sim->state.pinned[vertex];
}

static int finite3(const float *v) { return isfinite(v[0]) && isfinite(v[1]) && isfinite(v[2]); }

cs_status cs_grab(cs_sim *sim, int32_t vertex, const float target[3])
{
    if (!sim) return CS_E_INVALID;
    if (vertex < 0 || vertex >= sim->state.n)
        return cs_fail(sim, CS_E_RANGE, "vertex", "vertex %d is not in 0..%d", (int)vertex, (int)sim->state.n - 1);
    if (!target || !finite3(target)) return cs_fail(sim, CS_E_INVALID, "target", "target must be 3 finite numbers");
    for (int i = 0; i < 3; i++)
        if (fabsf(target[i]) > 1e6f) return cs_fail(sim, CS_E_RANGE, "target", "target must be within 1e6 m of the origin");
    cs_status st = cs_sim_sync(sim, CS_SYNC_ALL);
    if (st != CS_OK) return st;
    sim->state.grab = vertex;
    sim->state.grab_target = cs_v3_from(target);
    cs_state_update_mask(&sim->state);
    if ((st = cs_sim_commit(sim)) != CS_OK) return st;
    cs_ok(sim);
    return CS_OK;
}

cs_status cs_release(cs_sim *sim)
{
    if (!sim) return CS_E_INVALID;
    cs_status st = cs_sim_sync(sim, CS_SYNC_ALL);
    if (st != CS_OK) return st;
    sim->state.grab = -1;
    cs_state_update_mask(&sim->state);
    if ((st = cs_sim_commit(sim)) != CS_OK) return st;
    cs_ok(sim);
    return CS_OK;
}

int32_t cs_grabbed(const cs_sim *sim, float target[3])
{
    if (!sim) return -1;
    if (target && sim->state.grab >= 0) {
        target[0] = sim->state.grab_target.x;
        target[1] = sim->state.grab_target.y;
        target[2] = sim->state.grab_target.z;
    }
    return sim->state.grab;
}
