/* simloop.h - the sim thread: the one thread that steps every scene of the daemon's table.
 *
 * It runs each scene continuously at its time_scale (or max_speed), applies its queued commands
 * at frame boundaries (at once while it is paused), journals them with the step they applied at,
 * drops rocks (autodrop.h), keeps in-memory checkpoints and rolls back to the last one when the
 * state stops being finite, and publishes what readers need after every frame and every command
 * (scene_publish), so that readers never touch an engine and never wait for one. A command's
 * submitter is called back once it has been applied and the result published.
 *
 * Nothing keeps the thread from its queues for long: a step (POST /v1/sim/step, up to 100000
 * frames) runs in slices of about SIMLOOP_SLICE seconds of compute, and between slices the
 * thread answers reads, publishes its progress and notices a stop; a pause, a cancel, another
 * step or any command that changes the state ends it first (its answer says how far it got).
 * While running, a frame that takes longer than SIMLOOP_RUN_SLICE is stepped in parts, so a stop
 * is noticed within that whatever runs. (Each part costs the backend a pass over the vertices to
 * finish its last substep, so parts are not made smaller than they need to be.) */
#ifndef CLOTHD_SIMLOOP_H
#define CLOTHD_SIMLOOP_H

#include "core/metrics.h"
#include "sim/scenes.h"

/* Seconds of compute between two looks at the queues while a step runs, and between two looks at
 * a stop while a long frame runs. */
#define SIMLOOP_SLICE 0.05
#define SIMLOOP_RUN_SLICE 0.25

typedef struct simloop simloop;

/* The sim thread of a table's scenes (it becomes their waker: scenes_set_wake). */
simloop *simloop_new(scenes *table, metrics *m);
int simloop_start(simloop *sl);
/* Finishes the frame in progress, ends a step in progress ("shutdown"), refuses what is still
 * queued (503) and joins the thread; the scenes stay as they were (their state file is saved from
 * them). */
void simloop_stop(simloop *sl);
void simloop_free(simloop *sl);

/* The `threads` setting (before simloop_start): 0, the fewest threads that keep the scenes in
 * real time, counted as autothreads.h says; N, every engine on its own N (scene_engine_new). */
void simloop_set_threads(simloop *sl, int threads);

/* The heartbeat: the thread turns at least four times a second however idle (a turn waits no longer),
 * and each turn notes the time. simloop_last_turn: clock_mono() of the last turn, 0 before the
 * first (any thread; GET /livez compares it with liveness_timeout). simloop_set_beat (before
 * simloop_start): beat(ctx) is called from the sim thread at a turn at most every `every` seconds,
 * and the thread turns at least that often (systemd's watchdog: sdnotify.h). A wedged thread -
 * a frame that never ends, a lock never given back - turns no more, and both stop. */
double simloop_last_turn(simloop *sl);
void simloop_set_beat(simloop *sl, void (*beat)(void *ctx), void *ctx, double every);

#endif
