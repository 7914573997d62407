/* delta.h - the positions of the stream's `delta` encoding (proto/clothd_frame.h): the cloth
 * quantized on a fixed grid of `quantum` metres, as keyframes (the grid values) and deltas (per
 * axis, the difference from the newest keyframe or the grid values themselves, whichever
 * compresses smaller), each predicted from its grid neighbours, the residuals as int8 with int32
 * escapes, compressed with zstd (libzstd), one zstd frame per axis. A pure module: positions in,
 * the positions section of a frame out; which frames are keyframes is decided here too.
 *
 * One encoder serves every client of one quantum: every delta refers to the newest keyframe, so a
 * client that holds that keyframe decodes any later delta, however many it skipped. */
#ifndef CLOTHD_CORE_DELTA_H
#define CLOTHD_CORE_DELTA_H

#include <stddef.h>
#include <stdint.h>

/* Quantum bounds (m) and default: 1 um .. 1 cm, 0.1 mm. */
#define DELTA_QUANTUM_MIN 1e-6
#define DELTA_QUANTUM_MAX 1e-2
#define DELTA_QUANTUM_DEFAULT 1e-4
/* A keyframe at least this often (ns of the frames' wall clock), and asked-for ones at most this
 * often: a client asking a thousand times a second gets four. */
#define DELTA_KEY_INTERVAL_NS 1000000000ull
#define DELTA_KEY_MIN_GAP_NS 250000000ull
/* zstd's level: 1, the fastest, compresses these planes as well as 3 (measured:
 * docs/developing.md); its shortest match 7 bytes: shorter ones in planes of near-random low bytes cost more than they
 * save (1.52 bytes a vertex instead of 1.56 on the default scene, at the same speed). */
#define DELTA_ZSTD_LEVEL 1
#define DELTA_ZSTD_MIN_MATCH 7
/* Cloths of up to this many vertices (90 x 90) have each axis's chosen block compressed again
 * with zstd's optimal parser (btultra, matches of 7 bytes or more, long enough at 16, one search
 * step): 1.6 % smaller at 64 x 64 and 6 % at 128 x 128 than the fast parser, at 6 to 12 times its
 * time (docs/developing.md "Why this layout"). It costs about 0.75 ms a frame at 64 x 64 but
 * 3 ms at 128 x 128, where the fast parser alone keeps many scenes' streams cheap for the server. */
#define DELTA_TIGHT_MAX_N 8192u
#define DELTA_ZSTD_TIGHT_TARGET 16

typedef struct delta_enc {
    double quantum;
    int32_t n, row;              /* the shape of the current keyframe (0: none yet) */
    uint32_t key_id;             /* the newest keyframe's sequence number (from 1) */
    uint64_t key_frame;          /* ... its frame number */
    uint64_t key_wall_ns;        /* ... and its wall clock */
    int32_t origin[3];           /* ... its integer grid origin */
    int key_wanted;              /* a keyframe was asked for (delta_want_key) */
    int32_t *key;                /* 3 n: the keyframe's grid values */
    int32_t *grid;               /* 3 n: this frame's grid values */
    int32_t *res;                /* n: one axis's residuals */
    unsigned char *packed;       /* 5 n (10 n up to DELTA_TIGHT_MAX_N): one axis's int8 residuals and
                                  * int32 escapes, on each basis */
    unsigned char *alt;          /* ZSTD_compressBound(5 n): the other basis's zstd frame */
    size_t cap_n;
    void *zstd;                  /* ZSTD_CCtx: the fast parser (DELTA_ZSTD_LEVEL) */
    void *tight;                 /* ZSTD_CCtx: the optimal parser (DELTA_TIGHT_MAX_N) */
} delta_enc;

/* An encoder for quantum (DELTA_QUANTUM_MIN..MAX); 0 or -1 (out of memory). */
int delta_init(delta_enc *e, double quantum);
void delta_free(delta_enc *e);
/* Whether q is a quantum the stream accepts (finite, within the bounds). */
int delta_quantum_ok(double q);

/* Bytes the positions section of n vertices may take at most (a multiple of 4). */
size_t delta_bound(int32_t n);

/* Asks for a keyframe: the next frame at least DELTA_KEY_MIN_GAP_NS after the last keyframe is
 * one. */
void delta_want_key(delta_enc *e);

/* Encodes the positions section of one frame (xyz: 3 n floats, row vertices per grid row, the
 * frame's number and wall clock) into out, which holds delta_bound(n) bytes, zero-padded to 4
 * bytes. A keyframe when there is none yet, the shape changed, DELTA_KEY_INTERVAL_NS passed since
 * the last, or one was asked for and DELTA_KEY_MIN_GAP_NS passed; else a delta. Returns the bytes
 * written, 0 on failure (out of memory, zstd); *is_key tells which it made. */
size_t delta_encode(delta_enc *e, const float *xyz, int32_t n, int32_t row, uint64_t frame,
                    uint64_t wall_ns, unsigned char *out, int *is_key);

/* The grid value of one coordinate: round(x / quantum), clamped to int32 (NaN: 0). */
int32_t delta_grid(float x, double quantum);

#endif
