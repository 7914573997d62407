/* test_delta.c - server/core/delta.c against hand-computed cases: the grid values of a few
 * coordinates, the head and the axis blocks of a 2 x 2 keyframe and of deltas (decompressed by
 * libzstd itself, compared with bytes and grid values worked out by hand from the layout in
 * clothd_frame.h, escapes included), and
 * the keyframe policy (first frame, shape change, once a second, asked for at most 4 times a
 * second), and cloths on either side of DELTA_TIGHT_MAX_N (the optimal and the fast zstd parser)
 * in motion, every coordinate decoded within quantum / 2 of the one encoded. */
#include <math.h>
#include <setjmp.h>
#include <stdarg.h>
#include <stddef.h>
#include <stdint.h>
#include <stdlib.h>
#include <string.h>
#include <cmocka.h>
#include <zstd.h>

#include "clothd_frame.h"
#include "core/delta.h"

#define MS 1000000ull

static uint32_t get_u32(const unsigned char *p) { return p[0] | p[1] << 8 | p[2] << 16 | (uint32_t)p[3] << 24; }
static uint64_t get_u64(const unsigned char *p) { return get_u32(p) | (uint64_t)get_u32(p + 4) << 32; }

static void grid_values(void **state)
{
    (void)state;
    assert_int_equal(delta_grid(0.00015f, 1e-4), 2);   /* 1.5 (f32 0.000150000007) -> 2 */
    assert_int_equal(delta_grid(-0.00025f, 1e-4), -3); /* f32 -0.000250000012: -2.5000001 -> -3 */
    assert_int_equal(delta_grid(-0.00024f, 1e-4), -2);
    assert_int_equal(delta_grid(1.0f, 1e-4), 10000);
    assert_int_equal(delta_grid(-0.75f, 0.5), -2);     /* -1.5 exactly: half away from 0 */
    assert_int_equal(delta_grid(0.25f, 0.5), 1);       /* 0.5 exactly -> 1 */
    assert_int_equal(delta_grid(1e9f, 1e-6), INT32_MAX);
    assert_int_equal(delta_grid(-1e9f, 1e-6), INT32_MIN);
    assert_int_equal(delta_grid(NAN, 1e-4), 0);
    assert_true(delta_quantum_ok(1e-4) && delta_quantum_ok(1e-6) && delta_quantum_ok(1e-2));
    assert_false(delta_quantum_ok(0.9e-6) || delta_quantum_ok(0.011) || delta_quantum_ok(NAN) || delta_quantum_ok(0));
}

/* One axis block of a section (layout in clothd_frame.h), decompressed by libzstd itself. */
typedef struct {
    int basis;
    uint32_t escapes;
    unsigned char raw[64]; /* n + 4 E bytes (n <= 4 here) */
    int32_t r[4];          /* the residuals, escapes resolved */
} axis;

/* The three axis blocks of a section of n vertices, each checked against its head. */
static void axes_of(const unsigned char *section, size_t n, axis ax[3])
{
    const size_t len = get_u32(section + CLF_DELTA_OFF_LENGTH);
    const unsigned char *b = section + CLF_DELTA_HEAD;
    size_t at = 0;
    for (int c = 0; c < 3; c++) {
        assert_true(at + CLF_DELTA_AXIS_HEAD <= len);
        ax[c].basis = b[at];
        assert_int_equal(b[at + 1] | b[at + 2] | b[at + 3], 0);
        ax[c].escapes = get_u32(b + at + CLF_DELTA_AXIS_OFF_ESCAPES);
        const size_t zlen = get_u32(b + at + CLF_DELTA_AXIS_OFF_LENGTH), raw = n + 4 * ax[c].escapes;
        assert_true(raw <= sizeof ax[c].raw && ax[c].escapes <= n);
        assert_int_equal(ZSTD_getFrameContentSize(b + at + CLF_DELTA_AXIS_HEAD, zlen), raw);
        assert_int_equal(ZSTD_decompress(ax[c].raw, sizeof ax[c].raw, b + at + CLF_DELTA_AXIS_HEAD, zlen), raw);
        uint32_t e = 0;
        for (size_t v = 0; v < n; v++) {
            const int8_t x = (int8_t)ax[c].raw[v];
            ax[c].r[v] = x == CLF_DELTA_ESCAPE ? (int32_t)get_u32(ax[c].raw + n + 4 * e++) : x;
        }
        assert_int_equal(e, ax[c].escapes);
        at += CLF_ALIGN4(CLF_DELTA_AXIS_HEAD + zlen);
    }
    assert_int_equal(at, len);
}

