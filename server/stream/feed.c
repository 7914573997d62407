/* feed.c - the stream's feeds (see stream.c): a scene's channel, the sink the sim thread
 * hands its poses and events to, and a session's joining and leaving it. A closed feed's clients
 * are closed and it is freed by the service thread (stream_reap_feeds). */
#include <pthread.h>
#include <stdatomic.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "core/log.h"
#include "core/wire.h"
#include "stream/stream.h"
#include "stream/stream_internal.h"

/* ---- from the sim thread ---- */

static void pose_drop(pose *f)
{
    if (!f) return;
    pose_free(f);
    free(f);
}

static pose *sink_begin(void *ctx, unsigned *scalars)
{
    feed *fd = ctx;
    if (atomic_load(&fd->clients) == 0 || atomic_load(&fd->closed)) return NULL;
    pthread_mutex_lock(&fd->flock);
    pose *f = NULL;
    for (int k = 0; k < 2 && !f; k++) {
        if (fd->spare[k]) {
            f = fd->spare[k];
            fd->spare[k] = NULL;
        }
    }
    pthread_mutex_unlock(&fd->flock);
    if (!f) f = calloc(1, sizeof *f);
    *scalars = atomic_load(&fd->scalars_wanted);
    return f;
}

void stream_give_back(feed *fd, pose *f)
{
    /* Caller holds flock. */
    for (int k = 0; k < 2 && !atomic_load(&fd->closed); k++) {
        if (!fd->spare[k]) {
            fd->spare[k] = f;
            return;
        }
    }
    pose_drop(f);
}

static void sink_publish(void *ctx, pose *f)
{
    feed *fd = ctx;
    pthread_mutex_lock(&fd->flock);
    if (atomic_load(&fd->clients) == 0 || atomic_load(&fd->closed)) {
        /* The last client left since begin: kept, this pose could be shown to the next one after
         * changes it does not hold (see forget_frames). */
        stream_give_back(fd, f);
        pthread_mutex_unlock(&fd->flock);
        return;
    }
    if (fd->latest) stream_give_back(fd, fd->latest);
    fd->latest = f;
    fd->seq++;
    pthread_mutex_unlock(&fd->flock);
    lws_cancel_service(fd->st->ctx);
}

static void sink_discard(void *ctx, pose *f)
{
    feed *fd = ctx;
    pthread_mutex_lock(&fd->flock);
    stream_give_back(fd, f);
    pthread_mutex_unlock(&fd->flock);
}

static void sink_event(void *ctx, const char *json)
{
    feed *fd = ctx;
    if (atomic_load(&fd->closed)) return;
    char *copy = strdup(json); /* scene_emit named its scene ("scene_id") */
    if (!copy) return;
    const size_t len = strlen(copy);
    pthread_mutex_lock(&fd->elock);
    if (!fd->ring) { /* closed meanwhile */
        pthread_mutex_unlock(&fd->elock);
        free(copy);
        return;
    }
    /* Room for it: the oldest events go, within both caps (the newest is kept whatever its size). */
    while (fd->event_first < fd->event_seq &&
           (fd->event_seq - fd->event_first >= EVENT_RING || fd->ring_bytes + len > fd->st->ring_cap)) {
        event_slot *e = &fd->ring[fd->event_first++ % EVENT_RING];
        fd->ring_bytes -= e->len;
        free(e->text);
        e->text = NULL;
    }
    event_slot *e = &fd->ring[fd->event_seq++ % EVENT_RING];
    e->text = copy;
    e->len = len;
    fd->ring_bytes += len;
    pthread_mutex_unlock(&fd->elock);
    lws_cancel_service(fd->st->ctx);
}

/* ---- feeds ---- */

/* The open feed of a scene, or NULL (the feeds' lock held). */
static feed *find_feed(stream *st, const scene *sc)
{
    feed *fd = st->feeds;
    while (fd && (fd->sc != sc || atomic_load(&fd->closed))) fd = fd->next;
    return fd;
}

/* The open feed of a scene, or NULL. */
feed *stream_feed_of(stream *st, const scene *sc)
{
    pthread_mutex_lock(&st->feeds_lock);
    feed *fd = find_feed(st, sc);
    pthread_mutex_unlock(&st->feeds_lock);
    return fd;
}

