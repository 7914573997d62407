/* stream.c - the WebSocket stream (see stream.h).
 *
 * Channels: each scene of the daemon has one, a `feed` - its newest pose, its encodings in use
 * (one wire message per encoding and scalar, its delta encoders), its events - made when the
 * scene joins (stream_scene_sink: the feed is the scene's sink) and closed when it leaves
 * (stream_scene_removed). A client streams one feed at a time and holds a handle on its scene.
 *
 * Threads: the sim thread calls a feed's begin/publish/discard and event; libwebsockets runs in
 * its own service thread, which alone touches the sessions and the encoded frames. Handing a
 * frame over is a pointer swap under the feed's mutex among three buffers (one the sim thread
 * fills, the newest, one the service thread encodes), then lws_cancel_service, whose
 * LWS_CALLBACK_EVENT_WAIT_CANCELLED wakes every client with lws_callback_on_writable_all_protocol;
 * each client is written to in LWS_CALLBACK_SERVER_WRITEABLE, one message per callback. HTTP
 * threads add feeds (under feeds_lock); the sim thread closes one once it has let its deleted
 * scene go, after which the scene hands its sink nothing (scenes.h, the removed hook): a closed
 * feed takes no more poses or events, and the service thread then closes its clients (1001,
 * "scene deleted") and frees it.
 *
 * Memory per client is bounded: it holds no frame of its own (the encoded frame is shared and
 * replaced by the next one), lws keeps at most the unsent rest of one message, and pending text is
 * limited (errors and acks to 8; events are read from the feed's ring, and a client that falls
 * further behind than the ring is disconnected). A client whose newest frame has been waiting
 * longer than stream_stall_timeout is disconnected. Each feed's ring keeps at most EVENT_RING
 * events and stream_events_mb of their text (the oldest go first; the newest always stays).
 *
 * What clients make the sim thread do is bounded too: a grab or release is in flight at most
 * once per client (the newest waiting one replaces the others), and a request for a publication
 * (a client joins, or subscribes to a scalar the newest frame lacks) at most once per feed.
 *
 * The files: this one, the public entry points and the libwebsockets glue; feed.c, the feeds;
 * session.c, a client's messages and grabs; frames.c, encoding and writing frames; admission.c,
 * the checks before the upgrade; stream_metrics.c, /metrics (stream_internal.h: what they share).
 *
 * LWS_CALLBACK_HTTP_CONFIRM_UPGRADE is deliberately not handled (CVE-2025-11677 in 4.1.6):
 * connections are checked in LWS_CALLBACK_FILTER_PROTOCOL_CONNECTION instead. */
#include <libwebsockets.h>
#include <pthread.h>
#include <signal.h>
#include <stdatomic.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include <jansson.h>

#include "clothd_frame.h"
#include "core/clock.h"
#include "core/log.h"
#include "stream/stream.h"
#include "stream/stream_internal.h"

/* ---- libwebsockets ---- */

/* A new client's /metrics slot: the first free one (none when all are taken). */
static void claim_slot(stream *st, session *s)
{
    for (int k = 0; k < st->max_clients && !s->slot; k++) {
        if (atomic_load(&st->slots[k].id) == 0) {
            s->slot = &st->slots[k];
            atomic_store(&s->slot->frames, 0);
            atomic_store(&s->slot->bytes, 0);
            atomic_store(&s->slot->id, s->id);
        }
    }
}

/* LWS_CALLBACK_ESTABLISHED: an admitted client becomes a session with the default subscription,
 * counted, and joins its scene's feed; -1 when the scene was deleted since stream_admit(). */
