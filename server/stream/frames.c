/* frames.c - the stream's frames (see stream.c): each feed's newest pose encoded once per
 * encoding and scalar in use, written to each client as its rate allows, and stalled clients closed. */
#include <stdatomic.h>
#include <stdlib.h>
#include <string.h>

#include "core/clock.h"
#include "core/log.h"
#include "core/wire.h"
#include "stream/stream_internal.h"

/* ---- frames ---- */

/* Makes sure the wire frame of (encoding, scalar) holds the feed's current frame: encoded once
 * per frame, whoever asks first. */
static const wire *wire_for(stream *st, feed *fd, int e, int k)
{
    wire *w = &fd->wires[e][k];
    pose *f = fd->current;
    if (!f || w->seq == fd->current_seq || f->n == 0) return w;
    const size_t need = LWS_PRE + wire_bound(f, e, k);
    if (need > w->cap) {
        unsigned char *b = realloc(w->buf, need);
        if (!b) return w;
        w->buf = b;
        w->cap = need;
    }
    const double t0 = clock_mono();
    w->len = wire_encode(f, e, k, w->buf + LWS_PRE);
    w->seq = fd->current_seq;
    atomic_fetch_add(&st->encoded[e], 1);
    atomic_fetch_add(&st->encode_ns[e], (unsigned long long)((clock_mono() - t0) * 1e9));
    return w;
}

/* Fits a wire's buffer to need bytes (and LWS_PRE); 0 or -1. */
static int wire_room(wire *w, size_t need)
{
    need += LWS_PRE;
    if (need <= w->cap) return 0;
    unsigned char *b = realloc(w->buf, need);
    if (!b) return -1;
    w->buf = b;
    w->cap = need;
    return 0;
}

/* The delta channel's message of scalar k for the feed's current pose: its positions section
 * encoded once per pose (a keyframe or a delta, as the encoder decides), then wrapped per scalar. */
static const wire *delta_wire(stream *st, feed *fd, delta_chan *ch, int k)
{
    wire *w = &ch->wires[k];
    pose *f = fd->current;
    if (!f || w->seq == fd->current_seq || f->n == 0) return w;
    const double t0 = clock_mono();
    if (ch->seq != fd->current_seq) {
        int key = 0;
        const size_t cap = delta_bound(f->n);
        if (cap > ch->section_cap) {
            unsigned char *b = realloc(ch->section, cap);
            if (!b) return w;
            ch->section = b;
            ch->section_cap = cap;
        }
        const size_t len = delta_encode(&ch->enc, f->xyz, f->n, f->nx > 0 ? f->nx : f->n, f->frame, f->wall_ns, ch->section, &key);
        if (!len) return w;
        ch->section_len = len;
        ch->seq = fd->current_seq;
        atomic_fetch_add(&st->encoded[CLF_DELTA], 1);
        if (key && wire_room(&ch->key, wire_bound(f, CLF_DELTA, SCALAR_NONE)) == 0) {
            ch->key.len = wire_encode_delta(f, SCALAR_NONE, ch->section, len, ch->key.buf + LWS_PRE);
            ch->key.seq = fd->current_seq;
            ch->key.key_id = ch->enc.key_id;
        }
    }
    if (wire_room(w, wire_bound(f, CLF_DELTA, k)) != 0) return w;
    w->len = wire_encode_delta(f, k, ch->section, ch->section_len, w->buf + LWS_PRE);
    w->seq = fd->current_seq;
    w->key_id = ch->enc.key_id;
    atomic_fetch_add(&st->encode_ns[CLF_DELTA], (unsigned long long)((clock_mono() - t0) * 1e9));
    return w;
}

/* The message a session is due (encoded when it is not yet). */
static const wire *wire_of(stream *st, session *s)
{
    if (s->encoding == CLF_DELTA && s->chan >= 0) return delta_wire(st, s->f, &s->f->chans[s->chan], s->scalar);
    return wire_for(st, s->f, s->encoding, s->scalar);
}

/* ... without encoding it. */
static const wire *wire_now(const session *s)
{
    if (s->encoding == CLF_DELTA && s->chan >= 0) return &s->f->chans[s->chan].wires[s->scalar];
    return &s->f->wires[s->encoding][s->scalar];
}

