/* ratelimit.h - per-client token buckets for mutating HTTP requests: each client (an IP address)
 * may make `burst` requests at once and `rate` a second after that. The table is fixed in size
 * (RATE_CLIENTS): a new client takes the slot of the one idle longest among those its address
 * hashes to, so memory stays bounded whatever the number of clients. Thread-safe. */
#ifndef CLOTHD_RATELIMIT_H
#define CLOTHD_RATELIMIT_H

#include <stddef.h>

#define RATE_CLIENTS 4096

typedef struct ratelimit ratelimit;

/* rate <= 0: no limit (ratelimit_take always answers 0). */
ratelimit *ratelimit_new(double rate, double burst);
void ratelimit_free(ratelimit *rl);

/* Takes one request of the client `key` (len bytes, e.g. an address) at time now (seconds):
 * 0 when allowed, else the seconds until it would be (for Retry-After, at least 1). */
int ratelimit_take(ratelimit *rl, const void *key, size_t len, double now);

#endif
