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
 * LWS_CALLBACK_HTTP_CONFIRM_UPGRADE is deliberately not handled (CVE-2025-11677 in 4.1.6):
 * connections are checked in LWS_CALLBACK_FILTER_PROTOCOL_CONNECTION instead. */
#include <libwebsockets.h>
#include <math.h>
#include <pthread.h>
#include <signal.h>
#include <stdarg.h>
#include <stdatomic.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/socket.h>
#include <time.h>

#include <jansson.h>

#include "clothd_frame.h"
#include "core/access.h"
#include "core/clock.h"
#include "core/delta.h"
#include "core/json_write.h"
#include "core/log.h"
#include "core/problem.h"
#include "core/stream_msg.h"
#include "core/wire.h"
#include "sim/commands.h"
#include "stream/stream.h"

#define PROTOCOL_NAME STREAM_PROTOCOL
#define EVENT_RING 1024
#define MAX_TEXTS 8 /* queued text messages (errors, acks) per client */
#define N_ENC STREAM_ENCODINGS
/* Different quanta the delta clients of one scene may use at once: one encoder (and one encoding
 * of each frame) per quantum. */
#define DELTA_CHANNELS 4
/* The close reason of a client whose scene was deleted (with 1001, going away). */
#define CLOSE_SCENE_DELETED "scene deleted"

/* Why a connection was refused before the upgrade: the `reason` of clothd_stream_refused_total. */
enum { REFUSED_PATH, REFUSED_VERSION, REFUSED_HOST, REFUSED_ORIGIN, REFUSED_TOKEN, REFUSED_CLIENTS, REFUSED_SCENE, N_REFUSED };
static const char *const refused_names[N_REFUSED] = {"path", "version", "host", "origin", "token", "clients", "scene"};

typedef struct wire {
    unsigned char *buf; /* LWS_PRE bytes of headroom, then the frame */
    size_t len, cap;
    uint64_t seq;       /* of the raw frame it encodes */
    uint32_t key_id;    /* delta: the keyframe it refers to (its own when it is one) */
} wire;

/* The delta clients of one quantum: the encoder, the current frame's positions section (made
 * once per frame), its messages per scalar, and the newest keyframe's message (without a
 * scalar), which a client that lacks it gets before the next frame. */
typedef struct delta_chan {
    float quantum; /* 0: free */
    int users;
    delta_enc enc;
    unsigned char *section;
    size_t section_len, section_cap;
    uint64_t seq; /* of the pose the section encodes */
    wire wires[SCALAR_KINDS];
    wire key;
} delta_chan;

typedef struct event_slot {
    char *text;
    size_t len;
} event_slot;

/* One scene's channel: the sink its scene hands poses and events to. */
typedef struct feed feed;
struct feed {
    stream *st;
    scene *sc;           /* not held (the scene holds its sink): compared, its id copied, and asked
                          * whether it was deleted while the feed is open (stream_scene_removed) */
    char id[SCENE_ID_MAX];
    feed *next;          /* st->feeds, under feeds_lock */
    atomic_int closed;   /* the scene left: no more poses or events */

    /* frame handover (flock) */
    pthread_mutex_t flock;
    pose *latest, *spare[2];
    uint64_t seq, taken;

    /* events (elock) */
    pthread_mutex_t elock;
    event_slot *ring;     /* EVENT_RING; NULL once closed */
    uint64_t event_seq;   /* of the next event; event k is ring[k % EVENT_RING] */
    uint64_t event_first; /* of the oldest event still in the ring */
    size_t ring_bytes;

    atomic_int clients;
    atomic_uint scalars_wanted;
    atomic_int publish_asked; /* a "publish" command is on its way to the sim thread */
    atomic_int publish_again; /* and someone asked again meanwhile (it may come too late for them) */

    /* the service thread's own */
    wire wires[N_ENC][SCALAR_KINDS];
    delta_chan chans[DELTA_CHANNELS];
    pose *current;     /* the newest frame taken over, kept to encode for a new subscription */
    uint64_t current_seq;
};

/* A histogram of what each client got a second, observed for each client about once a second:
 * /metrics shows these, never a series per client (its labels would grow with every connection). */
#define N_BOUNDS 10
static const double fps_bounds[N_BOUNDS] = {1, 5, 10, 15, 20, 30, 45, 60, 90, 120};
static const double bps_bounds[N_BOUNDS] = {1e3, 1e4, 5e4, 1e5, 5e5, 1e6, 5e6, 1e7, 5e7, 1e8};
typedef struct hist {
    atomic_ullong bucket[N_BOUNDS + 1]; /* not cumulative; the last is +Inf */
    atomic_ullong sum_milli;            /* the sum of the observations, x 1000 */
} hist;

static void hist_observe(hist *h, const double *bounds, double v)
{
    int k = 0;
    while (k < N_BOUNDS && v > bounds[k]) k++;
    atomic_fetch_add(&h->bucket[k], 1);
    atomic_fetch_add(&h->sum_milli, (unsigned long long)(v * 1000.0));
}

