/* conns.h - the HTTP connections clothd holds, and the limits libmicrohttpd 0.9.75 does not keep
 * (slowloris): its connection_timeout counts idle gaps only, so a client that trickles a request
 * one byte at a time holds its connection for ever, and at max_connections no other client gets
 * in. This table follows every connection through its requests (libmicrohttpd's connection
 * notifications and the request callbacks tell it what each is doing) and closes those that
 *
 *   - take longer than header_timeout to send a request's head, counted from the moment the
 *     connection was ready for one: opened, or the previous answer sent (so an idle keep-alive
 *     connection goes after header_timeout as well);
 *   - send a body more slowly than min_body_rate bytes a second on average, once header_timeout
 *     has passed since its head;
 *   - are waiting for their request's head when the server is full (max_connections): a new
 *     connection then takes the place of the one that has waited longest among those of the
 *     address holding the most connections, so one address, or a few, cannot shut the others out.
 *
 * A connection whose request is being answered (or waits for the sim thread) is never closed
 * here. Closing is shutdown(2) of the socket under the table's lock; libmicrohttpd then sees the
 * end of the stream and closes the connection itself, and it tells the table (conns_close) before
 * it closes the descriptor, under the same lock, so a descriptor is never shut down once it may
 * have been reused. Thread-safe. */
#ifndef CLOTHD_CONNS_H
#define CLOTHD_CONNS_H

#include <stddef.h>
#include <stdint.h>
#include <sys/socket.h>

typedef struct conns conns;
typedef struct conn conn;

typedef struct conns_limits {
    int max_connections;  /* the table makes room above this many */
    double header_timeout; /* seconds */
    double min_body_rate;  /* bytes per second; 0: no minimum */
} conns_limits;

/* Why a connection was closed, for clothd_http_connections_closed_total{reason}. */
enum { CONNS_HEADER_TIMEOUT, CONNS_BODY_RATE, CONNS_EVICTED, CONNS_REASONS };
extern const char *const conns_reason_names[CONNS_REASONS];

conns *conns_new(const conns_limits *lim);
void conns_free(conns *t);

/* A connection libmicrohttpd accepted (its socket and the peer's address); NULL when out of
 * memory (then it is not guarded). May close another connection to make room, or this one when
 * none can give way. */
conn *conns_open(conns *t, int fd, const struct sockaddr *addr, double now);
/* libmicrohttpd is about to close it (the descriptor is still open). */
void conns_close(conns *t, conn *c);

/* A request's line has arrived: the per-request flags start afresh. */
void conns_request_line(conns *t, conn *c);
/* Flags a request's target as malformed (a NUL byte, a space); read with conns_target_bad. */
void conns_flag_target(conns *t, conn *c);
int conns_target_bad(conns *t, conn *c);
/* Its head is complete (the first call of the request handler): the body, if any, follows. */
void conns_head_done(conns *t, conn *c, double now);
/* n more body bytes arrived. */
void conns_body(conns *t, conn *c, size_t n);
/* The request is complete and being answered. */
void conns_busy(conns *t, conn *c);
/* Its answer has gone: the connection waits for its next request from now. */
void conns_done(conns *t, conn *c, double now);

/* Closes the connections past their deadlines; returns how many. */
int conns_sweep(conns *t, double now);

/* Connections held now, and how many were closed for each reason. */
int conns_count(conns *t);
void conns_closed(conns *t, uint64_t out[CONNS_REASONS]);

#endif
