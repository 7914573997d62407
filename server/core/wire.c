/* wire.c - encoding a pose as the stream's binary message (layout in proto/clothd_frame.h). */
#include <meshoptimizer.h>
#include <stdlib.h>
#include <string.h>

#include "clothd_frame.h"
#include "core/delta.h"
#include "core/wire.h"

static void put_u16(unsigned char *p, uint16_t v)
{
    p[0] = (unsigned char)v;
    p[1] = (unsigned char)(v >> 8);
}
static void put_u32(unsigned char *p, uint32_t v)
{
    for (int i = 0; i < 4; i++) p[i] = (unsigned char)(v >> (8 * i));
}
static void put_u64(unsigned char *p, uint64_t v)
{
    for (int i = 0; i < 8; i++) p[i] = (unsigned char)(v >> (8 * i));
}
static void put_f32(unsigned char *p, float f)
{
    uint32_t u;
    memcpy(&u, &f, 4);
    put_u32(p, u);
}
static void put_f64(unsigned char *p, double f)
{
    uint64_t u;
    memcpy(&u, &f, 8);
    put_u64(p, u);
}

static int wants_scalar(const pose *f, int scalar) { return scalar != SCALAR_NONE && f->has[scalar]; }

size_t wire_bound(const pose *f, int encoding, int scalar)
{
    const size_t n = (size_t)f->n;
    size_t pos;
    switch (encoding) {
    case CLF_Q16: pos = CLF_ALIGN4(6 * n); break;
    case CLF_MESHOPT: pos = 4 + CLF_ALIGN4(meshopt_encodeVertexBufferBound(n, CLF_MESHOPT_STRIDE)); break;
    case CLF_DELTA: pos = delta_bound(f->n); break;
    default: pos = 12 * n; break;
    }
    return CLF_HEADER_SIZE + pos + (wants_scalar(f, scalar) ? CLF_ALIGN4(n) : 0) + (size_t)f->n_rocks * CLF_ROCK_SIZE;
}

/* q16 of one coordinate: bbox min..max to 0..65535, rounded; a flat axis is 0. In double, so
 * that the rounding is to the nearest step (float arithmetic here put some values 1% of a
 * half-step beyond it). */
static uint16_t quantize(float x, float lo, double scale)
{
    double q = ((double)x - lo) * scale + 0.5;
    q = q < 0.0 ? 0.0 : (q > 65535.0 ? 65535.0 : q);
    return (uint16_t)q;
}

static size_t encode(const pose *f, int encoding, int scalar, const unsigned char *section, size_t section_len,
                     unsigned char *out);

size_t wire_encode(const pose *f, int encoding, int scalar, unsigned char *out)
{
    return encoding == CLF_DELTA ? 0 : encode(f, encoding, scalar, NULL, 0, out);
}

size_t wire_encode_delta(const pose *f, int scalar, const unsigned char *section, size_t len, unsigned char *out)
{
    return encode(f, CLF_DELTA, scalar, section, len, out);
}

static size_t encode(const pose *f, int encoding, int scalar, const unsigned char *section, size_t section_len,
                     unsigned char *out)
{
    const size_t n = (size_t)f->n;
    const int with_scalar = wants_scalar(f, scalar);
    memcpy(out + CLF_OFF_MAGIC, CLF_MAGIC, 4);
    put_u16(out + CLF_OFF_HEADER_SIZE, CLF_HEADER_SIZE);
    put_u16(out + CLF_OFF_FLAGS, (uint16_t)((unsigned)encoding | (with_scalar ? CLF_FLAG_SCALAR : 0u)));
    put_u64(out + CLF_OFF_FRAME, f->frame);
    put_u64(out + CLF_OFF_STEP, f->step);
    put_f64(out + CLF_OFF_SIM_TIME, f->sim_time);
    put_u64(out + CLF_OFF_WALL_NS, f->wall_ns);
    put_u32(out + CLF_OFF_N_VERTICES, (uint32_t)f->n);
    put_u32(out + CLF_OFF_N_ROCKS, (uint32_t)f->n_rocks);
    for (int c = 0; c < 6; c++) put_f32(out + CLF_OFF_BBOX_MIN + 4 * c, f->bbox[c]);
    size_t at = CLF_HEADER_SIZE;
    double scale[3];
    for (int c = 0; c < 3; c++) {
        const double ext = (double)f->bbox[3 + c] - f->bbox[c];
        scale[c] = ext >= CLF_Q16_EXTENT_MIN ? 65535.0 / ext : 0.0;
    }
    if (encoding == CLF_F32) {
        for (size_t k = 0; k < 3 * n; k++) put_f32(out + at + 4 * k, f->xyz[k]);
        at += 12 * n;
    } else if (encoding == CLF_Q16) {
        for (size_t v = 0; v < n; v++)
            for (int c = 0; c < 3; c++) put_u16(out + at + 6 * v + 2 * c, quantize(f->xyz[3 * v + c], f->bbox[c], scale[c]));
        at += 6 * n;
    } else if (encoding == CLF_DELTA) {
        memcpy(out + at, section, section_len); /* 4-byte aligned already */
        at += section_len;
    } else {
        uint16_t *q = malloc(n * CLF_MESHOPT_STRIDE + 1);
        size_t len = 0;
        if (q) {
            for (size_t v = 0; v < n; v++) {
                for (int c = 0; c < 3; c++) q[4 * v + c] = quantize(f->xyz[3 * v + c], f->bbox[c], scale[c]);
                q[4 * v + 3] = 0;
            }
            const size_t bound = meshopt_encodeVertexBufferBound(n, CLF_MESHOPT_STRIDE);
            len = meshopt_encodeVertexBuffer(out + at + 4, bound, q, n, CLF_MESHOPT_STRIDE);
            free(q);
        }
        put_u32(out + at, (uint32_t)len);
        at += 4 + len;
    }
    while (at % 4) out[at++] = 0;
    if (with_scalar) {
        memcpy(out + at, f->scalar[scalar], n);
        at += n;
        while (at % 4) out[at++] = 0;
    }
    for (int32_t r = 0; r < f->n_rocks; r++) {
        const pose_rock *k = &f->rocks[r];
        put_u32(out + at, k->id);
        for (int c = 0; c < 3; c++) put_f32(out + at + 4 + 4 * c, k->position[c]);
        put_f32(out + at + 16, k->radius);
        for (int c = 0; c < 4; c++) put_f32(out + at + 20 + 4 * c, k->orientation[c]);
        at += CLF_ROCK_SIZE;
    }
    return at;
}
