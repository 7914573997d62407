/* http.c - the HTTP API on libmicrohttpd (see http.h).
 *
 * The command table (sim/commands.h) drives dispatch, the token each route needs, 405 answers
 * with Allow, metrics labels and `clothd routes`; this file is what libmicrohttpd needs around
 * it. libmicrohttpd calls the access handler several times per request: the first call only
 * records the request (answering then would close a keep-alive connection), body calls append to
 * a buffer counted against max_body (413 beyond), the last call dispatches. A row either answers
 * from what its scene published at once, or makes a command for the sim thread: the connection is
 * suspended, the sim thread resumes it once the command has been run, and the next call answers
 * with the result. A request holds its scene (a handle from the scene table) until it is
 * answered. */
#include <arpa/inet.h>
#include <ctype.h>
#include <errno.h>
#include <limits.h>
#ifdef __GLIBC__
#include <malloc.h>
#endif
#include <microhttpd.h>
#include <netdb.h>
#include <pthread.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <strings.h>
#include <sys/resource.h>
#include <sys/syscall.h>
#include <time.h>
#include <unistd.h>

#include "core/access.h"
#include "core/clock.h"
#include "core/conns.h"
#include "core/log.h"
#include "core/problem.h"
#include "core/ratelimit.h"
#include "http/http.h"
#include "http/static_files.h"
#include "sim/commands.h"
#include "sim/simloop.h"
#include "stream/stream.h"

#if MHD_VERSION < 0x00097002
typedef int MHD_Result;
#else
typedef enum MHD_Result MHD_Result;
#endif

struct http_server {
    struct MHD_Daemon *d;
    scenes *table;
    metrics *m;
    http_info info;
    api_daemon daemon;       /* what the daemon-wide routes read */
    clothd_settings set;
    char web_root[PATH_MAX]; /* resolved; empty when the directory does not exist */
    int port;
    ratelimit *rate;         /* changing requests per client address */
    unsigned nonce;          /* made at start: the first part of the request ids made here */
    atomic_ullong requests;  /* requests given an id here: the second part */
    ratelimit *refused_rate; /* refused requests (401, 403) per client address: a budget of their own */
    conns *conns;            /* every connection, for the deadlines libmicrohttpd does not keep */
    pthread_t sweeper;
    int sweeping;
    pthread_mutex_t stop_lock;
    pthread_cond_t stop_cond;
    int stopping;
    atomic_int trims_due;    /* sweeps that give the free heap back, after a large body */
};

/* An answer and what only HTTP says of it. */
typedef struct reply {
    api_reply a;
    char allow[64];
    int authenticate; /* 401: ask for a bearer token */
    int close;        /* the request's framing is not to be trusted: answer, then close */
} reply;

typedef struct req {
    http_server *s;
    struct MHD_Connection *conn;
    const char *label; /* route pattern for metrics */
    char method[8];
    char url[2048];
    char authority[256]; /* of an absolute-form target (http://host:port/path), which names the host */
    int malformed;       /* answered 400/414/501 on its first call */
    char *body;
    size_t len, cap;
    int too_large;
    char request_id[129];
    double t0;           /* clock_mono when its head came (the access log's duration) */
    int phase;           /* 0 new, 1 waiting for the sim thread, 2 its answer is in */
    scene *sc;           /* the scene addressed, held until the request is answered */
    scene_cmd cmd;
} req;

static void reply_error(reply *out, int status, const char *slug, const char *param, const char *detail)
{
    problem pr;
    problem_set(&pr, status, slug, param, "%s", detail);
    api_problem(&out->a, &pr);
}

/* ---- request helpers ---- */

static const char *header(req *r, const char *name)
{
    return MHD_lookup_connection_value(r->conn, MHD_HEADER_KIND, name);
}

static const char *query(req *r, const char *name)
{
    return MHD_lookup_connection_value(r->conn, MHD_GET_ARGUMENT_KIND, name);
}

static int wants_binary(req *r)
{
    const char *a = header(r, "Accept");
    return a && strstr(a, "application/octet-stream") != NULL;
}

static char *http_metrics(void *ctx);

static double last_turn(void *loop) { return simloop_last_turn(loop); }

/* ---- libmicrohttpd glue ---- */

