/* http.h - the JSON HTTP API of DESIGN.md section 3 on libmicrohttpd, and the viewer's static
 * files at /. Reads answer from what the sim thread published; commands are queued to it and the
 * connection is suspended until it has applied them, so no HTTP thread ever waits on the engine. */
#ifndef CLOTHD_HTTP_H
#define CLOTHD_HTTP_H

#include <stdio.h>

#include "core/metrics.h"
#include "core/settings.h"
#include "sim/simloop.h"

typedef struct http_server http_server;

struct stream;
struct access_policy;

typedef struct http_info {
    const char *backend, *device, *backend_note, *version;
    struct stream *stream; /* NULL when there is none */
    int stream_port;
    const struct access_policy *access; /* tokens, allowed hosts */
} http_info;

/* Starts listening (settings: listen, port, http_threads, max_body, max_connections,
 * max_connections_per_ip, connection_timeout, rate_limit, rate_burst, web_root). NULL and the reason in err on failure. */
http_server *http_start(const clothd_settings *set, simloop *sl, metrics *m, const http_info *info, char *err,
                        size_t err_len);
/* The port actually bound (useful with --port 0). */
int http_port(http_server *s);
/* Stops accepting connections (the ones open go on). */
void http_quiesce(http_server *s);
void http_stop(http_server *s);

/* Writes the route table, "METHOD PATTERN" per line (clothd routes; the spec test reads it). */
void http_print_routes(FILE *out);

#endif
