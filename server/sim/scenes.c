/* scenes.c - the table of scenes (see scenes.h). */
#include <pthread.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "core/params_json.h"
#include "sim/scenes.h"

struct scenes {
    pthread_mutex_t lock;
    scene **list;
    int n, max;
    scene **gone; /* deleted, not yet taken by the sim thread */
    int n_gone, gone_cap;
    unsigned long long made; /* ids made up so far */
    void (*wake)(void *ctx);
    void *wake_ctx;
    scenes_hooks hooks;
    uint64_t cap;   /* what the scenes may cost together, 0: no cap */
    int32_t rocks;  /* the rock limit a scene is costed with */
    void *cost_ctx; /* scene_cost's */
    int closed;     /* the daemon is stopping: no scene joins */
    int has_factory;
    scene_config base;
    clothd_settings set;
    char backend[16];
};

scenes *scenes_new(int max)
{
    scenes *t = calloc(1, sizeof *t);
    if (!t) return NULL;
    t->list = calloc((size_t)(max > 0 ? max : 1), sizeof *t->list);
    if (!t->list) {
        free(t);
        return NULL;
    }
    t->max = max;
    t->rocks = CS_MAX_ROCKS;
    pthread_mutex_init(&t->lock, NULL);
    return t;
}

void scenes_free(scenes *t)
{
    if (!t) return;
    for (int k = 0; k < t->n; k++) scene_release(t->list[k]);
    for (int k = 0; k < t->n_gone; k++) {
        scene_drop_deleted(t->gone[k]);
        scene_release(t->gone[k]);
    }
    pthread_mutex_destroy(&t->lock);
    free(t->gone);
    free(t->list);
    free(t);
}

void scenes_set_budget(scenes *t, uint64_t cap, int32_t rocks, void *cost_ctx)
{
    pthread_mutex_lock(&t->lock);
    t->cap = cap;
    t->rocks = rocks;
    t->cost_ctx = cost_ctx;
    pthread_mutex_unlock(&t->lock);
}

void scenes_set_factory(scenes *t, const scene_config *base, const clothd_settings *set, const char *backend)
{
    pthread_mutex_lock(&t->lock);
    t->base = *base;
    t->set = *set;
    snprintf(t->backend, sizeof t->backend, "%s", backend);
    t->has_factory = 1;
    pthread_mutex_unlock(&t->lock);
}

/* ---- what the scenes cost ---- */

/* What the scenes other than sc cost (under the lock). */
static uint64_t others_bytes(const scenes *t, const scene *sc)
{
    uint64_t sum = 0;
    for (int k = 0; k < t->n; k++)
        if (t->list[k] != sc) sum += t->list[k]->bytes;
    return sum;
}

/* A scene's engine's cost function (cs_sim_set_memory_limit; ctx: the scene): what the daemon's
 * scenes would cost together with the scene built from fields in place of this one. A change that
 * fits is reserved at once (the larger of the two is counted until scenes_resized), so that a scene
 * created meanwhile cannot take the same room. */
static cs_status table_cost(const cs_scene *fields, const cs_params *params, int32_t rocks, void *ctx,
                            uint64_t *bytes)
{
    scene *sc = ctx;
    scenes *t = sc->table;
    uint64_t own;
    const cs_status st = scene_cost(fields, params, rocks, t->cost_ctx, &own);
    if (st != CS_OK) return st;
    pthread_mutex_lock(&t->lock);
    const uint64_t total = others_bytes(t, sc) + own;
    if (total <= t->cap && own > sc->bytes) sc->bytes = own;
    pthread_mutex_unlock(&t->lock);
    *bytes = total;
    return CS_OK;
}

/* What a scene costs as it is now (its engine is not being stepped meanwhile). */
static uint64_t cost_now(const scenes *t, const scene *sc)
{
    cs_scene fields;
    cs_params params;
    cs_sim_scene(sc->engine, &fields);
    cs_sim_params(sc->engine, &params);
    uint64_t own = 0;
    if (scene_cost(&fields, &params, t->rocks, t->cost_ctx, &own) != CS_OK) own = UINT64_MAX / 4;
    return own;
}

uint64_t scenes_bytes(scenes *t, uint64_t *cap)
{
    pthread_mutex_lock(&t->lock);
    const uint64_t sum = others_bytes(t, NULL);
    if (cap) *cap = t->cap;
    pthread_mutex_unlock(&t->lock);
    return sum;
}

void scenes_resized(scenes *t, scene *sc)
{
    if (!t) return;
    const uint64_t own = cost_now(t, sc);
    pthread_mutex_lock(&t->lock);
    sc->bytes = own;
    pthread_mutex_unlock(&t->lock);
}

/* ---- joining and leaving ---- */