static MHD_Result send_reply(req *r, reply *rep)
{
    api_reply *a = &rep->a;
    struct MHD_Response *resp =
        a->body && a->release ? MHD_create_response_from_buffer_with_free_callback_cls(a->len, a->body, a->release, a->release_cls)
                              : MHD_create_response_from_buffer(a->body ? a->len : 0, a->body ? a->body : (void *)"",
                                                                a->body ? MHD_RESPMEM_MUST_FREE : MHD_RESPMEM_PERSISTENT);
    if (!resp) {
        if (a->body && a->release) a->release(a->release_cls);
        else free(a->body);
        return MHD_NO;
    }
    if (a->ctype) MHD_add_response_header(resp, MHD_HTTP_HEADER_CONTENT_TYPE, a->ctype);
    MHD_add_response_header(resp, MHD_HTTP_HEADER_CACHE_CONTROL, "no-store");
    if (rep->allow[0]) MHD_add_response_header(resp, MHD_HTTP_HEADER_ALLOW, rep->allow);
    if (a->retry_after > 0) {
        char v[16];
        snprintf(v, sizeof v, "%d", a->retry_after);
        MHD_add_response_header(resp, MHD_HTTP_HEADER_RETRY_AFTER, v);
    }
    if (a->location[0]) MHD_add_response_header(resp, MHD_HTTP_HEADER_LOCATION, a->location);
    if (a->disposition[0]) MHD_add_response_header(resp, MHD_HTTP_HEADER_CONTENT_DISPOSITION, a->disposition);
    if (rep->authenticate) MHD_add_response_header(resp, MHD_HTTP_HEADER_WWW_AUTHENTICATE, "Bearer realm=\"clothd\"");
    if (rep->close) MHD_add_response_header(resp, MHD_HTTP_HEADER_CONNECTION, "close");
    if (r->request_id[0]) MHD_add_response_header(resp, "X-Request-Id", r->request_id);
    /* A page of an origin the operator allowed may read the answers; no other page may. */
    const char *origin = header(r, "Origin");
    if (r->s->info.access && access_origin_listed(r->s->info.access, origin)) {
        MHD_add_response_header(resp, "Access-Control-Allow-Origin", origin);
        MHD_add_response_header(resp, "Vary", "Origin");
    }
    const MHD_Result ret = MHD_queue_response(r->conn, (unsigned int)a->status, resp);
    MHD_destroy_response(resp);
    metrics_http(r->s->m, r->label, r->method, a->status);
    log_access(r->method, r->label, a->status, clock_mono() - r->t0, r->request_id, r->sc ? r->sc->id : NULL);
    return ret;
}

static void resume_cb(scene_cmd *c, void *arg)
{
    (void)c;
    req *r = arg;
    r->phase = 2;
    MHD_resume_connection(r->conn);
}

/* The request's id: the client's X-Request-Id when it is a sound one (1 to 128 characters of
 * letters, digits and -_.:/+=), else one made here - the server's start-up nonce and a count, so
 * unique within the server and unlikely across restarts. Echoed as X-Request-Id, logged with the
 * request and what it causes (access log, stream events). */
static void copy_request_id(req *r)
{
    const char *id = header(r, "X-Request-Id");
    const size_t n = id ? strlen(id) : 0;
    int sound = n > 0 && n < sizeof r->request_id;
    for (size_t k = 0; sound && k < n; k++)
        if (!isalnum((unsigned char)id[k]) && !strchr("-_.:/+=", id[k])) sound = 0; /* not echoed */
    if (sound) memcpy(r->request_id, id, n + 1);
    else
        snprintf(r->request_id, sizeof r->request_id, "%08x-%llu", r->s->nonce,
                 (unsigned long long)atomic_fetch_add(&r->s->requests, 1) + 1);
}

/* The client's address as a rate-limit key (4 or 16 bytes); 0 when unknown. */
static size_t client_key(req *r, unsigned char key[16])
{
    const union MHD_ConnectionInfo *ci = MHD_get_connection_info(r->conn, MHD_CONNECTION_INFO_CLIENT_ADDRESS);
    if (!ci || !ci->client_addr) return 0;
    if (ci->client_addr->sa_family == AF_INET) {
        memcpy(key, &((const struct sockaddr_in *)(const void *)ci->client_addr)->sin_addr, 4);
        return 4;
    }
    if (ci->client_addr->sa_family == AF_INET6) {
        memcpy(key, &((const struct sockaddr_in6 *)(const void *)ci->client_addr)->sin6_addr, 16);
        return 16;
    }
    return 0;
}

