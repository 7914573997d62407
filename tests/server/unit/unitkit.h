/* unitkit.h - what the server's unit tests share: cmocka, a small engine made as the daemon makes
 * one (CPU backend, one thread), and a JSON text compared as JSON. */
#ifndef CLOTHD_UNITKIT_H
#define CLOTHD_UNITKIT_H

#include <setjmp.h>
#include <stdarg.h>
#include <stddef.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <cmocka.h>

#include <jansson.h>

#include "clothsim/clothsim.h"
#include "core/settings.h"

/* An nx x ny engine of the defaults (automatic drops are the daemon's: none here), one thread. */
static inline cs_sim *uk_engine(int nx, int ny)
{
    cs_scene sc;
    cs_params p;
    cs_scene_default(&sc);
    cs_params_default(&p);
    sc.nx = nx;
    sc.ny = ny;
    cs_sim *sim = NULL;
    char err[256];
    if (cs_sim_create(&sc, &p, "cpu", &sim, err, sizeof err) != CS_OK) fail_msg("cs_sim_create: %s", err);
    assert_int_equal(cs_sim_set_threads(sim, 1), CS_OK);
    return sim;
}

/* The defaults of every setting. */
static inline clothd_config uk_defaults(void)
{
    clothd_config c;
    settings_default(&c);
    return c;
}

/* A file of tests/data, read whole into buf (cap bytes); returns its length. */
static inline size_t uk_data_file(const char *name, unsigned char *buf, size_t cap)
{
    char path[512];
    snprintf(path, sizeof path, "%s/%s", CLOTHD_TEST_DATA, name);
    FILE *f = fopen(path, "rb");
    if (!f) fail_msg("%s: cannot open it", path);
    const size_t n = fread(buf, 1, cap, f);
    fclose(f);
    if (n == cap) fail_msg("%s: larger than %zu bytes", path, cap);
    return n;
}

/* text parses to the same JSON as expected (member order aside). */
#define uk_assert_json(text, expected)                                                                 \
    do {                                                                                               \
        json_t *uk_a_ = json_loads((text), 0, NULL), *uk_b_ = json_loads((expected), 0, NULL);        \
        if (!uk_b_) fail_msg("the expected JSON does not parse: %s", (expected));                     \
        if (!uk_a_ || !json_equal(uk_a_, uk_b_)) fail_msg("got %s, expected %s", (text) ? (text) : "(null)", (expected)); \
        json_decref(uk_a_);                                                                            \
        json_decref(uk_b_);                                                                            \
    } while (0)

/* A JSON value's text, compact and sorted (free it). */
static inline char *uk_dump(const json_t *v) { return json_dumps(v, JSON_COMPACT | JSON_SORT_KEYS); }

#endif
