/* recordings.c - the daemon's recordings (see recordings.h).
 *
 * Locks, in the order they nest: a scene's rlock (its list of running recordings), then the
 * table's lock (every recording's state, counters and queue), then a recording's dlock (its bytes,
 * in memory or the file's length: the writer appends, GET copies). The sim thread takes a scene's
 * rlock and the table's lock for the time of a copy; nobody holds either across I/O or encoding. */
#include <dirent.h>
#include <errno.h>
#include <fcntl.h>
#include <math.h>
#include <pthread.h>
#include <signal.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/mman.h>
#include <sys/stat.h>
#include <unistd.h>

#include "clothd_frame.h"
#include "core/clock.h"
#include "core/delta.h"
#include "core/json_read.h"
#include "core/json_write.h"
#include "core/log.h"
#include "core/recording.h"
#include "core/stream_msg.h"
#include "core/wire.h"
#include "sim/recordings.h"

enum { REC_RECORDING, REC_DONE, REC_STOPPED };
static const char *const state_names[] = {"recording", "done", "stopped"};
/* What a recording's estimate allows for its hello and events besides its frames. */
#define REC_TEXT_ALLOWANCE (64u << 10)

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

void recordings_set_write_hook(recordings *r, void (*hook)(void)) { r->before_write = hook; }

int recording_id_valid(const char *rid) { return scene_id_valid(rid); }

/* The recording of an id (the table's lock held): one being started too when `starting`, else
 * only those the routes see (not one a POST is still setting up, nor one being deleted). */
static recording *find_as(recordings *r, const char *rid, int starting)
{
    for (recording *k = r->list; k; k = k->next)
        if ((starting || !k->starting) && !k->deleting && strcmp(k->id, rid) == 0) return k;
    return NULL;
}
static recording *find(recordings *r, const char *rid) { return find_as(r, rid, 0); }

/* What the recordings take together: the bytes written, and for a running one at least its estimate. */
static uint64_t reserved(const recordings *r)
{
    uint64_t sum = 0;
    for (const recording *k = r->list; k; k = k->next) sum += k->state == REC_RECORDING && k->estimate > k->bytes ? k->estimate : k->bytes;
    return sum;
}

static json_t *entry_json(const recording *k)
{
    json_t *o = json_pack("{s:s, s:s, s:s, s:s, s:I, s:f, s:f, s:I, s:I, s:I, s:f}", "id", k->id, "scene", k->scene_id, "state",
                          state_names[k->state], "encoding", stream_encoding_names[k->encoding], "frames", (json_int_t)k->frames,
                          "seconds", k->frames ? k->t_last - k->t_first : 0.0, "seconds_asked", k->seconds, "bytes",
                          (json_int_t)k->bytes, "frames_dropped", (json_int_t)k->frames_dropped, "events_dropped",
                          (json_int_t)k->events_dropped, "frame_rate", k->frame_rate);
    json_object_set_new(o, "reason", k->reason[0] ? json_string(k->reason) : json_null());
    return o;
}

/* ---- the bytes ---- */

/* Appends len bytes to a recording's file or memory: 0, or -1 (errno). */
static int append(recording *k, const void *data, size_t len)
{
    pthread_mutex_lock(&k->dlock);
    int rc = 0;
    if (k->on_disk) {
        const unsigned char *p = data;
        size_t done = 0;
        while (done < len) {
            const ssize_t n = write(k->fd, p + done, len - done);
            if (n < 0 && errno == EINTR) continue;
            if (n <= 0) {
                rc = -1;
                break;
            }
            done += (size_t)n;
        }
        k->mem_len += done;
    } else {
        if (k->mem_len + len > k->mem_cap) {
            size_t cap = k->mem_cap ? k->mem_cap : 65536;
            while (cap < k->mem_len + len) cap *= 2;
            unsigned char *b = realloc(k->mem, cap);
            if (!b) {
                pthread_mutex_unlock(&k->dlock);
                errno = ENOMEM;
                return -1;
            }
            k->mem = b;
            k->mem_cap = cap;
        }
        memcpy(k->mem + k->mem_len, data, len);
        k->mem_len += len;
    }
    pthread_mutex_unlock(&k->dlock);
    return rc;
}

static void free_recording(recording *k)
{
    for (unsigned i = 0; i < k->count; i++) {
        rec_item *it = &k->items[(k->head + i) % REC_QUEUE_ITEMS];
        free(it->text);
        if (it->p) k->spare[k->n_spare++] = it->p;
    }
    for (int i = 0; i < k->n_spare; i++) {
        pose_free(k->spare[i]);
        free(k->spare[i]);
    }
    rec_index_free(&k->ix);
    if (k->enc_ready) delta_free(&k->enc);
    free(k->buf);
    free(k->mem);
    if (k->fd >= 0) close(k->fd);
    pthread_mutex_destroy(&k->dlock);
    free(k);
}

static void file_path(const recordings *r, const char *rid, char *out, size_t len)
{
    snprintf(out, len, "%s/%s.clr", r->dir, rid);
}

/* Whether recordings_dir holds a file of that id (a recording it could not read, left alone). */
static int file_exists(const recordings *r, const char *rid)
{
    if (!r->dir[0]) return 0;
    char path[SETTING_TEXT_MAX + SCENE_ID_MAX + 8];
    file_path(r, rid, path, sizeof path);
    struct stat st;
    return lstat(path, &st) == 0;
}