static int session_open(stream *st, struct lws *wsi, session *s)
{
    const access_level granted = s->access; /* set by stream_admit() in this same allocation */
    char want[SCENE_ID_MAX];
    memcpy(want, s->want, sizeof want);
    memset(s, 0, sizeof *s);
    s->access = granted;
    scene *sc = scenes_get(st->table, want);
    feed *fd = sc ? stream_feed_of(st, sc) : NULL;
    if (!fd) { /* deleted since stream_admit() */
        scene_release(sc);
        return -1;
    }
    s->established = 1;
    s->wsi = wsi;
    s->id = ++st->next_id;
    s->max_fps = 60;
    s->encoding = CLF_F32;
    s->scalar = SCALAR_NONE;
    s->quantum = st->default_quantum;
    s->chan = -1;
    s->fps_at = clock_mono();
    claim_slot(st, s);
    s->next = st->sessions;
    st->sessions = s;
    atomic_fetch_add(&st->clients, 1);
    stream_join_feed(st, s, fd, sc);
    return 0;
}

/* LWS_CALLBACK_CLOSED: a session leaves the list, its feed and its slot, uncounted, and lets go
 * of what it holds (its scene's handle last). */
static void session_close(stream *st, session *s)
{
    for (session **p = &st->sessions; *p; p = &(*p)->next) {
        if (*p == s) {
            *p = s->next;
            break;
        }
    }
    stream_leave_feed(st, s);
    if (s->slot) atomic_store(&s->slot->id, 0);
    s->slot = NULL;
    atomic_fetch_sub(&st->clients, 1);
    free(s->hello);
    for (int k = 0; k < s->n_texts; k++) free(s->texts[k]);
    free(s->rx);
    json_decref(s->grab_pending);
    scene_release(s->sc);
    s->rx = NULL;
    s->sc = NULL;
}

/* LWS_CALLBACK_RECEIVE: a fragment of a client's message, gathered in s->rx up to max_message (a
 * larger or binary message is marked bad, not kept); a whole message is handled. -1: out of memory. */
static int session_receive(stream *st, struct lws *wsi, session *s, const void *in, size_t len)
{
    if (lws_is_first_fragment(wsi) && s->rx_len == 0) s->rx_bad = lws_frame_is_binary(wsi) ? 2 : 0;
    if (!s->rx_bad && s->rx_len + len > (size_t)st->max_message) {
        s->rx_bad = 1;
    } else if (!s->rx_bad) {
        char *b = realloc(s->rx, s->rx_len + len + 1);
        if (!b) return -1;
        s->rx = b;
        memcpy(s->rx + s->rx_len, in, len);
        s->rx_len += len;
    }
    if (lws_is_final_fragment(wsi) && lws_remaining_packet_payload(wsi) == 0) {
        stream_handle_message(st, s);
        s->rx_len = 0;
        s->rx_bad = 0;
    }
    return 0;
}

/* LWS_CALLBACK_EVENT_WAIT_CANCELLED (lws_cancel_service: another thread has something for the
 * service thread): grabs' answers, closed feeds, the newest poses, stalled clients, then every
 * client is asked whether it can be written to. */
static void service_wake(stream *st, struct lws *wsi)
{
    stream_take_answers(st);
    stream_reap_feeds(st);
    stream_take_newest(st);
    stream_sweep(st);
    lws_callback_on_writable_all_protocol(lws_get_context(wsi), st->protocol);
}

static int callback(struct lws *wsi, enum lws_callback_reasons reason, void *user, void *in, size_t len)
{
    stream *st = lws_context_user(lws_get_context(wsi));
    session *s = user;
    switch (reason) {
    case LWS_CALLBACK_FILTER_PROTOCOL_CONNECTION: return stream_admit(st, wsi, s) ? 0 : -1;
    case LWS_CALLBACK_ESTABLISHED: return session_open(st, wsi, s);
    case LWS_CALLBACK_CLOSED:
        /* libwebsockets closes the connections stream_admit() refused here too: they were never counted. */
        if (s && s->established) session_close(st, s);
        return 0;
    case LWS_CALLBACK_RECEIVE: return session_receive(st, wsi, s, in, len);
    case LWS_CALLBACK_SERVER_WRITEABLE: return stream_writeable(st, s);
    case LWS_CALLBACK_TIMER: lws_callback_on_writable(wsi); return 0;
    case LWS_CALLBACK_EVENT_WAIT_CANCELLED: service_wake(st, wsi); return 0;
    default: return lws_callback_http_dummy(wsi, reason, user, in, len);
    }
}

