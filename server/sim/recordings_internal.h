/* recordings_internal.h - what the recordings' files share (not for use outside server/sim/'s
 * recordings): a recording, the daemon's table of them, and the functions one file calls in
 * another. recordings.c says which locks there are and in what order they nest.
 *
 *   recordings.c   the table and its API (POST, GET, DELETE, the list), a recording's bytes (in
 *                  memory or its file), start and stop
 *   rec_writer.c   the writer thread: each queued item encoded and appended, the index and tail
 *   rec_tap.c      the sim thread's side: the recordings' sink (sim/sink.h), which queues a
 *                  scene's poses and events to its running recordings, rectap.h, and where a
 *                  recording ends
 *   rec_adopt.c    the .clr files recordings_dir holds at start, listed as recordings
 *
 * It declares `recordings` itself rather than include recordings.h (which the files include beside
 * it): a header of the recordings module that included this one back would be an include cycle. */
#ifndef CLOTHD_RECORDINGS_INTERNAL_H
#define CLOTHD_RECORDINGS_INTERNAL_H

#include <pthread.h>
#include <stddef.h>
#include <stdint.h>

#include "core/delta.h"
#include "core/pose.h"
#include "core/recording.h"
#include "core/settings.h"
#include "sim/scene.h"

typedef struct recordings recordings;

enum { REC_RECORDING, REC_DONE, REC_STOPPED };

typedef struct rec_item {
    int kind;    /* REC_TEXT or REC_FRAME */
    char *text;  /* REC_TEXT (malloc'd) */
    pose *p;     /* REC_FRAME: one of the recording's buffers */
} rec_item;

typedef struct recording recording;
struct recording {
    recordings *owner;
    char id[SCENE_ID_MAX], scene_id[SCENE_ID_MAX];
    int encoding;
    double seconds, frame_rate;
    uint64_t started_ns, estimate;

    /* the table's lock */
    int state;
    char reason[64];
    int ending;            /* no more items come: the writer ends it once its queue is empty */
    int deleting;          /* DELETE: the writer frees it */
    int starting;          /* POST is setting it up: its id is taken, the routes do not see it yet */
    int busy;              /* the writer works on it outside the lock, or GET copies it */
    int capped;            /* stopped at max_recordings_mb: what is still queued goes unwritten */
    int write_failed;      /* a write failed: no index is written after it */
    uint64_t frames, frames_dropped, events_dropped, bytes;
    double t_first, t_last; /* sim times of the first and last frames written */
    rec_item items[REC_QUEUE_ITEMS];
    unsigned head, count;
    pose *spare[REC_QUEUE_FRAMES];
    int n_spare, n_poses;
    scene *sc;             /* held while it runs on the scene (in sc's list) */
    recording *next;       /* the table's list */

    /* the sim thread's (under sc->rlock) */
    recording *scene_next;
    int need_hello;
    int have_first;
    double sim_first;
    int32_t n_first;

    /* the writer's */
    rec_index ix;
    delta_enc enc;
    int enc_ready;
    unsigned char *buf;
    size_t buf_cap;
    uint32_t last_key;

    /* the bytes (dlock) */
    pthread_mutex_t dlock;
    int on_disk;           /* in recordings_dir (<dir>/<id>.clr), else in memory */
    int fd;                /* on disk and written to: its file, else -1 */
    unsigned char *mem;    /* in memory */
    size_t mem_len, mem_cap;
};

struct recordings {
    pthread_mutex_t lock;
    pthread_cond_t work, freed;
    recording *list;
    int count, stop;
    uint64_t cap, total; /* max_recordings_mb, and the bytes of every recording */
    uint64_t copies;     /* bytes of the copies being sent to clients */
    uint64_t next_auto;
    char dir[SETTING_TEXT_MAX];
    double quantum;
    pthread_t writer;
    int writer_started;
    void (*before_write)(void); /* the test daemon's hook, or NULL */
};

/* recordings.c */
/* Appends len bytes to a recording's file or memory: 0, or -1 (errno). */
int recording_append(recording *k, const void *data, size_t len);
void recording_free(recording *k);
/* <recordings_dir>/<rid>.clr */
void recordings_file_path(const recordings *r, const char *rid, char *out, size_t len);

/* rec_writer.c */
/* The writer thread (arg: the table). */
void *recordings_writer(void *arg);
/* Stops a recording (the table's lock held): no more items are taken. */
void recording_stop_locked(recording *k, const char *reason);

/* rec_tap.c */
/* Detaches k from its scene (sc->rlock held) and ends it with reason (NULL: done). */
void recording_end_on_scene(scene *sc, recording *k, const char *reason);
/* Adds the recordings' sink to the scene (scene_add_sink; once, whatever the recordings on it): 0,
 * or -1 when the scene takes no more sinks. */
int recordings_attach(scene *sc);

/* rec_adopt.c */
/* Lists the .clr files of recordings_dir as recordings: 0, or -1 and the reason in err when the
 * directory cannot be read. */
int recordings_adopt_dir(recordings *r, char *err, size_t err_len);

#endif