/* 429 when the address has spent a budget (the rate limiter's), with Retry-After. */
static int over_budget(req *r, ratelimit *budget, const char *what, reply *rep)
{
    unsigned char key[16];
    const size_t kl = client_key(r, key);
    const int wait = kl ? ratelimit_take(budget, key, kl, clock_mono()) : 0;
    if (wait <= 0) return 0;
    problem p;
    problem_set(&p, 429, "rate-limited", NULL,
                "more than rate_limit (%d per second, after a burst of %d) %s from this address; retry in %d s",
                (int)r->s->set.rate_limit, (int)r->s->set.rate_burst, what, wait);
    api_problem(&rep->a, &p);
    rep->a.retry_after = wait;
    return 1;
}

/* A refusal (401, 403) spends the address's refused budget, not the one of its accepted
 * changes: a client guessing tokens or a hostile page is slowed (429 once the budget is spent),
 * and the control client behind the same address (loopback, NAT, a proxy) keeps its own. */
static int refuse(req *r, reply *rep, const problem *pr)
{
    if (over_budget(r, r->s->refused_rate, "refused requests", rep)) return 1;
    api_problem(&rep->a, pr);
    rep->authenticate = pr->status == 401;
    return 1;
}

/* The host the request names: an absolute-form target's, else the Host header. */
static const char *request_host(req *r)
{
    return r->authority[0] ? r->authority : header(r, MHD_HTTP_HEADER_HOST);
}

/* In order: the cross-site rule for changing requests (before anything else runs), Host (DNS
 * rebinding), the token the route needs (`needs`: the command table's access; the viewer's static
 * files and /v1/health are public), the rate of changing requests. 1 and rep filled when the
 * request is refused. */
static int refused(req *r, access_level needs, reply *rep)
{
    http_server *s = r->s;
    const access_policy *acc = s->info.access;
    if (!acc) return 0;
    const char *host = request_host(r);
    const int changes = command_method_changes(r->method);
    problem pr;
    if (changes) {
        const char *origin = header(r, "Origin"), *site = header(r, "Sec-Fetch-Site");
        if (!access_change_ok(acc, origin, site, host, s->port)) {
            problem_set(&pr, 403, "cross-site", NULL,
                        "a page of another origin (Origin: %.100s, Sec-Fetch-Site: %.20s) may not change anything: "
                        "only the viewer's own page, or an origin of allowed_origins",
                        origin ? origin : "none", site ? site : "none");
            return refuse(r, rep, &pr);
        }
    }
    if (!access_host_ok(acc, host)) {
        problem_set(&pr, 403, "host-not-allowed", NULL,
                    "Host '%.100s' is not a name of this server: use its address, localhost, or add the name to "
                    "allowed_hosts (a guard against DNS rebinding)", host);
        return refuse(r, rep, &pr);
    }
    if (needs != ACCESS_NONE) {
        const char *authorization = header(r, MHD_HTTP_HEADER_AUTHORIZATION);
        const access_level level = access_bearer(acc, authorization);
        if (level == ACCESS_NONE) {
            problem_set(&pr, 401, "unauthorized", NULL, "%s",
                        authorization ? "the token is not this server's"
                                      : "this server needs a token: send 'Authorization: Bearer <token>'");
            return refuse(r, rep, &pr);
        }
        if (level < needs) {
            problem_set(&pr, 403, "forbidden", NULL, "the view token reads only; changes need the control token");
            return refuse(r, rep, &pr);
        }
    }
    return changes && over_budget(r, s->rate, "changing requests", rep);
}

/* The viewer's files: GET and HEAD only. */
static MHD_Result serve_file(req *r)
{
    http_server *s = r->s;
    reply rep = {0};
    r->label = "static";
    if (strcmp(r->method, "GET") != 0 && strcmp(r->method, "HEAD") != 0) {
        snprintf(rep.allow, sizeof rep.allow, "GET, HEAD");
        reply_error(&rep, 405, "method-not-allowed", NULL, "static files are read with GET");
        return send_reply(r, &rep);
    }
    int status = 404;
    struct MHD_Response *resp = static_file(s->web_root, r->url, &status);
    if (!resp) {
        reply_error(&rep, 404, "not-found", NULL, "no such file");
        return send_reply(r, &rep);
    }
    MHD_add_response_header(resp, MHD_HTTP_HEADER_CACHE_CONTROL, "no-cache");
    if (r->request_id[0]) MHD_add_response_header(resp, "X-Request-Id", r->request_id);
    const MHD_Result ret = MHD_queue_response(r->conn, (unsigned int)status, resp);
    MHD_destroy_response(resp);
    metrics_http(s->m, r->label, r->method, status);
    log_access(r->method, r->label, status, clock_mono() - r->t0, r->request_id, NULL);
    return ret;
}

