/* delta_inverse.c - the inner loops of decoding a `delta` frame of kinds 2 and 3 (layout in
 * clothd_frame.h), for WebAssembly with SIMD: counting the escapes of an axis's int8 residuals, and
 * the parallelogram prediction's inverse of all three axes, plus the origin or the keyframe's grid
 * values, times the quantum, into interleaved float32 positions. proto/frame.mjs calls it (and
 * decodes with its own JavaScript where WebAssembly SIMD is missing: both give the same bits);
 * scripts/build-wasm.sh compiles it into clients/js/src/delta-wasm.mjs:
 *   clang --target=wasm32 -O2 -msimd128 -nostdlib -Wl,--no-entry -Wl,--import-memory
 * Freestanding: no libc, no allocation. frame.mjs owns the memory and passes byte offsets.
 *
 * The inverse, per axis: the residuals r of a row summed from the left (s), plus the row below's
 * a, is this row's a - which is a = r + left + below - below-left, the spec's parallelogram, with
 * the first row's below taken as 0 and the first column's left as 0. All in uint32 arithmetic
 * (mod 2^32), as the encoder's. */
#include <stdint.h>
#include <wasm_simd128.h>

#define ESCAPE (-128) /* CLF_DELTA_ESCAPE */

static int32_t load_i32(const unsigned char *p)
{
    int32_t v;
    __builtin_memcpy(&v, p, 4);
    return v;
}

/* How many of the n int8 residuals at r are escapes. */
__attribute__((export_name("count_escapes"))) uint32_t count_escapes(const int8_t *r, uint32_t n)
{
    const v128_t esc = wasm_i8x16_splat(ESCAPE);
    uint32_t found = 0, v = 0;
    for (; v + 16 <= n; v += 16)
        found += (uint32_t)__builtin_popcount(wasm_i8x16_bitmask(wasm_i8x16_eq(wasm_v128_load(r + v), esc)));
    for (; v < n; v++) found += r[v] == ESCAPE;
    return found;
}

/* One row of one axis: the L residuals at r (escapes from *esc on, in order), summed from the
 * left, added into prev (the row below's a on entry, this row's on return). */
static void row_axis(const int8_t *r, const unsigned char **esc, uint32_t L, uint32_t *prev)
{
    const v128_t escape = wasm_i8x16_splat(ESCAPE), zero = wasm_i32x4_splat(0);
    v128_t carry = zero; /* the row's sum so far, in every lane */
    uint32_t i = 0;
    for (; i + 16 <= L; i += 16) {
        const v128_t b = wasm_v128_load(r + i);
        const v128_t lo = wasm_i16x8_extend_low_i8x16(b), hi = wasm_i16x8_extend_high_i8x16(b);
        v128_t x[4] = {wasm_i32x4_extend_low_i16x8(lo), wasm_i32x4_extend_high_i16x8(lo),
                       wasm_i32x4_extend_low_i16x8(hi), wasm_i32x4_extend_high_i16x8(hi)};
        uint32_t mask = (uint32_t)wasm_i8x16_bitmask(wasm_i8x16_eq(b, escape));
        if (mask) {
            int32_t t[16];
            for (int k = 0; k < 4; k++) wasm_v128_store(t + 4 * k, x[k]);
            for (; mask; mask &= mask - 1) {
                t[__builtin_ctz(mask)] = load_i32(*esc);
                *esc += 4;
            }
            for (int k = 0; k < 4; k++) x[k] = wasm_v128_load(t + 4 * k);
        }
        for (int k = 0; k < 4; k++) {
            v128_t s = x[k];
            s = wasm_i32x4_add(s, wasm_i32x4_shuffle(zero, s, 3, 4, 5, 6)); /* + the lane before */
            s = wasm_i32x4_add(s, wasm_i32x4_shuffle(zero, s, 2, 3, 4, 5)); /* + the two before that */
            s = wasm_i32x4_add(s, carry);
            carry = wasm_i32x4_shuffle(s, s, 3, 3, 3, 3);
            uint32_t *p = prev + i + 4 * k;
            wasm_v128_store(p, wasm_i32x4_add(wasm_v128_load(p), s));
        }
    }
    uint32_t s = (uint32_t)wasm_i32x4_extract_lane(carry, 0);
    for (; i < L; i++) {
        int32_t x = r[i];
        if (x == ESCAPE) {
            x = load_i32(*esc);
            *esc += 4;
        }
        s += (uint32_t)x;
        prev[i] += s;
    }
}

/* 4 vertices' grid values as 3 vectors of interleaved x y z, each as float32 g x quantum (the
 * product in float64, then rounded to float32: JavaScript's Float32Array store of g * quantum). */