static struct lws_protocols protocols[] = {
    {PROTOCOL_NAME, callback, sizeof(session), 4096, 0, NULL, 0},
    {NULL, NULL, 0, 0, 0, NULL, 0},
};

static void lws_log(int level, const char *line)
{
    char text[512];
    snprintf(text, sizeof text, "%s", line);
    const size_t n = strlen(text);
    if (n && text[n - 1] == '\n') text[n - 1] = '\0';
    log_msg("stream: %s%s", level == LLL_ERR ? "error: " : "", text);
}

static void *service(void *arg)
{
    stream *st = arg;
    sigset_t all;
    sigfillset(&all);
    pthread_sigmask(SIG_BLOCK, &all, NULL);
    while (!atomic_load(&st->stop))
        if (lws_service(st->ctx, 0) < 0) break;
    return NULL;
}

/* Ping after 10 s without traffic, hang up after 30 s without an answer. */
static const lws_retry_bo_t keepalive = {.secs_since_valid_ping = 10, .secs_since_valid_hangup = 30};

stream *stream_start(const clothd_settings *set, scenes *table, const access_policy *acc, char *err, size_t err_len)
{
    stream *st = calloc(1, sizeof *st);
    if (!st) {
        snprintf(err, err_len, "out of memory");
        return NULL;
    }
    st->table = table;
    st->acc = acc;
    st->protocol = &protocols[0];
    st->max_clients = set->stream_max_clients;
    st->slots = calloc((size_t)st->max_clients, sizeof *st->slots);
    if (!st->slots) {
        snprintf(err, err_len, "out of memory");
        free(st);
        return NULL;
    }
    st->max_message = set->stream_max_message;
    st->stall_timeout = set->stream_stall_timeout;
    st->default_quantum = set->stream_delta_quantum;
    st->ring_cap = (size_t)set->stream_events_mb << 20;
    pthread_mutex_init(&st->feeds_lock, NULL);
    pthread_mutex_init(&st->glock, NULL);
    lws_set_log_level(LLL_ERR | LLL_WARN, lws_log);
    struct lws_context_creation_info info;
    memset(&info, 0, sizeof info);
    info.port = set->stream_port ? set->stream_port : CONTEXT_PORT_NO_LISTEN_SERVER;
    info.iface = set->listen;
    info.protocols = protocols;
    info.user = st;
    info.retry_and_idle_policy = &keepalive;
    info.options = LWS_SERVER_OPTION_VALIDATE_UTF8;
    if (!strchr(set->listen, ':')) info.options |= LWS_SERVER_OPTION_DISABLE_IPV6;
    if (set->stream_port == 0) info.port = 0;
    st->ctx = lws_create_context(&info);
    if (!st->ctx) {
        snprintf(err, err_len, "could not listen for the stream on %s port %d", set->listen, (int)set->stream_port);
        free(st->slots);
        free(st);
        return NULL;
    }
    struct lws_vhost *vh = lws_get_vhost_by_name(st->ctx, "default");
    st->port = vh ? lws_get_vhost_listen_port(vh) : set->stream_port;
    if (pthread_create(&st->thread, NULL, service, st) != 0) {
        lws_context_destroy(st->ctx);
        snprintf(err, err_len, "could not start the stream thread");
        free(st->slots);
        free(st);
        return NULL;
    }
    return st;
}

int stream_port(stream *st) { return st->port; }

void stream_set_http_port(stream *st, int port) { atomic_store(&st->http_port, port); }

void stream_stop(stream *st)
{
    if (!st) return;
    atomic_store(&st->stop, 1);
    lws_cancel_service(st->ctx);
    pthread_join(st->thread, NULL);
    lws_context_destroy(st->ctx);
    stream_take_answers(st);
    for (feed *fd = st->feeds, *next; fd; fd = next) {
        next = fd->next;
        stream_feed_free(fd);
    }
    pthread_mutex_destroy(&st->feeds_lock);
    pthread_mutex_destroy(&st->glock);
    free(st->slots);
    free(st);
}
