/* test_recording.c - the CLR1 format (core/recording.c) against the layout of PROTOCOL.md
 * "Recordings", byte by byte: a file of a hello, an event and two f32 frames of 2 vertices built
 * here by hand (frames from wire_encode), its header, records, index and tail at the offsets the
 * layout gives; read back complete; cut anywhere, read as far as its last complete record; and
 * refused, naming the offset, for each corruption the format lists. */
#include "clothd_frame.h"
#include "core/recording.h"
#include "core/wire.h"
#include "unitkit.h"

static uint32_t u32(const unsigned char *p) { return (uint32_t)p[0] | (uint32_t)p[1] << 8 | (uint32_t)p[2] << 16 | (uint32_t)p[3] << 24; }
static uint64_t u64(const unsigned char *p) { return (uint64_t)u32(p) | (uint64_t)u32(p + 4) << 32; }
static void put32(unsigned char *p, uint32_t v)
{
    for (int i = 0; i < 4; i++) p[i] = (unsigned char)(v >> (8 * i));
}

static const char hello[] = "{\"type\":\"hello\",\"scene\":{\"nx\":2,\"ny\":1},\"recording\":{\"id\":\"r\"}}"; /* 63 bytes */
static const char event[] = "{\"type\":\"event\",\"event\":\"x\"}";                                      /* 28 bytes */

typedef struct file {
    unsigned char b[4096];
    size_t len;
    rec_index ix;
} file;

static void add(file *f, uint32_t type, const void *payload, size_t len)
{
    rec_record_head(f->b + f->len, type, (uint32_t)len);
    memcpy(f->b + f->len + 8, payload, len);
    memset(f->b + f->len + 8 + len, 0, rec_padding(len));
    f->len += rec_record_size(len);
}

static size_t frame(unsigned char *out, double t)
{
    pose p;
    memset(&p, 0, sizeof p);
    assert_int_equal(pose_reserve(&p, 2, 0), 0);
    const float xyz[6] = {0, 0, 1, 1, 0, 1};
    memcpy(p.xyz, xyz, sizeof xyz);
    p.n = 2;
    p.sim_time = t;
    pose_bbox(&p);
    const size_t len = wire_encode(&p, CLF_F32, SCALAR_NONE, out);
    pose_free(&p);
    return len;
}

/* header, hello (16), event, frame at 0.5, frame at 0.75, index, tail */
static void build(file *f, int finished)
{
    memset(f, 0, sizeof *f);
    rec_file_header(f->b);
    f->len = REC_HEADER_SIZE;
    unsigned char fr[256];
    rec_index_add_text(&f->ix, f->len);
    add(f, REC_TEXT, hello, strlen(hello));
    rec_index_add_text(&f->ix, f->len);
    add(f, REC_TEXT, event, strlen(event));
    for (int k = 0; k < 2; k++) {
        const rec_frame e = {f->len, 0.5 + 0.25 * k, (uint32_t)k, 2};
        rec_index_add_frame(&f->ix, &e);
        add(f, REC_FRAME, fr, frame(fr, e.sim_time));
    }
    if (finished) {
        size_t len;
        unsigned char *tail = rec_index_finish(&f->ix, f->len, &len);
        memcpy(f->b + f->len, tail, len);
        f->len += len;
        free(tail);
    }
}

static void test_layout(void **unused)
{
    (void)unused;
    file f;
    build(&f, 1);
    /* header: "CLR1", version 1, flags 0, reserved 0 */
    assert_memory_equal(f.b, "CLR1\1\0\0\0\0\0\0\0\0\0\0\0", 16);
    /* the hello at 16: type 1, length 63, payload, one byte of padding */
    assert_int_equal(u32(f.b + 16), 1);
    assert_int_equal(u32(f.b + 20), 63);
    assert_memory_equal(f.b + 24, hello, 63);
    assert_int_equal(f.b[87], 0);
    /* the event at 88 (28 bytes, no padding), the first frame at 124: 72 + 2 x 12 = 96 bytes */
    assert_int_equal(u32(f.b + 88), 1);
    assert_int_equal(u32(f.b + 124), 2);
    assert_int_equal(u32(f.b + 128), 96);
    assert_memory_equal(f.b + 132, "CLF1", 4);
    assert_int_equal(u32(f.b + 228), 2); /* the second frame at 124 + 8 + 96 */
    /* the index at 332: n_frames 2, n_texts 2, 2 x 24 + 2 x 8 bytes of entries */
    const size_t ix = 332;
    assert_int_equal(u32(f.b + ix), 3);
    assert_int_equal(u32(f.b + ix + 4), 8 + 48 + 16);
    assert_int_equal(u32(f.b + ix + 8), 2);
    assert_int_equal(u32(f.b + ix + 12), 2);
    assert_int_equal(u64(f.b + ix + 16), 124);
    double t;
    memcpy(&t, f.b + ix + 24, 8);
    assert_true(t == 0.5);
    assert_int_equal(u32(f.b + ix + 32), 0);  /* key */
    assert_int_equal(u32(f.b + ix + 36), 2);  /* texts_before */
    assert_int_equal(u64(f.b + ix + 40), 228);
    assert_int_equal(u64(f.b + ix + 64), 16); /* the texts: the hello, the event */
    assert_int_equal(u64(f.b + ix + 72), 88);
    /* the tail: the last 16 bytes */
    assert_int_equal(f.len, ix + 8 + 72 + 16);
    assert_memory_equal(f.b + f.len - 16, "CLRX\0\0\0\0", 8);
    assert_int_equal(u64(f.b + f.len - 8), ix);

    rec_file r;
    assert_int_equal(rec_read(f.b, f.len, &r), 0);
    assert_true(r.complete);
    assert_int_equal(r.n_vertices, 2);
    assert_int_equal(r.encoding, CLF_F32);
    assert_int_equal(r.ix.n_frames, 2);
    assert_int_equal(r.ix.n_texts, 2);
    assert_int_equal(r.ix.frames[1].offset, 228);
    assert_true(r.ix.frames[1].sim_time == 0.75);
    assert_string_equal(json_string_value(json_object_get(json_object_get(r.hello, "recording"), "id")), "r");
    rec_file_free(&r);
    rec_index_free(&f.ix);
}