static void hist_print(FILE *f, const char *name, const char *help, hist *h, const double *bounds)
{
    fprintf(f, "# HELP %s %s\n# TYPE %s histogram\n", name, help, name);
    unsigned long long cum = 0;
    for (int k = 0; k <= N_BOUNDS; k++) {
        cum += atomic_load(&h->bucket[k]);
        if (k < N_BOUNDS) fprintf(f, "%s_bucket{le=\"%g\"} %llu\n", name, bounds[k], cum);
        else fprintf(f, "%s_bucket{le=\"+Inf\"} %llu\n", name, cum);
    }
    fprintf(f, "%s_sum %.3f\n%s_count %llu\n", name, (double)atomic_load(&h->sum_milli) / 1000.0, name, cum);
}

/* What the service thread knows of one connected client for /metrics: a slot per client
 * (stream_max_clients of them), written by the service thread. */
typedef struct client_slot {
    atomic_ullong id; /* 0: free */
    atomic_ullong frames, bytes;
} client_slot;

typedef struct session session;
struct session {
    struct lws *wsi;
    uint64_t id;
    scene *sc;            /* the scene it streams: a held handle */
    feed *f;              /* that scene's feed; NULL once the scene is deleted (it is closing) */
    char want[SCENE_ID_MAX]; /* admit(): the scene it asked for */
    session *next;
    int encoding, scalar, max_fps;
    long long max_kbps;  /* 0: no limit */
    double next_send;    /* with max_kbps: no frame before this (clock_mono) */
    float quantum;       /* delta's grid */
    int chan;            /* delta: its channel (f->chans), else -1 */
    uint32_t key_have;   /* delta: the id of the last keyframe it was sent (0: none) */
    uint64_t last_frame; /* seq of the last frame sent */
    double last_send, behind_since;
    uint64_t next_event;
    char *hello;
    char *texts[MAX_TEXTS];
    int n_texts;
    char *rx;
    size_t rx_len;
    int rx_bad; /* 1 too large, 2 binary */
    int grab_in_flight;
    json_t *grab_pending; /* the newest grab or release asked while one was in flight */
    int dead;
    int gone;             /* its scene was deleted: closed with 1001 at its next write */
    access_level access;  /* from the token it connected with */
    int established;      /* counted in clients (a refused connection is closed too, never counted) */
    client_slot *slot;    /* its /metrics slot (NULL when none was free) */
    uint64_t fps_frames;  /* frames sent when fps_at was taken */
    uint64_t fps_bytes;   /* bytes sent then */
    double fps_at;
};

/* A grab or release on its way to the sim thread; the answer comes back through `done`. */
typedef struct grab_req {
    scene_cmd cmd;
    json_t *body;
    scene *sc;           /* held while it is on its way */
    uint64_t client;
    struct grab_req *next;
} grab_req;

struct stream {
    struct lws_context *ctx;
    const struct lws_protocols *protocol;
    scenes *table;
    pthread_t thread;
    atomic_int stop;
    int port;
    int max_clients, max_message;
    double stall_timeout;
    size_t ring_cap;
    const access_policy *acc;
    atomic_int http_port;

    /* the feeds, closed ones too (HTTP threads add, the service thread reads) */
    pthread_mutex_t feeds_lock;
    feed *feeds;
    atomic_int to_reap; /* a feed was closed: the service thread closes its clients */

    /* answers to grabs */
    pthread_mutex_t glock;
    grab_req *answered;

    atomic_int clients;

    /* the service thread's own */
    session *sessions;
    uint64_t next_id;
    float default_quantum;

    /* metrics */
    atomic_ullong encoded[N_ENC], sent[N_ENC], skipped[N_ENC], bytes_sent, stalled, refused[N_REFUSED];
    atomic_ullong encode_ns[N_ENC]; /* time spent encoding (delta: each pose's positions section and its messages) */
    atomic_ullong scene_closed;     /* clients closed because their scene was deleted */
    client_slot *slots; /* max_clients */
    hist client_fps, client_bps; /* each client's frames and bytes a second, about once a second */
};

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

static void give_back(feed *fd, pose *f)
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
        give_back(fd, f);
        pthread_mutex_unlock(&fd->flock);
        return;
    }
    if (fd->latest) give_back(fd, fd->latest);
    fd->latest = f;
    fd->seq++;
    pthread_mutex_unlock(&fd->flock);
    lws_cancel_service(fd->st->ctx);
}