/* Takes over the newest raw frame each feed's scene published, and encodes it for every encoding
 * and scalar some client of it uses. */
void stream_take_newest(stream *st)
{
    int any = 0;
    pthread_mutex_lock(&st->feeds_lock);
    for (feed *fd = st->feeds; fd; fd = fd->next) {
        pthread_mutex_lock(&fd->flock);
        if (fd->latest && fd->seq != fd->taken) {
            pose *f = fd->latest;
            fd->latest = NULL;
            fd->taken = fd->seq;
            if (fd->current) stream_give_back(fd, fd->current);
            fd->current = f;
            fd->current_seq = fd->seq;
            any = 1;
        }
        pthread_mutex_unlock(&fd->flock);
    }
    pthread_mutex_unlock(&st->feeds_lock);
    if (!any) return;
    for (session *s = st->sessions; s; s = s->next)
        if (s->f) wire_of(st, s);
}

/* Stalled clients (their newest frame waiting too long) are closed. */
void stream_sweep(stream *st)
{
    const double t = clock_mono();
    for (session *s = st->sessions; s; s = s->next) {
        if (!s->f) continue;
        if (s->slot && t - s->fps_at >= 1.0) { /* the achieved frame rate, about once a second */
            const uint64_t frames = atomic_load(&s->slot->frames), bytes = atomic_load(&s->slot->bytes);
            const double fps = (double)(frames - s->fps_frames) / (t - s->fps_at);
            stream_observe_client(st, fps, (double)(bytes - s->fps_bytes) / (t - s->fps_at));
            s->fps_frames = frames;
            s->fps_bytes = bytes;
            s->fps_at = t;
        }
        const wire *w = wire_now(s);
        if (s->dead || w->seq <= s->last_frame || t < s->next_send) { /* up to date, or waiting on its own budget */
            s->behind_since = 0;
            continue;
        }
        if (s->behind_since == 0) s->behind_since = t;
        else if (t - s->behind_since > st->stall_timeout) {
            log_msg("stream: client %llu stalled for %.0f s: disconnected", (unsigned long long)s->id, st->stall_timeout);
            atomic_fetch_add(&st->stalled, 1);
            s->dead = 1;
            lws_set_timeout(s->wsi, PENDING_TIMEOUT_USER_OK, LWS_TO_KILL_ASYNC);
        }
    }
}

/* A client with max_kbps that was sent len bytes at t gets its next frame once its budget has
 * paid for them: a slow link gets fewer whole frames, never a queue. */
static void spend(session *s, size_t len, double t)
{
    if (!s->max_kbps) return;
    s->next_send = (s->next_send > t ? s->next_send : t) + (double)len * 8.0 / ((double)s->max_kbps * 1000.0);
}

/* Sends a text message to a client (and frees it), then asks to be called again for what is next. */
static int send_text(stream *st, session *s, char *text)
{
    const int rc = stream_send_text(s->wsi, text, st);
    free(text);
    lws_callback_on_writable(s->wsi);
    return rc;
}

/* The client's next event from its feed's ring (a copy, or NULL when it has them all) in *event; -1
 * when it fell further behind than the ring keeps (logged and counted: the client is closed). */
static int next_event(stream *st, session *s, char **event)
{
    feed *fd = s->f;
    pthread_mutex_lock(&fd->elock);
    if (fd->ring && s->next_event < fd->event_seq) {
        if (s->next_event < fd->event_first) {
            const unsigned long long behind = (unsigned long long)(fd->event_seq - s->next_event);
            pthread_mutex_unlock(&fd->elock);
            log_msg("stream: client %llu fell %llu events behind, past what the event ring keeps: disconnected",
                    (unsigned long long)s->id, behind);
            atomic_fetch_add(&st->stalled, 1);
            return -1;
        }
        *event = strdup(fd->ring[s->next_event % EVENT_RING].text);
        s->next_event++;
    }
    pthread_mutex_unlock(&fd->elock);
    return 0;
}

