/* session.c - a stream client's messages (see stream.c): the texts and errors queued to it,
 * its grabs through the sim thread, and what it sends (subscribe, keyframe, commands). */
#include <stdarg.h>
#include <stdatomic.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "core/json_write.h"
#include "core/stream_msg.h"
#include "stream/stream_internal.h"

/* ---- messages to one client ---- */

int stream_send_text(struct lws *wsi, const char *text, stream *st)
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
char *stream_hello_text(const session *s)
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
    if (atomic_exchange(&fd->publish_again, 0)) stream_request_frame(fd, sc);
    scene_release(sc);
}

/* Asks the sim thread to publish a scene now (a paused scene publishes only after commands).
 * One request at a time per feed: asks that come while one is on its way make one more after it,
 * however many they are. */
void stream_request_frame(feed *fd, scene *sc)
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

void stream_take_answers(stream *st)
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
    feed *fd = to ? stream_feed_of(st, to) : NULL;
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
            stream_leave_chan(to, s); /* its own channel alone: it takes the new quantum */
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
    if (new_chan || enc != CLF_DELTA) stream_leave_chan(s->f, s);
    if (switching) {
        stream_leave_feed(st, s);
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
    if (switching) stream_join_feed(st, s, to, to_sc); /* a hello of the new scene, then the ack */
    else stream_update_scalars(st, to);
    if (sc != SCALAR_NONE && (!to->current || !to->current->has[sc])) stream_request_frame(to, s->sc); /* poses lack it */
    json_t *ack = subscription_json(s);
    json_object_set_new(ack, "type", json_string("subscribed"));
    queue_text(s, json_dumps(ack, JSON_DUMP_FLAGS), 0); /* the same queue, in order */
    json_decref(ack);
}

void stream_handle_message(stream *st, session *s)
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