/* ---- the writer thread ---- */

static int grow_buf(recording *k, size_t need)
{
    if (need <= k->buf_cap) return 0;
    unsigned char *b = realloc(k->buf, need);
    if (!b) return -1;
    k->buf = b;
    k->buf_cap = need;
    return 0;
}

/* Stops a recording from the writer (the table's lock held): no more items are taken. */
static void stop_locked(recording *k, const char *reason)
{
    if (!k->reason[0]) snprintf(k->reason, sizeof k->reason, "%s", reason);
    k->ending = 1;
}

/* One record (type, payload) at the end of the file, within the cap: the bytes it took, 0 when the
 * cap or a failure stopped the recording. */
static uint64_t put_record(recordings *r, recording *k, uint32_t type, const unsigned char *payload, size_t len)
{
    const uint64_t size = rec_record_size(len);
    pthread_mutex_lock(&r->lock);
    const uint64_t after = r->total + size + rec_index_size(k->ix.n_frames + 1, k->ix.n_texts + 1);
    const int over = r->cap && after > r->cap;
    if (over) {
        stop_locked(k, "max_recordings_mb reached");
        k->capped = 1;
    }
    pthread_mutex_unlock(&r->lock);
    if (over) return 0;
    unsigned char head[REC_RECORD_HEAD], pad[4] = {0};
    rec_record_head(head, type, (uint32_t)len);
    if (append(k, head, sizeof head) != 0 || append(k, payload, len) != 0 || append(k, pad, rec_padding(len)) != 0) {
        log_msg("recording %s: write failed: %s; stopped", k->id, strerror(errno));
        pthread_mutex_lock(&r->lock);
        stop_locked(k, "write failed");
        k->capped = 1;      /* what is still queued goes unwritten */
        k->write_failed = 1; /* and no index after a record cut short: the file reads as cut */
        pthread_mutex_unlock(&r->lock);
        return 0;
    }
    return size;
}

/* Encodes a pose in the recording's encoding into k->buf: its length, 0 on failure. *key: a
 * keyframe (any encoding but delta: every frame is its own). */
static size_t encode(recordings *r, recording *k, const pose *p, int *key)
{
    *key = 1;
    if (grow_buf(k, wire_bound(p, k->encoding, SCALAR_NONE)) != 0) return 0;
    if (k->encoding != CLF_DELTA) return wire_encode(p, k->encoding, SCALAR_NONE, k->buf);
    if (!k->enc_ready) {
        if (delta_init(&k->enc, r->quantum) != 0) return 0;
        k->enc_ready = 1;
    }
    unsigned char *section = malloc(delta_bound(p->n));
    if (!section) return 0;
    /* The encoder's clock: frame_rate frames make its keyframe interval, so that a keyframe comes
     * at least every frame_rate frames (a second of sim time at the scene's rate). */
    const double fr = k->frame_rate > 0 ? k->frame_rate : 60.0;
    const uint64_t tick = (uint64_t)ceil((double)DELTA_KEY_INTERVAL_NS / fr);
    const size_t len = delta_encode(&k->enc, p->xyz, p->n, p->nx > 0 ? p->nx : p->n, p->frame, tick * k->ix.n_frames, section, key);
    const size_t out = len ? wire_encode_delta(p, SCALAR_NONE, section, len, k->buf) : 0;
    free(section);
    return out;
}

/* Writes one item of a recording (outside the table's lock). */
static void write_item(recordings *r, recording *k, rec_item *it)
{
    uint64_t at;
    pthread_mutex_lock(&k->dlock);
    at = k->mem_len;
    pthread_mutex_unlock(&k->dlock);
    if (it->kind == REC_TEXT) {
        /* In the index first (it may be full), so that no record is written that it lacks. */
        if (rec_index_add_text(&k->ix, at) != 0) {
            pthread_mutex_lock(&r->lock);
            k->events_dropped++;
            pthread_mutex_unlock(&r->lock);
            return;
        }
        const uint64_t size = put_record(r, k, REC_TEXT, (const unsigned char *)it->text, strlen(it->text));
        if (!size) k->ix.n_texts--;
        if (size) {
            pthread_mutex_lock(&r->lock);
            k->bytes += size;
            r->total += size;
            pthread_mutex_unlock(&r->lock);
        }
        return;
    }
    if (r->before_write) r->before_write();
    int key = 1;
    const size_t len = encode(r, k, it->p, &key);
    if (!len) {
        pthread_mutex_lock(&r->lock);
        k->frames_dropped++;
        pthread_mutex_unlock(&r->lock);
        return;
    }
    if (key) k->last_key = k->ix.n_frames;
    const rec_frame f = {at, it->p->sim_time, key ? k->ix.n_frames : k->last_key, k->ix.n_texts};
    if (rec_index_add_frame(&k->ix, &f) != 0) {
        pthread_mutex_lock(&r->lock);
        k->frames_dropped++;
        pthread_mutex_unlock(&r->lock);
        return;
    }
    const uint64_t size = put_record(r, k, REC_FRAME, k->buf, len);
    if (!size) {
        k->ix.n_frames--;
        return;
    }
    pthread_mutex_lock(&r->lock);
    if (k->frames == 0) k->t_first = f.sim_time;
    k->t_last = f.sim_time;
    k->frames++;
    k->bytes += size;
    r->total += size;
    pthread_mutex_unlock(&r->lock);
}

