/* scene.h - a scene: one cloth and its rocks on the engine, and everything the daemon keeps beside
 * it - its daemon-loop settings, command queue, journal, checkpoints, automatic drops, run state,
 * the reads it publishes and the sinks its poses and events go to.
 *
 * A scene is a passive struct: nothing here has a thread. Its owner - the sim thread, which steps
 * every scene of the daemon's table (simloop.h) - alone touches the engine and the fields under
 * "the sim thread's"; other threads reach a scene through a held reference (scene_hold and
 * scene_release; the table hands them out, scenes.h) and use only the functions marked "any
 * thread": they queue commands and copy what was last published, never waiting on the engine.
 * The last reference to go frees the scene.
 *
 * Published reads are made after every frame and every command (scene_publish), so a read never
 * touches the engine, and a command's submitter, called back once it has been applied and
 * published, sees it in the next read. */
#ifndef CLOTHD_SCENE_H
#define CLOTHD_SCENE_H

#include <pthread.h>
#include <stdatomic.h>
#include <stddef.h>
#include <stdint.h>

#include <jansson.h>

#include "clothsim/clothsim.h"
#include "core/journal.h"
#include "core/metrics.h"
#include "core/problem.h"
#include "core/pose.h"
#include "core/settings.h"
#include "sim/sink.h"

/* Longest scene id, its NUL included. */
#define SCENE_ID_MAX 64
/* The most sinks a scene has (the stream's and the recordings'). */
#define SCENE_SINKS 4

struct command;
typedef struct scene scene;
typedef struct scene_cmd scene_cmd;

/* A command on its way to the sim thread and back: what the request made of it, and the
 * results the sim thread fills in before it calls done(). Owned by the submitter. */
struct scene_cmd {
    const struct command *def;    /* its row of the command table (commands.h) */
    json_t *body;                 /* the command's JSON (owned by the submitter), or NULL */
    char request_id[129];         /* the request's X-Request-Id, echoed in the stream's event */
    const unsigned char *blob_in; /* bytes the request carried (a snapshot) */
    size_t blob_in_len;
    /* results, set by the sim thread before done() */
    int failed;
    problem pr;
    json_t *result;               /* response JSON (the submitter frees it) */
    unsigned char *blob;          /* binary or preformatted response (the submitter frees it) */
    size_t blob_len;
    void (*done)(scene_cmd *cmd, void *arg);
    void *done_arg;
    scene_cmd *next;
};

/* A step in progress (POST /v1/sim/step): run in slices between which the queue is drained. */
typedef struct step_job {
    scene_cmd *cmd;       /* NULL when none */
    int frames;           /* 1: frames were asked; 0: substeps */
    long long want;       /* how many */
    long long frames_run; /* complete frames run */
    uint64_t step0;       /* the step it started at */
    json_t *before_event; /* last_event when it started */
} step_job;

/* What a scene publishes as text for its readers. */
typedef enum scene_doc {
    DOC_SIM,    /* GET /v1/sim's JSON */
    DOC_PARAMS, /* GET /v1/params */
    DOC_FIELDS, /* GET /v1/scene */
    DOC_TORN,   /* the ids of the torn springs (type n + v), a JSON array */
    DOC_COUNT
} scene_doc;

struct scene {
    char id[SCENE_ID_MAX];
    atomic_int refs;
    struct scenes *table;  /* the table it joined (its memory is counted there), or NULL */
    uint64_t bytes;        /* what it costs (scene_cost), as the table counts it (under the table's lock) */

    /* the queue (any thread, under qlock) */
    pthread_mutex_t qlock;
    scene_cmd *head, *tail;
    int queued, queue_max; /* commands in the queue, and the most it takes */
    int closed;            /* the daemon is stopping: commands are refused at once */
    int deleted;           /* it left the table: commands are refused at once (404) */
    void (*wake)(void *ctx); /* tells the sim thread a command came */
    void *wake_ctx;

    /* what was last published (any thread, under plock) */
    pthread_mutex_t plock;
    char *docs[DOC_COUNT];
    size_t doc_len[DOC_COUNT];
    cs_rock *rocks;
    int n_rocks;
    metrics_gauges gauges;
    int healthy;           /* 0 once the backend has failed for good */

    journal *journal;      /* the sim thread appends, readers copy (it has its own lock) */

    /* its sinks (sink.h), in the order they were added: added from any thread under qlock, each
     * written before the count that shows it; the sim thread reads them without a lock */
    frame_sink sinks[SCENE_SINKS];
    atomic_int n_sinks;
    int sinks_closed;      /* it left the daemon (under qlock): no sink is added */

    /* the recordings' own (sim/rec_tap.c: the recordings' sink), under rlock; scene.c makes and
     * frees the lock only */
    pthread_mutex_t rlock;
    struct recording *recs;
    int recs_closed;       /* it left the daemon: no recording starts on it */
    atomic_int n_recs;