static MHD_Result dispatch(req *r)
{
    http_server *s = r->s;
    reply rep = {0};
    const int api = command_is_api(r->url);
    if (refused(r, api ? command_access(r->method, r->url) : ACCESS_NONE, &rep)) return send_reply(r, &rep);
    if (r->too_large) {
        char d[96];
        snprintf(d, sizeof d, "the body is larger than max_body (%d bytes)", (int)s->set.max_body);
        reply_error(&rep, 413, "too-large", NULL, d);
        return send_reply(r, &rep);
    }
    if (!api) return serve_file(r);
    route_match m;
    command_route(r->method, r->url, &m);
    r->label = m.label;
    if (!m.def) {
        if (m.path_known) {
            problem pr;
            snprintf(rep.allow, sizeof rep.allow, "%s", m.allow);
            problem_set(&pr, 405, "method-not-allowed", NULL, "%s is not allowed on %s (allowed: %s)", r->method, r->url,
                        m.allow);
            api_problem(&rep.a, &pr);
        } else {
            reply_error(&rep, 404, "not-found", NULL, "no such route");
        }
        return send_reply(r, &rep);
    }
    if (m.scene && !scene_id_valid(m.scene)) {
        reply_error(&rep, 400, "bad-scene-id", "scene",
                    "a scene id is 1 to 63 characters of a-z, 0-9, '_' and '-', starting with a letter or digit");
        return send_reply(r, &rep);
    }
    if (m.def->scope == SCOPE_SCENE && !(r->sc = scenes_get(s->table, m.scene))) {
        problem pr;
        problem_set(&pr, 404, "not-found", "scene", "no scene '%s'", m.scene);
        api_problem(&rep.a, &pr);
        return send_reply(r, &rep);
    }
    const char *h = query(r, "hash");
    const api_request rq = {m.def, r->sc, r->body, r->len, NULL, m.id, wants_binary(r),
                            h && (strcmp(h, "1") == 0 || strcmp(h, "true") == 0), &s->daemon, m.scene, m.rid};
    if (command_request(&rq, &rep.a, &r->cmd) == API_NOW) return send_reply(r, &rep);
    r->phase = 1;
    memcpy(r->cmd.request_id, r->request_id, sizeof r->cmd.request_id);
    r->cmd.done = resume_cb;
    r->cmd.done_arg = r;
    MHD_suspend_connection(r->conn); /* before submitting: the answer may come at once */
    scene_submit(r->sc, &r->cmd);
    return MHD_YES;
}

/* The simulation comes first: under overload, HTTP threads give way to the sim thread and its
 * workers instead of slowing the simulation below real time. Each libmicrohttpd thread lowers
 * its own priority on its first request (Linux priorities are per thread). */
static void lower_priority_once(int nice_value)
{
    static _Thread_local int done;
    if (done) return;
    done = 1;
    if (setpriority(PRIO_PROCESS, (id_t)syscall(SYS_gettid), nice_value) != 0)
        log_msg("http: could not lower this thread's priority: %s", strerror(errno));
}

/* ---- connections and strict HTTP (RFC 9110, 9112) ---- */

static conn *conn_of(struct MHD_Connection *c)
{
    const union MHD_ConnectionInfo *ci = MHD_get_connection_info(c, MHD_CONNECTION_INFO_SOCKET_CONTEXT);
    return ci ? ci->socket_context : NULL;
}

static void notify_cb(void *cls, struct MHD_Connection *c, void **socket_context,
                      enum MHD_ConnectionNotificationCode toe)
{
    http_server *s = cls;
    if (toe == MHD_CONNECTION_NOTIFY_STARTED) {
        const union MHD_ConnectionInfo *fd = MHD_get_connection_info(c, MHD_CONNECTION_INFO_CONNECTION_FD);
        const union MHD_ConnectionInfo *ad = MHD_get_connection_info(c, MHD_CONNECTION_INFO_CLIENT_ADDRESS);
        *socket_context = fd ? conns_open(s->conns, fd->connect_fd, ad ? ad->client_addr : NULL, clock_mono()) : NULL;
    } else {
        conns_close(s->conns, *socket_context); /* before libmicrohttpd closes the descriptor */
        *socket_context = NULL;
    }
}