/* Writes the index and tail of a recording that ended (outside the lock); its state then. */
static void finish(recordings *r, recording *k)
{
    pthread_mutex_lock(&k->dlock);
    const uint64_t at = k->mem_len;
    pthread_mutex_unlock(&k->dlock);
    size_t len = 0;
    unsigned char *tail = k->write_failed ? NULL : rec_index_finish(&k->ix, at, &len);
    const int ok = tail && append(k, tail, len) == 0;
    free(tail);
    if (ok && k->fd >= 0 && fsync(k->fd) != 0) log_msg("recording %s: fsync: %s", k->id, strerror(errno));
    if (!ok && !k->write_failed) log_msg("recording %s: its index could not be written: %s", k->id, strerror(errno));
    pthread_mutex_lock(&r->lock);
    if (ok) {
        k->bytes += len;
        r->total += len;
    }
    k->state = k->reason[0] ? REC_STOPPED : REC_DONE;
    pthread_mutex_unlock(&r->lock);
}

/* The table's lock held: the next recording with work for the writer. */
static recording *next_work(recordings *r)
{
    for (recording *k = r->list; k; k = k->next)
        if (!k->busy && ((k->deleting && !k->sc) || k->count || (k->ending && k->state == REC_RECORDING))) return k;
    return NULL;
}

static void unlink_locked(recordings *r, recording *k)
{
    for (recording **p = &r->list; *p; p = &(*p)->next)
        if (*p == k) {
            *p = k->next;
            break;
        }
    r->count--;
    r->total -= k->bytes < r->total ? k->bytes : r->total;
}

static void *writer(void *arg)
{
    recordings *r = arg;
    sigset_t all;
    sigfillset(&all);
    pthread_sigmask(SIG_BLOCK, &all, NULL);
    pthread_mutex_lock(&r->lock);
    for (;;) {
        recording *k = next_work(r);
        if (!k) {
            if (r->stop) break;
            pthread_cond_wait(&r->work, &r->lock);
            continue;
        }
        if (k->deleting && !k->sc) { /* off its scene: nobody hands it anything more */
            unlink_locked(r, k);
            pthread_mutex_unlock(&r->lock);
            if (k->on_disk) {
                char path[SETTING_TEXT_MAX + SCENE_ID_MAX + 8];
                file_path(r, k->id, path, sizeof path);
                if (unlink(path) != 0) log_msg("recording %s: could not remove %s: %s", k->id, path, strerror(errno));
            }
            free_recording(k);
            pthread_mutex_lock(&r->lock);
            pthread_cond_broadcast(&r->freed);
            continue;
        }
        k->busy++;
        if (k->count && !k->capped) {
            rec_item it = k->items[k->head];
            k->head = (k->head + 1) % REC_QUEUE_ITEMS;
            k->count--;
            pthread_mutex_unlock(&r->lock);
            write_item(r, k, &it);
            free(it.text);
            pthread_mutex_lock(&r->lock);
            if (it.p) k->spare[k->n_spare++] = it.p;
        } else if (k->count) { /* stopped at the cap: what is still queued goes unwritten */
            rec_item it = k->items[k->head];
            k->head = (k->head + 1) % REC_QUEUE_ITEMS;
            k->count--;
            free(it.text);
            if (it.p) {
                k->spare[k->n_spare++] = it.p;
                k->frames_dropped++;
            }
        } else {
            pthread_mutex_unlock(&r->lock);
            finish(r, k);
            pthread_mutex_lock(&r->lock);
        }
        k->busy--;
        pthread_cond_broadcast(&r->freed);
    }
    pthread_mutex_unlock(&r->lock);
    return NULL;
}

/* ---- the sim thread ---- */

/* The table's lock held: queues an item (0), or -1 when the queue is full. */
static int push_locked(recording *k, rec_item it)
{
    if (k->count == REC_QUEUE_ITEMS) return -1;
    k->items[(k->head + k->count) % REC_QUEUE_ITEMS] = it;
    k->count++;
    return 0;
}

/* Detaches k from its scene (sc->rlock held) and ends it with reason (NULL: done). */
static void end_on_scene(scene *sc, recording *k, const char *reason)
{
    for (recording **p = (recording **)&sc->recs; *p; p = &(*p)->scene_next)
        if (*p == k) {
            *p = k->scene_next;
            break;
        }
    atomic_fetch_sub(&sc->n_recs, 1);
    recordings *r = k->owner;
    pthread_mutex_lock(&r->lock);
    if (reason) stop_locked(k, reason);
    k->ending = 1;
    k->sc = NULL;
    pthread_cond_signal(&r->work);
    pthread_mutex_unlock(&r->lock);
    scene_release(sc);
}

int recordings_want(scene *sc, int changed)
{
    if (atomic_load(&sc->n_recs) == 0) return 0;
    int want = 0;
    pthread_mutex_lock(&sc->rlock);
    for (recording *k = sc->recs; k && !want; k = k->scene_next) want = changed || !k->have_first;
    pthread_mutex_unlock(&sc->rlock);
    return want;
}

