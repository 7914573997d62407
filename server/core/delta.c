/* delta.c - the `delta` encoding's positions section (layout in proto/clothd_frame.h). */
#include <math.h>
#include <stdlib.h>
#include <string.h>
#include <zstd.h>

#include "clothd_frame.h"
#include "core/delta.h"

int delta_quantum_ok(double q) { return isfinite(q) && q >= DELTA_QUANTUM_MIN && q <= DELTA_QUANTUM_MAX; }

int delta_init(delta_enc *e, double quantum)
{
    memset(e, 0, sizeof *e);
    e->quantum = quantum;
    e->zstd = ZSTD_createCCtx();
    if (!e->zstd) return -1;
    if (ZSTD_isError(ZSTD_CCtx_setParameter(e->zstd, ZSTD_c_compressionLevel, DELTA_ZSTD_LEVEL)) ||
        ZSTD_isError(ZSTD_CCtx_setParameter(e->zstd, ZSTD_c_minMatch, DELTA_ZSTD_MIN_MATCH))) {
        ZSTD_freeCCtx(e->zstd);
        e->zstd = NULL;
        return -1;
    }
    return 0;
}

void delta_free(delta_enc *e)
{
    free(e->key);
    free(e->work);
    free(e->planes);
    ZSTD_freeCCtx(e->zstd);
    memset(e, 0, sizeof *e);
}

size_t delta_bound(int32_t n)
{
    return CLF_ALIGN4(CLF_DELTA_HEAD + 3 * ZSTD_compressBound(4 * (size_t)n));
}

void delta_want_key(delta_enc *e) { e->key_wanted = 1; }

int32_t delta_grid(float x, double quantum)
{
    const double g = round((double)x / quantum); /* halves away from 0 */
    if (!(g == g)) return 0;
    if (g <= (double)INT32_MIN) return INT32_MIN;
    if (g >= (double)INT32_MAX) return INT32_MAX;
    return (int32_t)g;
}

static void put_u32(unsigned char *p, uint32_t v)
{
    for (int i = 0; i < 4; i++) p[i] = (unsigned char)(v >> (8 * i));
}
static void put_u64(unsigned char *p, uint64_t v)
{
    for (int i = 0; i < 8; i++) p[i] = (unsigned char)(v >> (8 * i));
}

static int reserve(delta_enc *e, int32_t n)
{
    if ((size_t)n <= e->cap_n) return 0;
    int32_t *key = realloc(e->key, 12 * (size_t)n), *work = key ? realloc(e->work, 12 * (size_t)n) : NULL;
    if (key) e->key = key;
    if (work) e->work = work;
    unsigned char *planes = work ? realloc(e->planes, 12 * (size_t)n) : NULL;
    if (!planes) return -1;
    e->planes = planes;
    e->cap_n = (size_t)n;
    return 0;
}

/* a (3 n values, rows of row vertices) to the byte planes of the zigzagged residuals of the
 * parallelogram prediction, all in uint32 arithmetic (mod 2^32). */
static void predict_to_planes(const int32_t *a, int32_t n, int32_t row, unsigned char *planes)
{
    const size_t nn = (size_t)n, w = (size_t)row;
    for (size_t v = 0; v < nn; v++) {
        const size_t i = v % w, j = v / w;
        for (int c = 0; c < 3; c++) {
            const uint32_t *u = (const uint32_t *)a;
            const size_t k = 3 * v + (size_t)c;
            uint32_t p = 0;
            if (i && j) p = u[k - 3] + u[k - 3 * w] - u[k - 3 - 3 * w];
            else if (i) p = u[k - 3];
            else if (j) p = u[k - 3 * w];
            const uint32_t r = u[k] - p;
            const uint32_t z = (r << 1) ^ (0u - (r >> 31));
            for (int b = 0; b < 4; b++) planes[(size_t)(4 * c + b) * nn + v] = (unsigned char)(z >> (8 * b));
        }
    }
}

size_t delta_encode(delta_enc *e, const float *xyz, int32_t n, int32_t row, uint64_t frame,
                    uint64_t wall_ns, unsigned char *out, int *is_key)
{
    if (n < 0 || row < 1 || reserve(e, n) < 0) return 0;
    const uint64_t since = wall_ns - e->key_wall_ns;
    const int key = e->n != n || e->row != row || e->key_id == 0 || wall_ns < e->key_wall_ns ||
                    since >= DELTA_KEY_INTERVAL_NS || (e->key_wanted && since >= DELTA_KEY_MIN_GAP_NS);
    const size_t m = 3 * (size_t)n;
    if (key) {
        int32_t lo[3] = {0, 0, 0};
        for (size_t k = 0; k < m; k++) {
            e->key[k] = delta_grid(xyz[k], e->quantum);
            if (k < 3 || e->key[k] < lo[k % 3]) lo[k % 3] = e->key[k];
        }
        for (size_t k = 0; k < m; k++) e->work[k] = (int32_t)((uint32_t)e->key[k] - (uint32_t)lo[k % 3]);
        memcpy(e->origin, lo, sizeof lo);
        e->n = n;
        e->row = row;
        e->key_id++;
        e->key_frame = frame;
        e->key_wall_ns = wall_ns;
        e->key_wanted = 0;
    } else {
        for (size_t k = 0; k < m; k++)
            e->work[k] = (int32_t)((uint32_t)delta_grid(xyz[k], e->quantum) - (uint32_t)e->key[k]);
    }
    predict_to_planes(e->work, n, row, e->planes);
    /* One zstd frame per axis: each gets literal statistics of its own (z's residuals spread
     * wider than x's and y's: one frame of all three took 7 % more, README "Speed"). */
    const size_t bound = delta_bound(n);
    size_t len = 0;
    for (int c = 0; c < 3; c++) {
        const size_t got = ZSTD_compress2(e->zstd, out + CLF_DELTA_HEAD + len, bound - CLF_DELTA_HEAD - len,
                                          e->planes + 4 * (size_t)c * (size_t)n, 4 * (size_t)n);
        if (ZSTD_isError(got)) {
            e->n = 0; /* whatever this was, the next frame is a keyframe */
            return 0;
        }
        len += got;
    }
    put_u32(out + CLF_DELTA_OFF_KIND, key ? CLF_DELTA_KEY : CLF_DELTA_DELTA);
    put_u32(out + CLF_DELTA_OFF_KEY_ID, e->key_id);
    put_u64(out + CLF_DELTA_OFF_KEY_FRAME, e->key_frame);
    uint64_t qbits;
    memcpy(&qbits, &e->quantum, 8);
    put_u64(out + CLF_DELTA_OFF_QUANTUM, qbits);
    for (int c = 0; c < 3; c++) put_u32(out + CLF_DELTA_OFF_ORIGIN + 4 * c, (uint32_t)e->origin[c]);
    put_u32(out + CLF_DELTA_OFF_ROW, (uint32_t)row);
    put_u32(out + CLF_DELTA_OFF_LENGTH, (uint32_t)len);
    size_t at = CLF_DELTA_HEAD + len;
    while (at % 4) out[at++] = 0;
    *is_key = key;
    return at;
}