static void sink_discard(void *ctx, pose *f)
{
    feed *fd = ctx;
    pthread_mutex_lock(&fd->flock);
    give_back(fd, f);
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

/* ---- messages to one client ---- */

static int send_text(struct lws *wsi, const char *text, stream *st)
{
    const size_t len = strlen(text);
    unsigned char *buf = malloc(LWS_PRE + len);
    if (!buf) return -1;
    memcpy(buf + LWS_PRE, text, len);
    const int n = lws_write(wsi, buf + LWS_PRE, len, LWS_WRITE_TEXT);
    free(buf);
    if (n < (int)len) return -1;
    atomic_fetch_add(&st->bytes_sent, len);
    return 0;
}

/* Queues a text for the client; a client that lets MAX_TEXTS pile up is closed (with `close`)
 * or the text is dropped. */
static void queue_text(session *s, char *text, int close)
{
    if (!text) return; /* out of memory: no message rather than a NULL in the queue */
    if (s->n_texts == MAX_TEXTS) {
        free(text);
        if (close) {
            s->dead = 1;
            lws_set_timeout(s->wsi, PENDING_TIMEOUT_USER_OK, LWS_TO_KILL_ASYNC);
        }
        return;
    }
    s->texts[s->n_texts++] = text;
    lws_callback_on_writable(s->wsi);
}

/* Queues an error for the client; a client that lets 8 pile up is closed. */
static void client_error(session *s, const char *about, int status, const char *param, const char *fmt, ...)
    __attribute__((format(printf, 5, 6)));
static void client_error(session *s, const char *about, int status, const char *param, const char *fmt, ...)
{
    char detail[256];
    va_list ap;
    va_start(ap, fmt);
    vsnprintf(detail, sizeof detail, fmt, ap);
    va_end(ap);
    queue_text(s, stream_msg_error(about, status, param, detail), 1);
}

/* The client's subscription as hello and the ack show it. */
static json_t *subscription_json(const session *s)
{
    return json_pack("{s:s, s:s, s:i, s:s, s:o, s:o}", "scene", s->f ? s->f->id : "", "encoding",
                     stream_encoding_names[s->encoding], "max_fps", s->max_fps, "scalar", stream_scalar_names[s->scalar],
                     "quantum", json_float(s->quantum), "max_kbps", s->max_kbps ? json_integer(s->max_kbps) : json_null());
}

/* The scene's hello (the same one a recording starts with: scene_hello) with the subscription. */
static char *hello_text(const session *s)
{
    json_t *o = scene_hello(s->sc, NULL, 0);
    if (!o) return NULL;
    json_object_set_new(o, "subscription", subscription_json(s));
    char *text = json_dumps(o, JSON_DUMP_FLAGS);
    json_decref(o);
    return text;
}

/* ---- grabs, through the sim thread ---- */

static void submit_grab(stream *st, session *s, json_t *body);

static void answered_cb(scene_cmd *cmd, void *arg)
{
    stream *st = arg;
    grab_req *g = (grab_req *)cmd; /* cmd is the first member */
    pthread_mutex_lock(&st->glock);
    g->next = st->answered;
    st->answered = g;
    pthread_mutex_unlock(&st->glock);
    lws_cancel_service(st->ctx);
}

/* A grab goes to the scene the client streams. */
static void submit_grab(stream *st, session *s, json_t *body)
{
    if (s->access < ACCESS_CONTROL) {
        const char *op = json_string_value(json_object_get(body, "op"));
        client_error(s, op, 403, NULL, "%s needs the control token (this connection has the view token)", op);
        json_decref(body);
        return;
    }
    if (s->grab_in_flight) {
        json_decref(s->grab_pending);
        s->grab_pending = body;
        return;
    }
    grab_req *g = calloc(1, sizeof *g);
    if (!g) {
        json_decref(body);
        return;
    }
    g->body = body;
    g->client = s->id;
    g->cmd.def = command_find(json_string_value(json_object_get(body, "op")));
    g->cmd.body = body;
    g->cmd.done = answered_cb;
    g->cmd.done_arg = st;
    snprintf(g->cmd.request_id, sizeof g->cmd.request_id, "stream-%llu", (unsigned long long)s->id);
    s->grab_in_flight = 1;
    g->sc = scene_hold(s->sc);
    scene_submit(g->sc, &g->cmd);
}

static void request_frame(feed *fd, scene *sc);

/* A publication asked for, with the scene it was asked of and its feed. */
typedef struct publish_req {
    scene_cmd cmd;
    scene *sc; /* held while it is on its way */
    feed *fd;
} publish_req;

static void published_cb(scene_cmd *cmd, void *arg)
{
    (void)arg;
    publish_req *p = (publish_req *)cmd; /* cmd is the first member */
    scene *sc = p->sc;
    feed *fd = p->fd;
    free(p);
    atomic_store(&fd->publish_asked, 0);
    if (atomic_exchange(&fd->publish_again, 0)) request_frame(fd, sc);
    scene_release(sc);
}

/* Asks the sim thread to publish a scene now (a paused scene publishes only after commands).
 * One request at a time per feed: asks that come while one is on its way make one more after it,
 * however many they are. */
static void request_frame(feed *fd, scene *sc)
{
    if (atomic_exchange(&fd->publish_asked, 1)) {
        atomic_store(&fd->publish_again, 1);
        return;
    }
    publish_req *p = calloc(1, sizeof *p);
    if (!p) {
        atomic_store(&fd->publish_asked, 0);
        return;
    }
    p->sc = scene_hold(sc);
    p->fd = fd;
    p->cmd.def = command_find("publish");
    p->cmd.done = published_cb;
    p->cmd.done_arg = fd->st;
    scene_submit(p->sc, &p->cmd);
}

static session *find(stream *st, uint64_t id)
{
    for (session *s = st->sessions; s; s = s->next)
        if (s->id == id) return s;
    return NULL;
}

static void take_answers(stream *st)
{
    pthread_mutex_lock(&st->glock);
    grab_req *list = st->answered;
    st->answered = NULL;
    pthread_mutex_unlock(&st->glock);
    while (list) {
        grab_req *g = list;
        list = g->next;
        session *s = find(st, g->client);
        if (s) {
            s->grab_in_flight = 0;
            if (g->cmd.failed)
                client_error(s, json_string_value(json_object_get(g->body, "op")), g->cmd.pr.status,
                             g->cmd.pr.param[0] ? g->cmd.pr.param : NULL, "%s", g->cmd.pr.detail);
            if (s->grab_pending) {
                json_t *next = s->grab_pending;
                s->grab_pending = NULL;
                if (s->f) submit_grab(st, s, next);
                else json_decref(next);
            }
        }
        json_decref(g->body);
        json_decref(g->cmd.result);
        free(g->cmd.blob);
        scene_release(g->sc);
        free(g);
    }
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
static feed *feed_of(stream *st, const scene *sc)
{
    pthread_mutex_lock(&st->feeds_lock);
    feed *fd = find_feed(st, sc);
    pthread_mutex_unlock(&st->feeds_lock);
    return fd;
}

/* A session leaves its delta channel; the last to leave frees it. */
static void leave_chan(feed *fd, session *s)
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
    if (fd->latest) give_back(fd, fd->latest);
    if (fd->current) give_back(fd, fd->current);
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
static void update_scalars(stream *st, feed *fd)
{
    unsigned want = 0;
    for (session *o = st->sessions; o; o = o->next)
        if (o->f == fd && o->scalar) want |= 1u << o->scalar;
    atomic_store(&fd->scalars_wanted, want);
}

/* A session starts streaming a feed (sc: its scene, a handle the session takes over): from its
 * events on, with a hello that shows the scene as it is. */
static void join_feed(stream *st, session *s, feed *fd, scene *sc)
{
    s->f = fd;
    s->sc = sc;
    s->last_frame = 0;
    s->key_have = 0;
    pthread_mutex_lock(&fd->elock);
    s->next_event = fd->event_seq; /* events from here on; hello shows the state before */
    pthread_mutex_unlock(&fd->elock);
    free(s->hello);
    s->hello = hello_text(s);
    update_scalars(st, fd);
    if (atomic_fetch_add(&fd->clients, 1) == 0 || !fd->current) request_frame(fd, sc);
    lws_callback_on_writable(s->wsi);
}

/* A session stops streaming its feed (its delta channel left already); its scene's handle is
 * the caller's to release. */
static void leave_feed(stream *st, session *s)
{
    feed *fd = s->f;
    if (!fd) return;
    leave_chan(fd, s);
    s->f = NULL;
    if (atomic_fetch_sub(&fd->clients, 1) == 1) forget_frames(fd);
    update_scalars(st, fd);
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
        leave_chan(fd, &none);
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

static void feed_free(feed *fd)
{
    feed_free_buffers(fd);
    pthread_mutex_destroy(&fd->flock);
    pthread_mutex_destroy(&fd->elock);
    free(fd);
}

/* The service thread closes the clients of the feeds closed since it last looked (1001, "scene
 * deleted", at their next write) and frees those feeds. */
static void reap_feeds(stream *st)
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
            leave_feed(st, s);
            s->gone = 1;
            atomic_fetch_add(&st->scene_closed, 1);
            lws_callback_on_writable(s->wsi);
        }
        *p = fd->next;
        feed_free(fd);
    }
    pthread_mutex_unlock(&st->feeds_lock);
}