int recordings_room(scene *sc)
{
    if (atomic_load(&sc->n_recs) == 0) return 1;
    int room = 1;
    pthread_mutex_lock(&sc->rlock);
    for (recording *k = sc->recs; k && room; k = k->scene_next) {
        recordings *r = k->owner;
        pthread_mutex_lock(&r->lock);
        /* a pose buffer and two items (its hello or an event, and the frame); one that is ending
         * takes nothing more */
        room = k->ending || ((k->n_spare > 0 || k->n_poses < REC_QUEUE_FRAMES) && k->count + 2 <= REC_QUEUE_ITEMS);
        pthread_mutex_unlock(&r->lock);
    }
    pthread_mutex_unlock(&sc->rlock);
    return room;
}

static char *hello_of(scene *sc, recording *k, const cs_rock *rocks, int n_rocks)
{
    json_t *h = scene_hello(sc, rocks, n_rocks);
    if (!h) return NULL;
    json_object_set_new(h, "recording",
                        json_pack("{s:s, s:s, s:s, s:f, s:I, s:f}", "id", k->id, "scene", k->scene_id, "encoding",
                                  stream_encoding_names[k->encoding], "seconds", k->seconds, "started_ns",
                                  (json_int_t)k->started_ns, "frame_rate", k->frame_rate));
    char *text = json_dumps(h, JSON_DUMP_FLAGS);
    json_decref(h);
    return text;
}

/* Copies p's positions and rocks (no scalars) into dst: 0, or -1 (out of memory). */
static int copy_pose(pose *dst, const pose *p)
{
    if (pose_reserve(dst, p->n, p->n_rocks) != 0) return -1;
    dst->frame = p->frame;
    dst->step = p->step;
    dst->wall_ns = p->wall_ns;
    dst->sim_time = p->sim_time;
    dst->n = p->n;
    dst->n_rocks = p->n_rocks;
    dst->nx = p->nx;
    memcpy(dst->xyz, p->xyz, sizeof(float) * 3 * (size_t)p->n);
    memcpy(dst->bbox, p->bbox, sizeof dst->bbox);
    if (p->n_rocks) memcpy(dst->rocks, p->rocks, sizeof *dst->rocks * (size_t)p->n_rocks);
    for (int s = 0; s < SCALAR_KINDS; s++) dst->has[s] = 0;
    return 0;
}

/* One of k's pose buffers for the sim thread: a spare one, or a new one while it has fewer than
 * REC_QUEUE_FRAMES; NULL when all are waiting for the writer. */
static pose *take_buffer(recording *k)
{
    recordings *r = k->owner;
    pthread_mutex_lock(&r->lock);
    pose *buf = k->n_spare ? k->spare[--k->n_spare] : NULL;
    const int grow = !buf && k->n_poses < REC_QUEUE_FRAMES;
    if (grow) k->n_poses++;
    pthread_mutex_unlock(&r->lock);
    if (!grow) return buf;
    buf = calloc(1, sizeof *buf);
    if (!buf) {
        pthread_mutex_lock(&r->lock);
        k->n_poses--;
        pthread_mutex_unlock(&r->lock);
    }
    return buf;
}

void recordings_frame(scene *sc, const pose *p, const cs_rock *rocks, int n_rocks, int changed)
{
    if (atomic_load(&sc->n_recs) == 0) return;
    pthread_mutex_lock(&sc->rlock);
    for (recording *k = sc->recs, *next; k; k = next) {
        next = k->scene_next;
        if (k->have_first && !changed) continue; /* it has this pose */
        recordings *r = k->owner;
        pthread_mutex_lock(&r->lock);
        const int ended = k->ending; /* the writer stopped it (the cap, a failed write) */
        pthread_mutex_unlock(&r->lock);
        if (ended) {
            end_on_scene(sc, k, NULL);
            continue;
        }
        if (k->have_first && p->n != k->n_first) { /* a file holds frames of one vertex count */
            end_on_scene(sc, k, "scene changed");
            continue;
        }
        if (k->need_hello) {
            char *hello = hello_of(sc, k, rocks, n_rocks);
            if (!hello) continue; /* out of memory: the next pose tries again */
            pthread_mutex_lock(&r->lock);
            const int pushed = push_locked(k, (rec_item){REC_TEXT, hello, NULL}) == 0;
            pthread_mutex_unlock(&r->lock);
            if (!pushed) {
                free(hello);
                continue;
            }
            k->need_hello = 0;
        }
        pose *buf = take_buffer(k);
        const int copied = buf && copy_pose(buf, p) == 0;
        pthread_mutex_lock(&r->lock);
        const int queued = copied && push_locked(k, (rec_item){REC_FRAME, NULL, buf}) == 0;
        if (buf && !queued) k->spare[k->n_spare++] = buf;
        if (!queued) k->frames_dropped++;
        pthread_cond_signal(&r->work);
        pthread_mutex_unlock(&r->lock);
        if (!k->have_first) {
            k->have_first = 1;
            k->sim_first = p->sim_time;
            k->n_first = p->n;
        }
        /* Its length reached: the first frame `seconds` past the first (a quarter frame's leeway
         * for the sim clock's rounding). */
        const double leeway = 0.25 / (k->frame_rate > 0 ? k->frame_rate : 60.0);
        if (p->sim_time - k->sim_first >= k->seconds - leeway) end_on_scene(sc, k, NULL);
    }
    pthread_mutex_unlock(&sc->rlock);
}