static int lookup(const scenes *t, const char *id)
{
    for (int k = 0; k < t->n; k++)
        if (strcmp(t->list[k]->id, id) == 0) return k;
    return -1;
}

int scenes_add(scenes *t, scene *sc)
{
    const uint64_t own = cost_now(t, sc);
    pthread_mutex_lock(&t->lock);
    int rc = 0;
    if (t->closed) rc = SCENES_FULL;
    else if (lookup(t, sc->id) >= 0) rc = SCENES_TAKEN;
    else if (t->n >= t->max) rc = SCENES_FULL;
    else if (t->cap && others_bytes(t, NULL) + own > t->cap) rc = SCENES_NO_ROOM;
    if (rc == 0) {
        t->list[t->n++] = scene_hold(sc);
        sc->table = t;
        sc->bytes = own;
        if (t->cap) cs_sim_set_memory_limit(sc->engine, t->cap, table_cost, sc);
        scene_set_wake(sc, t->wake, t->wake_ctx);
    }
    const scenes_hooks h = t->hooks;
    void (*wake)(void *) = t->wake;
    void *wake_ctx = t->wake_ctx;
    pthread_mutex_unlock(&t->lock);
    if (rc == 0 && h.added) h.added(h.ctx, sc);
    if (rc == 0 && wake) wake(wake_ctx);
    return rc;
}

int scenes_create(scenes *t, const char *want, const json_t *fields, const json_t *params, scene **out, problem *pr)
{
    *out = NULL;
    char id[SCENE_ID_MAX];
    pthread_mutex_lock(&t->lock);
    int rc = 0;
    if (t->closed) {
        rc = problem_set(pr, 503, "unavailable", NULL, "clothd is shutting down");
    } else if (!t->has_factory) {
        rc = problem_set(pr, 500, "internal", NULL, "this daemon makes no scenes");
    } else if (want && !scene_id_valid(want)) {
        rc = problem_set(pr, 400, "bad-scene-id", "id",
                         "a scene id is 1 to 63 characters of a-z, 0-9, '_' and '-', starting with a letter or digit");
    } else if (want) {
        snprintf(id, sizeof id, "%s", want);
    } else {
        do snprintf(id, sizeof id, "scene-%llu", ++t->made);
        while (lookup(t, id) >= 0);
    }
    if (rc == 0 && lookup(t, id) >= 0) rc = problem_set(pr, 409, "exists", "id", "a scene '%s' exists already", id);
    else if (rc == 0 && t->n >= t->max)
        rc = problem_set(pr, 422, "limit", "max_scenes", "the daemon holds max_scenes (%d) scenes already", t->max);
    scene_config cfg = t->base;
    const clothd_settings set = t->set;
    const char *backend = t->backend;
    const uint64_t room = t->cap ? t->cap - (others_bytes(t, NULL) < t->cap ? others_bytes(t, NULL) : t->cap) : 0;
    void *cost_ctx = t->cost_ctx;
    pthread_mutex_unlock(&t->lock);
    if (rc != 0) return -1;
    if (fields && params_from_json(fields, SET_SCENE, &cfg, pr) != 0) return -1;
    if (params && params_from_json(params, SET_LIVE, &cfg, pr) != 0) return -1;
    uint64_t own;
    if (t->cap && (scene_cost(&cfg.fields, &cfg.params, set.max_rocks, cost_ctx, &own) != CS_OK || own > room))
        return problem_set(pr, 422, "limit", "max_state_mb",
                           "a %d x %d scene does not fit in what max_state_mb (%d MiB) leaves beside the other scenes",
                           (int)cfg.fields.nx, (int)cfg.fields.ny, (int)set.max_state_mb);
    char err[300];
    cs_status st;
    cs_sim *engine = scene_engine_new(&cfg, &set, backend, cost_ctx, &st, err, sizeof err);
    if (!engine)
        return problem_set(pr, st == CS_E_NOMEM ? 503 : 422, st == CS_E_NOMEM ? "unavailable" : "out-of-range", NULL,
                           "the scene cannot be built: %s", err);
    scene *sc = scene_new(id, engine, &cfg.loop, 0, &set);
    if (!sc) return problem_set(pr, 503, "unavailable", NULL, "out of memory");
    switch (scenes_add(t, sc)) {
    case 0: *out = sc; return 0;
    case SCENES_TAKEN: problem_set(pr, 409, "exists", "id", "a scene '%s' exists already", id); break;
    case SCENES_FULL: problem_set(pr, 422, "limit", "max_scenes", "the daemon holds max_scenes (%d) scenes already", t->max); break;
    default:
        problem_set(pr, 422, "limit", "max_state_mb",
                    "a %d x %d scene does not fit in what max_state_mb (%d MiB) leaves beside the other scenes",
                    (int)cfg.fields.nx, (int)cfg.fields.ny, (int)set.max_state_mb);
    }
    scene_release(sc);
    return -1;
}

