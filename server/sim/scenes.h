/* scenes.h - the daemon's table of scenes, by id, and the handles other threads reach a scene by.
 *
 * Today the table holds one scene, "default", which the routes without a scene prefix address.
 * A handle is a held reference (scene_hold / scene_release): a request or a stream client that
 * got one keeps a valid scene however long it takes, even once the scene has left the table
 * (the last reference frees it). The sim thread lists the table each turn and holds what it
 * steps. Thread-safe. */
#ifndef CLOTHD_SCENES_H
#define CLOTHD_SCENES_H

#include "sim/scene.h"

/* The scene the routes without a scene prefix address, and the one the daemon starts with. */
#define SCENE_DEFAULT "default"

typedef struct scenes scenes;

/* A table of at most max scenes. */
scenes *scenes_new(int max);
/* Drops the table's references. */
void scenes_free(scenes *t);
/* Adds a scene (the table takes a reference of its own): 0, or -1 when the table is full or the
 * id is taken. The scene gets the table's wake (scenes_set_wake). */
int scenes_add(scenes *t, scene *sc);
/* A held reference to the scene of an id (scene_release it), or NULL when there is none. */
scene *scenes_get(scenes *t, const char *id);
/* Held references to up to cap scenes, in the order they were added; returns how many. */
int scenes_list(scenes *t, scene **out, int cap);
/* How many scenes the table holds, and the most it takes. */
int scenes_count(scenes *t);
int scenes_max(scenes *t);
/* The sim thread's wake, given to every scene now in the table and added later. */
void scenes_set_wake(scenes *t, void (*wake)(void *ctx), void *ctx);
/* 1 while every scene's backend answers (/v1/health). */
int scenes_healthy(scenes *t);

/* What the daemon does as a scene joins or leaves the table (main.c wires the stream here):
 * `added` runs after scenes_add put it in (give it its sink), `removed` after scenes_remove took
 * it out (close what streams it). Called on the adding or removing thread, outside the table's
 * lock; either may be NULL. */
typedef struct scenes_hooks {
    void (*added)(void *ctx, scene *sc);
    void (*removed)(void *ctx, scene *sc);
    void *ctx;
} scenes_hooks;
void scenes_set_hooks(scenes *t, scenes_hooks hooks);
/* Takes the scene of an id out of the table (its holders keep it until they release it): 0, or
 * -1 when there is none. */
int scenes_remove(scenes *t, const char *id);

#endif