void recordings_event(scene *sc, const char *text)
{
    if (atomic_load(&sc->n_recs) == 0) return;
    pthread_mutex_lock(&sc->rlock);
    for (recording *k = sc->recs; k; k = k->scene_next) {
        if (k->need_hello) continue; /* its hello, made after, shows what this event did */
        char *copy = strdup(text);
        recordings *r = k->owner;
        pthread_mutex_lock(&r->lock);
        if (!copy || push_locked(k, (rec_item){REC_TEXT, copy, NULL}) != 0) {
            free(copy);
            k->events_dropped++;
        }
        pthread_cond_signal(&r->work);
        pthread_mutex_unlock(&r->lock);
    }
    pthread_mutex_unlock(&sc->rlock);
}

void recordings_scene_gone(scene *sc)
{
    pthread_mutex_lock(&sc->rlock);
    sc->recs_closed = 1;
    while (sc->recs) end_on_scene(sc, sc->recs, "scene deleted");
    pthread_mutex_unlock(&sc->rlock);
}

/* ---- HTTP threads ---- */

/* Positions bytes a vertex that meshopt and delta frames typically take on a moving cloth (the
 * default scene with rocks falling: 4.2-4.5 and 1.6, docs/performance.md "The stream"); a cloth
 * at rest takes far less, and a recording that outgrows its estimate stops at the cap with its file whole. */
#define REC_MESHOPT_TYPICAL 4.5
#define REC_DELTA_TYPICAL 1.75

/* A frame's bytes in an encoding, for the estimate: f32 and q16 exactly, meshopt and delta as
 * typical (above). */
static uint64_t frame_estimate(int encoding, int32_t n, int32_t rocks)
{
    pose f = {.n = n, .n_rocks = rocks};
    const int as = encoding == CLF_F32 ? CLF_F32 : CLF_Q16;
    uint64_t bytes = wire_bound(&f, as, SCALAR_NONE);
    if (encoding == CLF_MESHOPT || encoding == CLF_DELTA) /* the q16 positions, as typical instead */
        bytes = bytes - 6 * (uint64_t)n + (uint64_t)((encoding == CLF_DELTA ? REC_DELTA_TYPICAL : REC_MESHOPT_TYPICAL) * n);
    return rec_record_size(bytes) + REC_INDEX_FRAME;
}

/* A number member of a published JSON text. */
static double doc_number(scene *sc, scene_doc doc, const char *name)
{
    size_t len = 0;
    char *text = scene_doc_copy(sc, doc, &len);
    json_t *j = text ? json_loadb(text, len, 0, NULL) : NULL;
    free(text);
    const double v = json_number_value(json_object_get(j, name));
    json_decref(j);
    return v;
}

