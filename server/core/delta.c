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
    e->tight = ZSTD_createCCtx();
    if (!e->zstd || !e->tight || ZSTD_isError(ZSTD_CCtx_setParameter(e->zstd, ZSTD_c_compressionLevel, DELTA_ZSTD_LEVEL)) ||
        ZSTD_isError(ZSTD_CCtx_setParameter(e->zstd, ZSTD_c_minMatch, DELTA_ZSTD_MIN_MATCH)) ||
        ZSTD_isError(ZSTD_CCtx_setParameter(e->tight, ZSTD_c_compressionLevel, DELTA_ZSTD_LEVEL)) ||
        ZSTD_isError(ZSTD_CCtx_setParameter(e->tight, ZSTD_c_strategy, ZSTD_btultra)) ||
        ZSTD_isError(ZSTD_CCtx_setParameter(e->tight, ZSTD_c_minMatch, DELTA_ZSTD_MIN_MATCH)) ||
        ZSTD_isError(ZSTD_CCtx_setParameter(e->tight, ZSTD_c_targetLength, DELTA_ZSTD_TIGHT_TARGET)) ||
        ZSTD_isError(ZSTD_CCtx_setParameter(e->tight, ZSTD_c_searchLog, 1))) {
        ZSTD_freeCCtx(e->zstd);
        ZSTD_freeCCtx(e->tight);
        e->zstd = e->tight = NULL;
        return -1;
    }
    return 0;
}

void delta_free(delta_enc *e)
{
    free(e->key);
    free(e->grid);
    free(e->res);
    free(e->packed);
    free(e->alt);
    ZSTD_freeCCtx(e->zstd);
    ZSTD_freeCCtx(e->tight);
    memset(e, 0, sizeof *e);
}

/* One axis block: its head and a zstd frame of n + 4 E bytes, padded to 4. */
static size_t axis_bound(size_t n) { return CLF_DELTA_AXIS_HEAD + CLF_ALIGN4(ZSTD_compressBound(5 * n)); }

size_t delta_bound(int32_t n) { return CLF_DELTA_HEAD + 3 * axis_bound((size_t)n); }

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

/* p grown to bytes, or return -1 from the function (p unchanged). */
#define GROW(p, bytes)                         \
    do {                                       \
        void *grown_ = realloc((p), (bytes));  \
        if (!grown_) return -1;                \
        (p) = grown_;                          \
    } while (0)

static int reserve(delta_enc *e, int32_t n)
{
    const size_t nn = (size_t)n;
    if (nn <= e->cap_n) return 0;
    GROW(e->key, 12 * nn);
    GROW(e->grid, 12 * nn);
    GROW(e->res, 4 * nn);
    GROW(e->packed, 5 * nn + 5 * (nn < DELTA_TIGHT_MAX_N ? nn : DELTA_TIGHT_MAX_N));
    GROW(e->alt, axis_bound(nn));
    e->cap_n = nn;
    return 0;
}

/* The residuals of the parallelogram prediction of axis c of a = g - base (base: 3 n values, or
 * NULL for the constant origin), rows of row vertices, in uint32 arithmetic (mod 2^32). Worked
 * backwards in place: a value's neighbours are still a's when it is predicted. */
static void residuals(const int32_t *g, const int32_t *base, int32_t origin, int c, size_t n, size_t w, uint32_t *r)
{
    for (size_t v = 0; v < n; v++)
        r[v] = (uint32_t)g[3 * v + (size_t)c] - (base ? (uint32_t)base[3 * v + (size_t)c] : (uint32_t)origin);
    for (size_t v = n; v-- > 0;) {
        const size_t i = v % w;
        uint32_t p = 0;
        if (i && v >= w) p = r[v - 1] + r[v - w] - r[v - 1 - w];
        else if (i) p = r[v - 1];
        else if (v >= w) p = r[v - w];
        r[v] -= p;
    }
}

/* Residuals as int8 (CLF_DELTA_ESCAPE: the next int32 escape) then the escapes: n + 4 E bytes. */
static size_t pack(const uint32_t *r, size_t n, unsigned char *out, uint32_t *escapes)
{
    size_t e = 0;
    for (size_t v = 0; v < n; v++) {
        const int32_t x = (int32_t)r[v];
        if (x > CLF_DELTA_ESCAPE && x <= 127) {
            out[v] = (unsigned char)(x & 0xff);
        } else {
            out[v] = (unsigned char)(CLF_DELTA_ESCAPE & 0xff);
            unsigned char *p = out + n + 4 * e++;
            for (int b = 0; b < 4; b++) p[b] = (unsigned char)(r[v] >> (8 * b));
        }
    }
    *escapes = (uint32_t)e;
    return n + 4 * e;
}

/* One axis's values as an axis block holds them, before zstd: its basis, the n + 4 E bytes at
 * bytes, E. */