int scenes_remove(scenes *t, const char *id)
{
    pthread_mutex_lock(&t->lock);
    const int k = lookup(t, id);
    scene *gone = k >= 0 ? t->list[k] : NULL;
    int kept = 1;
    if (gone && t->n_gone == t->gone_cap) {
        const int cap = t->gone_cap ? 2 * t->gone_cap : 8;
        scene **g = realloc(t->gone, sizeof *g * (size_t)cap);
        if (g) t->gone = g, t->gone_cap = cap;
        else kept = 0;
    }
    if (gone && kept) {
        memmove(t->list + k, t->list + k + 1, (size_t)(t->n - k - 1) * sizeof *t->list);
        t->n--;
        t->gone[t->n_gone++] = gone; /* the table's reference, for the sim thread */
        scene_mark_deleted(gone);
    }
    void (*wake)(void *) = t->wake;
    void *wake_ctx = t->wake_ctx;
    pthread_mutex_unlock(&t->lock);
    if (!gone || !kept) return -1;
    if (wake) wake(wake_ctx); /* the sim thread lets it go (scenes_drop_gone) */
    return 0;
}

void scenes_drop_gone(scenes *t)
{
    for (;;) {
        pthread_mutex_lock(&t->lock);
        scene *sc = t->n_gone ? t->gone[--t->n_gone] : NULL;
        const scenes_hooks h = t->hooks;
        pthread_mutex_unlock(&t->lock);
        if (!sc) return;
        scene_drop_deleted(sc); /* nothing goes to its sink from here on */
        if (h.removed) h.removed(h.ctx, sc);
        scene_release(sc);
    }
}

void scenes_close(scenes *t)
{
    pthread_mutex_lock(&t->lock);
    t->closed = 1;
    pthread_mutex_unlock(&t->lock);
}

void scenes_set_hooks(scenes *t, scenes_hooks hooks)
{
    pthread_mutex_lock(&t->lock);
    t->hooks = hooks;
    pthread_mutex_unlock(&t->lock);
}

scene *scenes_get(scenes *t, const char *id)
{
    pthread_mutex_lock(&t->lock);
    const int k = lookup(t, id);
    scene *found = k >= 0 ? scene_hold(t->list[k]) : NULL;
    pthread_mutex_unlock(&t->lock);
    return found;
}

int scenes_list(scenes *t, scene **out, int cap)
{
    pthread_mutex_lock(&t->lock);
    const int n = t->n < cap ? t->n : cap;
    for (int k = 0; k < n; k++) out[k] = scene_hold(t->list[k]);
    pthread_mutex_unlock(&t->lock);
    return n;
}

int scenes_count(scenes *t)
{
    pthread_mutex_lock(&t->lock);
    const int n = t->n;
    pthread_mutex_unlock(&t->lock);
    return n;
}

int scenes_max(scenes *t) { return t->max; }

void scenes_set_wake(scenes *t, void (*wake)(void *ctx), void *ctx)
{
    pthread_mutex_lock(&t->lock);
    t->wake = wake;
    t->wake_ctx = ctx;
    for (int k = 0; k < t->n; k++) scene_set_wake(t->list[k], wake, ctx);
    pthread_mutex_unlock(&t->lock);
}

int scenes_room(scenes *t, problem *pr)
{
    pthread_mutex_lock(&t->lock);
    const int n = t->n, max = t->max, closed = t->closed;
    const uint64_t used = others_bytes(t, NULL), cap = t->cap;
    const cs_scene fields = t->base.fields;
    const cs_params params = t->base.params;
    const int32_t rocks = t->has_factory ? t->set.max_rocks : t->rocks;
    void *cost_ctx = t->cost_ctx;
    pthread_mutex_unlock(&t->lock);
    if (closed) return problem_set(pr, 503, "not-ready", NULL, "the daemon is stopping");
    if (n >= max) return problem_set(pr, 503, "not-ready", "max_scenes", "the daemon holds max_scenes (%d) scenes", max);
    uint64_t own = 0;
    if (cap && (used >= cap || scene_cost(&fields, &params, rocks, cost_ctx, &own) != CS_OK || own > cap - used))
        return problem_set(pr, 503, "not-ready", "max_state_mb",
                           "another %d x %d scene does not fit in what max_state_mb (%llu MiB) leaves beside %d scene%s",
                           (int)fields.nx, (int)fields.ny, (unsigned long long)(cap >> 20), n, n == 1 ? "" : "s");
    return 0;
}

int scenes_healthy(scenes *t)
{
    pthread_mutex_lock(&t->lock);
    int ok = 1;
    for (int k = 0; k < t->n && ok; k++) ok = scene_healthy(t->list[k]);
    pthread_mutex_unlock(&t->lock);
    return ok;
}