/* ---- client messages ---- */

/* The channel of quantum q in a feed: the one in use, else a free one (initialised); -1 when all
 * are taken by other quanta (or out of memory). */
static int find_chan(feed *fd, float q)
{
    int free_one = -1;
    for (int c = 0; c < DELTA_CHANNELS; c++) {
        if (fd->chans[c].users > 0 && fd->chans[c].quantum == q) return c;
        if (fd->chans[c].users == 0 && free_one < 0) free_one = c;
    }
    if (free_one < 0 || delta_init(&fd->chans[free_one].enc, (double)q) != 0) return -1;
    fd->chans[free_one].quantum = q;
    return free_one;
}

/* The feed a subscribe names (a held handle on its scene in *sc), or the session's own (*sc
 * NULL); NULL after an error to the client when the daemon has no such scene. */
static feed *subscribe_target(stream *st, session *s, const stream_msg *m, scene **sc)
{
    *sc = NULL;
    if (!m->scene[0] || strcmp(m->scene, s->f->id) == 0) return s->f;
    scene *to = scenes_get(st->table, m->scene);
    feed *fd = to ? feed_of(st, to) : NULL;
    if (!fd) {
        scene_release(to);
        client_error(s, "subscribe", 404, "scene", "this clothd has no scene '%s' (GET /v1/scenes lists them)", m->scene);
        return NULL;
    }
    *sc = to;
    return fd;
}

