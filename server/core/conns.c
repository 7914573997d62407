/* conns.c - the HTTP connection table and its deadlines (see conns.h). */
#include <netinet/in.h>
#include <pthread.h>
#include <stdlib.h>
#include <string.h>
#include <sys/socket.h>

#include "core/conns.h"

const char *const conns_reason_names[CONNS_REASONS] = {"header_timeout", "body_rate", "evicted"};

typedef enum { WAITING, BODY, BUSY } phase;

/* One client address and how many connections it holds. */
typedef struct peer {
    unsigned char key[16];
    size_t len;
    int held; /* open connections, those being closed left out */
    int refs; /* table entries naming it */
    struct peer *next;
} peer;

struct conn {
    int fd;
    peer *from;
    phase ph;
    double since;  /* WAITING: ready for a request since; BODY: its head arrived at */
    size_t body;   /* BODY: bytes so far */
    int closing;   /* shut down here, libmicrohttpd has yet to close it */
    int bad_target;
    conn *prev, *next;
};

struct conns {
    pthread_mutex_t lock;
    conns_limits lim;
    conn *head;
    peer *peers;
    int n;          /* connections in the table, closing ones included */
    int n_closing;
    uint64_t closed[CONNS_REASONS];
};

conns *conns_new(const conns_limits *lim)
{
    conns *t = calloc(1, sizeof *t);
    if (!t) return NULL;
    pthread_mutex_init(&t->lock, NULL);
    t->lim = *lim;
    return t;
}

void conns_free(conns *t)
{
    if (!t) return;
    while (t->head) {
        conn *c = t->head;
        t->head = c->next;
        free(c);
    }
    while (t->peers) {
        peer *p = t->peers;
        t->peers = p->next;
        free(p);
    }
    pthread_mutex_destroy(&t->lock);
    free(t);
}

static size_t addr_key(const struct sockaddr *a, unsigned char key[16])
{
    if (a && a->sa_family == AF_INET) {
        memcpy(key, &((const struct sockaddr_in *)(const void *)a)->sin_addr, 4);
        return 4;
    }
    if (a && a->sa_family == AF_INET6) {
        memcpy(key, &((const struct sockaddr_in6 *)(const void *)a)->sin6_addr, 16);
        return 16;
    }
    return 0;
}

static peer *peer_of(conns *t, const unsigned char *key, size_t len)
{
    for (peer *p = t->peers; p; p = p->next)
        if (p->len == len && memcmp(p->key, key, len) == 0) return p;
    peer *p = calloc(1, sizeof *p);
    if (!p) return NULL;
    memcpy(p->key, key, len);
    p->len = len;
    p->next = t->peers;
    t->peers = p;
    return p;
}

static void peer_release(conns *t, peer *p)
{
    if (!p || --p->refs > 0) return;
    for (peer **q = &t->peers; *q; q = &(*q)->next) {
        if (*q == p) {
            *q = p->next;
            free(p);
            return;
        }
    }
}

/* Caller holds the lock. The connection leaves the counts at once; the table forgets it when
 * libmicrohttpd closes it. */
static void shut(conns *t, conn *c, int reason)
{
    if (c->closing) return;
    c->closing = 1;
    t->n_closing++;
    t->closed[reason]++;
    if (c->from) c->from->held--;
    shutdown(c->fd, SHUT_RDWR);
}

/* The connection to close to make room: among those waiting for a request, one of the address
 * holding the most connections, the one that has waited longest. NULL when none waits. */
static conn *victim(conns *t)
{
    conn *best = NULL;
    for (conn *c = t->head; c; c = c->next) {
        if (c->closing || c->ph != WAITING) continue;
        const int held = c->from ? c->from->held : 1, best_held = best && best->from ? best->from->held : 1;
        if (!best || held > best_held || (held == best_held && c->since < best->since)) best = c;
    }
    return best;
}