/* The grid values a 2 x 2 section decodes to, by the spec: a from r (the parallelogram's
 * inverse), plus the origin (basis 0) or the keyframe's g (basis 1). */
static void grid_of(const unsigned char *section, const int32_t *key_g, int32_t g[12])
{
    axis ax[3];
    axes_of(section, 4, ax);
    for (int c = 0; c < 3; c++) {
        const int32_t *r = ax[c].r;
        const int32_t a[4] = {r[0], r[1] + r[0], r[2] + r[0], r[3] + (r[1] + r[0]) + (r[2] + r[0]) - r[0]};
        assert_true(ax[c].basis == CLF_DELTA_BASIS_ORIGIN || (key_g && ax[c].basis == CLF_DELTA_BASIS_KEY));
        for (int v = 0; v < 4; v++)
            g[3 * v + c] = a[v] + (ax[c].basis ? key_g[3 * v + c] : (int32_t)get_u32(section + CLF_DELTA_OFF_ORIGIN + 4 * c));
    }
}

/* A 2 x 2 cloth, quantum 0.5 m: vertices (i, j) = (0,0) (1,0) (0,1) (1,1). */
static const float KEY[12] = {1.0f, 2.0f, 0.0f,  2.0f, 2.0f, 0.0f,  1.0f, 3.0f, 0.25f,  2.5f, 3.0f, -1.0f};
/* g:      (2,4,0) (4,4,0) (2,6,1) (5,6,-2); origin = per-axis minimum (2,4,-2)
 * a:      (0,0,2) (2,0,2) (0,2,3) (3,2,0)
 * r:      v0 (0,0,2); v1 minus v0 (2,0,0); v2 minus v0 (0,2,1);
 *         v3 minus (v1 + v2 - v0) = (3,2,0) - (2,2,3) = (1,0,-3)
 * int8:   x 0 2 0 1, y 0 0 2 0, z 2 0 1 -3 (0xfd) */
static const unsigned char KEY_BYTES[3][4] = {{0, 2, 0, 1}, {0, 0, 2, 0}, {2, 0, 1, 0xfd}};
static const int32_t KEY_G[12] = {2, 4, 0,  4, 4, 0,  2, 6, 1,  5, 6, -2};

