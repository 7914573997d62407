/* recordings.h - the daemon's recordings (PROTOCOL.md, "Recordings"): every frame a scene
 * publishes, in one encoding, and its events, written as a CLR1 file (core/recording.h), in memory
 * or in recordings_dir.
 *
 * Threads. HTTP threads start, list, read and delete recordings (under the table's lock). The sim
 * thread hands each running recording of a scene every pose the scene publishes and every event
 * it emits, through the recordings' sink (sim/sink.h), which a recording's start adds to its
 * scene: a copy of the pose into one of the recording's REC_QUEUE_FRAMES buffers and an item in
 * its bounded queue, never waiting - with no free buffer the frame is dropped and counted
 * (frames_dropped). The recordings' own writer thread encodes
 * each frame (core/wire.c, core/delta.c) and appends it to the file, strictly sequentially, and
 * writes the index and tail when the recording ends. The sim thread decides when one ends: the
 * first frame `seconds` of sim time past its first, the scene deleted, the daemon stopping.
 *
 * Limits: at most RECORDINGS_MAX recordings held (any state), max_recordings_mb of files in all
 * (a start is refused when its estimate does not fit; one that reaches the cap stops). */
#ifndef CLOTHD_RECORDINGS_H
#define CLOTHD_RECORDINGS_H

#include <stddef.h>
#include <stdint.h>

#include <jansson.h>

#include "core/pose.h"
#include "core/problem.h"
#include "core/settings.h"
#include "sim/rectap.h"
#include "sim/scene.h"

/* Recordings held at once, whatever their state (POST is 422 beyond: delete one). */
#define RECORDINGS_MAX 64
/* Frames waiting for the writer per recording (each a pose buffer), and events. */
#define REC_QUEUE_FRAMES 16
#define REC_QUEUE_ITEMS 256
/* The longest recording, in seconds of sim time. */
#define REC_MAX_SECONDS 3600.0

typedef struct recordings recordings;

/* The recordings of a daemon (set: max_recordings_mb, recordings_dir, stream_delta_quantum):
 * lists the .clr files already in recordings_dir and starts the writer thread. NULL with the reason
 * in err. */
recordings *recordings_new(const clothd_settings *set, char *err, size_t err_len);
/* The daemon stops (after the sim thread): running recordings stop ("shutdown") and get their
 * index and tail; the writer thread ends. Then frees everything. */
void recordings_free(recordings *r);

/* The test daemon's hook (testhooks.h): called by the writer thread before it writes each frame. */
void recordings_set_write_hook(recordings *r, void (*hook)(void));

/* ---- HTTP threads ---- */

/* POST /v1/scenes/{id}/recordings: checks the body ({seconds, encoding?, id?}) and the limits,
 * and starts a recording of sc: 0 with *answer (201's JSON) and its id in rid (SCENE_ID_MAX
 * bytes), or -1 with the problem, and nothing started. The caller has the scene publish (a paused
 * one publishes only after a command). */
int recordings_start(recordings *r, scene *sc, const json_t *body, json_t **answer, char *rid, problem *pr);
/* GET /v1/recordings's JSON. */
json_t *recordings_list(recordings *r);
/* A copy of the bytes of a recording so far (*out, *len), to be handed back with
 * recordings_release(*copy) once sent: 0, or -1 with the problem (404; 503 busy while copies being
 * sent already take max_recordings_mb). */
int recordings_bytes(recordings *r, const char *rid, unsigned char **out, size_t *len, void **copy, problem *pr);
void recordings_release(void *copy);
/* Deletes one (a running one stops first): 0, or -1 with the problem (404). */
int recordings_delete(recordings *r, const char *rid, problem *pr);
/* Whether rid is a recording id (a scene id's shape). */
int recording_id_valid(const char *rid);

/* The sim thread's side: the recordings' sink on each scene recorded (sim/sink.h), and what
 * simloop.c asks between frames (sim/rectap.h). */

#endif