/* Called with the request line's target as it came (libmicrohttpd unescapes it afterwards). A
 * target holds no space or control character (RFC 9112 3.2); libmicrohttpd 0.9.75 takes both. A
 * NUL byte cuts the string it hands over: it ends the target at the line's last space, and the
 * HTTP version follows that NUL, so when the version is not what follows the string's end, a NUL
 * came before. Every byte read lies within the request line (reading stops at the first NUL). */
static void *uri_cb(void *cls, const char *uri, struct MHD_Connection *c)
{
    http_server *s = cls;
    conn *e = conn_of(c);
    conns_request_line(s->conns, e);
    if (!uri) return NULL; /* no target at all: libmicrohttpd refuses such a line itself */
    int bad = 0;
    for (const unsigned char *p = (const unsigned char *)uri; *p && !bad; p++) bad = *p <= ' ' || *p == 0x7f;
    const char *end = uri + strlen(uri);
    if (strncmp(end + 1, "HTTP/1.", 7) != 0 || !isdigit((unsigned char)end[8]) || end[9] != '\0') bad = 1;
    if (bad) conns_flag_target(s->conns, e);
    return NULL;
}

/* libmicrohttpd's own unescaping, but a %00 (a NUL in the path or a query value) is refused. */
static size_t unescape_cb(void *cls, struct MHD_Connection *c, char *text)
{
    http_server *s = cls;
    for (const char *p = text; (p = strchr(p, '%')) != NULL; p++) {
        if (p[1] == '0' && p[2] == '0') {
            conns_flag_target(s->conns, conn_of(c));
            break;
        }
    }
    return MHD_http_unescape(text);
}

typedef struct head_fields {
    int host, content_length, transfer_encoding, other_coding, spaced_name;
} head_fields;

static MHD_Result count_field(void *cls, enum MHD_ValueKind kind, const char *key, const char *value)
{
    (void)kind;
    head_fields *h = cls;
    if (strcasecmp(key, MHD_HTTP_HEADER_HOST) == 0) h->host++;
    if (strcasecmp(key, MHD_HTTP_HEADER_CONTENT_LENGTH) == 0) h->content_length++;
    if (strcasecmp(key, MHD_HTTP_HEADER_TRANSFER_ENCODING) == 0) {
        h->transfer_encoding++;
        if (!value || strcasecmp(value, "chunked") != 0) h->other_coding = 1;
    }
    if (strpbrk(key, " \t")) h->spaced_name = 1; /* "Host : x": libmicrohttpd keeps the space in the name */
    return MHD_YES;
}

/* The request line and head as RFC 9112 wants them, where libmicrohttpd 0.9.75 lets them
 * through: 0, or 1 with the answer in rep (a 400 family status; the connection is then closed,
 * since the request's framing cannot be trusted). */
static int malformed(req *r, const char *url, const char *version, reply *rep)
{
    head_fields h = {0, 0, 0, 0, 0};
    MHD_get_connection_values(r->conn, MHD_HEADER_KIND, count_field, &h);
    const char *why = NULL;
    int status = 400;
    if (conns_target_bad(r->s->conns, conn_of(r->conn)))
        why = "the request target holds a NUL byte, a space or a control character";
    else if (h.spaced_name)
        why = "a header field name ends in white space (RFC 9112 section 5.1)";
    else if (h.host == 0 && strcmp(version, MHD_HTTP_VERSION_1_1) == 0)
        why = "an HTTP/1.1 request needs a Host header (RFC 9112 section 3.2)";
    else if (h.host > 1)
        why = "more than one Host header";
    else if (h.content_length > 1)
        why = "more than one Content-Length header";
    else if (h.content_length && h.transfer_encoding)
        why = "Content-Length together with Transfer-Encoding (RFC 9112 section 6.1)";
    else if (h.transfer_encoding > 1 || h.other_coding)
        why = "the only transfer coding understood is chunked, once", status = 501;
    else if (strlen(url) >= sizeof r->url)
        why = "the request target is longer than this server reads", status = 414;
    if (!why) return 0;
    problem pr;
    problem_set(&pr, status, status == 400 ? "bad-request" : status == 414 ? "uri-too-long" : "not-implemented", NULL,
                "%s", why);
    api_problem(&rep->a, &pr);
    rep->close = 1;
    return 1;
}

/* An absolute-form target (RFC 9112 3.2.2: "http://host:port/path") names the host itself, in
 * place of the Host header; the route is its path. */
