/* recordings.c - the daemon's recordings (see recordings.h).
 *
 * Locks, in the order they nest: a scene's rlock (its list of running recordings), then the
 * table's lock (every recording's state, counters and queue), then a recording's dlock (its bytes,
 * in memory or the file's length: the writer appends, GET copies). The sim thread takes a scene's
 * rlock and the table's lock for the time of a copy; nobody holds either across I/O or encoding.
 *
 * The files: this one, the table and its API, a recording's bytes, start and stop; rec_writer.c,
 * the writer thread; rec_tap.c, the sim thread's side; rec_adopt.c, the files of recordings_dir
 * at start (recordings_internal.h: what they share). */
#include <errno.h>
#include <fcntl.h>
#include <math.h>
#include <pthread.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/stat.h>
#include <unistd.h>

#include "clothd_frame.h"
#include "core/clock.h"
#include "core/json_read.h"
#include "core/json_write.h"
#include "core/log.h"
#include "core/recording.h"
#include "core/stream_msg.h"
#include "core/wire.h"
#include "sim/recordings.h"
#include "sim/recordings_internal.h"

static const char *const state_names[] = {"recording", "done", "stopped"};
/* What a recording's estimate allows for its hello and events besides its frames. */
#define REC_TEXT_ALLOWANCE (64u << 10)

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
int recording_append(recording *k, const void *data, size_t len)
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

void recording_free(recording *k)
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

void recordings_file_path(const recordings *r, const char *rid, char *out, size_t len)
{
    snprintf(out, len, "%s/%s.clr", r->dir, rid);
}

/* Whether recordings_dir holds a file of that id (a recording it could not read, left alone). */
static int file_exists(const recordings *r, const char *rid)
{
    if (!r->dir[0]) return 0;
    char path[SETTING_TEXT_MAX + SCENE_ID_MAX + 8];
    recordings_file_path(r, rid, path, sizeof path);
    struct stat st;
    return lstat(path, &st) == 0;
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

/* What a POST asks for. */
typedef struct start_ask {
    double seconds;
    int encoding;
    const char *id; /* NULL: one is made */
} start_ask;

/* Step 1 of recordings_start: the body checked: 0, or -1 and the problem. */
static int start_ask_parse(const json_t *body, start_ask *a, problem *pr)
{
    static const char *const fields[] = {"seconds", "encoding", "id", NULL};
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
    a->seconds = seconds;
    a->encoding = encoding;
    a->id = ji ? json_string_value(ji) : NULL;
    return 0;
}

/* Step 2: what the recording may take (its file at the scene's frame_rate, in *frame_rate). */
static uint64_t start_estimate(scene *sc, const start_ask *a, double *frame_rate_out)
{
    const double seconds = a->seconds;
    const int encoding = a->encoding;
    const double frame_rate = doc_number(sc, DOC_PARAMS, "frame_rate");
    const int32_t n = (int32_t)doc_number(sc, DOC_SIM, "n_vertices"), rocks = (int32_t)doc_number(sc, DOC_SIM, "n_rocks");
    const double frames = ceil(seconds * (frame_rate > 0 ? frame_rate : 60.0)) + 1;
    /* and, while it runs, its working memory: its pose buffers, its encoder (36 bytes a vertex for
     * delta's grids and planes) and encoding buffers (about 24 bytes a vertex) */
    const uint64_t working = REC_QUEUE_FRAMES * (12 * (uint64_t)n + sizeof(pose_rock) * (uint64_t)rocks) + 60 * (uint64_t)n;
    const uint64_t estimate = REC_HEADER_SIZE + REC_TEXT_ALLOWANCE + (uint64_t)frames * frame_estimate(encoding, n, rocks) +
                              rec_index_size(0, 0) + working;
    *frame_rate_out = frame_rate;
    return estimate;
}

/* Step 3: k's id taken in the table (the one asked for, else the next rec-N free in the table
 * and recordings_dir), within the caps: 0, or -1 and the problem (k is not in the table then). */
static int start_take_id(recordings *r, recording *k, const char *id, problem *pr)
{
    const uint64_t estimate = k->estimate;
    pthread_mutex_lock(&r->lock);
    int bad = 0;
    if (id) snprintf(k->id, sizeof k->id, "%s", id);
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
    return bad;
}

/* Step 4: its file, with the header; in memory the header too. 0, or 1 and the problem. */
static int start_file(recordings *r, recording *k, problem *pr)
{
    unsigned char head[REC_HEADER_SIZE];
    rec_file_header(head);
    int failed = 0;
    if (r->dir[0]) {
        char path[SETTING_TEXT_MAX + SCENE_ID_MAX + 8];
        recordings_file_path(r, k->id, path, sizeof path);
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
    if (!failed && recording_append(k, head, sizeof head) != 0) {
        problem_set(pr, 500, "internal", NULL, "could not write the recording: %s", strerror(errno));
        failed = 1;
    }
    return failed;
}

/* Step 5: on its scene, unless the scene left meanwhile. 0, or 1 and the problem. */
static int start_on_scene(scene *sc, recording *k, problem *pr)
{
    int failed = 0;
    pthread_mutex_lock(&sc->rlock);
    if (sc->recs_closed || scene_is_deleted(sc)) {
        problem_set(pr, 404, "not-found", "scene", "no scene '%s'", sc->id);
        failed = 1;
    } else if (recordings_attach(sc) != 0) {
        problem_set(pr, 503, "unavailable", "scene", "the scene '%s' takes no more sinks", sc->id);
        failed = 1;
    } else {
        k->sc = scene_hold(sc);
        k->scene_next = sc->recs;
        sc->recs = k;
        atomic_fetch_add(&sc->n_recs, 1);
    }
    pthread_mutex_unlock(&sc->rlock);
    return failed;
}

int recordings_start(recordings *r, scene *sc, const json_t *body, json_t **answer, char *rid, problem *pr)
{
    *answer = NULL;
    start_ask a = {0};
    if (start_ask_parse(body, &a, pr) != 0) return -1;
    double frame_rate;
    const uint64_t estimate = start_estimate(sc, &a, &frame_rate);

    recording *k = calloc(1, sizeof *k);
    if (!k) return problem_set(pr, 500, "internal", NULL, "out of memory");
    k->owner = r;
    k->encoding = a.encoding;
    k->seconds = a.seconds;
    k->frame_rate = frame_rate;
    k->started_ns = clock_wall_ns();
    k->estimate = estimate;
    k->fd = -1;
    k->need_hello = 1;
    snprintf(k->scene_id, sizeof k->scene_id, "%s", sc->id);
    pthread_mutex_init(&k->dlock, NULL);

    if (start_take_id(r, k, a.id, pr) != 0) {
        recording_free(k);
        return -1;
    }
    int failed = start_file(r, k, pr);
    if (!failed) failed = start_on_scene(sc, k, pr);
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
        recordings_file_path(r, k->id, path, sizeof path);
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
                recording_end_on_scene(sc, k, "deleted");
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
    if (r->dir[0] && recordings_adopt_dir(r, err, err_len) != 0) {
        recordings_free(r);
        return NULL;
    }
    if (pthread_create(&r->writer, NULL, recordings_writer, r) != 0) {
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
        recording_end_on_scene(sc, k, "shutdown");
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
        recording_free(k);
    }
    pthread_mutex_destroy(&r->lock);
    pthread_cond_destroy(&r->work);
    pthread_cond_destroy(&r->freed);
    free(r);
}