/* Cut at every length: read up to the last complete record (a record is complete with its padding). */
static void test_cut(void **unused)
{
    (void)unused;
    file f;
    build(&f, 1);
    for (size_t len = 16; len < f.len; len++) {
        rec_file r;
        const int rc = rec_read(f.b, len, &r);
        if (len < 88) { /* the hello incomplete: nothing to read */
            assert_int_equal(rc, -1);
            continue;
        }
        assert_int_equal(rc, 0);
        assert_false(r.complete);
        const uint32_t frames = len >= 332 ? 2 : len >= 228 ? 1 : 0, texts = len >= 124 ? 2 : 1;
        assert_int_equal(r.ix.n_frames, frames);
        assert_int_equal(r.ix.n_texts, texts);
        assert_int_equal(r.end, frames == 2 ? 332 : frames == 1 ? 228 : texts == 2 ? 124 : 88);
        rec_file_free(&r);
    }
    rec_index_free(&f.ix);
}

/* Each corruption refused, at its offset. */
static void test_refused(void **unused)
{
    (void)unused;
    struct {
        size_t at;
        uint32_t value;
        size_t error_at;
        const char *why;
    } cases[] = {
        {0, 0x32524c43, 0, "magic"},                  /* "CLR2" */
        {4, 2, 4, "version"},
        {8, 1, 8, "flags"},
        {88, 4, 88, "unknown type"},                  /* the event's type */
        {16, 2, 16, "first record"},                  /* the hello as a frame */
        {132, 0x32464c43, 124, "CLF1"},               /* the first frame's magic */
        {132 + 40, 3, 124, "vertices"},               /* its n_vertices */
        {132 + 6, 0x10, 124, "flags"},                /* its flags (u16, and the 2 bytes after: frame's low bytes) */
        {332 + 8, 3, 332, "counts"},                  /* the index's n_frames */
        {332 + 16, 125, 332, "frame"},                /* the first frame's index offset */
    };
    for (size_t c = 0; c < sizeof cases / sizeof cases[0]; c++) {
        file f;
        build(&f, 1);
        if (cases[c].at == 132 + 6) {
            f.b[cases[c].at] = 0x10, f.b[cases[c].at + 1] = 0;
        } else {
            put32(f.b + cases[c].at, cases[c].value);
        }
        rec_file r;
        assert_int_equal(rec_read(f.b, f.len, &r), -1);
        if (!strstr(r.error, cases[c].why) || r.error_offset != cases[c].error_at)
            fail_msg("case %zu: '%s' at %llu (expected '%s' at %zu)", c, r.error, (unsigned long long)r.error_offset, cases[c].why,
                     cases[c].error_at);
        rec_index_free(&f.ix);
    }
    /* A text record that is not JSON; one holding a NUL. */
    file f;
    build(&f, 0);
    f.b[96] = '[';
    rec_file r;
    assert_int_equal(rec_read(f.b, f.len, &r), -1);
    assert_int_equal(r.error_offset, 88);
    f.b[96] = 0;
    assert_int_equal(rec_read(f.b, f.len, &r), -1);
    assert_non_null(strstr(r.error, "NUL"));
    /* A payload length past the file: cut, not refused (what comes before counts). */
    rec_index_free(&f.ix);
    build(&f, 0);
    put32(f.b + 228 + 4, 1u << 30);
    assert_int_equal(rec_read(f.b, f.len, &r), 0);
    assert_int_equal(r.ix.n_frames, 1);
    rec_file_free(&r);
    rec_index_free(&f.ix);
}

int main(void)
{
    const struct CMUnitTest tests[] = {
        cmocka_unit_test(test_layout),
        cmocka_unit_test(test_cut),
        cmocka_unit_test(test_refused),
    };
    return cmocka_run_group_tests(tests, NULL, NULL);
}