int recordings_start(recordings *r, scene *sc, const json_t *body, json_t **answer, char *rid, problem *pr)
{
    static const char *const fields[] = {"seconds", "encoding", "id", NULL};
    *answer = NULL;
    if (only_fields(body, fields, pr) != 0) return -1;
    const json_t *js = json_object_get(body, "seconds"), *je = json_object_get(body, "encoding"), *ji = json_object_get(body, "id");
    if (!js) return problem_set(pr, 400, "wrong-type", "seconds", "seconds (of simulated time to record) is required");
    if (!json_is_number(js)) return problem_set(pr, 400, "wrong-type", "seconds", "seconds must be a number, not %s", json_type_word(js));
    const double seconds = json_number_value(js);
    if (!isfinite(seconds) || seconds <= 0 || seconds > REC_MAX_SECONDS)
        return problem_set(pr, 422, "out-of-range", "seconds", "seconds must be above 0 and at most %g", REC_MAX_SECONDS);
    int encoding = CLF_DELTA;
    if (je && !json_is_string(je)) return problem_set(pr, 400, "wrong-type", "encoding", "encoding must be a string, not %s", json_type_word(je));
    if (je) {
        encoding = -1;
        for (int e = 0; e < STREAM_ENCODINGS; e++)
            if (strcmp(json_string_value(je), stream_encoding_names[e]) == 0) encoding = e;
        if (encoding < 0) return problem_set(pr, 422, "out-of-range", "encoding", "encoding must be f32, q16, meshopt or delta, not '%.40s'", json_string_value(je));
    }
    if (ji && !json_is_string(ji)) return problem_set(pr, 400, "wrong-type", "id", "id must be a string, not %s", json_type_word(ji));
    if (ji && !recording_id_valid(json_string_value(ji)))
        return problem_set(pr, 400, "bad-recording-id", "id",
                           "a recording id is 1 to 63 characters of a-z, 0-9, '_' and '-', starting with a letter or digit");
    const double frame_rate = doc_number(sc, DOC_PARAMS, "frame_rate");
    const int32_t n = (int32_t)doc_number(sc, DOC_SIM, "n_vertices"), rocks = (int32_t)doc_number(sc, DOC_SIM, "n_rocks");
    const double frames = ceil(seconds * (frame_rate > 0 ? frame_rate : 60.0)) + 1;
    /* and, while it runs, its working memory: its pose buffers, its encoder (36 bytes a vertex for
     * delta's grids and planes) and encoding buffers (about 24 bytes a vertex) */
    const uint64_t working = REC_QUEUE_FRAMES * (12 * (uint64_t)n + sizeof(pose_rock) * (uint64_t)rocks) + 60 * (uint64_t)n;
    const uint64_t estimate = REC_HEADER_SIZE + REC_TEXT_ALLOWANCE + (uint64_t)frames * frame_estimate(encoding, n, rocks) +
                              rec_index_size(0, 0) + working;

    recording *k = calloc(1, sizeof *k);
    if (!k) return problem_set(pr, 500, "internal", NULL, "out of memory");
    k->owner = r;
    k->encoding = encoding;
    k->seconds = seconds;
    k->frame_rate = frame_rate;
    k->started_ns = clock_wall_ns();
    k->estimate = estimate;
    k->fd = -1;
    k->need_hello = 1;
    snprintf(k->scene_id, sizeof k->scene_id, "%s", sc->id);
    pthread_mutex_init(&k->dlock, NULL);

    pthread_mutex_lock(&r->lock);
    int bad = 0;
    if (ji) snprintf(k->id, sizeof k->id, "%s", json_string_value(ji));
    else
        do snprintf(k->id, sizeof k->id, "rec-%llu", (unsigned long long)++r->next_auto);
        while (find_as(r, k->id, 1) || file_exists(r, k->id));
    if (find_as(r, k->id, 1)) bad = problem_set(pr, 409, "exists", "id", "a recording '%s' exists already", k->id);
    else if (r->count >= RECORDINGS_MAX)
        bad = problem_set(pr, 422, "limit", "max_recordings", "clothd holds at most %d recordings: delete one first", RECORDINGS_MAX);
    else if (r->cap && reserved(r) + estimate > r->cap)
        bad = problem_set(pr, 422, "limit", "max_recordings_mb",
                          "this recording would take about %.1f MiB and max_recordings_mb leaves %.1f MiB: record fewer seconds, "
                          "another encoding, or delete recordings",
                          (double)estimate / 1048576.0, (double)(r->cap - (reserved(r) < r->cap ? reserved(r) : r->cap)) / 1048576.0);
    if (!bad) { /* in the list (its id taken) but nothing to write yet: the writer leaves it be */
        k->starting = 1;
        k->next = r->list;
        r->list = k;
        r->count++;
    }
    pthread_mutex_unlock(&r->lock);
    if (bad) {
        free_recording(k);
        return -1;
    }
    /* Its file, with the header; in memory the header too. */
    unsigned char head[REC_HEADER_SIZE];
    rec_file_header(head);
    int failed = 0;
    if (r->dir[0]) {
        char path[SETTING_TEXT_MAX + SCENE_ID_MAX + 8];
        file_path(r, k->id, path, sizeof path);
        k->on_disk = 1;
        k->fd = open(path, O_WRONLY | O_CREAT | O_EXCL | O_CLOEXEC | O_NOFOLLOW, 0644);
        if (k->fd < 0 && errno == EEXIST) { /* a file it did not list (not a recording it can read) */
            problem_set(pr, 409, "exists", "id", "recordings_dir holds a file %s.clr already that is no recording of this clothd's list", k->id);
            failed = 1;
            k->on_disk = 0; /* not its own: left alone */
        } else if (k->fd < 0) {
            problem_set(pr, 500, "internal", NULL, "could not create %s: %s", path, strerror(errno));
            failed = 1;
            k->on_disk = 0;
        }
    }
    if (!failed && append(k, head, sizeof head) != 0) {
        problem_set(pr, 500, "internal", NULL, "could not write the recording: %s", strerror(errno));
        failed = 1;
    }
    /* On its scene, unless the scene left meanwhile. */
    if (!failed) {
        pthread_mutex_lock(&sc->rlock);
        if (sc->recs_closed || scene_is_deleted(sc)) {
            problem_set(pr, 404, "not-found", "scene", "no scene '%s'", sc->id);
            failed = 1;
        } else {
            k->sc = scene_hold(sc);
            k->scene_next = sc->recs;
            sc->recs = k;
            atomic_fetch_add(&sc->n_recs, 1);
        }
        pthread_mutex_unlock(&sc->rlock);
    }
    pthread_mutex_lock(&r->lock);
    k->starting = 0;
    if (failed) {
        k->deleting = 1; /* the writer removes it (and its file) */
        pthread_cond_signal(&r->work);
    } else {
        k->bytes = REC_HEADER_SIZE;
        r->total += REC_HEADER_SIZE;
        *answer = entry_json(k);
        snprintf(rid, SCENE_ID_MAX, "%s", k->id);
    }
    pthread_mutex_unlock(&r->lock);
    return failed ? -1 : 0;
}

json_t *recordings_list(recordings *r)
{
    json_t *list = json_array();
    pthread_mutex_lock(&r->lock);
    for (const recording *k = r->list; k; k = k->next)
        if (!k->deleting && !k->starting) json_array_append_new(list, entry_json(k));
    const uint64_t total = r->total, cap = r->cap;
    pthread_mutex_unlock(&r->lock);
    return json_pack("{s:o, s:i, s:f, s:f}", "recordings", list, "max_recordings", RECORDINGS_MAX, "recordings_mb",
                     (double)total / 1048576.0, "max_recordings_mb", (double)cap / 1048576.0);
}

static int not_found(const char *rid, problem *pr)
{
    return problem_set(pr, 404, "not-found", "id", "no recording '%.64s' (GET /v1/recordings lists them)", rid);
}

/* A copy on its way to a client: what it counts in r->copies until it is handed back. */
typedef struct rec_copy {
    recordings *r;
    size_t len;
    unsigned char *bytes;
} rec_copy;