    /* the sim thread's */
    cs_sim *engine;
    loop_settings loop;    /* the daemon-loop settings (PATCH /v1/params sets them) */
    void (*before_frame)(cs_sim *engine, uint64_t frame); /* the test daemon's hook, or NULL */
    int paused, paused_before_failure;
    int was_running;       /* running at the sim thread's last look (it starts its frame clock when it starts) */
    int lost;              /* the backend failed and the sim thread has not said so yet */
    uint64_t frame;        /* frames since the cloth was built */
    int32_t frame_sub;     /* substeps run of the frame in progress (a frame stepped in parts) */
    double frame_wall;     /* compute time of the frame in progress */
    double cost;           /* measured s per vertex and substep, for sizing slices */
    const char *failed_as; /* how the last failed substeps ended: instability, step_limit, NULL (backend) */
    step_job job;
    double due, last_publish, last_energy, rtf, rtf_wall, rtf_sim;
    cs_energy energy;
    unsigned char *checkpoint;
    size_t checkpoint_len, checkpoint_cap;
    uint64_t checkpoint_frame, frames_since_checkpoint;
    uint64_t rng;          /* the automatic drops' random numbers (autodrop.h) */
    int32_t seed;          /* the seed they were drawn from */
    double next_drop;
    uint32_t autos[CS_MAX_ROCKS];
    int n_autos;
    json_t *last_event;
    /* Every step and every state-changing command counts a change; a sink is handed a pose only
     * when there is one since the last it was handed (framed_changes, by sink), or the lender
     * wants a scalar it lacks: commands that change nothing (reads, pauses, a client joining)
     * publish no duplicate pose. */
    uint64_t changes, framed_changes[SCENE_SINKS];
    unsigned framed_scalars; /* the scalars of the last pose the lender was handed */
    int pose_asked; /* the stream asked for a pose, changed or not (control_pose) */
    pose own_pose;         /* the pose the copiers are handed when no sink lends one */
    uint32_t *torn;        /* ids of the torn springs, ascending */
    int64_t n_torn;
    float *scratch;        /* velocities or strains for the scalars */
    size_t scratch_cap;
};

/* ---- lifecycle (its owner, before the sim thread runs it) ---- */

/* A scene of the engine (taken: the scene destroys it), with the daemon-loop settings loop,
 * paused or not, its queue and journal capped by set (queue_max, journal_max, journal_max_mb).
 * Its state is published and journaled from the engine's current step. One reference, the
 * caller's; NULL when out of memory (the engine is destroyed then too). */
scene *scene_new(const char *id, cs_sim *engine, const loop_settings *loop, int paused, const clothd_settings *set);
/* Adds a sink (any thread): from the next publication on it is handed the scene's poses and
 * events, after those added before it. 0, also when it is there already (the same ops and ctx);
 * -1 when the scene has SCENE_SINKS, or a sink that lends already and this one lends too, or it
 * left the daemon. A sink with no ops is not added (0). */
int scene_add_sink(scene *sc, frame_sink sink);
/* scene_add_sink, for a sink given at the scene's start (the stream's). */
void scene_set_sink(scene *sc, frame_sink sink);
/* Calls hook before each frame is stepped, with the frames done so far (testhooks.h). */
void scene_set_frame_hook(scene *sc, void (*hook)(cs_sim *engine, uint64_t frame));

/* ---- any thread ---- */

scene *scene_hold(scene *sc);
/* Drops a reference; the last frees the scene (and its engine). */
void scene_release(scene *sc);
/* Queues a command; done() is called from the sim thread, or at once when the queue is full
 * (503 busy) or the daemon is stopping (503). */
void scene_submit(scene *sc, scene_cmd *cmd);
/* A copy of a published text (malloc'd, *len bytes, NUL-terminated), or NULL. */
char *scene_doc_copy(scene *sc, scene_doc doc, size_t *len);
/* A copy of the rocks; returns how many (the array is malloc'd, possibly NULL when none). */
int scene_rocks(scene *sc, cs_rock **out);
void scene_gauges(scene *sc, metrics_gauges *g);
int scene_healthy(scene *sc);
/* The stream's hello of the scene (PROTOCOL.md, "hello"; without its subscription) from what it
 * published: type, protocol, scene_id, scene, params, rocks (these, or the published ones when
 * rocks is NULL), torn, state, step. A new reference, or NULL. */
json_t *scene_hello(scene *sc, const cs_rock *rocks, int n_rocks);