static void handle_subscribe(stream *st, session *s, const stream_msg *m)
{
    scene *to_sc;
    feed *to = subscribe_target(st, s, m, &to_sc);
    if (!to) return; /* the subscription stays as it was */
    const int enc = m->encoding >= 0 ? m->encoding : s->encoding, sc = m->scalar >= 0 ? m->scalar : s->scalar;
    const int fps = m->max_fps >= 0 ? m->max_fps : s->max_fps;
    const long long kbps = m->max_kbps >= 0 ? m->max_kbps : s->max_kbps;
    const float q = m->quantum >= 0 ? (float)m->quantum : s->quantum;
    const int switching = to != s->f;
    const int new_chan = enc == CLF_DELTA && (switching || s->chan < 0 || s->f->chans[s->chan].quantum != q);
    int c = s->chan;
    if (new_chan) {
        c = find_chan(to, q);
        if (c < 0 && !switching && s->chan >= 0 && to->chans[s->chan].users == 1) {
            leave_chan(to, s); /* its own channel alone: it takes the new quantum */
            c = find_chan(to, q);
        }
        if (c < 0) {
            scene_release(to_sc);
            client_error(s, "subscribe", 422, "quantum",
                         "at most %d different quanta are in use at once in a scene, by all its clients together; "
                         "subscribe with one of theirs (or without one, for the default %g)", DELTA_CHANNELS,
                         (double)st->default_quantum);
            return; /* the subscription stays as it was */
        }
        to->chans[c].users++;
    }
    if (new_chan || enc != CLF_DELTA) leave_chan(s->f, s);
    if (switching) {
        leave_feed(st, s);
        scene_release(s->sc);
        s->sc = NULL;
    }
    s->chan = new_chan ? c : s->chan;
    s->quantum = q;
    s->key_have = 0; /* a delta subscriber gets the keyframe first */
    s->encoding = enc;
    s->scalar = sc;
    s->max_fps = fps;
    s->max_kbps = kbps;
    s->next_send = 0;
    s->last_frame = 0; /* the next frame in the new encoding at once */
    if (switching) join_feed(st, s, to, to_sc); /* a hello of the new scene, then the ack */
    else update_scalars(st, to);
    if (sc != SCALAR_NONE && (!to->current || !to->current->has[sc])) request_frame(to, s->sc); /* poses lack it */
    json_t *ack = subscription_json(s);
    json_object_set_new(ack, "type", json_string("subscribed"));
    queue_text(s, json_dumps(ack, JSON_DUMP_FLAGS), 0); /* the same queue, in order */
    json_decref(ack);
}