static v128_t to_f32(v128_t g, v128_t q)
{
    const v128_t lo = wasm_f64x2_mul(wasm_f64x2_convert_low_i32x4(g), q);
    const v128_t hi = wasm_f64x2_mul(wasm_f64x2_convert_low_i32x4(wasm_i32x4_shuffle(g, g, 2, 3, 2, 3)), q);
    return wasm_i32x4_shuffle(wasm_f32x4_demote_f64x2_zero(lo), wasm_f32x4_demote_f64x2_zero(hi), 0, 1, 4, 5);
}

/* The positions of n vertices in rows of w (the last row may be shorter): r[c] the n int8
 * residuals of axis c and its int32 escapes after them (count_escapes checked them); bit c of
 * on_key: axis c is on basis 1 (a = g - key), else basis 0 (a = g - origin[c]); pos: 3 n floats;
 * prev: 3 w uint32 of scratch. A keyframe (is_key, on_key 0) writes its grid values into key. */
__attribute__((export_name("undo"))) void undo(uint32_t n, uint32_t w, const int8_t *rx, const int8_t *ry,
                                               const int8_t *rz, uint32_t on_key, int32_t ox, int32_t oy, int32_t oz,
                                               double quantum, int32_t *key, float *pos, uint32_t *prev, uint32_t is_key)
{
    const int8_t *r[3] = {rx, ry, rz};
    const unsigned char *esc[3] = {(const unsigned char *)rx + n, (const unsigned char *)ry + n,
                                   (const unsigned char *)rz + n};
    const int32_t origin[3] = {ox, oy, oz};
    /* Lane l of the j-th vector of 4 interleaved values is axis (4 j + l) % 3: its base. */
    v128_t base[3], mask[3];
    for (int j = 0; j < 3; j++) {
        int32_t o[4], m[4];
        for (int l = 0; l < 4; l++) {
            const int c = (4 * j + l) % 3;
            o[l] = on_key >> c & 1 ? 0 : origin[c];
            m[l] = on_key >> c & 1 ? -1 : 0;
        }
        base[j] = wasm_v128_load(o);
        mask[j] = wasm_v128_load(m);
    }
    const v128_t q = wasm_f64x2_splat(quantum);
    for (uint32_t i = 0; i < 3 * w; i++) prev[i] = 0;
    uint32_t *px = prev, *py = prev + w, *pz = prev + 2 * w;
    for (uint32_t j0 = 0; j0 < n; j0 += w) {
        const uint32_t L = n - j0 < w ? n - j0 : w;
        for (int c = 0; c < 3; c++) row_axis(r[c] + j0, &esc[c], L, prev + (uint32_t)c * w);
        int32_t *k = key + 3 * j0;
        float *p = pos + 3 * j0;
        uint32_t i = 0;
        for (; i + 4 <= L; i += 4, k += 12, p += 12) {
            const v128_t X = wasm_v128_load(px + i), Y = wasm_v128_load(py + i), Z = wasm_v128_load(pz + i);
            v128_t g[3];
            g[0] = wasm_i32x4_shuffle(wasm_i32x4_shuffle(X, Y, 0, 4, 1, 5), Z, 0, 1, 4, 2); /* x0 y0 z0 x1 */
            g[1] = wasm_i32x4_shuffle(wasm_i32x4_shuffle(Y, Z, 1, 5, 2, 6), X, 0, 1, 6, 2); /* y1 z1 x2 y2 */
            g[2] = wasm_i32x4_shuffle(wasm_i32x4_shuffle(X, Y, 3, 7, 3, 7), Z, 6, 0, 1, 7); /* z2 x3 y3 z3 */
            for (int j = 0; j < 3; j++) {
                g[j] = wasm_i32x4_add(g[j], base[j]);
                if (on_key) g[j] = wasm_i32x4_add(g[j], wasm_v128_and(wasm_v128_load(k + 4 * j), mask[j]));
                if (is_key) wasm_v128_store(k + 4 * j, g[j]);
                wasm_v128_store(p + 4 * j, to_f32(g[j], q));
            }
        }
        for (; i < L; i++, k += 3, p += 3) {
            const uint32_t a[3] = {px[i], py[i], pz[i]};
            for (int c = 0; c < 3; c++) {
                const int32_t gv = (int32_t)(a[c] + (uint32_t)(on_key >> c & 1 ? k[c] : origin[c]));
                if (is_key) k[c] = gv;
                p[c] = (float)((double)gv * quantum);
            }
        }
    }
}
