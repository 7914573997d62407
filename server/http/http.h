/* http.h - the JSON HTTP API (PROTOCOL.md) on libmicrohttpd, and the viewer's static files at /.
 * Routes, the token each needs and what each does come from the command table
 * (sim/commands.h); reads answer from what a scene published, commands are queued to the sim
 * thread and the connection is suspended until it has run them, so no HTTP thread ever waits on
 * an engine. Around that: the connection deadlines libmicrohttpd does not keep (conns.h), strict
 * HTTP (RFC 9110, 9112), the cross-site rule, Host, tokens and rate limits (access.h,
 * ratelimit.h). */
#ifndef CLOTHD_HTTP_H
#define CLOTHD_HTTP_H

#include <stdatomic.h>
#include <stddef.h>

#include "core/access.h"
#include "core/metrics.h"
#include "core/settings.h"
#include "sim/scenes.h"

typedef struct http_server http_server;

struct stream;
struct recordings;

typedef struct http_info {
    const char *backend, *device, *backend_note, *version;
    struct stream *stream; /* NULL when there is none */
    int stream_port;
    const access_policy *access; /* tokens, allowed hosts */
    struct recordings *recordings; /* NULL: none */
    struct simloop *loop;          /* the sim thread's heartbeat (GET /livez) */
    const atomic_int *life;        /* DAEMON_* (GET /readyz); NULL: serving */
} http_info;

/* Starts listening (settings: listen, port, http_threads, http_nice, max_body, max_connections,
 * max_connections_per_ip, connection_timeout, header_timeout, min_body_rate, rate_limit,
 * rate_burst, web_root) for the scenes of table. NULL and the reason in err on failure. */
http_server *http_start(const clothd_settings *set, scenes *table, metrics *m, const http_info *info, char *err,
                        size_t err_len);
/* The port actually bound (useful with --port 0). */
int http_port(http_server *s);
/* Stops accepting connections (the ones open go on). */
void http_quiesce(http_server *s);
void http_stop(http_server *s);

#endif
