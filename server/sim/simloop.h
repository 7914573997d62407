/* simloop.h - the sim thread: the only owner of the engine.
 *
 * It runs the simulation continuously at time_scale (or max_speed), applies queued commands at
 * frame boundaries (at once while paused), journals each with the step it applied at, drops
 * rocks into the default scene, keeps in-memory checkpoints and rolls back to the last one when
 * the state stops being finite, and publishes what readers need (GET /v1/sim's JSON, params,
 * scene, rocks) after every frame and every command, so that readers never touch the engine and
 * never wait for it. A command's submitter is called back once it has been applied and the
 * result published, so a read that follows sees it.
 *
 * Nothing keeps the thread from its queue for long: a step (POST /v1/sim/step, up to 100000
 * frames) runs in slices of about SIMLOOP_SLICE seconds of compute, and between slices the
 * thread answers reads, publishes its progress and notices a stop; a pause, a cancel, another
 * step or any command that changes the state ends it first (its answer says how far it got).
 * While running, a frame that takes longer than SIMLOOP_RUN_SLICE is stepped in parts, so a stop
 * is noticed within that whatever runs. (Each part costs the backend a pass over the vertices to
 * finish its last substep, so parts are not made smaller than they need to be.) The queue holds
 * at most queue_max commands (503 `busy` beyond). */
#ifndef CLOTHD_SIMLOOP_H
#define CLOTHD_SIMLOOP_H

#include <jansson.h>

#include "clothsim/clothsim.h"
#include "core/journal.h"
#include "core/metrics.h"
#include "core/problem.h"
#include "core/settings.h"

typedef enum sim_cmd_kind {
    CMD_APPLY,        /* body: a command of commands.h */
    CMD_PAUSE,
    CMD_RESUME,
    CMD_STEP,         /* body: {frames: N} or {substeps: N}, while paused */
    CMD_SNAPSHOT_GET, /* blob: the snapshot */
    CMD_SNAPSHOT_PUT, /* blob_in: a snapshot to restore */
    CMD_CLOTH_STATE,  /* blob: positions then velocities; body {"binary": bool} */
    CMD_HASH,         /* blob: GET /v1/sim's JSON with the state hash of this moment */
    CMD_BUNDLE,       /* blob: the journal bundle for clothd replay */
    CMD_PUBLISH,      /* nothing but a publication (a new stream client wants a frame now) */
    CMD_STEP_CANCEL   /* ends the step in progress, if any (result {"cancelled": bool}) */
} sim_cmd_kind;

/* Seconds of compute between two looks at the queue while a step runs, and between two looks at
 * a stop while a long frame runs. */
#define SIMLOOP_SLICE 0.05
#define SIMLOOP_RUN_SLICE 0.25

typedef struct sim_cmd sim_cmd;
struct sim_cmd {
    sim_cmd_kind kind;
    json_t *body;                 /* the request (owned by the submitter) */
    char request_id[129];         /* the request's X-Request-Id, echoed in the stream's event */
    const unsigned char *blob_in; /* CMD_SNAPSHOT_PUT */
    size_t blob_in_len;
    /* results, set by the sim thread before done() */
    int failed;
    problem pr;
    json_t *result;               /* response JSON (the submitter frees it) */
    unsigned char *blob;          /* binary or preformatted response (the submitter frees it) */
    size_t blob_len;
    void (*done)(sim_cmd *cmd, void *arg);
    void *done_arg;
    sim_cmd *next;
};

typedef struct simloop simloop;
struct stream;

/* Takes the engine (the loop owns and destroys it). The state is published and journaled from
 * its current step. */
simloop *simloop_new(cs_sim *sim, const clothd_config *cfg, metrics *m);
/* What a scene costs the daemon, in bytes, with up to `rocks` rocks: the engine's part
 * (cs_scene_memory), two snapshots (the last checkpoint and the journal's base), one answer the
 * sim thread builds (the cloth state as JSON, or a snapshot), the stream's frames and their
 * encodings (stream_memory), the scalars' scratch, and the list of torn springs with its JSON.
 * The one estimate max_state_mb caps: the engine is given it (cs_sim_set_memory_limit), for
 * scene changes and snapshots, and the daemon checks its starting scene with it. ctx is unused. */
cs_status simloop_scene_cost(const cs_scene *scene, int32_t rocks, void *ctx, uint64_t *bytes);
/* Frames and events go to this stream from now on (before simloop_start). */
void simloop_attach_stream(simloop *sl, struct stream *st);
/* Calls hook before each frame is stepped, with the frames done so far (the test daemon's fault
 * injection, testhooks.h; before simloop_start). */
void simloop_set_frame_hook(simloop *sl, void (*hook)(cs_sim *sim, uint64_t frame));
int simloop_start(simloop *sl);
/* Queues a command; done() is called from the sim thread. While stopping, it fails at once. */
void simloop_submit(simloop *sl, sim_cmd *cmd);
/* Finishes the frame in progress, fails the queued commands (503), joins the thread. */
void simloop_stop(simloop *sl);
/* The engine, for the owner once the loop has stopped (state file). */
cs_sim *simloop_engine(simloop *sl);
/* Whether the simulation was paused, for the state file once the loop has stopped (a backend
 * failure pauses it: then whether it was paused before). */
int simloop_paused(simloop *sl);
/* The daemon-loop settings, for the state file once the loop has stopped. */
const loop_settings *simloop_loop(simloop *sl);
/* The last in-memory checkpoint (a snapshot), for when the engine cannot be read any more. */
const unsigned char *simloop_checkpoint(simloop *sl, size_t *len);
void simloop_free(simloop *sl);

/* Published reads (malloc'd copies). */
char *simloop_sim_json(simloop *sl, size_t *len);
char *simloop_params_json(simloop *sl, size_t *len);
char *simloop_scene_json(simloop *sl, size_t *len);
/* The ids of the torn springs (type n + v) as a JSON array. */
char *simloop_torn_json(simloop *sl, size_t *len);
/* A copy of the rocks; returns how many (the array is malloc'd, possibly NULL when none). */
int simloop_rocks(simloop *sl, cs_rock **out);
journal *simloop_journal(simloop *sl);
void simloop_gauges(simloop *sl, metrics_gauges *g);
/* 0 once the backend has failed for good (CS_E_DEVICE). */
int simloop_healthy(simloop *sl);

#endif
