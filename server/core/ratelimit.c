/* ratelimit.c - per-client token buckets (see ratelimit.h). */
#include <math.h>
#include <pthread.h>
#include <stdint.h>
#include <stdlib.h>
#include <string.h>

#include "core/ratelimit.h"

#define KEY_MAX 16
#define PROBE 8 /* slots a key may live in */

typedef struct bucket {
    unsigned char key[KEY_MAX];
    size_t len;   /* 0: free */
    double tokens;
    double at;    /* when tokens was last brought up to date */
} bucket;

struct ratelimit {
    pthread_mutex_t lock;
    double rate, burst;
    bucket slots[RATE_CLIENTS];
};

ratelimit *ratelimit_new(double rate, double burst)
{
    ratelimit *rl = calloc(1, sizeof *rl);
    if (!rl) return NULL;
    pthread_mutex_init(&rl->lock, NULL);
    rl->rate = rate;
    rl->burst = burst < 1 ? 1 : burst;
    return rl;
}

void ratelimit_free(ratelimit *rl)
{
    if (!rl) return;
    pthread_mutex_destroy(&rl->lock);
    free(rl);
}

static uint32_t fnv1a(const unsigned char *k, size_t n)
{
    uint32_t h = 2166136261u;
    for (size_t i = 0; i < n; i++) h = (h ^ k[i]) * 16777619u;
    return h;
}

int ratelimit_take(ratelimit *rl, const void *key, size_t len, double now)
{
    if (!rl || rl->rate <= 0) return 0;
    if (len > KEY_MAX) len = KEY_MAX;
    const uint32_t h = fnv1a(key, len);
    pthread_mutex_lock(&rl->lock);
    bucket *b = NULL, *oldest = NULL;
    for (int i = 0; i < PROBE && !b; i++) {
        bucket *s = &rl->slots[(h + (uint32_t)i) % RATE_CLIENTS];
        if (s->len == len && memcmp(s->key, key, len) == 0) b = s;
        else if (!oldest || s->len == 0 || (oldest->len && s->at < oldest->at)) oldest = s;
    }
    if (!b) { /* a new client: a full bucket, in the free or longest-idle slot */
        b = oldest;
        memcpy(b->key, key, len);
        b->len = len;
        b->tokens = rl->burst;
        b->at = now;
    }
    b->tokens = fmin(rl->burst, b->tokens + (now - b->at) * rl->rate);
    b->at = now;
    int wait = 0;
    if (b->tokens >= 1) b->tokens -= 1;
    else wait = (int)ceil((1 - b->tokens) / rl->rate);
    pthread_mutex_unlock(&rl->lock);
    return wait;
}