/* Whether a client must wait before its next frame at t (its max_fps, its byte budget): then a
 * timer calls it back when it may. */
static int must_wait(session *s, double t)
{
    double wait = 1.0 / s->max_fps - (t - s->last_send);
    if (s->max_kbps && s->next_send - t > wait) wait = s->next_send - t; /* its byte budget */
    if (wait > 0.0005) {
        lws_set_timer_usecs(s->wsi, (lws_usec_t)(wait * 1e6));
        return 1;
    }
    return 0;
}

/* The keyframe a delta client lacks and frame w refers to, when the client must get it first
 * (unless w is it), or NULL. */
static const wire *missing_keyframe(const session *s, const wire *w)
{
    if (s->chan < 0 || s->encoding != CLF_DELTA || w->key_id == s->key_have) return NULL;
    const wire *key = &s->f->chans[s->chan].key;
    return key->len && key->key_id == w->key_id && key->seq != w->seq ? key : NULL;
}

/* Writes the keyframe a client lacks (at t), then asks to be called again for the frame. */
static int send_keyframe(stream *st, session *s, const wire *key, double t)
{
    const int n = lws_write(s->wsi, key->buf + LWS_PRE, key->len, LWS_WRITE_BINARY);
    if (n < (int)key->len) return -1;
    atomic_fetch_add(&st->bytes_sent, key->len);
    if (s->slot) atomic_fetch_add(&s->slot->bytes, key->len);
    spend(s, key->len, t);
    s->key_have = key->key_id;
    lws_callback_on_writable(s->wsi);
    return 0;
}

/* Writes frame w to a client (at t) and counts it: the frames it skipped, what it was sent. */
static int send_frame(stream *st, session *s, const wire *w, double t)
{
    const int n = lws_write(s->wsi, w->buf + LWS_PRE, w->len, LWS_WRITE_BINARY);
    if (n < (int)w->len) return -1;
    if (s->last_frame && w->seq > s->last_frame + 1) atomic_fetch_add(&st->skipped[s->encoding], w->seq - s->last_frame - 1);
    atomic_fetch_add(&st->sent[s->encoding], 1);
    if (s->slot) {
        atomic_fetch_add(&s->slot->frames, 1);
        atomic_fetch_add(&s->slot->bytes, w->len);
    }
    atomic_fetch_add(&st->bytes_sent, w->len);
    s->last_frame = w->seq;
    spend(s, w->len, t);
    s->key_have = w->key_id;
    s->last_send = t;
    s->behind_since = 0;
    return 0;
}

/* The newest frame to a client that has not had it, when its rate allows: the keyframe it refers
 * to first when the client lacks it. */
static int send_newest(stream *st, session *s)
{
    const wire *w = wire_of(st, s);
    if (w->seq <= s->last_frame || !w->len) return 0;
    const double t = clock_mono();
    if (must_wait(s, t)) return 0;
    const wire *key = missing_keyframe(s, w);
    if (key) return send_keyframe(st, s, key, t);
    return send_frame(st, s, w, t);
}

/* One message to a client that can take it: hello, errors and acks, events, then the newest
 * frame (when its rate allows). A client whose scene was deleted is closed instead. */
int stream_writeable(stream *st, session *s)
{
    if (s->dead) return -1;
    if (s->gone) {
        lws_close_reason(s->wsi, LWS_CLOSE_STATUS_GOINGAWAY, (unsigned char *)CLOSE_SCENE_DELETED, strlen(CLOSE_SCENE_DELETED));
        return -1;
    }
    if (!s->f) return 0;
    if (lws_send_pipe_choked(s->wsi)) {
        lws_callback_on_writable(s->wsi);
        return 0;
    }
    if (s->hello) {
        char *hello = s->hello;
        s->hello = NULL;
        return send_text(st, s, hello);
    }
    if (s->n_texts) {
        char *text = s->texts[0];
        memmove(s->texts, s->texts + 1, sizeof s->texts[0] * (size_t)(--s->n_texts));
        return send_text(st, s, text);
    }
    char *event = NULL;
    if (next_event(st, s, &event) != 0) return -1;
    if (event) return send_text(st, s, event);
    return send_newest(st, s);
}
