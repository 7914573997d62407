/* rec_tap.c - the sim thread's side of the recordings (see recordings.c): the recordings' sink
 * (sim/sink.h), which copies a scene's poses and events onto its running recordings' queues without
 * waiting on the writer, what rectap.h tells the sim thread, and where a recording ends (its
 * length, its scene changed or deleted). */
#include <pthread.h>
#include <stdatomic.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "clothd_frame.h"
#include "core/json_write.h"
#include "core/recording.h"
#include "core/stream_msg.h"
#include "sim/recordings.h"
#include "sim/recordings_internal.h"

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
void recording_end_on_scene(scene *sc, recording *k, const char *reason)
{
    for (recording **p = (recording **)&sc->recs; *p; p = &(*p)->scene_next)
        if (*p == k) {
            *p = k->scene_next;
            break;
        }
    atomic_fetch_sub(&sc->n_recs, 1);
    recordings *r = k->owner;
    pthread_mutex_lock(&r->lock);
    if (reason) recording_stop_locked(k, reason);
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

/* ---- the recordings' sink: its ctx is the scene ---- */

static int tap_want(void *ctx, int changed) { return recordings_want(ctx, changed); }

/* The pose to the scene's running recordings (copied): to all when the scene changed since the
 * last, else only to those that have none yet; with the scene's hello first for one that starts
 * (the scene's published reads, and these rocks). */
static void tap_take(void *ctx, const pose *p, const cs_rock *rocks, int n_rocks, int changed)
{
    scene *sc = ctx;
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
            recording_end_on_scene(sc, k, NULL);
            continue;
        }
        if (k->have_first && p->n != k->n_first) { /* a file holds frames of one vertex count */
            recording_end_on_scene(sc, k, "scene changed");
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
        if (p->sim_time - k->sim_first >= k->seconds - leeway) recording_end_on_scene(sc, k, NULL);
    }
    pthread_mutex_unlock(&sc->rlock);
}

/* An event's text to the scene's running recordings that have their hello (copied). */
static void tap_event(void *ctx, const char *text)
{
    scene *sc = ctx;
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

/* The scene left the daemon: its recordings stop ("scene deleted"); none starts on it again. */
static void tap_gone(void *ctx)
{
    scene *sc = ctx;
    pthread_mutex_lock(&sc->rlock);
    sc->recs_closed = 1;
    while (sc->recs) recording_end_on_scene(sc, sc->recs, "scene deleted");
    pthread_mutex_unlock(&sc->rlock);
}

static const frame_sink_ops tap_ops = {.event = tap_event, .want = tap_want, .take = tap_take, .gone = tap_gone};

int recordings_attach(scene *sc) { return scene_add_sink(sc, (frame_sink){&tap_ops, sc}); }