static void take_target(req *r, const char *url)
{
    const char *rest = strncasecmp(url, "http://", 7) == 0 ? url + 7 : strncasecmp(url, "https://", 8) == 0 ? url + 8 : NULL;
    if (!rest) {
        snprintf(r->url, sizeof r->url, "%s", url);
        return;
    }
    const size_t n = strcspn(rest, "/");
    snprintf(r->authority, sizeof r->authority, "%.*s", (int)(n < sizeof r->authority ? n : 0), rest);
    if (!r->authority[0]) snprintf(r->authority, sizeof r->authority, "%s", "-"); /* not a host: refused */
    snprintf(r->url, sizeof r->url, "%s", rest[n] ? rest + n : "/");
}

static MHD_Result access_cb(void *cls, struct MHD_Connection *conn, const char *url, const char *method,
                            const char *version, const char *upload_data, size_t *upload_data_size, void **con_cls)
{
    http_server *s = cls;
    req *r = *con_cls;
    lower_priority_once(s->set.http_nice);
    if (!r) {
        /* First call: the head is in. Record the request only (answering now would end
         * keep-alive), unless it is malformed. */
        conns_head_done(s->conns, conn_of(conn), clock_mono());
        r = calloc(1, sizeof *r);
        if (!r) return MHD_NO;
        r->s = s;
        r->conn = conn;
        r->label = "unknown";
        r->t0 = clock_mono();
        snprintf(r->method, sizeof r->method, "%s", method);
        take_target(r, url);
        copy_request_id(r);
        const char *cl = header(r, MHD_HTTP_HEADER_CONTENT_LENGTH);
        if (cl && strtoull(cl, NULL, 10) > (unsigned long long)s->set.max_body) r->too_large = 1;
        *con_cls = r;
        reply rep = {0};
        if (malformed(r, url, version, &rep)) {
            r->malformed = 1;
            r->phase = 3;
            conns_busy(s->conns, conn_of(conn));
            return send_reply(r, &rep);
        }
        return MHD_YES;
    }
    if (r->malformed) {
        *upload_data_size = 0; /* answered: the rest is dropped */
        return MHD_YES;
    }
    if (*upload_data_size) {
        conns_body(s->conns, conn_of(conn), *upload_data_size);
        /* Counted as it arrives; past max_body it is dropped and the answer is 413. */
        if (!r->too_large) {
            if (r->len + *upload_data_size > (size_t)s->set.max_body) {
                r->too_large = 1;
                free(r->body);
                r->body = NULL;
                r->len = r->cap = 0;
            } else {
                if (r->len + *upload_data_size + 1 > r->cap) {
                    size_t cap = r->cap ? r->cap : 1024;
                    while (cap < r->len + *upload_data_size + 1) cap *= 2;
                    char *b = realloc(r->body, cap);
                    if (!b) return MHD_NO;
                    r->body = b;
                    r->cap = cap;
                }
                memcpy(r->body + r->len, upload_data, *upload_data_size);
                r->len += *upload_data_size;
                r->body[r->len] = '\0';
            }
        }
        *upload_data_size = 0;
        return MHD_YES;
    }
    if (r->phase == 1) return MHD_YES; /* woken before its answer: keep waiting */
    if (r->phase == 2) {
        reply rep = {0};
        command_answer(&r->cmd, wants_binary(r), &rep.a);
        r->phase = 3;
        return send_reply(r, &rep);
    }
    if (!r->body) {
        r->body = calloc(1, 1);
        if (!r->body) return MHD_NO;
    }
    conns_busy(s->conns, conn_of(conn));
    return dispatch(r);
}

/* Request bodies of at least this many bytes give the heap back once answered (completed_cb). */
enum { TRIM_AFTER_BODY = 128 * 1024 };

static void completed_cb(void *cls, struct MHD_Connection *conn, void **con_cls, enum MHD_RequestTerminationCode toe)
{
    (void)toe;
    http_server *s = cls;
    conns_done(s->conns, conn_of(conn), clock_mono()); /* ready for the next request from now */
    req *r = *con_cls;
    if (!r) return;
    const size_t body_len = r->len;
    json_decref(r->cmd.body);
    json_decref(r->cmd.result);
    free(r->cmd.blob);
    free(r->body);
    scene_release(r->sc);
    free(r);
    *con_cls = NULL;
#ifdef __GLIBC__
    /* A large JSON body was parsed into a tree of about 40 bytes an element (a 1 MiB array of
     * vertex ids: some 20 MB of small blocks). glibc keeps freed heap in the arena of the thread
     * that used it, below blocks still held, so without this each such request left the RSS tens
     * of MB higher (tests/server/memory.test.mjs). malloc_trim gives the free pages of every arena
     * back: now, and on the sweeper's next two turns (100-200 ms on), since the sim thread may
     * drop its reference to the command after the answer went out. */
    if (body_len >= TRIM_AFTER_BODY) {
        malloc_trim(0);
        atomic_store(&s->trims_due, 2);
    }
#else
    (void)body_len;
#endif
}