/* A session leaves its delta channel; the last to leave frees it. */
void stream_leave_chan(feed *fd, session *s)
{
    if (s->chan < 0) return;
    delta_chan *ch = &fd->chans[s->chan];
    s->chan = -1;
    if (--ch->users > 0) return;
    delta_free(&ch->enc);
    free(ch->section);
    for (int k = 0; k < SCALAR_KINDS; k++) free(ch->wires[k].buf);
    free(ch->key.buf);
    memset(ch, 0, sizeof *ch);
}

/* The last client of a feed has left: it forgets its frames. With nobody listening the sim
 * thread makes none (begin answers NULL), so a pose kept from now on could miss any change that
 * follows (a new scene, a reset, a rock while paused); the next client to join would get that
 * stale pose before the one its join asks for. Without one, a joiner waits for the pose its join
 * asks for. */
static void forget_frames(feed *fd)
{
    pthread_mutex_lock(&fd->flock);
    if (fd->latest) stream_give_back(fd, fd->latest);
    if (fd->current) stream_give_back(fd, fd->current);
    fd->latest = fd->current = NULL;
    fd->taken = fd->seq;
    pthread_mutex_unlock(&fd->flock);
    for (int e = 0; e < N_ENC; e++)
        for (int k = 0; k < SCALAR_KINDS; k++) fd->wires[e][k].len = 0, fd->wires[e][k].seq = 0;
    for (int c = 0; c < DELTA_CHANNELS; c++) {
        delta_chan *ch = &fd->chans[c];
        ch->seq = ch->key.seq = 0;
        ch->key.len = 0;
        for (int k = 0; k < SCALAR_KINDS; k++) ch->wires[k].len = 0, ch->wires[k].seq = 0;
    }
}

/* The scalars the clients of a feed want, for the sim thread. */
void stream_update_scalars(stream *st, feed *fd)
{
    unsigned want = 0;
    for (session *o = st->sessions; o; o = o->next)
        if (o->f == fd && o->scalar) want |= 1u << o->scalar;
    atomic_store(&fd->scalars_wanted, want);
}

/* A session starts streaming a feed (sc: its scene, a handle the session takes over): from its
 * events on, with a hello that shows the scene as it is. */
void stream_join_feed(stream *st, session *s, feed *fd, scene *sc)
{
    s->f = fd;
    s->sc = sc;
    s->last_frame = 0;
    s->key_have = 0;
    pthread_mutex_lock(&fd->elock);
    s->next_event = fd->event_seq; /* events from here on; hello shows the state before */
    pthread_mutex_unlock(&fd->elock);
    free(s->hello);
    s->hello = stream_hello_text(s);
    stream_update_scalars(st, fd);
    if (atomic_fetch_add(&fd->clients, 1) == 0 || !fd->current) stream_request_frame(fd, sc);
    lws_callback_on_writable(s->wsi);
}

/* A session stops streaming its feed (its delta channel left already); its scene's handle is
 * the caller's to release. */
void stream_leave_feed(stream *st, session *s)
{
    feed *fd = s->f;
    if (!fd) return;
    stream_leave_chan(fd, s);
    s->f = NULL;
    if (atomic_fetch_sub(&fd->clients, 1) == 1) forget_frames(fd);
    stream_update_scalars(st, fd);
}

/* Frees what a closed feed's service side holds (no session streams it any more). */
static void feed_free_buffers(feed *fd)
{
    for (int e = 0; e < N_ENC; e++)
        for (int k = 0; k < SCALAR_KINDS; k++) {
            free(fd->wires[e][k].buf);
            memset(&fd->wires[e][k], 0, sizeof fd->wires[e][k]);
        }
    for (int c = 0; c < DELTA_CHANNELS; c++) {
        fd->chans[c].users = 1;
        session none = {.chan = c};
        stream_leave_chan(fd, &none);
    }
    pthread_mutex_lock(&fd->flock);
    pose *frames[4] = {fd->latest, fd->spare[0], fd->spare[1], fd->current};
    fd->latest = fd->spare[0] = fd->spare[1] = fd->current = NULL;
    pthread_mutex_unlock(&fd->flock);
    for (int k = 0; k < 4; k++) pose_drop(frames[k]);
    pthread_mutex_lock(&fd->elock);
    event_slot *ring = fd->ring;
    fd->ring = NULL;
    pthread_mutex_unlock(&fd->elock);
    for (int k = 0; ring && k < EVENT_RING; k++) free(ring[k].text);
    free(ring);
}