static void keyframe_by_hand(void **state)
{
    (void)state;
    delta_enc e;
    assert_int_equal(delta_init(&e, 0.5), 0);
    unsigned char *out = calloc(1, delta_bound(4));
    int is_key = -1;
    const size_t len = delta_encode(&e, KEY, 4, 2, 77, 1000 * MS, out, &is_key);
    assert_int_equal(is_key, 1);
    assert_int_equal(len % 4, 0);
    assert_int_equal(len, CLF_ALIGN4(CLF_DELTA_HEAD + get_u32(out + CLF_DELTA_OFF_LENGTH)));
    assert_true(len <= delta_bound(4));
    assert_int_equal(get_u32(out + CLF_DELTA_OFF_KIND), CLF_DELTA_KEY);
    assert_int_equal(get_u32(out + CLF_DELTA_OFF_KIND), 2);
    assert_int_equal(get_u32(out + CLF_DELTA_OFF_KEY_ID), 1);
    assert_int_equal(get_u64(out + CLF_DELTA_OFF_KEY_FRAME), 77);
    assert_int_equal(get_u64(out + CLF_DELTA_OFF_QUANTUM), 0x3fe0000000000000ull); /* 0.5 */
    assert_int_equal((int32_t)get_u32(out + CLF_DELTA_OFF_ORIGIN), 2);
    assert_int_equal((int32_t)get_u32(out + CLF_DELTA_OFF_ORIGIN + 4), 4);
    assert_int_equal((int32_t)get_u32(out + CLF_DELTA_OFF_ORIGIN + 8), -2);
    assert_int_equal(get_u32(out + CLF_DELTA_OFF_ROW), 2);
    axis ax[3];
    axes_of(out, 4, ax);
    for (int c = 0; c < 3; c++) {
        assert_int_equal(ax[c].basis, 0);
        assert_int_equal(ax[c].escapes, 0);
        assert_memory_equal(ax[c].raw, KEY_BYTES[c], 4);
    }
    int32_t g[12];
    grid_of(out, NULL, g);
    assert_memory_equal(g, KEY_G, sizeof g);

    /* The next frame, 10 ms later: a delta against it. Moves: v0 +x 0.5 (g + 1), v3 z -1.0
     * (g - 2), v2 y -0.25 (3 - 0.25 = 2.75 / 0.5 = 5.5 -> 6: unchanged). Whichever basis each
     * axis took, it decodes to these grid values. */
    float next[12];
    memcpy(next, KEY, sizeof next);
    next[0] += 0.5f;
    next[11] -= 1.0f;
    next[7] -= 0.25f;
    const size_t len2 = delta_encode(&e, next, 4, 2, 78, 1010 * MS, out, &is_key);
    assert_true(len2 > CLF_DELTA_HEAD && len2 <= delta_bound(4));
    assert_int_equal(is_key, 0);
    assert_int_equal(get_u32(out + CLF_DELTA_OFF_KIND), CLF_DELTA_DELTA);
    assert_int_equal(get_u32(out + CLF_DELTA_OFF_KIND), 3);
    assert_int_equal(get_u32(out + CLF_DELTA_OFF_KEY_ID), 1);
    assert_int_equal(get_u64(out + CLF_DELTA_OFF_KEY_FRAME), 77);
    assert_int_equal((int32_t)get_u32(out + CLF_DELTA_OFF_ORIGIN + 8), -2);
    static const int32_t NEXT_G[12] = {3, 4, 0,  4, 4, 0,  2, 6, 1,  5, 6, -4};
    grid_of(out, KEY_G, g);
    assert_memory_equal(g, NEXT_G, sizeof g);

    /* Residuals past a byte escape: v0 x at -999 m is g = -1998. Against the keyframe
     * d = (-2000, 0, 0, 0): r = (-2000, 2000, 2000, -2000); against the origin 2,
     * a = (-2000, 2, 0, 3): r = (-2000, 2002, 2000, -1999). Either way all four escape. */
    next[0] = KEY[0] - 1000.0f;
    next[11] = KEY[11];
    assert_true(delta_encode(&e, next, 4, 2, 79, 1020 * MS, out, &is_key) > 0);
    assert_int_equal(is_key, 0);
    axes_of(out, 4, ax);
    assert_int_equal(ax[0].escapes, 4);
    assert_memory_equal(ax[0].raw, "\x80\x80\x80\x80", 4);
    assert_int_equal(ax[0].r[0], -2000);
    assert_int_equal(ax[0].r[2], 2000);
    static const int32_t FAR_G[12] = {-1998, 4, 0,  4, 4, 0,  2, 6, 1,  5, 6, -2};
    grid_of(out, KEY_G, g);
    assert_memory_equal(g, FAR_G, sizeof g);
    /* A cloth at rest: every axis of a delta is all zeros against its keyframe. */
    assert_true(delta_encode(&e, KEY, 4, 2, 80, 1030 * MS, out, &is_key) > 0);
    axes_of(out, 4, ax);
    for (int c = 0; c < 3; c++) assert_memory_equal(ax[c].r, ((int32_t[4]){0, 0, 0, 0}), 16);
    free(out);
    delta_free(&e);
}