static void mhd_log(void *cls, const char *fmt, va_list ap)
{
    (void)cls;
    char line[512];
    vsnprintf(line, sizeof line, fmt, ap);
    const size_t n = strlen(line);
    if (n && line[n - 1] == '\n') line[n - 1] = '\0';
    log_msg("http: %s", line);
}

/* Closes the connections past their deadlines (conns.h), ten times a second. */
static void *sweep_main(void *arg)
{
    http_server *s = arg;
    pthread_mutex_lock(&s->stop_lock);
    while (!s->stopping) {
        pthread_mutex_unlock(&s->stop_lock);
        conns_sweep(s->conns, clock_mono());
#ifdef __GLIBC__
        int due = atomic_load(&s->trims_due);
        while (due > 0 && !atomic_compare_exchange_weak(&s->trims_due, &due, due - 1)) {
        }
        if (due > 0) malloc_trim(0);
#endif
        struct timespec until;
        clock_gettime(CLOCK_REALTIME, &until);
        until.tv_nsec += 100000000L;
        if (until.tv_nsec >= 1000000000L) until.tv_sec++, until.tv_nsec -= 1000000000L;
        pthread_mutex_lock(&s->stop_lock);
        if (!s->stopping) pthread_cond_timedwait(&s->stop_cond, &s->stop_lock, &until);
    }
    pthread_mutex_unlock(&s->stop_lock);
    return NULL;
}

static void free_server(http_server *s)
{
    ratelimit_free(s->rate);
    ratelimit_free(s->refused_rate);
    conns_free(s->conns);
    pthread_mutex_destroy(&s->stop_lock);
    pthread_cond_destroy(&s->stop_cond);
    free(s);
}

