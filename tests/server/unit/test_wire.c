/* test_wire.c - the wire codec (core/wire.c) against the layout PROTOCOL.md gives for a binary
 * frame, byte by byte, on a pose of 3 vertices and one rock; q16's quantization on hand-computed
 * values; meshopt decoded by the meshoptimizer library itself back to the q16 values. */
#include <math.h>
#include <meshoptimizer.h>

#include "core/wire.h"
#include "unitkit.h"

static uint16_t u16(const unsigned char *p) { return (uint16_t)(p[0] | p[1] << 8); }
static uint32_t u32(const unsigned char *p) { return (uint32_t)p[0] | (uint32_t)p[1] << 8 | (uint32_t)p[2] << 16 | (uint32_t)p[3] << 24; }
static uint64_t u64(const unsigned char *p) { return (uint64_t)u32(p) | (uint64_t)u32(p + 4) << 32; }
static float f32(const unsigned char *p)
{
    const uint32_t u = u32(p);
    float f;
    memcpy(&f, &u, 4);
    return f;
}

/* Vertices (0, 0, 1), (2, 1, 1), (1, 0.5, 1) (a flat z), speeds 0, 255, 7, one rock. */
static pose sample(void)
{
    pose p;
    memset(&p, 0, sizeof p);
    assert_int_equal(pose_reserve(&p, 3, 1), 0);
    const float xyz[9] = {0, 0, 1, 2, 1, 1, 1, 0.5f, 1};
    memcpy(p.xyz, xyz, sizeof xyz);
    p.n = 3;
    p.n_rocks = 1;
    p.frame = 5;
    p.step = 150;
    p.sim_time = 0.25;
    p.wall_ns = 1700000000123456789ull;
    p.scalar[SCALAR_SPEED][0] = 0, p.scalar[SCALAR_SPEED][1] = 255, p.scalar[SCALAR_SPEED][2] = 7;
    p.has[SCALAR_SPEED] = 1;
    p.rocks[0] = (pose_rock){42, {0.5f, -1, 3}, 0.25f, {0, 0, 0, 1}};
    pose_bbox(&p);
    return p;
}

static void test_header_and_f32(void **unused)
{
    (void)unused;
    pose p = sample();
    assert_true(p.bbox[0] == 0 && p.bbox[1] == 0 && p.bbox[2] == 1 && p.bbox[3] == 2 && p.bbox[4] == 1 && p.bbox[5] == 1);
    unsigned char out[512];
    const size_t n = wire_encode(&p, 0, SCALAR_SPEED, out);
    /* 72-byte header; 3 x 3 f32 (36); 3 scalar bytes padded to 4; a rock of 36 bytes. */
    assert_int_equal(n, 72 + 36 + 4 + 36);
    assert_true(n <= wire_bound(&p, 0, SCALAR_SPEED));
    assert_memory_equal(out, "CLF1", 4);
    assert_int_equal(u16(out + 4), 72);
    assert_int_equal(u16(out + 6), 0 | 4); /* f32, scalar present */
    assert_true(u64(out + 8) == 5 && u64(out + 16) == 150);
    double t;
    uint64_t tb = u64(out + 24);
    memcpy(&t, &tb, 8);
    assert_true(t == 0.25);
    assert_true(u64(out + 32) == 1700000000123456789ull);
    assert_int_equal(u32(out + 40), 3);
    assert_int_equal(u32(out + 44), 1);
    assert_true(f32(out + 48) == 0 && f32(out + 56) == 1 && f32(out + 60) == 2 && f32(out + 68) == 1);
    assert_true(f32(out + 72) == 0 && f32(out + 72 + 12) == 2 && f32(out + 72 + 28) == 0.5f);
    assert_int_equal(out[108], 0);
    assert_int_equal(out[109], 255);
    assert_int_equal(out[110], 7);
    assert_int_equal(out[111], 0); /* padding */
    assert_int_equal(u32(out + 112), 42);
    assert_true(f32(out + 116) == 0.5f && f32(out + 120) == -1 && f32(out + 124) == 3 && f32(out + 128) == 0.25f);
    assert_true(f32(out + 132) == 0 && f32(out + 144) == 1);
    /* Without a scalar (or one the pose lacks), no scalar section and no flag. */
    assert_int_equal(wire_encode(&p, 0, SCALAR_NONE, out), 72 + 36 + 36);
    assert_int_equal(u16(out + 6), 0);
    assert_int_equal(wire_encode(&p, 0, SCALAR_STRAIN, out), 72 + 36 + 36);
    pose_free(&p);
}

/* q16: bbox min -> 0, max -> 65535, in between rounded; an axis of no extent -> 0. */
static void test_q16(void **unused)
{
    (void)unused;
    pose p = sample();
    unsigned char out[512];
    const size_t n = wire_encode(&p, 1, SCALAR_NONE, out);
    assert_int_equal(n, 72 + 20 + 36); /* 3 x 3 u16 = 18, padded to 20 */
    assert_int_equal(u16(out + 6), 1);
    const uint16_t want[9] = {0, 0, 0, 65535, 65535, 0, 32768, 32768, 0}; /* 0.5 x 65535 + 0.5 */
    for (int k = 0; k < 9; k++) assert_int_equal(u16(out + 72 + 2 * k), want[k]);
    assert_int_equal(u16(out + 90), 0);
    assert_int_equal(u32(out + 92), 42);
    pose_free(&p);
}

/* meshopt: a byte count, then the q16 triples padded to 8 bytes, encoded; the library's decoder
 * gives the q16 values back. */
static void test_meshopt(void **unused)
{
    (void)unused;
    pose p = sample();
    unsigned char out[1024];
    const size_t n = wire_encode(&p, 2, SCALAR_NONE, out);
    assert_true(n <= wire_bound(&p, 2, SCALAR_NONE));
    assert_int_equal(u16(out + 6), 2);
    const uint32_t len = u32(out + 72);
    assert_int_equal(n, 72 + 4 + ((len + 3) & ~3u) + 36);
    uint16_t back[12];
    assert_int_equal(meshopt_decodeVertexBuffer(back, 3, 8, out + 76, len), 0);
    const uint16_t want[12] = {0, 0, 0, 0, 65535, 65535, 0, 0, 32768, 32768, 0, 0};
    assert_memory_equal(back, want, sizeof want);
    pose_free(&p);
}

/* An empty pose: the header alone. */
static void test_empty(void **unused)
{
    (void)unused;
    pose p;
    memset(&p, 0, sizeof p);
    pose_bbox(&p);
    unsigned char out[128];
    assert_int_equal(wire_encode(&p, 0, SCALAR_NONE, out), 72);
    assert_true(f32(out + 48) == 0 && f32(out + 60) == 0);
    pose_free(&p);
}

int main(void)
{
    const struct CMUnitTest tests[] = {
        cmocka_unit_test(test_header_and_f32),
        cmocka_unit_test(test_q16),
        cmocka_unit_test(test_meshopt),
        cmocka_unit_test(test_empty),
    };
    return cmocka_run_group_tests(tests, NULL, NULL);
}