static void keyframe_policy(void **state)
{
    (void)state;
    delta_enc e;
    assert_int_equal(delta_init(&e, 1e-4), 0);
    float xyz[3 * 6] = {0};
    unsigned char *out = calloc(1, delta_bound(6));
    int key;
    uint64_t t = 5000 * MS;
    assert_true(delta_encode(&e, xyz, 6, 3, 1, t, out, &key) && key);
    assert_true(delta_encode(&e, xyz, 6, 3, 2, t + 16 * MS, out, &key) && !key);
    /* A keyframe once a second: not at 999 ms, at 1000 ms. */
    assert_true(delta_encode(&e, xyz, 6, 3, 3, t + 999 * MS, out, &key) && !key);
    assert_true(delta_encode(&e, xyz, 6, 3, 4, t + 1000 * MS, out, &key) && key);
    assert_int_equal(get_u32(out + CLF_DELTA_OFF_KEY_ID), 2);
    t += 1000 * MS;
    /* Asked for: not before 250 ms since the last, then at once; one ask, one keyframe. */
    delta_want_key(&e);
    assert_true(delta_encode(&e, xyz, 6, 3, 5, t + 100 * MS, out, &key) && !key);
    assert_true(delta_encode(&e, xyz, 6, 3, 6, t + 250 * MS, out, &key) && key);
    assert_true(delta_encode(&e, xyz, 6, 3, 7, t + 600 * MS, out, &key) && !key);
    /* Asked for a thousand times a second: 4 keyframes a second, the policy's, not 1000. */
    int keys = 0;
    for (int ms = 1; ms <= 1000; ms++) {
        delta_want_key(&e);
        assert_true(delta_encode(&e, xyz, 6, 3, 8, t + 600 * MS + (uint64_t)ms * MS, out, &key));
        keys += key;
    }
    assert_int_equal(keys, 4);
    /* A new shape is a keyframe at once: another row, another n. */
    assert_true(delta_encode(&e, xyz, 6, 2, 9, t + 1601 * MS, out, &key) && key);
    assert_true(delta_encode(&e, xyz, 4, 2, 10, t + 1602 * MS, out, &key) && key);
    assert_true(delta_encode(&e, xyz, 4, 2, 11, t + 1603 * MS, out, &key) && !key);
    /* A clock that goes back (a restart of the frames' clock) starts again with a keyframe. */
    assert_true(delta_encode(&e, xyz, 4, 2, 12, t, out, &key) && key);
    assert_int_equal(delta_encode(&e, xyz, 4, 0, 13, t, out, &key), 0); /* no rows: refused */
    free(out);
    delta_free(&e);
}

/* A whole section decoded by the spec (libzstd, then per axis the parallelogram's inverse, row
 * by row, plus the origin or key_g), into positions xyz (3 n) and the grid values g. */
static void decode_section(const unsigned char *section, size_t n, size_t w, const int32_t *key_g, int32_t *g, float *xyz)
{
    double quantum;
    const uint64_t qbits = get_u64(section + CLF_DELTA_OFF_QUANTUM);
    memcpy(&quantum, &qbits, 8);
    const size_t len = get_u32(section + CLF_DELTA_OFF_LENGTH);
    const unsigned char *b = section + CLF_DELTA_HEAD;
    unsigned char *raw = malloc(5 * n);
    uint32_t *a = malloc(4 * n);
    size_t at = 0;
    for (int c = 0; c < 3; c++) {
        const int basis = b[at];
        const uint32_t escapes = get_u32(b + at + CLF_DELTA_AXIS_OFF_ESCAPES);
        const size_t zlen = get_u32(b + at + CLF_DELTA_AXIS_OFF_LENGTH);
        assert_true(basis == CLF_DELTA_BASIS_ORIGIN || (key_g && basis == CLF_DELTA_BASIS_KEY));
        assert_int_equal(ZSTD_decompress(raw, 5 * n, b + at + CLF_DELTA_AXIS_HEAD, zlen), n + 4 * escapes);
        uint32_t e = 0;
        for (size_t v = 0; v < n; v++) {
            const int8_t x = (int8_t)raw[v];
            const uint32_t r = x == CLF_DELTA_ESCAPE ? get_u32(raw + n + 4 * e++) : (uint32_t)(int32_t)x;
            const size_t i = v % w;
            uint32_t p = 0;
            if (i && v >= w) p = a[v - 1] + a[v - w] - a[v - 1 - w];
            else if (i) p = a[v - 1];
            else if (v >= w) p = a[v - w];
            a[v] = r + p;
        }
        assert_int_equal(e, escapes);
        const uint32_t origin = get_u32(section + CLF_DELTA_OFF_ORIGIN + 4 * c);
        for (size_t v = 0; v < n; v++) {
            g[3 * v + c] = (int32_t)(a[v] + (basis ? (uint32_t)key_g[3 * v + c] : origin));
            xyz[3 * v + c] = (float)(g[3 * v + c] * quantum);
        }
        at += CLF_ALIGN4(CLF_DELTA_AXIS_HEAD + zlen);
    }
    assert_int_equal(at, len);
    free(raw);
    free(a);
}

