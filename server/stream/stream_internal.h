/* stream_internal.h - what the stream's files share (not for use outside server/stream/): the
 * feed (a scene's channel), the session (a client), the stream itself, and the functions one file
 * of the stream calls in another. stream.c describes the threads and who owns what.
 *
 *   stream.c          the public entry points and the libwebsockets glue (the protocol callback,
 *                     the service thread, start and stop)
 *   feed.c            feeds: the sink the sim thread hands poses and events to, a session's
 *                     joining and leaving, closing a deleted scene's feed
 *   session.c         a client's messages: texts and errors to it, grabs through the sim thread,
 *                     what it sends (subscribe, keyframe, commands)
 *   frames.c          frames: encoding the newest pose once per encoding, writing to a client,
 *                     stalled clients
 *   admission.c       the checks before the upgrade (path, version, Host, Origin, token, scene,
 *                     client limit)
 *   stream_metrics.c  /metrics: the counters and the per-client histograms
 *
 * It declares `stream` itself rather than include stream.h (which the files include beside it):
 * a header of the stream module that included this one back would be an include cycle. */
#ifndef CLOTHD_STREAM_INTERNAL_H
#define CLOTHD_STREAM_INTERNAL_H

#include <libwebsockets.h>
#include <pthread.h>
#include <stdatomic.h>
#include <stddef.h>
#include <stdint.h>

#include <jansson.h>

#include "clothd_frame.h"
#include "core/access.h"
#include "core/delta.h"
#include "core/pose.h"
#include "core/settings.h"
#include "core/stream_msg.h"
#include "sim/commands.h"
#include "sim/scenes.h"
#include "sim/sink.h"

typedef struct stream stream;

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

/* A histogram of what each client got a second (stream_metrics.c). */
#define N_BOUNDS 10
typedef struct hist {
    atomic_ullong bucket[N_BOUNDS + 1]; /* not cumulative; the last is +Inf */
    atomic_ullong sum_milli;            /* the sum of the observations, x 1000 */
} hist;


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
    char want[SCENE_ID_MAX]; /* stream_admit(): the scene it asked for */
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

/* feed.c */
/* The open feed of a scene, or NULL. */
feed *stream_feed_of(stream *st, const scene *sc);
/* Hands a pose back to the feed's spares, or frees it (the feed's flock held). */
void stream_give_back(feed *fd, pose *f);
/* A session leaves its delta channel; the last to leave frees it. */
void stream_leave_chan(feed *fd, session *s);
/* The scalars the clients of a feed want, for the sim thread. */
void stream_update_scalars(stream *st, feed *fd);
/* A session starts streaming a feed (sc: its scene, a handle the session takes over). */
void stream_join_feed(stream *st, session *s, feed *fd, scene *sc);
/* A session stops streaming its feed; its scene's handle is the caller's to release. */
void stream_leave_feed(stream *st, session *s);
void stream_feed_free(feed *fd);
/* The service thread closes the clients of the feeds closed since it last looked and frees them. */
void stream_reap_feeds(stream *st);

/* session.c */
int stream_send_text(struct lws *wsi, const char *text, stream *st);
/* The scene's hello with the session's subscription (malloc'd), or NULL. */
char *stream_hello_text(const session *s);
/* Asks the sim thread to publish a scene now (at most one request per feed on its way). */
void stream_request_frame(feed *fd, scene *sc);
/* The answers to grabs that came back from the sim thread. */
void stream_take_answers(stream *st);
/* A whole message the client sent (in s->rx). */
void stream_handle_message(stream *st, session *s);

/* frames.c */
/* Takes over the newest pose of each feed and encodes it for what its clients use. */
void stream_take_newest(stream *st);
/* Observes each client's rates; closes the stalled ones. */
void stream_sweep(stream *st);
/* One message to a client that can take it; -1 closes it. */
int stream_writeable(stream *st, session *s);

/* admission.c */
/* Before the upgrade completes: 1 to admit the connection, 0 when it was refused (answered). */
int stream_admit(stream *st, struct lws *wsi, session *s);

/* stream_metrics.c */
/* One client's frames and bytes a second, into the histograms. */
void stream_observe_client(stream *st, double fps, double bps);

#endif
