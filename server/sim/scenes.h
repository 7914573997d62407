/* scenes.h - the daemon's table of scenes, by id, and the handles other threads reach a scene by.
 *
 * The table holds up to max_scenes scenes; "default", the one the daemon starts with, is the one
 * the routes without a scene prefix address. A handle is a held reference (scene_hold /
 * scene_release): a request or a stream client that got one keeps a valid scene however long it
 * takes, even once the scene has left the table (the last reference frees it). The sim thread
 * lists the table each turn and holds what it steps; a scene that leaves the table goes to the
 * table's list of deleted scenes, which the sim thread lets go (scenes_drop_gone) once it has
 * ended what it still had running for it.
 *
 * The table also keeps what its scenes cost together (scene_cost): max_state_mb caps their sum.
 * A scene that joins is counted, and a scene change or snapshot that would take the sum past the
 * cap is refused by the scene's engine (its memory limit is the table's). Thread-safe. */
#ifndef CLOTHD_SCENES_H
#define CLOTHD_SCENES_H

#include "core/json_read.h" /* scene_id_valid, SCENE_DEFAULT */
#include "sim/scene.h"

typedef struct scenes scenes;

/* A table of at most max scenes. */
scenes *scenes_new(int max);
/* Drops the table's references (and those of the deleted scenes nobody took). */
void scenes_free(scenes *t);
/* Caps what the scenes cost together (0: no cap), counted with scene_cost(fields, rocks, cost_ctx). */
void scenes_set_budget(scenes *t, uint64_t cap, int32_t rocks, void *cost_ctx);
/* What a new scene (scenes_create) is made of: the configuration it starts from, the settings of
 * its engine and queue, the backend it runs on. Copied. */
void scenes_set_factory(scenes *t, const scene_config *base, const clothd_settings *set, const char *backend);

enum { SCENES_TAKEN = -1, SCENES_FULL = -2, SCENES_NO_ROOM = -3 };
/* Adds a scene (the table takes a reference of its own): 0, or SCENES_TAKEN (the id is in the
 * table), SCENES_FULL (max scenes) or SCENES_NO_ROOM (the cost cap), and then nothing changed. The
 * scene gets the table's wake (scenes_set_wake) and its memory limit. Its owner may be the sim
 * thread already: a scene is added before anything steps it. */
int scenes_add(scenes *t, scene *sc);
/* Makes and adds a scene: id (NULL: one is made up), the scene fields and live parameters of
 * `fields` and `params` (JSON objects, or NULL) over the factory's configuration; it runs. 0 with
 * *out (a reference of the caller's), or -1 with the problem (400 a bad id or field, 409 the id is
 * taken, 422 a value, max_scenes or max_state_mb), and the table is as it was. */
int scenes_create(scenes *t, const char *id, const json_t *fields, const json_t *params, scene **out, problem *pr);
/* A held reference to the scene of an id (scene_release it), or NULL when there is none. */
scene *scenes_get(scenes *t, const char *id);
/* Held references to up to cap scenes, in the order they were added; returns how many. */
int scenes_list(scenes *t, scene **out, int cap);
/* How many scenes the table holds, and the most it takes. */
int scenes_count(scenes *t);
int scenes_max(scenes *t);
/* What the scenes cost together, and the cap (0: none). */
uint64_t scenes_bytes(scenes *t, uint64_t *cap);
/* The sim thread, after a command that may have resized a scene: counts what it costs now. */
void scenes_resized(scenes *t, scene *sc);
/* The sim thread's wake, given to every scene now in the table and added later; a scene added or
 * removed wakes it too. */
void scenes_set_wake(scenes *t, void (*wake)(void *ctx), void *ctx);
/* Whether the table can take another scene (GET /readyz): 0 when it is below max_scenes and a scene
 * of the factory's configuration fits in what max_state_mb leaves; else -1 and pr says why (503). */
int scenes_room(scenes *t, problem *pr);
/* 1 while every scene's backend answers (/v1/health). */
int scenes_healthy(scenes *t);

/* What the daemon does as a scene joins or leaves the table (serve.c wires the stream here):
 * `added` runs after scenes_add put it in (give it its sink), on the adding thread; `removed`
 * once the sim thread has let a deleted scene go (close what streams it): the scene hands its
 * sink nothing from then on. Called outside the table's lock; either may be NULL. */
typedef struct scenes_hooks {
    void (*added)(void *ctx, scene *sc);
    void (*removed)(void *ctx, scene *sc);
    void *ctx;
} scenes_hooks;
void scenes_set_hooks(scenes *t, scenes_hooks hooks);
/* Takes the scene of an id out of the table (its holders keep it until they release it; commands
 * are refused from now on, 404): 0, or -1 when there is none. It joins the deleted scenes and the
 * sim thread is woken to let it go. */
int scenes_remove(scenes *t, const char *id);
/* The daemon is stopping: no scene joins from now on (scenes_create: 503). */
void scenes_close(scenes *t);
/* The sim thread: lets the deleted scenes go - each one's step in progress ends ("deleted"), what
 * it had queued is refused (404), its sink is dropped, then the `removed` hook runs and the
 * table's reference goes. (scenes_free drops those left without the hook: the stream is gone by
 * then.) */
void scenes_drop_gone(scenes *t);

#endif