/* A wrinkled sheet, 1 m across, falling and rippling over a second of frames; a keyframe, then
 * deltas, each decoded by the spec: every coordinate within quantum / 2 (plus float32's rounding of
 * the decoded value) of what was encoded. w x w vertices: 64 x 64 takes the optimal parser, 100 x
 * 100 (above DELTA_TIGHT_MAX_N) the fast one. */
static void sheet_round_trip(size_t w)
{
    const size_t n = w * w;
    const double quantum = 1e-4;
    delta_enc e;
    assert_int_equal(delta_init(&e, quantum), 0);
    float *xyz = malloc(12 * n), *back = malloc(12 * n);
    int32_t *g = malloc(12 * n), *key_g = malloc(12 * n);
    unsigned char *out = calloc(1, delta_bound((int32_t)n));
    double worst = 0;
    int keys = 0;
    for (int f = 0; f < 60; f++) {
        const double t = f / 60.0;
        for (size_t v = 0; v < n; v++) {
            const double x = (double)(v % w) / (double)(w - 1), y = (double)(v / w) / (double)(w - 1);
            xyz[3 * v] = (float)(x - 0.5 + 0.002 * sin(40 * y + 9 * t));
            xyz[3 * v + 1] = (float)(y - 0.5);
            xyz[3 * v + 2] = (float)(1.0 - 0.5 * 9.81 * t * t + 0.01 * sin(25 * x + 13 * t) * cos(31 * y - 7 * t));
        }
        int key;
        const size_t len = delta_encode(&e, xyz, (int32_t)n, (int32_t)w, (uint64_t)f, (uint64_t)f * 16 * MS, out, &key);
        assert_true(len > CLF_DELTA_HEAD && len <= delta_bound((int32_t)n));
        assert_int_equal(key, f == 0);
        keys += key;
        decode_section(out, n, w, key ? NULL : key_g, g, back);
        if (key) memcpy(key_g, g, 12 * n);
        for (size_t k = 0; k < 3 * n; k++) {
            const double err = fabs((double)back[k] - (double)xyz[k]);
            const double bound = quantum / 2 + 2 * fabs((double)xyz[k]) * 0x1p-24;
            if (err > bound) fail_msg("frame %d coordinate %zu: %.9g decoded as %.9g", f, k, (double)xyz[k], (double)back[k]);
            if (err > worst) worst = err;
        }
    }
    assert_int_equal(keys, 1);
    assert_true(worst > 0.4 * quantum); /* the bound is reached, not avoided by a finer grid */
    free(xyz);
    free(back);
    free(g);
    free(key_g);
    free(out);
    delta_free(&e);
}

static void both_parsers(void **state)
{
    (void)state;
    assert_true(64 * 64 <= DELTA_TIGHT_MAX_N && 100 * 100 > DELTA_TIGHT_MAX_N);
    sheet_round_trip(64);
    sheet_round_trip(100);
}

int main(void)
{
    const struct CMUnitTest tests[] = {
        cmocka_unit_test(grid_values),
        cmocka_unit_test(keyframe_by_hand),
        cmocka_unit_test(keyframe_policy),
        cmocka_unit_test(both_parsers),
    };
    return cmocka_run_group_tests(tests, NULL, NULL);
}
