/* access.h - who may use clothd: tokens, the Host header (DNS rebinding) and the Origin of a
 * stream connection (cross-site WebSocket hijacking). One immutable policy, loaded at start and
 * read by the HTTP threads and the stream thread alike.
 *
 *   No token set (the default, loopback only): everyone who can connect has control.
 *   A control token: every API route needs `Authorization: Bearer <control>`; with a view token
 *   too, `Bearer <view>` reads (GET, HEAD and the stream) but changes nothing (403).
 *   Host: an IP literal, `localhost`, or a name of allowed_hosts (`*`: any).
 *   Origin (stream, and changing HTTP requests): none (not a browser), one of allowed_origins
 *   (`*`: any), or the page's own: the same host as the request's Host, which passes the Host
 *   rule, on the HTTP port. `null` (a sandboxed or file: page) is never the page's own.
 *   Sec-Fetch-Site (changing HTTP requests): `cross-site` only from an origin of allowed_origins. */
#ifndef CLOTHD_ACCESS_H
#define CLOTHD_ACCESS_H

#include <stddef.h>

#include "core/settings.h"

typedef enum { ACCESS_NONE = 0, ACCESS_VIEW = 1, ACCESS_CONTROL = 2 } access_level;

typedef struct access_policy access_policy;

/* Reads the token files and checks the listen address: beyond loopback only with a control token
 * or `insecure`. NULL with the reason (for a person) in err. */
access_policy *access_load(const clothd_settings *set, char *err, size_t err_len);
void access_free(access_policy *p);

/* Whether a control token is set (then every API route needs a token). */
int access_required(const access_policy *p);

/* The level a token grants (NULL or "": none), compared in constant time. Without tokens set
 * everyone has ACCESS_CONTROL. */
access_level access_token(const access_policy *p, const char *token);

/* The level an Authorization header grants ("Bearer <token>"; NULL when absent). */
access_level access_bearer(const access_policy *p, const char *authorization);

/* Whether a Host header (with or without its port) names this server acceptably. NULL (an
 * HTTP/1.0 request without one) is accepted. */
int access_host_ok(const access_policy *p, const char *host);

/* Whether a stream request from a page of `origin` (NULL when the client sent none) may connect,
 * given the request's Host header and the HTTP port the viewer is served on. */
int access_origin_ok(const access_policy *p, const char *origin, const char *host, int http_port);

/* Whether origin is one of allowed_origins (answers to it carry Access-Control-Allow-Origin). */
int access_origin_listed(const access_policy *p, const char *origin);

/* Whether a changing HTTP request (POST, PUT, PATCH, DELETE) may go on, given its Origin and
 * Sec-Fetch-Site headers (NULL when absent): the cross-site rule (PROTOCOL.md, Access). */
int access_change_ok(const access_policy *p, const char *origin, const char *fetch_site, const char *host,
                     int http_port);

#endif
