/* admission.c - who may open the stream (see stream.c): the checks before the upgrade
 * completes, and a refused request's answer (its status and a problem+json body).
 *
 * LWS_CALLBACK_HTTP_CONFIRM_UPGRADE is deliberately not handled (CVE-2025-11677 in 4.1.6):
 * connections are checked in LWS_CALLBACK_FILTER_PROTOCOL_CONNECTION instead (stream.c). */
#include <stdarg.h>
#include <stdatomic.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/socket.h>

#include "core/access.h"
#include "core/log.h"
#include "core/problem.h"
#include "stream/stream_internal.h"

/* ---- before the upgrade ---- */

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
int stream_admit(stream *st, struct lws *wsi, session *s)
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
    const feed *fd = sc ? stream_feed_of(st, sc) : NULL;
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
