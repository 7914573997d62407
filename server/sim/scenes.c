/* scenes.c - the table of scenes (see scenes.h). */
#include <pthread.h>
#include <stdlib.h>
#include <string.h>

#include "sim/scenes.h"

struct scenes {
    pthread_mutex_t lock;
    scene **list;
    int n, max;
    void (*wake)(void *ctx);
    void *wake_ctx;
    scenes_hooks hooks;
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
    pthread_mutex_init(&t->lock, NULL);
    return t;
}

void scenes_free(scenes *t)
{
    if (!t) return;
    for (int k = 0; k < t->n; k++) scene_release(t->list[k]);
    pthread_mutex_destroy(&t->lock);
    free(t->list);
    free(t);
}

int scenes_add(scenes *t, scene *sc)
{
    pthread_mutex_lock(&t->lock);
    int ok = t->n < t->max;
    for (int k = 0; ok && k < t->n; k++) ok = strcmp(t->list[k]->id, sc->id) != 0;
    if (ok) {
        t->list[t->n++] = scene_hold(sc);
        scene_set_wake(sc, t->wake, t->wake_ctx);
    }
    const scenes_hooks h = t->hooks;
    pthread_mutex_unlock(&t->lock);
    if (ok && h.added) h.added(h.ctx, sc);
    return ok ? 0 : -1;
}

int scenes_remove(scenes *t, const char *id)
{
    scene *gone = NULL;
    pthread_mutex_lock(&t->lock);
    for (int k = 0; k < t->n && !gone; k++) {
        if (strcmp(t->list[k]->id, id) != 0) continue;
        gone = t->list[k];
        memmove(t->list + k, t->list + k + 1, (size_t)(t->n - k - 1) * sizeof *t->list);
        t->n--;
    }
    const scenes_hooks h = t->hooks;
    pthread_mutex_unlock(&t->lock);
    if (!gone) return -1;
    if (h.removed) h.removed(h.ctx, gone);
    scene_release(gone); /* the table's reference */
    return 0;
}

void scenes_set_hooks(scenes *t, scenes_hooks hooks)
{
    pthread_mutex_lock(&t->lock);
    t->hooks = hooks;
    pthread_mutex_unlock(&t->lock);
}

scene *scenes_get(scenes *t, const char *id)
{
    scene *found = NULL;
    pthread_mutex_lock(&t->lock);
    for (int k = 0; k < t->n && !found; k++)
        if (strcmp(t->list[k]->id, id) == 0) found = scene_hold(t->list[k]);
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

int scenes_healthy(scenes *t)
{
    pthread_mutex_lock(&t->lock);
    int ok = 1;
    for (int k = 0; k < t->n && ok; k++) ok = scene_healthy(t->list[k]);
    pthread_mutex_unlock(&t->lock);
    return ok;
}