static void handle_message(stream *st, session *s)
{
    if (!s->f) return; /* its scene was deleted: it is closing */
    if (s->rx_bad) {
        client_error(s, "message", s->rx_bad == 1 ? 413 : 400, NULL,
                     s->rx_bad == 1 ? "a message may hold at most %d bytes" : "binary messages are not understood (%d)",
                     st->max_message);
        return;
    }
    stream_msg m;
    switch (stream_msg_parse(s->rx, s->rx_len, &m)) {
    case STREAM_MSG_REFUSED:
        client_error(s, m.about, m.pr.status, m.has_param ? m.pr.param : NULL, "%s", m.pr.detail);
        break;
    case STREAM_MSG_SUBSCRIBE: handle_subscribe(st, s, &m); break;
    case STREAM_MSG_KEYFRAME:
        if (s->chan < 0) {
            client_error(s, "keyframe", 422, NULL, "keyframes are for delta clients: subscribe with \"encoding\": \"delta\" first");
            break;
        }
        delta_want_key(&s->f->chans[s->chan].enc); /* the encoder keeps them at most 4 a second */
        break;
    case STREAM_MSG_COMMAND:
        submit_grab(st, s, m.cmd);
        m.cmd = NULL; /* submit_grab owns it */
        break;
    }
    stream_msg_free(&m);
}

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
static void take_newest(stream *st)
{
    int any = 0;
    pthread_mutex_lock(&st->feeds_lock);
    for (feed *fd = st->feeds; fd; fd = fd->next) {
        pthread_mutex_lock(&fd->flock);
        if (fd->latest && fd->seq != fd->taken) {
            pose *f = fd->latest;
            fd->latest = NULL;
            fd->taken = fd->seq;
            if (fd->current) give_back(fd, fd->current);
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
static void sweep(stream *st)
{
    const double t = clock_mono();
    for (session *s = st->sessions; s; s = s->next) {
        if (!s->f) continue;
        if (s->slot && t - s->fps_at >= 1.0) { /* the achieved frame rate, about once a second */
            const uint64_t frames = atomic_load(&s->slot->frames), bytes = atomic_load(&s->slot->bytes);
            const double fps = (double)(frames - s->fps_frames) / (t - s->fps_at);
            hist_observe(&st->client_fps, fps_bounds, fps);
            hist_observe(&st->client_bps, bps_bounds, (double)(bytes - s->fps_bytes) / (t - s->fps_at));
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

/* One message to a client that can take it: hello, errors and acks, events, then the newest
 * frame (when its rate allows). A client whose scene was deleted is closed instead. */
static int writeable(stream *st, session *s)
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
        const int rc = send_text(s->wsi, s->hello, st);
        free(s->hello);
        s->hello = NULL;
        lws_callback_on_writable(s->wsi);
        return rc;
    }
    if (s->n_texts) {
        const int rc = send_text(s->wsi, s->texts[0], st);
        free(s->texts[0]);
        memmove(s->texts, s->texts + 1, sizeof s->texts[0] * (size_t)(--s->n_texts));
        lws_callback_on_writable(s->wsi);
        return rc;
    }
    feed *fd = s->f;
    pthread_mutex_lock(&fd->elock);
    char *event = NULL;
    if (fd->ring && s->next_event < fd->event_seq) {
        if (s->next_event < fd->event_first) {
            const unsigned long long behind = (unsigned long long)(fd->event_seq - s->next_event);
            pthread_mutex_unlock(&fd->elock);
            log_msg("stream: client %llu fell %llu events behind, past what the event ring keeps: disconnected",
                    (unsigned long long)s->id, behind);
            atomic_fetch_add(&st->stalled, 1);
            return -1;
        }
        event = strdup(fd->ring[s->next_event % EVENT_RING].text);
        s->next_event++;
    }
    pthread_mutex_unlock(&fd->elock);
    if (event) {
        const int rc = send_text(s->wsi, event, st);
        free(event);
        lws_callback_on_writable(s->wsi);
        return rc;
    }
    const wire *w = wire_of(st, s);
    if (w->seq > s->last_frame && w->len) {
        const double t = clock_mono();
        double wait = 1.0 / s->max_fps - (t - s->last_send);
        if (s->max_kbps && s->next_send - t > wait) wait = s->next_send - t; /* its byte budget */
        if (wait > 0.0005) {
            lws_set_timer_usecs(s->wsi, (lws_usec_t)(wait * 1e6));
            return 0;
        }
        if (s->chan >= 0 && s->encoding == CLF_DELTA && w->key_id != s->key_have) {
            /* It lacks the keyframe this frame refers to: that first (unless this is it). */
            const wire *key = &fd->chans[s->chan].key;
            if (key->len && key->key_id == w->key_id && key->seq != w->seq) {
                const int n = lws_write(s->wsi, key->buf + LWS_PRE, key->len, LWS_WRITE_BINARY);
                if (n < (int)key->len) return -1;
                atomic_fetch_add(&st->bytes_sent, key->len);
                if (s->slot) atomic_fetch_add(&s->slot->bytes, key->len);
                spend(s, key->len, t);
                s->key_have = key->key_id;
                lws_callback_on_writable(s->wsi);
                return 0;
            }
        }
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
    }
    return 0;
}

/* ---- libwebsockets ---- */

static int path_ok(struct lws *wsi)
{
    char uri[128];
    if (lws_hdr_copy(wsi, uri, sizeof uri, WSI_TOKEN_GET_URI) <= 0) return 0;
    return strcmp(uri, STREAM_PATH) == 0;
}

/* A header's value; NULL when the request has none. *too_long is set when it has one that does
 * not fit buf (it is then neither absent nor readable: the caller refuses it). */
static const char *header_of(struct lws *wsi, enum lws_token_indexes h, char *buf, int len, int *too_long)
{
    const int n = lws_hdr_total_length(wsi, h);
    if (n <= 0) return NULL;
    if (n >= len || lws_hdr_copy(wsi, buf, len, h) <= 0) {
        *too_long = 1;
        return NULL;
    }
    return buf;
}

/* The token a client offers: `?token=` in the URL, or a `bearer.<token>` entry of the
 * subprotocol list (`Sec-WebSocket-Protocol: clothd.v1, bearer.<token>`: what a browser, which
 * cannot set Authorization on a WebSocket, can send). */
static const char *offered_token(struct lws *wsi, char *buf, int len)
{
    const char *q = lws_get_urlarg_by_name(wsi, "token=", buf, len);
    if (q) return q;
    char list[1200];
    int too_long = 0;
    if (!header_of(wsi, WSI_TOKEN_PROTOCOL, list, sizeof list, &too_long)) return NULL;
    for (char *save = NULL, *t = strtok_r(list, ", ", &save); t; t = strtok_r(NULL, ", ", &save)) {
        if (strncmp(t, "bearer.", 7) == 0 && strlen(t + 7) < (size_t)len) {
            memcpy(buf, t + 7, strlen(t + 7) + 1);
            return buf;
        }
    }
    return NULL;
}

/* Answers a refused upgrade request with its HTTP status and a problem+json body, written to the
 * socket before libwebsockets closes it, so a client can tell 401 from 404 from 503 (the answer
 * is a few hundred bytes: the socket's empty send buffer takes it whole). */
static void refuse(stream *st, struct lws *wsi, int why, int status, const char *slug, const char *extra,
                   const char *fmt, ...) __attribute__((format(printf, 7, 8)));
static void refuse(stream *st, struct lws *wsi, int why, int status, const char *slug, const char *extra,
                   const char *fmt, ...)
{
    atomic_fetch_add(&st->refused[why], 1);
    problem pr;
    pr.status = status;
    pr.slug = slug;
    pr.param[0] = '\0';
    va_list ap;
    va_start(ap, fmt);
    vsnprintf(pr.detail, sizeof pr.detail, fmt, ap);
    va_end(ap);
    char *body = problem_body(&pr);
    const char *phrase = status == 401 ? "Unauthorized" : status == 403 ? "Forbidden" : status == 404 ? "Not Found"
                       : status == 426 ? "Upgrade Required" : status == 503 ? "Service Unavailable" : "Bad Request";
    char *msg = NULL;
    const int n = asprintf(&msg,
                           "HTTP/1.1 %d %s\r\nContent-Type: application/problem+json\r\nContent-Length: %zu\r\n"
                           "Cache-Control: no-store\r\nConnection: close\r\n%s\r\n%s",
                           status, phrase, body ? strlen(body) : 0, extra ? extra : "", body ? body : "");
    free(body);
    if (n > 0) {
        const int fd = lws_get_socket_fd(wsi);
        if (fd >= 0 && send(fd, msg, (size_t)n, MSG_NOSIGNAL | MSG_DONTWAIT) != n)
            log_msg("stream: could not send a refusal (%d) whole", status);
    }
    free(msg);
}

/* Before the upgrade completes: the path, the version (RFC 6455's 13 only), Host and the page's
 * Origin, the token, the scene (?scene=), the client limit. A refused request gets its status and a problem+json
 * body, then libwebsockets closes the connection. (A subprotocol list without clothd.v1 is
 * refused by libwebsockets itself, before this, by closing the connection.) */
static int admit(stream *st, struct lws *wsi, session *s)
{
    if (!path_ok(wsi)) {
        refuse(st, wsi, REFUSED_PATH, 404, "not-found", NULL, "the stream is at %s", STREAM_PATH);
        return 0;
    }
    char version[16], origin[300], host[300], token[600];
    int too_long = 0;
    const char *v = header_of(wsi, WSI_TOKEN_VERSION, version, sizeof version, &too_long);
    if (!v || strcmp(v, "13") != 0) {
        refuse(st, wsi, REFUSED_VERSION, 426, "upgrade-required", "Sec-WebSocket-Version: 13\r\n",
               "this server speaks WebSocket version 13 (RFC 6455) only");
        return 0;
    }
    const char *h = header_of(wsi, WSI_TOKEN_HOST, host, sizeof host, &too_long);
    if (too_long || !access_host_ok(st->acc, h)) {
        refuse(st, wsi, REFUSED_HOST, 403, "host-not-allowed", NULL,
               "Host '%.100s' is not a name of this server: use its address, localhost, or add the name to allowed_hosts",
               h ? h : "(too long)");
        return 0;
    }
    const char *o = header_of(wsi, WSI_TOKEN_ORIGIN, origin, sizeof origin, &too_long);
    if (too_long || !access_origin_ok(st->acc, o, h, atomic_load(&st->http_port))) {
        log_msg("stream: refused a connection from origin %.200s (host %.200s): not this viewer's and not in "
                "allowed_origins", o ? o : too_long ? "(too long)" : "(none)", h ? h : "(none)");
        refuse(st, wsi, REFUSED_ORIGIN, 403, "cross-site", NULL,
               "a page of origin %.100s may not open the stream: only the viewer's own page, or an origin of "
               "allowed_origins", o ? o : "(too long)");
        return 0;
    }
    s->access = access_token(st->acc, offered_token(wsi, token, sizeof token));
    if (s->access == ACCESS_NONE) {
        refuse(st, wsi, REFUSED_TOKEN, 401, "unauthorized", "WWW-Authenticate: Bearer realm=\"clothd\"\r\n",
               "this stream needs the control or view token: a 'bearer.<token>' subprotocol or ?token=<token>");
        return 0;
    }
    /* The scene: ?scene=ID, "default" without one. */
    char want[SCENE_ID_MAX + 8];
    const char *id = lws_get_urlarg_by_name(wsi, "scene=", want, sizeof want);
    if (!id) id = SCENE_DEFAULT;
    if (!scene_id_valid(id)) {
        refuse(st, wsi, REFUSED_SCENE, 400, "bad-scene-id", NULL,
               "a scene id is 1 to 63 of a-z, 0-9, _ and -, starting with a letter or digit (got '%.80s')", id);
        return 0;
    }
    scene *sc = scenes_get(st->table, id);
    const feed *fd = sc ? feed_of(st, sc) : NULL;
    scene_release(sc);
    if (!fd) {
        refuse(st, wsi, REFUSED_SCENE, 404, "not-found", NULL, "this clothd has no scene '%s' (GET /v1/scenes lists them)", id);
        return 0;
    }
    snprintf(s->want, sizeof s->want, "%s", id);
    if (atomic_load(&st->clients) >= st->max_clients) {
        refuse(st, wsi, REFUSED_CLIENTS, 503, "too-many-clients", NULL,
               "the stream has stream_max_clients (%d) clients already", st->max_clients);
        return 0;
    }
    return 1;
}

static int callback(struct lws *wsi, enum lws_callback_reasons reason, void *user, void *in, size_t len)
{
    stream *st = lws_context_user(lws_get_context(wsi));
    session *s = user;
    switch (reason) {
    case LWS_CALLBACK_FILTER_PROTOCOL_CONNECTION:
        return admit(st, wsi, s) ? 0 : -1;
    case LWS_CALLBACK_ESTABLISHED: {
        const access_level granted = s->access; /* set by admit() in this same allocation */
        char want[SCENE_ID_MAX];
        memcpy(want, s->want, sizeof want);
        memset(s, 0, sizeof *s);
        s->access = granted;
        scene *sc = scenes_get(st->table, want);
        feed *fd = sc ? feed_of(st, sc) : NULL;
        if (!fd) { /* deleted since admit() */
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
        for (int k = 0; k < st->max_clients && !s->slot; k++) {
            if (atomic_load(&st->slots[k].id) == 0) {
                s->slot = &st->slots[k];
                atomic_store(&s->slot->frames, 0);
                atomic_store(&s->slot->bytes, 0);
                atomic_store(&s->slot->id, s->id);
            }
        }
        s->next = st->sessions;
        st->sessions = s;
        atomic_fetch_add(&st->clients, 1);
        join_feed(st, s, fd, sc);
        return 0;
    }
    case LWS_CALLBACK_CLOSED:
        /* libwebsockets closes the connections admit() refused here too: they were never counted. */
        if (!s || !s->established) return 0;
        for (session **p = &st->sessions; *p; p = &(*p)->next) {
            if (*p == s) {
                *p = s->next;
                break;
            }
        }
        leave_feed(st, s);
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
        return 0;
    case LWS_CALLBACK_RECEIVE: {
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
            handle_message(st, s);
            s->rx_len = 0;
            s->rx_bad = 0;
        }
        return 0;
    }
    case LWS_CALLBACK_SERVER_WRITEABLE: return writeable(st, s);
    case LWS_CALLBACK_TIMER: lws_callback_on_writable(wsi); return 0;
    case LWS_CALLBACK_EVENT_WAIT_CANCELLED:
        take_answers(st);
        reap_feeds(st);
        take_newest(st);
        sweep(st);
        lws_callback_on_writable_all_protocol(lws_get_context(wsi), st->protocol);
        return 0;
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
    take_answers(st);
    for (feed *fd = st->feeds, *next; fd; fd = next) {
        next = fd->next;
        feed_free(fd);
    }
    pthread_mutex_destroy(&st->feeds_lock);
    pthread_mutex_destroy(&st->glock);
    free(st->slots);
    free(st);
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

char *stream_metrics(stream *st)
{
    char *out = NULL;
    size_t len = 0;
    FILE *f = open_memstream(&out, &len);
    if (!f) return NULL;
    fprintf(f, "# HELP clothd_stream_clients WebSocket clients connected.\n# TYPE clothd_stream_clients gauge\n"
               "clothd_stream_clients %d\n", atomic_load(&st->clients));
    const char *what[3] = {"encoded", "sent", "skipped"};
    atomic_ullong *arrays[3] = {st->encoded, st->sent, st->skipped};
    for (int a = 0; a < 3; a++) {
        fprintf(f, "# HELP clothd_stream_frames_%s_total Frames %s, by encoding.\n# TYPE clothd_stream_frames_%s_total counter\n",
                what[a], what[a], what[a]);
        for (int e = 0; e < N_ENC; e++)
            fprintf(f, "clothd_stream_frames_%s_total{encoding=\"%s\"} %llu\n", what[a], stream_encoding_names[e],
                    (unsigned long long)atomic_load(&arrays[a][e]));
    }
    fprintf(f, "# HELP clothd_stream_encode_seconds_total Time spent encoding frames, by encoding.\n"
               "# TYPE clothd_stream_encode_seconds_total counter\n");
    for (int e = 0; e < N_ENC; e++)
        fprintf(f, "clothd_stream_encode_seconds_total{encoding=\"%s\"} %.6f\n", stream_encoding_names[e],
                (double)atomic_load(&st->encode_ns[e]) * 1e-9);
    hist_print(f, "clothd_stream_client_fps",
               "Frames a second a connected client got, observed for each client about once a second.", &st->client_fps,
               fps_bounds);
    hist_print(f, "clothd_stream_client_bytes_per_second",
               "Bytes a second a connected client got, observed for each client about once a second.", &st->client_bps,
               bps_bounds);
    fprintf(f, "# HELP clothd_stream_scene_clients WebSocket clients streaming each scene (at most max_scenes series).\n"
               "# TYPE clothd_stream_scene_clients gauge\n");
    pthread_mutex_lock(&st->feeds_lock);
    /* A scene deleted from the table has no series, though the sim thread has not closed its feed
     * yet (it does so on its next turn): its scene is alive until then (stream_scene_removed). */
    for (const feed *fd = st->feeds; fd; fd = fd->next)
        if (!atomic_load(&fd->closed) && !scene_is_deleted(fd->sc)) fprintf(f, "clothd_stream_scene_clients{scene=\"%s\"} %d\n", fd->id, atomic_load(&fd->clients));
    pthread_mutex_unlock(&st->feeds_lock);
    fprintf(f, "# HELP clothd_stream_scene_closed_total Clients closed because the scene they streamed was deleted.\n"
               "# TYPE clothd_stream_scene_closed_total counter\nclothd_stream_scene_closed_total %llu\n",
            (unsigned long long)atomic_load(&st->scene_closed));
    fprintf(f, "# HELP clothd_stream_bytes_sent_total Bytes written to stream clients.\n"
               "# TYPE clothd_stream_bytes_sent_total counter\nclothd_stream_bytes_sent_total %llu\n",
            (unsigned long long)atomic_load(&st->bytes_sent));
    fprintf(f, "# HELP clothd_stream_disconnected_total Clients disconnected for stalling.\n"
               "# TYPE clothd_stream_disconnected_total counter\nclothd_stream_disconnected_total %llu\n",
            (unsigned long long)atomic_load(&st->stalled));
    fprintf(f, "# HELP clothd_stream_refused_total Connections refused before the upgrade, by reason: path, version, "
               "host, origin, token, scene (an invalid or unknown ?scene=), clients (stream_max_clients).\n# TYPE clothd_stream_refused_total counter\n");
    for (int k = 0; k < N_REFUSED; k++)
        fprintf(f, "clothd_stream_refused_total{reason=\"%s\"} %llu\n", refused_names[k],
                (unsigned long long)atomic_load(&st->refused[k]));
    fclose(f);
    return out;
}

const frame_sink_ops stream_sink_ops = {sink_begin, sink_publish, sink_discard, sink_event, sink_bytes};

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
