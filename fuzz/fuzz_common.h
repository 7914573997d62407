/* fuzz_common.h - what the fuzz targets share: a small simulation made the way the daemon makes
 * one (CPU backend, one thread, a memory cap), its whole state as bytes (a snapshot) to compare
 * and to set it back with, and a failure that libFuzzer records as a crash.
 *
 * A target makes its simulations once and sets them back to the fresh state before each input
 * (fuzz_reset: the snapshot of a fresh one, loaded): making one takes milliseconds (the CPU
 * backend's per-thread buffers), loading an 8 x 8 snapshot a tenth of that. */
#ifndef CLOTHD_FUZZ_COMMON_H
#define CLOTHD_FUZZ_COMMON_H

#include <stdarg.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "clothsim/clothsim.h"

/* The cap on a scene's state (max_state_mb in the daemon, 1024 MiB by default): small here so
 * that a fuzzed scene stays quick to build. The checks before allocating are the same. */
#define FUZZ_STATE_LIMIT (1u << 20)

/* A property the input broke: said on stderr, then abort() (libFuzzer saves the input). */
static inline void fuzz_fail(const char *fmt, ...) __attribute__((format(printf, 1, 2), noreturn));
static inline void fuzz_fail(const char *fmt, ...)
{
    va_list ap;
    va_start(ap, fmt);
    fprintf(stderr, "fuzz: ");
    vfprintf(stderr, fmt, ap);
    fprintf(stderr, "\n");
    va_end(ap);
    abort();
}

/* An 8 x 8 cloth with the default parameters and one rock (id 1), as make_engine() sets one up. */
static inline cs_sim *fuzz_sim(void)
{
    cs_scene sc;
    cs_params p;
    cs_scene_default(&sc);
    cs_params_default(&p);
    sc.nx = sc.ny = 8;
    char err[300];
    cs_sim *sim = NULL;
    if (cs_sim_create(&sc, &p, "cpu", &sim, err, sizeof err) != CS_OK) fuzz_fail("cs_sim_create: %s", err);
    cs_sim_set_threads(sim, 1);
    cs_sim_set_memory_limit(sim, FUZZ_STATE_LIMIT, NULL, NULL);
    cs_rock_def d;
    cs_rock_def_default(&d);
    d.position[2] = 1.5f;
    uint32_t id = 0;
    if (cs_rock_add(sim, &d, &id) != CS_OK || id != 1) fuzz_fail("cs_rock_add: %s", cs_sim_error(sim));
    return sim;
}

/* The whole state (scene, parameters, clock, grab, vertices, rest lengths, pins, rocks) as a
 * snapshot (malloc'd). */
static inline unsigned char *fuzz_state(cs_sim *sim, size_t *len)
{
    const size_t cap = cs_snapshot_size(sim);
    unsigned char *buf = malloc(cap ? cap : 1);
    if (!buf) fuzz_fail("out of memory");
    if (cs_snapshot_save(sim, buf, cap, len) != CS_OK) fuzz_fail("cs_snapshot_save: %s", cs_sim_error(sim));
    return buf;
}

/* Whether two simulations hold the same state. */
static inline int fuzz_same_state(cs_sim *a, cs_sim *b)
{
    size_t la, lb;
    unsigned char *sa = fuzz_state(a, &la), *sb = fuzz_state(b, &lb);
    const int same = la == lb && memcmp(sa, sb, la) == 0;
    free(sa);
    free(sb);
    return same;
}

/* Whether sim holds the state of `state` (from fuzz_state). */
static inline int fuzz_state_is(cs_sim *sim, const unsigned char *state, size_t len)
{
    size_t l;
    unsigned char *s = fuzz_state(sim, &l);
    const int same = l == len && memcmp(s, state, l) == 0;
    free(s);
    return same;
}

/* Sets sim back to `state` (from fuzz_state). */
static inline void fuzz_reset(cs_sim *sim, const unsigned char *state, size_t len)
{
    if (cs_snapshot_load(sim, state, len) != CS_OK) fuzz_fail("setting a simulation back: %s", cs_sim_error(sim));
}

#endif