void recordings_release(void *copy)
{
    rec_copy *c = copy;
    if (!c) return;
    pthread_mutex_lock(&c->r->lock);
    c->r->copies -= c->len;
    pthread_mutex_unlock(&c->r->lock);
    free(c->bytes);
    free(c);
}

int recordings_bytes(recordings *r, const char *rid, unsigned char **out, size_t *len, void **copy, problem *pr)
{
    *out = NULL;
    *len = 0;
    *copy = NULL;
    rec_copy *c = calloc(1, sizeof *c);
    if (!c) return problem_set(pr, 500, "internal", NULL, "out of memory");
    c->r = r;
    pthread_mutex_lock(&r->lock);
    recording *k = recording_id_valid(rid) ? find(r, rid) : NULL;
    if (!k) {
        pthread_mutex_unlock(&r->lock);
        free(c);
        return not_found(rid, pr);
    }
    /* Copies being sent take at most max_recordings_mb besides the recordings (a slow client holds
     * its copy until it has read it). */
    if (r->cap && r->copies + k->bytes > r->cap && r->copies > 0) {
        pthread_mutex_unlock(&r->lock);
        free(c);
        return problem_set(pr, 503, "busy", NULL, "downloads of recordings take max_recordings_mb already: try again");
    }
    k->busy++; /* the writer leaves it (and DELETE waits) while it is copied */
    pthread_mutex_unlock(&r->lock);
    int rc = 0;
    pthread_mutex_lock(&k->dlock);
    const size_t n = k->mem_len;
    unsigned char *b = malloc(n ? n : 1);
    if (!b) {
        rc = problem_set(pr, 500, "internal", NULL, "out of memory");
    } else if (!k->on_disk) {
        memcpy(b, k->mem, n);
    } else {
        char path[SETTING_TEXT_MAX + SCENE_ID_MAX + 8];
        file_path(r, k->id, path, sizeof path);
        const int fd = open(path, O_RDONLY | O_CLOEXEC | O_NOFOLLOW);
        size_t got = 0;
        while (fd >= 0 && got < n) {
            const ssize_t m = pread(fd, b + got, n - got, (off_t)got);
            if (m < 0 && errno == EINTR) continue;
            if (m <= 0) break;
            got += (size_t)m;
        }
        if (fd >= 0) close(fd);
        if (got != n) {
            free(b);
            b = NULL;
            rc = problem_set(pr, 500, "internal", NULL, "could not read %s", path);
        }
    }
    pthread_mutex_unlock(&k->dlock);
    pthread_mutex_lock(&r->lock);
    k->busy--;
    if (!rc) r->copies += n;
    pthread_cond_broadcast(&r->work);
    pthread_mutex_unlock(&r->lock);
    if (rc) {
        free(c);
        return rc;
    }
    c->bytes = b;
    c->len = n;
    *out = b;
    *len = n;
    *copy = c;
    return 0;
}

int recordings_delete(recordings *r, const char *rid, problem *pr)
{
    pthread_mutex_lock(&r->lock);
    recording *k = recording_id_valid(rid) ? find(r, rid) : NULL;
    if (!k) {
        pthread_mutex_unlock(&r->lock);
        return not_found(rid, pr);
    }
    scene *sc = k->sc ? scene_hold(k->sc) : NULL;
    k->deleting = 1; /* hidden from now on; its id stays taken until it is gone */
    pthread_mutex_unlock(&r->lock);
    if (sc) { /* off its scene first: the sim thread hands it nothing more */
        pthread_mutex_lock(&sc->rlock);
        for (recording *o = sc->recs; o; o = o->scene_next)
            if (o == k) {
                end_on_scene(sc, k, "deleted");
                break;
            }
        pthread_mutex_unlock(&sc->rlock);
        scene_release(sc);
    }
    pthread_mutex_lock(&r->lock);
    pthread_cond_signal(&r->work);
    for (;;) { /* the writer frees it (it may be writing an item of it now) */
        int there = 0;
        for (recording *o = r->list; o && !there; o = o->next) there = o == k;
        if (!there) break;
        pthread_cond_wait(&r->freed, &r->lock);
    }
    pthread_mutex_unlock(&r->lock);
    return 0;
}

/* ---- start and stop ---- */

/* A .clr file of recordings_dir as a listed recording: done when it has its tail, else stopped
 * ("cut"). 0, or -1 when it is not a recording (logged, left alone). */