typedef struct {
    int basis;
    const unsigned char *bytes;
    size_t len;
    uint32_t escapes;
} packed_axis;

/* Axis c of basis 0 (base NULL: a = g - origin) or 1 (a = g - base), packed into buf (5 n bytes). */
static packed_axis pack_axis(delta_enc *e, const int32_t *base, int c, size_t n, size_t w, unsigned char *buf)
{
    uint32_t *r = (uint32_t *)e->res;
    residuals(e->grid, base, e->origin[c], c, n, w, r);
    packed_axis p = {base ? CLF_DELTA_BASIS_KEY : CLF_DELTA_BASIS_ORIGIN, buf, 0, 0};
    p.len = pack(r, n, buf, &p.escapes);
    return p;
}

/* The axis block of p at out, compressed with zstd context z; the bytes written, 0 on a zstd
 * error. */
static size_t axis_block(void *z, const packed_axis *p, unsigned char *out, size_t cap)
{
    const size_t got = ZSTD_compress2(z, out + CLF_DELTA_AXIS_HEAD, cap - CLF_DELTA_AXIS_HEAD, p->bytes, p->len);
    if (ZSTD_isError(got)) return 0;
    memset(out, 0, CLF_DELTA_AXIS_HEAD);
    out[CLF_DELTA_AXIS_OFF_BASIS] = (unsigned char)p->basis;
    put_u32(out + CLF_DELTA_AXIS_OFF_ESCAPES, p->escapes);
    put_u32(out + CLF_DELTA_AXIS_OFF_LENGTH, (uint32_t)got);
    size_t at = CLF_DELTA_AXIS_HEAD + got;
    while (at % 4) out[at++] = 0;
    return at;
}

size_t delta_encode(delta_enc *e, const float *xyz, int32_t n, int32_t row, uint64_t frame,
                    uint64_t wall_ns, unsigned char *out, int *is_key)
{
    if (n < 0 || row < 1 || reserve(e, n) < 0) return 0;
    const uint64_t since = wall_ns - e->key_wall_ns;
    const int key = e->n != n || e->row != row || e->key_id == 0 || wall_ns < e->key_wall_ns ||
                    since >= DELTA_KEY_INTERVAL_NS || (e->key_wanted && since >= DELTA_KEY_MIN_GAP_NS);
    const size_t m = 3 * (size_t)n, nn = (size_t)n, w = (size_t)row;
    for (size_t k = 0; k < m; k++) e->grid[k] = delta_grid(xyz[k], e->quantum);
    if (key) {
        int32_t lo[3] = {0, 0, 0};
        for (size_t k = 0; k < m; k++)
            if (k < 3 || e->grid[k] < lo[k % 3]) lo[k % 3] = e->grid[k];
        memcpy(e->key, e->grid, 12 * nn);
        memcpy(e->origin, lo, sizeof lo);
        e->n = n;
        e->row = row;
        e->key_id++;
        e->key_frame = frame;
        e->key_wall_ns = wall_ns;
        e->key_wanted = 0;
    }
    /* One zstd frame per axis: each gets literal statistics of its own (z's residuals spread
     * wider than x's and y's: one frame of all three took 7 % more, docs/developing.md "Why this
     * layout"). A delta tries both bases per axis and keeps the smaller: on a cloth in motion the grid values
     * themselves often predict better than their difference from a keyframe up to a second old,
     * on a cloth at rest the difference is all zeros. */
    /* The basis is chosen on the fast parser's sizes; a cloth of up to DELTA_TIGHT_MAX_N vertices
     * then has the chosen one compressed again with the optimal parser (a keyframe: at once). */
    const size_t cap = axis_bound(nn);
    const int tight = nn <= DELTA_TIGHT_MAX_N;
    size_t len = 0;
    for (int c = 0; c < 3; c++) {
        unsigned char *block = out + CLF_DELTA_HEAD + len;
        const packed_axis first = pack_axis(e, key ? NULL : e->key, c, nn, w, e->packed);
        const packed_axis *chosen = &first;
        packed_axis own;
        size_t got = axis_block(key && tight ? e->tight : e->zstd, &first, block, cap);
        if (got && !key) {
            /* Packed beside the first where the optimal parser will compress the chosen one
             * again, over it (no longer needed) where not. */
            own = pack_axis(e, NULL, c, nn, w, e->packed + (tight ? 5 * nn : 0));
            const size_t got_own = axis_block(e->zstd, &own, e->alt, cap);
            if (!got_own) got = 0;
            else if (got_own < got) {
                memcpy(block, e->alt, got_own);
                got = got_own;
                chosen = &own;
            }
            if (got && tight) { /* kept only where smaller (it all but always is) */
                const size_t again = axis_block(e->tight, chosen, e->alt, cap);
                if (again && again < got) {
                    memcpy(block, e->alt, again);
                    got = again;
                }
            }
        }
        if (!got) {
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