http_server *http_start(const clothd_settings *set, scenes *table, metrics *m, const http_info *info, char *err,
                        size_t err_len)
{
    http_server *s = calloc(1, sizeof *s);
    if (!s) {
        snprintf(err, err_len, "out of memory");
        return NULL;
    }
    s->table = table;
    s->m = m;
    s->info = *info;
    s->set = *set;
    s->daemon = (api_daemon){info->backend, info->device, info->backend_note, info->version,
                             info->stream ? info->stream_port : 0, table, info->recordings, m, http_metrics, s,
                             last_turn, info->loop, set->liveness_timeout, info->life};
    pthread_mutex_init(&s->stop_lock, NULL);
    pthread_cond_init(&s->stop_cond, NULL);
    s->nonce = (unsigned)(clock_wall_ns() ^ (clock_wall_ns() >> 32) ^ ((uint64_t)getpid() << 16));
    s->rate = ratelimit_new(set->rate_limit, set->rate_burst);
    s->refused_rate = ratelimit_new(set->rate_limit, set->rate_burst);
    const conns_limits lim = {set->max_connections, set->header_timeout, set->min_body_rate};
    s->conns = conns_new(&lim);
    if (!s->rate || !s->refused_rate || !s->conns) {
        snprintf(err, err_len, "out of memory");
        free_server(s);
        return NULL;
    }
    if (!realpath(set->web_root, s->web_root)) {
        log_msg("web_root %s: %s; serving a placeholder page at /", set->web_root, strerror(errno));
        s->web_root[0] = '\0';
    }

    struct addrinfo hints, *ai = NULL;
    memset(&hints, 0, sizeof hints);
    hints.ai_flags = AI_NUMERICHOST | AI_PASSIVE;
    hints.ai_socktype = SOCK_STREAM;
    char port[16];
    snprintf(port, sizeof port, "%d", (int)set->port);
    const int gai = getaddrinfo(set->listen, port, &hints, &ai);
    if (gai != 0) {
        snprintf(err, err_len, "listen address '%s': %s (give a numeric IPv4 or IPv6 address)", set->listen,
                 gai_strerror(gai));
        free_server(s);
        return NULL;
    }
    /* poll, not epoll: libmicrohttpd 0.9.75 (Debian 12) aborts in MHD_quiesce_daemon when a worker
     * thread has taken the listen socket out of its epoll set first ("Failed to remove listen FD
     * from epoll set"), a race a SIGTERM under traffic lost about once in a hundred under strace -
     * and an abort saves no state. With poll, quiescing only signals the workers (MHD_USE_ITC). */
    unsigned int flags = MHD_USE_INTERNAL_POLLING_THREAD | MHD_USE_POLL | MHD_USE_ITC | MHD_ALLOW_SUSPEND_RESUME | MHD_USE_ERROR_LOG;
    if (ai->ai_family == AF_INET6) flags |= MHD_USE_IPv6;
    /* libmicrohttpd may hold one connection per thread beyond max_connections: the connection
     * table (conns.h) makes room at max_connections itself, so a new client is never left in the
     * backlog behind connections that only wait. */
    s->d = MHD_start_daemon(flags, (uint16_t)set->port, NULL, NULL, access_cb, s, MHD_OPTION_EXTERNAL_LOGGER, mhd_log,
                            s, MHD_OPTION_SOCK_ADDR, ai->ai_addr,
                            MHD_OPTION_THREAD_POOL_SIZE, (unsigned int)set->http_threads, MHD_OPTION_CONNECTION_LIMIT,
                            (unsigned int)(set->max_connections + set->http_threads), MHD_OPTION_PER_IP_CONNECTION_LIMIT,
                            (unsigned int)set->max_connections_per_ip, MHD_OPTION_CONNECTION_TIMEOUT,
                            (unsigned int)set->connection_timeout, MHD_OPTION_NOTIFY_COMPLETED, completed_cb, s,
                            MHD_OPTION_NOTIFY_CONNECTION, notify_cb, s, MHD_OPTION_URI_LOG_CALLBACK, uri_cb, s,
                            MHD_OPTION_UNESCAPE_CALLBACK, unescape_cb, s,
                            MHD_OPTION_LISTENING_ADDRESS_REUSE, 1U,
                            MHD_OPTION_END);
    freeaddrinfo(ai);
    if (!s->d) {
        snprintf(err, err_len, "could not listen on %s port %d (in use, or not allowed?)", set->listen, (int)set->port);
        free_server(s);
        return NULL;
    }
    const union MHD_DaemonInfo *di = MHD_get_daemon_info(s->d, MHD_DAEMON_INFO_BIND_PORT);
    s->port = di ? di->port : set->port;
    s->sweeping = pthread_create(&s->sweeper, NULL, sweep_main, s) == 0;
    if (!s->sweeping) log_msg("http: could not start the connection sweeper: header_timeout is not enforced");
    return s;
}

int http_port(http_server *s) { return s->port; }

void http_quiesce(http_server *s)
{
    const MHD_socket fd = MHD_quiesce_daemon(s->d);
    if (fd != MHD_INVALID_SOCKET) close(fd);
}

void http_stop(http_server *s)
{
    if (!s) return;
    if (s->sweeping) {
        pthread_mutex_lock(&s->stop_lock);
        s->stopping = 1;
        pthread_cond_signal(&s->stop_cond);
        pthread_mutex_unlock(&s->stop_lock);
        pthread_join(s->sweeper, NULL);
    }
    MHD_stop_daemon(s->d);
    free_server(s);
}

/* The HTTP server's own metrics and the stream's, for /metrics. */
static char *http_metrics(void *ctx)
{
    http_server *s = ctx;
    uint64_t closed[CONNS_REASONS];
    conns_closed(s->conns, closed);
    char *out = NULL;
    size_t len = 0;
    FILE *f = open_memstream(&out, &len);
    if (!f) return NULL;
    fprintf(f, "# HELP clothd_http_connections HTTP connections open.\n# TYPE clothd_http_connections gauge\n"
               "clothd_http_connections %d\n", conns_count(s->conns));
    fprintf(f, "# HELP clothd_http_connections_closed_total HTTP connections the server closed, by reason: "
               "header_timeout, body_rate, evicted (to make room at max_connections).\n"
               "# TYPE clothd_http_connections_closed_total counter\n");
    for (int k = 0; k < CONNS_REASONS; k++)
        fprintf(f, "clothd_http_connections_closed_total{reason=\"%s\"} %llu\n", conns_reason_names[k],
                (unsigned long long)closed[k]);
    char *stream = s->info.stream ? stream_metrics(s->info.stream) : NULL;
    if (stream) fputs(stream, f);
    free(stream);
    fclose(f);
    return out;
}