void stream_feed_free(feed *fd)
{
    feed_free_buffers(fd);
    pthread_mutex_destroy(&fd->flock);
    pthread_mutex_destroy(&fd->elock);
    free(fd);
}

/* The service thread closes the clients of the feeds closed since it last looked (1001, "scene
 * deleted", at their next write) and frees those feeds. */
void stream_reap_feeds(stream *st)
{
    if (!atomic_exchange(&st->to_reap, 0)) return;
    pthread_mutex_lock(&st->feeds_lock);
    for (feed **p = &st->feeds; *p;) {
        feed *fd = *p;
        if (!atomic_load(&fd->closed)) {
            p = &fd->next;
            continue;
        }
        for (session *s = st->sessions; s; s = s->next) {
            if (s->f != fd) continue;
            stream_leave_feed(st, s);
            s->gone = 1;
            atomic_fetch_add(&st->scene_closed, 1);
            lws_callback_on_writable(s->wsi);
        }
        *p = fd->next;
        stream_feed_free(fd);
    }
    pthread_mutex_unlock(&st->feeds_lock);
}

/* Bytes the stream may hold for a scene of n vertices and `rocks` rocks: its poses (the one the
 * sim thread fills, the newest, the one being sent, a spare), one wire message for each
 * encoding and scalar, and each delta channel's encoder (36 bytes a vertex), positions section,
 * messages and keyframe. */
static uint64_t sink_bytes(int32_t n, int32_t rocks)
{
    pose f = {.n = n, .n_rocks = rocks, .has = {0, 1, 1}};
    const uint64_t raw = sizeof(float) * 3 * (uint64_t)n + (SCALAR_KINDS - 1) * (uint64_t)n + sizeof(pose_rock) * (uint64_t)rocks;
    uint64_t wires = 0;
    for (int e = 0; e < N_ENC; e++)
        for (int k = 0; k < SCALAR_KINDS && e != CLF_DELTA; k++) wires += LWS_PRE + wire_bound(&f, e, k);
    uint64_t chan = 36 * (uint64_t)n + delta_bound(n) + LWS_PRE + wire_bound(&f, CLF_DELTA, SCALAR_NONE);
    for (int k = 0; k < SCALAR_KINDS; k++) chan += LWS_PRE + wire_bound(&f, CLF_DELTA, k);
    return 4 * (sizeof f + raw) + wires + DELTA_CHANNELS * chan;
}

const frame_sink_ops stream_sink_ops = {
    .begin = sink_begin, .publish = sink_publish, .discard = sink_discard, .event = sink_event, .bytes = sink_bytes};

frame_sink stream_scene_sink(stream *st, scene *sc)
{
    feed *fd = calloc(1, sizeof *fd);
    event_slot *ring = fd ? calloc(EVENT_RING, sizeof *ring) : NULL;
    if (!ring) {
        free(fd);
        log_msg("stream: out of memory: scene %s streams nothing", sc->id);
        return (frame_sink){NULL, NULL};
    }
    fd->st = st;
    fd->sc = sc;
    snprintf(fd->id, sizeof fd->id, "%s", sc->id);
    fd->ring = ring;
    pthread_mutex_init(&fd->flock, NULL);
    pthread_mutex_init(&fd->elock, NULL);
    pthread_mutex_lock(&st->feeds_lock);
    fd->next = st->feeds;
    st->feeds = fd;
    pthread_mutex_unlock(&st->feeds_lock);
    return (frame_sink){&stream_sink_ops, fd};
}

void stream_scene_removed(stream *st, scene *sc)
{
    /* Closed under the feeds' lock: a reader that holds it and sees the feed open may still read
     * its scene (released only after this returns). */
    pthread_mutex_lock(&st->feeds_lock);
    feed *fd = find_feed(st, sc);
    if (fd) atomic_store(&fd->closed, 1);
    pthread_mutex_unlock(&st->feeds_lock);
    if (!fd) return;
    atomic_store(&st->to_reap, 1);
    lws_cancel_service(st->ctx);
}