conn *conns_open(conns *t, int fd, const struct sockaddr *addr, double now)
{
    conn *c = calloc(1, sizeof *c);
    if (!c) return NULL;
    unsigned char key[16];
    const size_t len = addr_key(addr, key);
    pthread_mutex_lock(&t->lock);
    c->fd = fd;
    c->from = len ? peer_of(t, key, len) : NULL;
    if (c->from) c->from->held++, c->from->refs++;
    c->ph = WAITING;
    c->since = now;
    c->next = t->head;
    if (t->head) t->head->prev = c;
    t->head = c;
    t->n++;
    if (t->n - t->n_closing > t->lim.max_connections) {
        conn *v = victim(t); /* this one, when it is the only one waiting */
        shut(t, v ? v : c, CONNS_EVICTED);
    }
    pthread_mutex_unlock(&t->lock);
    return c;
}

void conns_close(conns *t, conn *c)
{
    if (!c) return;
    pthread_mutex_lock(&t->lock);
    if (c->closing) t->n_closing--;
    else if (c->from) c->from->held--;
    peer_release(t, c->from);
    if (c->prev) c->prev->next = c->next;
    else t->head = c->next;
    if (c->next) c->next->prev = c->prev;
    t->n--;
    pthread_mutex_unlock(&t->lock);
    free(c);
}

void conns_request_line(conns *t, conn *c)
{
    if (!c) return;
    pthread_mutex_lock(&t->lock);
    c->bad_target = 0;
    pthread_mutex_unlock(&t->lock);
}

void conns_flag_target(conns *t, conn *c)
{
    if (!c) return;
    pthread_mutex_lock(&t->lock);
    c->bad_target = 1;
    pthread_mutex_unlock(&t->lock);
}

int conns_target_bad(conns *t, conn *c)
{
    if (!c) return 0;
    pthread_mutex_lock(&t->lock);
    const int bad = c->bad_target;
    pthread_mutex_unlock(&t->lock);
    return bad;
}

void conns_head_done(conns *t, conn *c, double now)
{
    if (!c) return;
    pthread_mutex_lock(&t->lock);
    c->ph = BODY;
    c->since = now;
    c->body = 0;
    pthread_mutex_unlock(&t->lock);
}

void conns_body(conns *t, conn *c, size_t n)
{
    if (!c) return;
    pthread_mutex_lock(&t->lock);
    c->body += n;
    pthread_mutex_unlock(&t->lock);
}

void conns_busy(conns *t, conn *c)
{
    if (!c) return;
    pthread_mutex_lock(&t->lock);
    c->ph = BUSY;
    pthread_mutex_unlock(&t->lock);
}

void conns_done(conns *t, conn *c, double now)
{
    if (!c) return;
    pthread_mutex_lock(&t->lock);
    c->ph = WAITING;
    c->since = now;
    pthread_mutex_unlock(&t->lock);
}

int conns_sweep(conns *t, double now)
{
    int n = 0;
    pthread_mutex_lock(&t->lock);
    for (conn *c = t->head; c; c = c->next) {
        if (c->closing) continue;
        const double age = now - c->since;
        if (c->ph == WAITING && age > t->lim.header_timeout) {
            shut(t, c, CONNS_HEADER_TIMEOUT);
            n++;
        } else if (c->ph == BODY && t->lim.min_body_rate > 0 && age > t->lim.header_timeout &&
                   (double)c->body < t->lim.min_body_rate * (age - t->lim.header_timeout)) {
            shut(t, c, CONNS_BODY_RATE);
            n++;
        }
    }
    pthread_mutex_unlock(&t->lock);
    return n;
}

int conns_count(conns *t)
{
    pthread_mutex_lock(&t->lock);
    const int n = t->n - t->n_closing;
    pthread_mutex_unlock(&t->lock);
    return n;
}

void conns_closed(conns *t, uint64_t out[CONNS_REASONS])
{
    pthread_mutex_lock(&t->lock);
    memcpy(out, t->closed, sizeof t->closed);
    pthread_mutex_unlock(&t->lock);
}