/* What a scene of these fields costs the daemon under params, in bytes, with up to `rocks` rocks:
 * the engine's part (cs_scene_memory, its workspaces included where params use them), two
 * snapshots (the last checkpoint and the journal's base), one answer the sim thread builds (the
 * cloth state as JSON, or a snapshot), what the sink holds (ctx: its const frame_sink_ops, or
 * NULL), the scalars' scratch, and the list of torn springs with its JSON. The one estimate max_state_mb caps: the engine is given it (cs_sim_set_memory_limit), for
 * scene changes, snapshots and changes of parameters, and the daemon checks its starting scene
 * with it. */
cs_status scene_cost(const cs_scene *fields, const cs_params *params, int32_t rocks, void *ctx, uint64_t *bytes);
/* Bytes GET /v1/cloth/state's JSON may take for n vertices (part of scene_cost). */
uint64_t scene_cloth_json_cap(uint64_t n);
/* An engine of a scene configuration on a backend, with the limits of the settings: threads,
 * max_rocks and max_state_mb (through scene_cost with cost_ctx, the sink's ops). NULL with the
 * status in *st and the reason in err. */
cs_sim *scene_engine_new(const scene_config *cfg, const clothd_settings *set, const char *backend, void *cost_ctx,
                         cs_status *st, char *err, size_t err_len);

/* ---- the sim thread's ---- */

void scene_set_wake(scene *sc, void (*wake)(void *ctx), void *ctx);
/* Takes every queued command, in order (a list through ->next). */
scene_cmd *scene_take_queue(scene *sc);
/* Refuses commands from now on (503 at once); those already queued stay for the sim thread. */
void scene_close(scene *sc);
/* Answers what is still queued with 503 (once the sim thread has stopped). */
void scene_refuse_queued(scene *sc);
/* The scene left the table (any thread): commands are refused from now on (404), and what is still
 * queued, the sim thread answers so with scene_drop_deleted. */
void scene_mark_deleted(scene *sc);
/* Whether it left the table (any thread). */
int scene_is_deleted(scene *sc);
/* The sim thread's last look at a deleted scene: its sinks are told it is gone (each in turn) and
 * handed nothing more, a step in progress ends ("deleted"), what is queued is refused (404). */
void scene_drop_deleted(scene *sc);

/* The scene's fields, the engine's parameters and the daemon-loop settings as they are now. */
void scene_config_of(const scene *sc, scene_config *out);
/* Publishes the reads, the pose (when a sink wants one) and torn springs' events; with_hash
 * adds the state hash to GET /v1/sim's JSON. */
void scene_publish(scene *sc, int with_hash);
/* Sends an event to the sinks: ev gets "type": "event" and the request id (stolen). */
void scene_emit(scene *sc, json_t *ev, const char *request_id);
/* Replaces last_event (stolen). */
void scene_set_event(scene *sc, json_t *ev);
/* Takes a checkpoint of the state (kept in memory, for a rollback). */
void scene_take_checkpoint(scene *sc);
/* The journal starts afresh from the current state (which is also the new checkpoint). */
void scene_rebase(scene *sc);
/* Restarts the automatic drops: seeded afresh from the loop's seed, the first within a second. */
void scene_reseed(scene *sc);
/* Runs n substeps and measures them; the engine's status, with a failure dealt with: rolled back
 * to the last checkpoint and paused (instability), paused at the step limit, or the backend lost
 * (unhealthy; sc->lost is set for the sim thread to tell the daemon). */
cs_status scene_run_substeps(scene *sc, int64_t n);
/* What scene_run_substeps does after the engine ran: n substeps that took `took` seconds of
 * compute (the scene's share of a batched call) and ended with st. Returns st. */
cs_status scene_ran_substeps(scene *sc, int64_t n, cs_status st, double took);
/* The body of POST /v1/sim/step: {"frames": N} or {"substeps": N}, N from 1 to 100000. 0 with
 * *frames (1 for frames, 0 for substeps) and *n, or -1 with the problem. */
int step_from_json(const json_t *body, int *frames, long long *n, problem *pr);
/* Starts a step (c's body) as the step in progress, or refuses it (the step limit). 1 when it is
 * kept (scene_end_step answers it), 0 when refused (c failed). */
int scene_step_start(scene *sc, scene_cmd *c);
/* Ends the step in progress, if any, and answers it: how far it got, and why it stopped early
 * (interrupted_by: pause, cancel, step, command, shutdown, instability, step_limit; NULL when it
 * ran to its end), or 503 when the backend failed meanwhile. */
void scene_end_step(scene *sc, const char *interrupted_by);

/* For the state file, once the sim thread has stopped: the engine, the daemon-loop settings,
 * whether it was paused (a backend failure pauses it: then whether it was paused before), and
 * the last in-memory checkpoint (for when the engine cannot be read any more). */
cs_sim *scene_engine(scene *sc);
const loop_settings *scene_loop(const scene *sc);
int scene_paused_for_save(scene *sc);
const unsigned char *scene_last_checkpoint(const scene *sc, size_t *len);

#endif