static int adopt(recordings *r, const char *rid)
{
    char path[SETTING_TEXT_MAX + SCENE_ID_MAX + 8];
    file_path(r, rid, path, sizeof path);
    const int fd = open(path, O_RDONLY | O_CLOEXEC | O_NOFOLLOW);
    struct stat st;
    if (fd < 0 || fstat(fd, &st) != 0 || !S_ISREG(st.st_mode) || st.st_size <= 0) {
        if (fd >= 0) close(fd);
        log_msg("recordings: %s cannot be read; left alone", path);
        return -1;
    }
    const size_t len = (size_t)st.st_size;
    void *map = mmap(NULL, len, PROT_READ, MAP_PRIVATE, fd, 0);
    close(fd);
    if (map == MAP_FAILED) return -1;
    rec_file f;
    const int rc = rec_read(map, len, &f);
    munmap(map, len);
    if (rc != 0) {
        log_msg("recordings: %s is not a recording clothd can read: %s; left alone", path, f.error);
        return -1;
    }
    recording *k = calloc(1, sizeof *k);
    if (!k) {
        rec_file_free(&f);
        return -1;
    }
    const json_t *m = json_object_get(f.hello, "recording");
    k->owner = r;
    k->on_disk = 1; /* GET reads it, DELETE unlinks it; nothing writes to it */
    k->fd = -1;
    snprintf(k->id, sizeof k->id, "%s", rid);
    snprintf(k->scene_id, sizeof k->scene_id, "%s", json_string_value(json_object_get(m, "scene")) ? json_string_value(json_object_get(m, "scene")) : "");
    k->encoding = f.encoding >= 0 ? f.encoding : CLF_DELTA;
    k->seconds = json_number_value(json_object_get(m, "seconds"));
    k->frame_rate = json_number_value(json_object_get(m, "frame_rate"));
    k->started_ns = (uint64_t)json_integer_value(json_object_get(m, "started_ns"));
    /* Finished: done when its frames span what was asked (a quarter frame's leeway, as when it
     * ran), else it was stopped (the file does not say why). */
    const double span = f.ix.n_frames ? f.ix.frames[f.ix.n_frames - 1].sim_time - f.ix.frames[0].sim_time : 0;
    const int whole = span >= k->seconds - 0.25 / (k->frame_rate > 0 ? k->frame_rate : 60.0);
    k->state = f.complete && whole ? REC_DONE : REC_STOPPED;
    if (k->state == REC_STOPPED) snprintf(k->reason, sizeof k->reason, "%s", f.complete ? "ended early" : "cut");
    k->frames = f.ix.n_frames;
    if (f.ix.n_frames) {
        k->t_first = f.ix.frames[0].sim_time;
        k->t_last = f.ix.frames[f.ix.n_frames - 1].sim_time;
    }
    k->bytes = len;
    k->mem_len = len;
    pthread_mutex_init(&k->dlock, NULL);
    rec_file_free(&f);
    k->next = r->list;
    r->list = k;
    r->count++;
    r->total += len;
    return 0;
}

static int list_dir(recordings *r, char *err, size_t err_len)
{
    DIR *d = opendir(r->dir);
    if (!d) {
        snprintf(err, err_len, "recordings_dir %s: %s", r->dir, strerror(errno));
        return -1;
    }
    struct dirent *e;
    int n = 0;
    while ((e = readdir(d)) != NULL) {
        const size_t len = strlen(e->d_name);
        if (len < 5 || strcmp(e->d_name + len - 4, ".clr") != 0 || len - 4 >= SCENE_ID_MAX) continue;
        char rid[SCENE_ID_MAX];
        snprintf(rid, sizeof rid, "%.*s", (int)(len - 4), e->d_name);
        if (!recording_id_valid(rid)) continue;
        if (r->count >= RECORDINGS_MAX) {
            log_msg("recordings: more than %d files in %s; %s and others are not listed", RECORDINGS_MAX, r->dir, e->d_name);
            break;
        }
        if (adopt(r, rid) == 0) n++;
    }
    closedir(d);
    if (n) log_msg("recordings: %d in %s (%.1f MiB)", n, r->dir, (double)r->total / 1048576.0);
    return 0;
}

recordings *recordings_new(const clothd_settings *set, char *err, size_t err_len)
{
    recordings *r = calloc(1, sizeof *r);
    if (!r) {
        snprintf(err, err_len, "out of memory");
        return NULL;
    }
    pthread_mutex_init(&r->lock, NULL);
    pthread_cond_init(&r->work, NULL);
    pthread_cond_init(&r->freed, NULL);
    r->cap = (uint64_t)set->max_recordings_mb << 20;
    r->quantum = set->stream_delta_quantum;
    snprintf(r->dir, sizeof r->dir, "%s", set->recordings_dir);
    if (r->dir[0] && list_dir(r, err, err_len) != 0) {
        recordings_free(r);
        return NULL;
    }
    if (pthread_create(&r->writer, NULL, writer, r) != 0) {
        snprintf(err, err_len, "could not start the recordings' writer thread");
        recordings_free(r);
        return NULL;
    }
    r->writer_started = 1;
    return r;
}

void recordings_free(recordings *r)
{
    if (!r) return;
    /* Running ones stop: off their scenes (the sim thread has stopped), then the writer ends them. */
    for (;;) {
        pthread_mutex_lock(&r->lock);
        recording *k = r->list;
        while (k && !k->sc) k = k->next;
        scene *sc = k ? scene_hold(k->sc) : NULL;
        pthread_mutex_unlock(&r->lock);
        if (!sc) break;
        pthread_mutex_lock(&sc->rlock);
        end_on_scene(sc, k, "shutdown");
        pthread_mutex_unlock(&sc->rlock);
        scene_release(sc);
    }
    pthread_mutex_lock(&r->lock);
    r->stop = 1;
    pthread_cond_broadcast(&r->work);
    pthread_mutex_unlock(&r->lock);
    if (r->writer_started) pthread_join(r->writer, NULL);
    for (recording *k = r->list, *next; k; k = next) {
        next = k->next;
        free_recording(k);
    }
    pthread_mutex_destroy(&r->lock);
    pthread_cond_destroy(&r->work);
    pthread_cond_destroy(&r->freed);
    free(r);
}
