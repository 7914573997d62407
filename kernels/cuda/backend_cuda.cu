/* backend_cuda.cu - the CUDA backend: the SIM_HD functions of physics.h in kernels, running the
 * substep sequence of backend.h so that its state equals the CPU backend's bit for bit (both built
 * without contraction: -fmad=false here, -ffp-contract=off there).
 *
 * Layout (structure of arrays, as the host keeps it): the state read and the state written are
 * two buffers of x, y, z, vx, vy, vz (6 n floats each), swapped every substep, so one kernel per
 * substep reads every neighbour's current state and writes its own vertex's next one; a byte mask
 * (1 free, 0 pinned or grabbed); accelerations (3 n), written where a step call or a refresh ends;
 * rest lengths in two buffers read and written alternately, with a byte per vertex saying whether
 * its springs changed in the last update: a vertex writes its six rest lengths into the other
 * buffer only when they changed now or then, so a cloth at rest writes 2 bytes a vertex per
 * substep for its strain, not 24.
 *
 * The cloth kernel: a block is 256 columns (one chunk wide) and tile_rows rows of the grid, walked
 * row by row. For each row it stores the positions and velocities of the row two below into a
 * ring of four rows in shared memory (r-1 .. r+2, loaded one row ahead, so the loads overlap the work), evaluates the six springs each vertex owns (cs_spring_force once
 * per spring, as the CPU backend does: the far end gets the exact negation), gathers each vertex's
 * 12 springs in CS_SPRING_SLOTS order from its own registers, its neighbours' shared-memory forces
 * and the rows above, adds air and gravity, then contacts, and writes the vertex's next state.
 * The two rows above a tile and the three columns beside it are evaluated again by this block
 * without being written (their owners write them). Contacts: each tile culls the rocks against
 * its bounding box once; for each rock that may touch it and each of its rows, the vertices add
 * the rock's force in rock order, and the row chunk's reactions are summed with cs_tree_sum's tree
 * (shared memory, then warp shuffles) into the chunk's partial, and the chunk's bit set in the
 * rock's word for its chunk group. Surface contact (contact_model surface) instead takes each
 * candidate rock in turn: every vertex gathers its share from its 1-ring (cs_surface_gather, the
 * ring kept in registers from rows r-1 .. r+1 of a four-row ring), then the reactions the row's
 * vertices own go through the same tree. The tile's box then covers the row above and below and
 * the columns beside it (a vertex's triangles reach that far).
 *
 * Rocks: a warp per rock sums its partials - only the chunks whose bits are set, in chunk order
 * within a group, then the groups in order, as cs_rock_force does - then the other rocks (tested
 * in parallel, added in order), the ground and gravity. Up to ROCKS_FUSED rocks one block does it
 * all and moves them; beyond, one kernel computes accelerations and another moves. No float
 * atomics anywhere.
 *
 * A step call runs as CUDA graphs of at most one frame of substeps (GRAPH_MAX), kept per shape and
 * buffer parity and updated in place (cudaGraphExecUpdate) when only pointers or launch sizes
 * change; what changes with commands (parameters, grab, rocks' count) is read from device memory.
 * After a call whose frame was read, the positions (and velocities, rocks) are copied on the
 * device, then to pinned double buffers on a second stream, overlapping whatever comes next; a
 * read waits for that copy only. Everything else (rest lengths, accelerations) is copied when a
 * snapshot, a hash or a command asks.
 *
 * Batches (step_batch, cs_sims_step): many scenes advanced together, one launch per kernel per
 * substep for all of them. Each scene keeps its own device buffers; the batch passes a device
 * table of per-scene descriptors - the scene struct (parameters, rock count, grab), its buffers
 * for even and odd substeps, its substeps, integrator, strain and rock path - and, per kernel, the
 * prefix sums of the blocks each scene takes, so a block finds its scene by binary search and runs
 * the block function the lone launch runs (cloth_block, drift_first_block, strain_block,
 * rocks_block, rock_force_warp, rock_move_thread: one source). The table sorts the scenes by
 * substeps, most first, so the scenes still running at a substep are a prefix and a launch covers
 * only their blocks; the others have finished. A table of each scene's own pointers, not shared
 * arrays with per-scene offsets: the launch shape is the same (one launch covers every scene's
 * vertices), and adding, deleting or resizing a scene allocates or frees that scene's buffers only
 * - nothing of another scene moves or is copied, so no scene can disturb another. The rows of a
 * cloth block are chosen for the batch as a whole (tile_rows_for's rule over all its blocks): a
 * scene's bits do not depend on them. What the scenes' frames were read for is copied on the
 * device in one launch after the batch and to pinned memory on the batch's copy stream. The
 * batch launches its kernels one by one on its stream (no graph yet): about substeps + 1 launches
 * a frame for the whole batch.
 *
 * Integrator implicit_euler has a sequence of its own (see "integrator implicit_euler" below):
 * plain launches of per-vertex and per-chunk kernels around the functions of clothsim/implicit.h,
 * with the solver's scalars on the host; a batch steps such scenes alone. */
#include <cuda_runtime.h>

#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include <mutex>

#include "clothsim/backend.h"
#include "clothsim/implicit.h"
#include "clothsim/physics.h"

/* ---- device memory access: the CPU imitation of CUDA (tests/emu) counts bytes through these ---- */
#ifndef CS_DEVMEM_HOOKS
template <class T> __device__ __forceinline__ T dload(const T *p) { return *p; }
template <class T> __device__ __forceinline__ void dstore(T *p, T v) { *p = v; }
/* What other blocks of the same launch wrote: from L2, past this SM's L1. */
template <class T> __device__ __forceinline__ T dload_cg(const T *p) { return __ldcg(p); }
#endif
#ifndef CS_DYNAMIC_SHARED
#define CS_DYNAMIC_SHARED(T, name)                                                                     \
    extern __shared__ __align__(16) unsigned char cs_dynamic_smem[];                                  \
    T *name = reinterpret_cast<T *>(cs_dynamic_smem)
#endif

#define TILE_W CS_CHUNK            /* threads of a cloth block: the columns of one chunk */
#define RING_OFF 3                 /* ring rows hold columns c0 - 3 .. c0 + 258 */
#define RING_W (TILE_W + 6)
#define FORCE_OFF 2                /* force rows hold columns c0 - 2 .. c0 + 257 */
#define FORCE_W (TILE_W + 4)
#define WARPS (TILE_W / 32)
#define MAX_TILE_ROWS 8
#define ROCKS_FUSED 64             /* up to this many rocks, one block sums and moves them all */
#define ROCK_WARPS 8               /* rocks per block of the split rock kernel */
#define GRAPH_MAX 256              /* most substeps in one graph */
#define GRAPHS 8                   /* graphs kept */
#define FULL 0xffffffffu

static_assert(CS_CHUNK_GROUP == 64, "a chunk group's chunks are the bits of one 64-bit word");
static_assert(TILE_W % 32 == 0 && TILE_W <= 1024, "a chunk is whole warps");

/* ---- what the kernels read for one scene (one struct: a per-scene table can replace it) ---- */

struct cuda_scene {
    cs_phys p;
    int32_t nr;          /* rocks */
    int32_t grab;        /* grabbed vertex or -1 */
    cs_vec3 grab_target;
    int32_t tile_rows;   /* rows of a cloth block */
    int32_t ngroups;     /* chunk groups: ceil(nchunks / CS_CHUNK_GROUP) */
};

/* The arrays one launch works on (by value: a graph node holds them). */
struct cuda_bufs {
    const float *in;             /* x, y, z, vx, vy, vz: the state read (6 n) */
    float *out;                  /* the state written (6 n) */
    const unsigned char *mask;   /* 1 free, 0 pinned or grabbed (n) */
    float *acc;                  /* ax, ay, az (3 n) */
    const float *L0;             /* rest lengths read (6 n, type-major) */
    float *L0n;                  /* the other buffer: written where a vertex's springs changed */
    unsigned char *chg;          /* 1 where the vertex's rest lengths changed in the last update */
    cs_rock_state *rocks;
    float *partials;             /* [rock][chunk][6]: a chunk's force and torque on a rock */
    unsigned long long *hits;    /* [rock][group]: bit c % 64 set when chunk c wrote its partial */
    float *gsum;                 /* [rock][group][6]: a chunk group's force and torque on a rock */
    int *group_done;             /* [group]: chunks of the group done this launch */
    int *flags;
};

enum { FLAG_TORN = 0, FLAG_NONFINITE = 1, FLAG_COUNT = 2 };

/* What the cloth kernel does after the forces. */
enum {
    MODE_ACCEL,       /* store a only (refresh after a command) */
    MODE_VERLET,      /* finish this substep's kick, start the next one's kick and drift */
    MODE_VERLET_LAST, /* finish the kick; store a */
    MODE_EULER,       /* v += dt a; x += dt v */
    MODE_EULER_LAST   /* the same, and store a */
};
/* What the rock kernels do after the forces. */
enum { ROCKS_ACCEL, ROCKS_VERLET, ROCKS_VERLET_LAST, ROCKS_EULER, ROCKS_FIRST };

__device__ static inline int finite3(cs_vec3 v) { return isfinite(v.x) && isfinite(v.y) && isfinite(v.z); }

/* ---- shared memory of the cloth kernel (floats) ---- */

#define RING_SLOTS 4                               /* rows r-1 .. r+2 (surface contact reads r-1) */
#define SM_RING 0                                  /* [RING_SLOTS][6][RING_W] */
#define SM_FROW (SM_RING + RING_SLOTS * 6 * RING_W) /* [SX, BX][3][FORCE_W]; also the tree's [6][TILE_W] */
#define SM_FPREV (SM_FROW + 2 * 3 * FORCE_W)       /* [row parity][D1, D2][3][FORCE_W] */
#define SM_RED (SM_FPREV + 2 * 2 * 3 * FORCE_W)    /* [6][WARPS]: the tile's bounding box */
#define SM_COUNT (SM_RED + 6 * WARPS)              /* [WARPS] ints: candidates per warp */
#define SM_TOUCHED (SM_COUNT + WARPS)              /* [32] bits: candidates a row touches */
#define SM_CAND (SM_TOUCHED + 32)                  /* candidate rocks (ints) */
static_assert(2 * 3 * FORCE_W >= 6 * TILE_W, "the tree scratch fits in the force rows");

static size_t cloth_smem(int32_t rock_cap) { return sizeof(float) * (size_t)(SM_CAND + rock_cap); }

#define RING(sm, slot, q, k) (sm)[SM_RING + ((slot) * 6 + (q)) * RING_W + (k)]
#define FROW(sm, which, c, k) (sm)[SM_FROW + ((which) * 3 + (c)) * FORCE_W + (k)]
#define FPREV(sm, par, which, c, k) (sm)[SM_FPREV + (((par) * 2 + (which)) * 3 + (c)) * FORCE_W + (k)]

__device__ static inline cs_vec3 ring_x(const float *sm, int32_t r, int k)
{
    const int s = r % RING_SLOTS;
    return cs_v3(RING(sm, s, 0, k), RING(sm, s, 1, k), RING(sm, s, 2, k));
}
__device__ static inline cs_vec3 ring_v(const float *sm, int32_t r, int k)
{
    const int s = r % RING_SLOTS;
    return cs_v3(RING(sm, s, 3, k), RING(sm, s, 4, k), RING(sm, s, 5, k));
}

/* A row of the state as one thread carries it to the ring: its column, and for threads 0..5 one
 * of the six columns past the chunk's 256 (the ring holds columns c0 - 3 .. c0 + 258). */
struct row_regs {
    float q[2][6];
};

/* Loads row r's columns of this thread into registers (those that exist). */
__device__ static void fetch_row(const cuda_bufs &b, const cs_phys *p, int32_t r, int32_t c0, row_regs *f)
{
    if (r < 0 || r >= p->ny) return;
    for (int h = 0; h < 2; h++) {
        const int k = (int)threadIdx.x + h * TILE_W;
        const int32_t i = c0 - RING_OFF + k;
        if (k >= RING_W || i < 0 || i >= p->nx) continue;
        const size_t v = (size_t)r * (size_t)p->nx + (size_t)i;
        for (int q = 0; q < 6; q++) f->q[h][q] = dload(&b.in[(size_t)q * (size_t)p->n + v]);
    }
}

/* Stores what fetch_row loaded into row r's ring slot. */
__device__ static void put_row(const cs_phys *p, float *sm, int32_t r, int32_t c0, const row_regs *f)
{
    if (r < 0 || r >= p->ny) return;
    for (int h = 0; h < 2; h++) {
        const int k = (int)threadIdx.x + h * TILE_W;
        const int32_t i = c0 - RING_OFF + k;
        if (k >= RING_W || i < 0 || i >= p->nx) continue;
        for (int q = 0; q < 6; q++) RING(sm, r % RING_SLOTS, q, k) = f->q[h][q];
    }
}

/* The springs vertex (i, r) owns, of the types in `types`, from the ring: forces F[t] (zero where
 * the grid has no such spring or the type is not asked for), lengths len[t], rest lengths l0[t]. */
__device__ static void eval_owned(const cuda_bufs &b, const cs_phys *p, const float *sm, int32_t i, int32_t r,
                                  int32_t c0, unsigned types, cs_vec3 *F, float *len, float *l0)
{
    const int k = i - c0 + RING_OFF;
    const cs_vec3 xi = ring_x(sm, r, k), vi = ring_v(sm, r, k);
    const size_t v = (size_t)r * (size_t)p->nx + (size_t)i;
#define CUDA_OWNED(t, di, dj)                                                                          \
    F[t] = cs_v3(0.0f, 0.0f, 0.0f);                                                                    \
    len[t] = 0.0f;                                                                                     \
    l0[t] = CS_TORN;                                                                                   \
    if ((types >> (t) & 1u) && cs_far_end_on_grid(p->nx, p->ny, i, r, (di), (dj))) {                       \
        l0[t] = dload(&b.L0[(size_t)(t) * (size_t)p->n + v]);                                          \
        F[t] = cs_spring_force(xi, vi, ring_x(sm, r + (dj), k + (di)), ring_v(sm, r + (dj), k + (di)), l0[t], \
                               p->k[t], p->c_spring, &len[t]);                                         \
    }
    CS_SPRING_TYPES(CUDA_OWNED)
#undef CUDA_OWNED
}

/* Puts the owned forces other vertices gather into shared memory: SX and BX of this row, D1 and
 * D2 for the next row (at parity r & 1). */
__device__ static void share_owned(float *sm, int32_t r, int k, const cs_vec3 *F)
{
    const int par = r & 1;
    const float sx[3] = {F[CS_SX].x, F[CS_SX].y, F[CS_SX].z}, bx[3] = {F[CS_BX].x, F[CS_BX].y, F[CS_BX].z};
    const float d1[3] = {F[CS_D1].x, F[CS_D1].y, F[CS_D1].z}, d2[3] = {F[CS_D2].x, F[CS_D2].y, F[CS_D2].z};
    for (int c = 0; c < 3; c++) {
        FROW(sm, 0, c, k) = sx[c];
        FROW(sm, 1, c, k) = bx[c];
        FPREV(sm, par, 0, c, k) = d1[c];
        FPREV(sm, par, 1, c, k) = d2[c];
    }
}

__device__ static inline cs_vec3 frow_at(const float *sm, int which, int k)
{
    return cs_v3(FROW(sm, which, 0, k), FROW(sm, which, 1, k), FROW(sm, which, 2, k));
}
__device__ static inline cs_vec3 fprev_at(const float *sm, int par, int which, int k)
{
    return cs_v3(FPREV(sm, par, which, 0, k), FPREV(sm, par, which, 1, k), FPREV(sm, par, which, 2, k));
}

/* Sums each of q[0..5] over the block with cs_tree_sum's tree: buf[t] += buf[t + s] for
 * s = TILE_W/2 .. 1, in shared memory down to s = 32, then by shuffles in the first warp (lane t
 * adds lane t + s exactly as the tree does; the other lanes' sums are never used). Every thread
 * calls it; the sums are valid in thread 0. */
__device__ static void tree_sum6(const float *q, float *buf, float *out)
{
    const int t = (int)threadIdx.x;
    for (int c = 0; c < 6; c++) buf[c * TILE_W + t] = q[c];
    __syncthreads();
    for (int s = TILE_W / 2; s >= 32; s >>= 1) {
        if (t < s)
            for (int c = 0; c < 6; c++) buf[c * TILE_W + t] += buf[c * TILE_W + t + s];
        __syncthreads();
    }
    if (t < 32) {
        float v[6];
        for (int c = 0; c < 6; c++) v[c] = buf[c * TILE_W + t];
        for (int s = 16; s > 0; s >>= 1)
            for (int c = 0; c < 6; c += 2) { /* two floats a shuffle */
                const unsigned long long w = __shfl_down_sync(
                    FULL, (unsigned long long)__float_as_uint(v[c]) | (unsigned long long)__float_as_uint(v[c + 1]) << 32,
                    (unsigned)s);
                v[c] += __uint_as_float((unsigned)w);
                v[c + 1] += __uint_as_float((unsigned)(w >> 32));
            }
        for (int c = 0; c < 6; c++) out[c] = v[c];
    }
}

/* Whether a sphere may touch a box (never a false no: the exact test is per vertex). */
__device__ static inline int sphere_may_touch(cs_vec3 c, float r, cs_vec3 lo, cs_vec3 hi)
{
    const float dx = c.x < lo.x ? lo.x - c.x : (c.x > hi.x ? c.x - hi.x : 0.0f);
    const float dy = c.y < lo.y ? lo.y - c.y : (c.y > hi.y ? c.y - hi.y : 0.0f);
    const float dz = c.z < lo.z ? lo.z - c.z : (c.z > hi.z ? c.z - hi.z : 0.0f);
    const float reach = r * 1.001f + 1e-6f;
    return dx * dx + dy * dy + dz * dz <= reach * reach;
}

/* The rocks that may touch the tile (rows j0 .. j1-1, this block's columns), in index order, into
 * shared memory; returns how many. */
__device__ static int cull_rocks(const cuda_scene *sc, const cuda_bufs &b, float *sm, int32_t j0, int32_t j1,
                                 int32_t i)
{
    const cs_phys *p = &sc->p;
    const int t = (int)threadIdx.x, lane = t & 31, warp = t >> 5;
    static_assert(WARPS >= 6, "six warps reduce the box");
    const float big = 3.0e38f;
    float lo[3] = {big, big, big}, hi[3] = {-big, -big, -big};
    /* Surface contact: a vertex's features reach one row and one column past it, so the box holds
     * the rows above and below the tile and the columns beside the chunk too. */
    const bool surface = p->contact_model == CS_CONTACT_SURFACE;
    const int32_t r0 = surface && j0 > 0 ? j0 - 1 : j0, r1 = surface && j1 < p->ny ? j1 + 1 : j1;
    for (int side = 0; side < (surface ? 2 : 1); side++) {
        /* side 1: threads 0 and 1 take columns c0 - 1 and c0 + TILE_W */
        const int32_t ic = side == 0 ? i : t == 0 ? i - 1 : t == 1 ? i - 1 + TILE_W : -1;
        if (ic < 0 || ic >= p->nx) continue;
        for (int32_t r = r0; r < r1; r++) {
            const size_t v = (size_t)r * (size_t)p->nx + (size_t)ic;
            for (int c = 0; c < 3; c++) {
                const float x = dload(&b.in[(size_t)c * (size_t)p->n + v]);
                lo[c] = x < lo[c] ? x : lo[c];
                hi[c] = x > hi[c] ? x : hi[c];
            }
        }
    }
    /* The box over the block: each of six warps reduces one bound (min and max are exact, so the
     * order does not matter). The force rows are free until the row loop. */
    float *box = sm + SM_FROW;
    for (int c = 0; c < 3; c++) {
        box[c * TILE_W + t] = lo[c];
        box[(3 + c) * TILE_W + t] = hi[c];
    }
    __syncthreads();
    if (warp < 6) {
        const bool mx = warp >= 3;
        float e = box[warp * TILE_W + lane];
        for (int k = lane + 32; k < TILE_W; k += 32) {
            const float x = box[warp * TILE_W + k];
            e = mx ? (x > e ? x : e) : (x < e ? x : e);
        }
        for (int s = 16; s > 0; s >>= 1) {
            const float x = __shfl_xor_sync(FULL, e, s);
            e = mx ? (x > e ? x : e) : (x < e ? x : e);
        }
        if (lane == 0) sm[SM_RED + warp] = e;
    }
    __syncthreads();
    const cs_vec3 blo = cs_v3(sm[SM_RED], sm[SM_RED + 1], sm[SM_RED + 2]);
    const cs_vec3 bhi = cs_v3(sm[SM_RED + 3], sm[SM_RED + 4], sm[SM_RED + 5]);
    int *count = reinterpret_cast<int *>(sm + SM_COUNT), *cand = reinterpret_cast<int *>(sm + SM_CAND);
    int total = 0;
    for (int32_t base = 0; base < sc->nr; base += TILE_W) {
        const int32_t k = base + t;
        int near = 0;
        if (k < sc->nr) {
            const cs_vec3 x = dload(&b.rocks[k].x);
            near = sphere_may_touch(x, dload(&b.rocks[k].radius) + p->contact_offset, blo, bhi);
        }
        const unsigned ballot = __ballot_sync(FULL, near);
        if (lane == 0) count[warp] = __popc(ballot);
        __syncthreads();
        int before = total;
        for (int w = 0; w < warp; w++) before += count[w];
        if (near) cand[before + __popc(ballot & ((1u << lane) - 1u))] = k;
        for (int w = 0; w < WARPS; w++) total += count[w];
        __syncthreads(); /* count is rewritten next round; cand is read after the last */
    }
    return total;
}

/* Chunk group g's share of each rock's force: for every rock a chunk of the group touched, its
 * partials in chunk order (cs_rock_group_sum's order; the chunks that did not touch are +0), into
 * gsum. A warp per rock: lanes load 32 chunks' partials at a time, every lane adds them in order.
 * Run by the last block of the cloth kernel to finish its part of the group, so the groups are
 * summed in parallel, as they end. */
__device__ static void group_sums(const cuda_scene *sc, const cuda_bufs &b, int32_t g)
{
    const cs_phys *p = &sc->p;
    const int lane = (int)(threadIdx.x & 31u), warp = (int)(threadIdx.x >> 5);
    const int32_t gc = g * CS_CHUNK_GROUP;
    for (int32_t r = warp; r < sc->nr; r += WARPS) {
        const size_t rg = (size_t)r * (size_t)sc->ngroups + (size_t)g;
        unsigned long long left = dload_cg(&b.hits[rg]); /* written by other blocks' atomics */
        if (!left) continue;                             /* warp-uniform */
        cs_vec3 f = cs_v3(0.0f, 0.0f, 0.0f), tq = f;
        while (left) {
            const int cnt = __popcll(left) < 32 ? __popcll(left) : 32;
            unsigned long long mine = left;
            for (int k = 0; k < lane && mine; k++) mine &= mine - 1ull;
            float q[6] = {0, 0, 0, 0, 0, 0};
            if (lane < cnt) {
                const int32_t c = gc + __ffsll((long long)mine) - 1;
                const float *src = b.partials + ((size_t)r * (size_t)p->nchunks + (size_t)c) * 6;
                for (int k = 0; k < 6; k++) q[k] = dload_cg(&src[k]);
            }
            for (int m = 0; m < cnt; m++) {
                f = cs_add(f, cs_v3(__shfl_sync(FULL, q[0], m), __shfl_sync(FULL, q[1], m), __shfl_sync(FULL, q[2], m)));
                tq = cs_add(tq, cs_v3(__shfl_sync(FULL, q[3], m), __shfl_sync(FULL, q[4], m), __shfl_sync(FULL, q[5], m)));
            }
            for (int m = 0; m < cnt; m++) left &= left - 1ull;
        }
        if (lane == 0) {
            const float o[6] = {f.x, f.y, f.z, tq.x, tq.y, tq.z};
            for (int k = 0; k < 6; k++) dstore(&b.gsum[rg * 6 + (size_t)k], o[k]);
        }
    }
}

/* After a block's rows: it counts its chunks into each chunk group they belong to; the block that
 * completes a group sums it (the pattern of cuda-samples' threadFenceReduction). */
__device__ static void finish_groups(const cuda_scene *sc, const cuda_bufs &b, float *sm, int32_t j0, int32_t j1,
                                     int32_t seg)
{
    const cs_phys *p = &sc->p;
    int *last = reinterpret_cast<int *>(sm + SM_COUNT);
    const int32_t g0 = (j0 * p->nseg + seg) / CS_CHUNK_GROUP, g1 = ((j1 - 1) * p->nseg + seg) / CS_CHUNK_GROUP;
    __threadfence(); /* this block's partials and hit words, before it counts itself */
    __syncthreads();
    if (threadIdx.x == 0)
        for (int32_t g = g0; g < g0 + 4; g++) {
            last[g - g0] = -1;
            if (g > g1) continue;
            int mine = 0;
            for (int32_t r = j0; r < j1; r++) mine += (r * p->nseg + seg) / CS_CHUNK_GROUP == g;
            const int size = p->nchunks - g * CS_CHUNK_GROUP < CS_CHUNK_GROUP ? p->nchunks - g * CS_CHUNK_GROUP : CS_CHUNK_GROUP;
            if (atomicAdd(&b.group_done[g], mine) + mine == size) last[g - g0] = g;
        }
    __syncthreads();
    for (int k = 0; k < 4; k++) {
        const int32_t g = last[k]; /* block-uniform */
        if (g < 0) continue;
        __threadfence();
        group_sums(sc, b, g);
        if (threadIdx.x == 0) b.group_done[g] = 0; /* every block of this launch has counted */
    }
}

/* One block of the cloth kernel (see the top of the file): chunk column seg of rows tile_rows
 * tile .. on, TILE_W threads. k_cloth runs it for one scene, k_cloth_batch for the block's scene of
 * a batch. What a vertex ends with does not depend on the tiling: every sum is in a fixed order
 * (its springs, the rocks, a row chunk's tree, the chunks of a group, the groups). */
template <int MODE, bool STRAIN, bool ROCKS>
__device__ static void cloth_block(const cuda_scene *__restrict__ sc, const cuda_bufs &b, int32_t seg, int32_t tile,
                                   int32_t tile_rows)
{
    CS_DYNAMIC_SHARED(float, sm);
    const cs_phys *p = &sc->p;
    const int t = (int)threadIdx.x;
    const int32_t nx = p->nx, c0 = seg * TILE_W, i = c0 + t;
    const int32_t j0 = tile * tile_rows;
    const int32_t j1 = j0 + tile_rows < p->ny ? j0 + tile_rows : p->ny;
    const bool live = i < nx;
    const bool surface = ROCKS && p->contact_model == CS_CONTACT_SURFACE;
    const int kf = t + FORCE_OFF; /* this column in the force rows */
    /* Rows above row 0 have no springs: their forces read as zeros. */
    for (int k = t; k < 2 * 2 * 3 * FORCE_W; k += TILE_W) sm[SM_FPREV + k] = 0.0f;
    const int ncand = ROCKS ? cull_rocks(sc, b, sm, j0, j1, i) : 0;
    const int *cand = reinterpret_cast<const int *>(sm + SM_CAND);
    /* The two rows above the tile into the ring; the next row in flight in registers, so its
     * loads overlap a row's work (each iteration stores row r+2 and fetches row r+3). */
    row_regs next;
    for (int32_t r = j0 - 2; r < j0; r++) {
        fetch_row(b, p, r, c0, &next);
        put_row(p, sm, r, c0, &next);
    }
    fetch_row(b, p, j0, c0, &next);
    cs_vec3 sy_prev = cs_v3(0.0f, 0.0f, 0.0f), by1 = sy_prev, by2 = sy_prev; /* SY of row r-1; BY of r-1, r-2 */
    int torn = 0, bad = 0;
    for (int32_t r = j0 - 2; r < j1; r++) {
        put_row(p, sm, r + 2, c0, &next);
        if (r + 3 < j1 + 2) fetch_row(b, p, r + 3, c0, &next);
        __syncthreads(); /* rows r .. r+2 are in the ring */
        const bool own = r >= j0;
        /* Above the tile only what rows j0, j0+1 gather: BY of row j0-2; SY, D1, D2, BY of j0-1. */
        const unsigned types = own ? 0x3fu
                                   : r == j0 - 1 ? (1u << CS_SY) | (1u << CS_D1) | (1u << CS_D2) | (1u << CS_BY)
                                                 : (1u << CS_BY);
        cs_vec3 F[CS_NTYPES];
        float len[CS_NTYPES], l0[CS_NTYPES];
        cs_vec3 xi = cs_v3(0.0f, 0.0f, 0.0f), vi = xi;
        cs_ring g; /* surface contact: the vertex's 1-ring (cs_ring), from rows r-1 .. r+1 */
        if (r >= 0) {
            if (live) {
                eval_owned(b, p, sm, i, r, c0, types, F, len, l0);
                xi = ring_x(sm, r, t + RING_OFF);
                vi = ring_v(sm, r, t + RING_OFF);
                if (surface && own) {
                    /* Read before the barrier below: the next row's load overwrites row r-1. */
                    for (int q = 0; q < CS_RING; q++) {
                        const int32_t ii = i + cs_ring_di(q), jj = r + cs_ring_dj(q);
                        const bool in = ii >= 0 && ii < nx && jj >= 0 && jj < p->ny;
                        g.x[q] = in ? ring_x(sm, jj, t + RING_OFF + cs_ring_di(q)) : xi;
                    }
                    g.faces = cs_ring_faces(b.L0, nx, p->ny, i, r);
                }
            } else {
                for (int q = 0; q < CS_NTYPES; q++) F[q] = cs_v3(0.0f, 0.0f, 0.0f);
            }
            share_owned(sm, r, kf, F);
            /* The three columns beside the chunk: c0-2, c0-1 (left), c0+256 (right). */
            if (t < 3) {
                const int32_t ih = t < 2 ? c0 - 2 + t : c0 + TILE_W;
                cs_vec3 Fh[CS_NTYPES];
                float lh[CS_NTYPES], l0h[CS_NTYPES];
                if (ih >= 0 && ih < nx) eval_owned(b, p, sm, ih, r, c0, types, Fh, lh, l0h);
                else
                    for (int q = 0; q < CS_NTYPES; q++) Fh[q] = cs_v3(0.0f, 0.0f, 0.0f);
                share_owned(sm, r, ih - c0 + FORCE_OFF, Fh);
            }
            if (ROCKS && own && t < (ncand + 31) / 32) reinterpret_cast<unsigned *>(sm + SM_TOUCHED)[t] = 0u;
            if (STRAIN && own && live) {
                const size_t v = (size_t)r * (size_t)nx + (size_t)i, n = (size_t)p->n;
                float nl[CS_NTYPES];
                int changed = 0;
                for (int q = 0; q < CS_NTYPES; q++) {
                    nl[q] = l0[q] > 0.0f ? cs_strain_update(len[q], l0[q], p) : l0[q];
                    torn += l0[q] > 0.0f && nl[q] <= 0.0f;
                    changed |= nl[q] != l0[q];
                }
                const unsigned char before = dload(&b.chg[v]);
                if (changed || before)
                    for (int q = 0; q < CS_NTYPES; q++) dstore(&b.L0n[(size_t)q * n + v], nl[q]);
                if ((unsigned char)changed != before) dstore(&b.chg[v], (unsigned char)changed);
            }
        }
        __syncthreads(); /* the owned forces are shared */
        if (own) {
            const int par = (r - 1) & 1;
            cs_vec3 f = cs_v3(0.0f, 0.0f, 0.0f);
            /* The 12 springs in CS_SPRING_SLOTS order; a neighbour's spring enters negated. */
#define CUDA_BACK(t, di, dj)                                                                           \
    ((dj) == 0 ? frow_at(sm, (t) == CS_SX ? 0 : 1, kf + (di))                                          \
               : (dj) == -2 ? by2 : (t) == CS_SY ? sy_prev : fprev_at(sm, par, (t) == CS_D1 ? 0 : 1, kf + (di)))
#define CUDA_GATHER(t, di, dj, fwd) f = cs_add(f, (fwd) ? F[t] : cs_neg(CUDA_BACK(t, di, dj)));
            if (live) {
                CS_SPRING_SLOTS(CUDA_GATHER)
                f = cs_add(f, cs_air_gravity(vi, p));
            }
#undef CUDA_GATHER
#undef CUDA_BACK
            const cs_vec3 ro = f;
            const int32_t chunk = r * p->nseg + seg;
            if (surface) {
                /* Surface contact: rock by rock in index order (as the CPU backend adds them), each
                 * vertex gathers its share from its ring (cs_surface_gather, with the force so far);
                 * the reactions the row's vertices own go through the chunk tree. */
                const float w = live ? (float)dload(&b.mask[(size_t)r * (size_t)nx + (size_t)i]) : 0.0f;
                g.v = vi;
                g.ro = p->friction == CS_FRICTION_RESULTANT ? ro : cs_v3(0.0f, 0.0f, 0.0f);
                for (int c = 0; c < ncand; c++) {
                    const int32_t rk = cand[c];
                    cs_surface_out o;
                    int owns = 0;
                    if (live) {
                        cs_surface_gather(&g, &b.rocks[rk], p, f, w, &o);
                        if (o.touches) f = cs_add(f, o.share);
                        owns = o.owns != 0;
                    }
                    if (!__syncthreads_or(owns)) continue; /* block-uniform */
                    const cs_vec3 zero = cs_v3(0.0f, 0.0f, 0.0f), R = owns ? o.force : zero, T = owns ? o.torque : zero;
                    const float q[6] = {R.x, R.y, R.z, T.x, T.y, T.z};
                    float s6[6];
                    tree_sum6(q, sm + SM_FROW, s6);
                    if (t == 0) {
                        float *out = b.partials + ((size_t)rk * (size_t)p->nchunks + (size_t)chunk) * 6;
                        for (int k = 0; k < 6; k++) dstore(&out[k], s6[k]);
                        atomicOr(&b.hits[(size_t)rk * (size_t)sc->ngroups + (size_t)(chunk / CS_CHUNK_GROUP)],
                                 1ull << (chunk % CS_CHUNK_GROUP));
                    }
                }
            }
            const int ncand_vertex = surface ? 0 : ncand;
            /* Each vertex adds the candidates' forces in rock order and marks the ones it touches;
             * then, for each rock the row touched, the chunk's reactions go through the tree. */
            unsigned *touched = reinterpret_cast<unsigned *>(sm + SM_TOUCHED);
            for (int c32 = 0; c32 < ncand_vertex; c32 += 32) {
                unsigned mine = 0;
                for (int k = 0; k < 32 && c32 + k < ncand_vertex; k++) {
                    cs_vec3 Fc, arm;
                    if (live && cs_vertex_rock_contact(xi, vi, ro, &b.rocks[cand[c32 + k]], p, &Fc, &arm)) {
                        f = cs_add(f, Fc);
                        mine |= 1u << k;
                    }
                }
                if (mine) atomicOr(&touched[c32 / 32], mine);
            }
            if (ncand_vertex) __syncthreads(); /* every vertex has marked what it touches */
            for (int c32 = 0; c32 < ncand_vertex; c32 += 32)
                for (unsigned hits = touched[c32 / 32]; hits; hits &= hits - 1u) {
                    const int32_t rk = cand[c32 + __ffs((int)hits) - 1];
                    cs_vec3 Fc = cs_v3(0.0f, 0.0f, 0.0f), arm = Fc;
                    const int hit = live && cs_vertex_rock_contact(xi, vi, ro, &b.rocks[rk], p, &Fc, &arm);
                    const cs_vec3 R = hit ? cs_neg(Fc) : cs_v3(0.0f, 0.0f, 0.0f);
                    const cs_vec3 T = hit ? cs_cross(arm, R) : cs_v3(0.0f, 0.0f, 0.0f);
                    const float q[6] = {R.x, R.y, R.z, T.x, T.y, T.z};
                    float s6[6];
                    tree_sum6(q, sm + SM_FROW, s6);
                    if (t == 0) {
                        float *out = b.partials + ((size_t)rk * (size_t)p->nchunks + (size_t)chunk) * 6;
                        for (int c = 0; c < 6; c++) dstore(&out[c], s6[c]);
                        atomicOr(&b.hits[(size_t)rk * (size_t)sc->ngroups + (size_t)(chunk / CS_CHUNK_GROUP)],
                                 1ull << (chunk % CS_CHUNK_GROUP));
                    }
                }
            if (live) {
                cs_vec3 Fg;
                if (cs_vertex_ground_contact(xi, vi, ro, p, &Fg)) f = cs_add(f, Fg);
                const size_t v = (size_t)r * (size_t)nx + (size_t)i, n = (size_t)p->n;
                const float w = (float)dload(&b.mask[v]);
                const cs_vec3 a = cs_scale(f, p->inv_mass * w);
                if (MODE == MODE_ACCEL || MODE == MODE_VERLET_LAST || MODE == MODE_EULER_LAST) {
                    dstore(&b.acc[v], a.x);
                    dstore(&b.acc[n + v], a.y);
                    dstore(&b.acc[2 * n + v], a.z);
                }
                if (MODE != MODE_ACCEL) {
                    const bool euler = MODE == MODE_EULER || MODE == MODE_EULER_LAST;
                    const float h = euler ? p->dt : p->hdt;
                    cs_vec3 vv = vi, xx = xi;
                    if (MODE == MODE_VERLET_LAST) {
                        vv = cs_add(vv, cs_scale(a, h)); /* the last substep's kick */
                    } else {
                        if ((int32_t)v == sc->grab) vv = cs_grab_velocity(xi, sc->grab_target, p);
                        vv = cs_add(vv, cs_scale(a, h)); /* Verlet: finish; Euler: the update */
                        if (MODE == MODE_VERLET) vv = cs_add(vv, cs_scale(a, h)); /* the next half kick */
                        xx = cs_add(xi, cs_scale(vv, p->dt));
                    }
                    const float o[6] = {xx.x, xx.y, xx.z, vv.x, vv.y, vv.z};
                    for (int q = 0; q < 6; q++) dstore(&b.out[(size_t)q * n + v], o[q]);
                    if (MODE == MODE_VERLET_LAST || MODE == MODE_EULER_LAST) bad |= !finite3(xx) || !finite3(vv);
                }
            }
        }
        /* Registers for the rows below: SY of this row, BY of this row and the one above. */
        if (r >= 0) {
            sy_prev = F[CS_SY];
            by2 = by1;
            by1 = F[CS_BY];
        }
    }
    if (ROCKS) finish_groups(sc, b, sm, j0, j1, seg);
    if (torn) atomicAdd(&b.flags[FLAG_TORN], torn);
    if (bad) atomicOr(&b.flags[FLAG_NONFINITE], 1);
}

/* The cloth kernel of one scene. Grid: (chunks per row, tiles). */
template <int MODE, bool STRAIN, bool ROCKS>
__global__ void __launch_bounds__(TILE_W) k_cloth(const cuda_scene *__restrict__ sc, cuda_bufs b)
{
    cloth_block<MODE, STRAIN, ROCKS>(sc, b, (int32_t)blockIdx.x, (int32_t)blockIdx.y, sc->tile_rows);
}

/* Velocity Verlet's first substep of a graph: grab, kick, drift of every vertex (no kick to
 * finish: a is complete) in place, and of every rock (block 0). Block blk of 256 threads. */
__device__ static void drift_first_block(const cuda_scene *__restrict__ sc, const cuda_bufs &b, uint32_t blk)
{
    const cs_phys *p = &sc->p;
    if (blk == 0)
        for (int32_t r = (int32_t)threadIdx.x; r < sc->nr; r += (int32_t)blockDim.x) {
            cs_rock_state k = dload(&b.rocks[r]);
            cs_rock_kick(&k, p->hdt);
            cs_rock_drift(&k, p->dt);
            dstore(&b.rocks[r], k);
        }
    const size_t v = (size_t)blk * blockDim.x + threadIdx.x, n = (size_t)p->n;
    if (v >= n) return;
    float *s = b.out; /* in place: in == out */
    const cs_vec3 xi = cs_v3(dload(&s[v]), dload(&s[n + v]), dload(&s[2 * n + v]));
    const cs_vec3 a = cs_v3(dload(&b.acc[v]), dload(&b.acc[n + v]), dload(&b.acc[2 * n + v]));
    cs_vec3 vv = (int32_t)v == sc->grab ? cs_grab_velocity(xi, sc->grab_target, p)
                                        : cs_v3(dload(&s[3 * n + v]), dload(&s[4 * n + v]), dload(&s[5 * n + v]));
    vv = cs_add(vv, cs_scale(a, p->hdt));
    const cs_vec3 xx = cs_add(xi, cs_scale(vv, p->dt));
    const float o[6] = {xx.x, xx.y, xx.z, vv.x, vv.y, vv.z};
    for (int q = 0; q < 6; q++) dstore(&s[(size_t)q * n + v], o[q]);
}

__global__ void k_drift_first(const cuda_scene *__restrict__ sc, cuda_bufs b) { drift_first_block(sc, b, blockIdx.x); }

/* Symplectic Euler's strain pass on the new positions (b.in), rest lengths as in k_cloth. Block
 * blk of 256 threads. */
__device__ static void strain_block(const cuda_scene *__restrict__ sc, const cuda_bufs &b, uint32_t blk)
{
    const cs_phys *p = &sc->p;
    const int32_t v = (int32_t)(blk * blockDim.x + threadIdx.x);
    if (v >= p->n) return;
    const int32_t nx = p->nx, ny = p->ny, i = v % nx, j = v / nx;
    const size_t n = (size_t)p->n;
    const cs_vec3 xi = cs_v3(dload(&b.in[v]), dload(&b.in[n + v]), dload(&b.in[2 * n + v]));
    float nl[CS_NTYPES], l0[CS_NTYPES];
    int torn = 0, changed = 0;
#define CUDA_STRAIN(t, di, dj)                                                                         \
    l0[t] = dload(&b.L0[(size_t)(t) * n + v]);                                                         \
    nl[t] = l0[t];                                                                                     \
    if (l0[t] > 0.0f && cs_far_end_on_grid(nx, ny, i, j, (di), (dj))) {                                    \
        const size_t o = (size_t)(v + (di) + (dj) * nx);                                               \
        const cs_vec3 xo = cs_v3(dload(&b.in[o]), dload(&b.in[n + o]), dload(&b.in[2 * n + o]));       \
        nl[t] = cs_strain_update(cs_len(cs_sub(xo, xi)), l0[t], p);                                    \
        torn += nl[t] <= 0.0f;                                                                         \
        changed |= nl[t] != l0[t];                                                                     \
    }
    CS_SPRING_TYPES(CUDA_STRAIN)
#undef CUDA_STRAIN
    const unsigned char before = dload(&b.chg[v]);
    if (changed || before)
        for (int q = 0; q < CS_NTYPES; q++) dstore(&b.L0n[(size_t)q * n + v], nl[q]);
    if ((unsigned char)changed != before) dstore(&b.chg[v], (unsigned char)changed);
    if (torn) atomicAdd(&b.flags[FLAG_TORN], torn);
}

__global__ void k_strain(const cuda_scene *__restrict__ sc, cuda_bufs b) { strain_block(sc, b, blockIdx.x); }

/* ---- rocks ---- */

/* Total force and torque on rock r, in cs_rock_force's order, by one warp: the sums of the chunk
 * groups that touched it (group_sums; the others are +0) in group order; then the other rocks
 * (tested by the lanes, added in index order), the ground, gravity. The hit words read are
 * cleared for the next substep. Every lane ends with the same sums. */
__device__ static void rock_force(const cuda_scene *sc, const cuda_bufs &b, int32_t r, cs_vec3 *F_out, cs_vec3 *T_out)
{
    const cs_phys *p = &sc->p;
    const int lane = (int)(threadIdx.x & 31u);
    const int32_t nr = sc->nr, ng = sc->ngroups;
    cs_vec3 F = cs_v3(0.0f, 0.0f, 0.0f), T = F;
    for (int32_t g0 = 0; g0 < ng; g0 += 32) {
        const int32_t g = g0 + lane;
        const size_t rg = (size_t)r * (size_t)ng + (size_t)g;
        unsigned long long bits = 0;
        float q[6] = {0, 0, 0, 0, 0, 0};
        if (g < ng && (bits = dload(&b.hits[rg])) != 0) {
            dstore(&b.hits[rg], 0ull); /* clean for the next substep */
            for (int k = 0; k < 6; k++) q[k] = dload(&b.gsum[rg * 6 + (size_t)k]);
        }
        for (unsigned m = __ballot_sync(FULL, bits != 0); m; m &= m - 1u) {
            const int l = __ffs((int)m) - 1;
            F = cs_add(F, cs_v3(__shfl_sync(FULL, q[0], l), __shfl_sync(FULL, q[1], l), __shfl_sync(FULL, q[2], l)));
            T = cs_add(T, cs_v3(__shfl_sync(FULL, q[3], l), __shfl_sync(FULL, q[4], l), __shfl_sync(FULL, q[5], l)));
        }
    }
    /* Through pointers: these read positions, velocities, spins and radii only, never the
     * accelerations that other warps of k_rock_force write meanwhile. */
    const cs_rock_state *me = &b.rocks[r];
    for (int32_t b0 = 0; b0 < nr; b0 += 32) {
        const int32_t o = b0 + lane;
        cs_vec3 f = cs_v3(0.0f, 0.0f, 0.0f), tq = f;
        int touch = 0;
        if (o < nr && o != r) touch = cs_rock_pair_contact(me, &b.rocks[o], p, &f, &tq);
        for (unsigned m = __ballot_sync(FULL, touch); m; m &= m - 1u) {
            const int l = __ffs((int)m) - 1;
            F = cs_add(F, cs_v3(__shfl_sync(FULL, f.x, l), __shfl_sync(FULL, f.y, l), __shfl_sync(FULL, f.z, l)));
            T = cs_add(T, cs_v3(__shfl_sync(FULL, tq.x, l), __shfl_sync(FULL, tq.y, l), __shfl_sync(FULL, tq.z, l)));
        }
    }
    cs_vec3 f, tq;
    if (cs_rock_ground_contact(me, p, &f, &tq)) {
        F = cs_add(F, f);
        T = cs_add(T, tq);
    }
    *F_out = cs_add(F, cs_scale(p->gravity, me->mass));
    *T_out = T;
}

/* A rock's velocity and position steps after its accelerations are stored (backend.h). */
__device__ static void rock_move(int mode, cs_rock_state *k, const cs_phys *p, int *flags)
{
    switch (mode) {
    case ROCKS_VERLET:
        cs_rock_kick(k, p->hdt);
        cs_rock_kick(k, p->hdt);
        cs_rock_drift(k, p->dt);
        break;
    case ROCKS_VERLET_LAST: cs_rock_kick(k, p->hdt); break;
    case ROCKS_EULER:
        cs_rock_kick(k, p->dt);
        cs_rock_drift(k, p->dt);
        break;
    default: break;
    }
    if ((mode == ROCKS_VERLET_LAST || mode == ROCKS_EULER) && (!finite3(k->x) || !finite3(k->v) || !finite3(k->w)))
        atomicOr(&flags[FLAG_NONFINITE], 1);
}

/* Up to ROCKS_FUSED rocks: one block of 32 warps, a warp per rock (two rounds), then the moves. */
__device__ static void rocks_block(const cuda_scene *__restrict__ sc, const cuda_bufs &b, int mode)
{
    const int warp = (int)(threadIdx.x >> 5), lane = (int)(threadIdx.x & 31u);
    cs_vec3 F[2] = {cs_v3(0.0f, 0.0f, 0.0f), cs_v3(0.0f, 0.0f, 0.0f)}, T[2] = {F[0], F[1]};
    for (int k = 0; k < 2; k++) {
        const int32_t r = warp + 32 * k;
        if (r < sc->nr) rock_force(sc, b, r, &F[k], &T[k]); /* warp-uniform */
    }
    __syncthreads(); /* every force read the other rocks before any moves */
    if (lane == 0)
        for (int k = 0; k < 2; k++) {
            const int32_t r = warp + 32 * k;
            if (r >= sc->nr) continue;
            cs_rock_state rk = dload(&b.rocks[r]);
            cs_rock_accel(&rk, F[k], T[k]);
            rock_move(mode, &rk, &sc->p, b.flags);
            dstore(&b.rocks[r], rk);
        }
}

template <int MODE> __global__ void __launch_bounds__(1024) k_rocks(const cuda_scene *__restrict__ sc, cuda_bufs b)
{
    rocks_block(sc, b, MODE);
}

/* More rocks: accelerations (a warp per rock; a rock's force never reads another's a) ... */
__device__ static void rock_force_warp(const cuda_scene *__restrict__ sc, const cuda_bufs &b, int32_t r)
{
    if (r >= sc->nr) return; /* warp-uniform */
    cs_vec3 F, T;
    rock_force(sc, b, r, &F, &T);
    if ((threadIdx.x & 31u) == 0) {
        cs_vec3 a = cs_scale(F, dload(&b.rocks[r].inv_mass)), al = cs_scale(T, dload(&b.rocks[r].inv_inertia));
        dstore(&b.rocks[r].a, a);
        dstore(&b.rocks[r].alpha, al);
    }
}

__global__ void __launch_bounds__(32 * ROCK_WARPS) k_rock_force(const cuda_scene *__restrict__ sc, cuda_bufs b)
{
    rock_force_warp(sc, b, (int32_t)(blockIdx.x * ROCK_WARPS + (threadIdx.x >> 5)));
}

/* ... then the moves, a thread per rock. */
__device__ static void rock_move_thread(const cuda_scene *__restrict__ sc, const cuda_bufs &b, int32_t r, int mode)
{
    if (r >= sc->nr) return;
    cs_rock_state k = dload(&b.rocks[r]);
    rock_move(mode, &k, &sc->p, b.flags);
    dstore(&b.rocks[r], k);
}

template <int MODE> __global__ void k_rock_move(const cuda_scene *__restrict__ sc, cuda_bufs b)
{
    rock_move_thread(sc, b, (int32_t)(blockIdx.x * blockDim.x + threadIdx.x), MODE);
}

/* ---- batches: many scenes, one launch per kernel per substep ----
 *
 * Each scene keeps its own device buffers (its cuda_ctx's); a batch launch reads a device table of
 * the scenes' descriptors and, per kernel, the prefix sums of the blocks each scene takes. A block
 * finds its scene by binary search, and its place within the scene's launch, and runs the same
 * block function (cloth_block, drift_first_block, strain_block, rocks_block, rock_force_warp,
 * rock_move_thread) with the same arguments a lone launch gives it. Scenes past their substeps
 * exit. */

/* The kernels of a batch substep, in launch order: the index of each's block prefix sums. */
enum { BK_DRIFT, BK_CLOTH, BK_ROCKS, BK_ROCK_MOVE, BK_STRAIN, BK_COUNT };
#define BATCH_ROCK_THREADS 1024 /* the fused rock block's threads; the split force kernel's warps */

/* One scene of a batch (device memory). Substep s reads cloth[s & 1] (the state and rest
 * lengths of that substep), and the drift and strain passes swapped[s & 1] (their state is the
 * other buffer: the drift works in place on it, the strain pass reads the positions just written). */
struct batch_scene {
    const cuda_scene *sc;
    cuda_bufs cloth[2], swapped[2];
    int32_t substeps;  /* of this round */
    int32_t graph;     /* the lone step's graph length: a drift starts and a last kick ends each */
    int32_t verlet, strain, rocks; /* rocks: rock_path */
    int32_t tile_rows; /* rows of a cloth block: the batch's, not the lone step's */
};

/* The scene block `blk` of a launch belongs to: the last k with start[k] <= blk (empty scenes have
 * start[k] == start[k + 1]). Block-uniform. */
__device__ static int32_t batch_scene_of(const int32_t *__restrict__ start, int32_t n, uint32_t blk)
{
    int32_t lo = 0, hi = n; /* start[lo] <= blk < start[hi] */
    while (hi - lo > 1) {
        const int32_t mid = lo + (hi - lo) / 2;
        if ((uint32_t)start[mid] <= blk) lo = mid;
        else hi = mid;
    }
    return lo;
}

/* This block's scene in a batch launch at substep s, and the block's index in the scene's own
 * launch; NULL when the scene has run all its substeps. */
__device__ static const batch_scene *batch_block(const batch_scene *__restrict__ tab, const int32_t *__restrict__ start,
                                                 int32_t n, int32_t s, uint32_t *local)
{
    const int32_t k = batch_scene_of(start, n, blockIdx.x);
    *local = blockIdx.x - (uint32_t)start[k];
    return s < tab[k].substeps ? &tab[k] : NULL;
}

__device__ static inline bool batch_first(const batch_scene &d, int32_t s) { return s % d.graph == 0; }
__device__ static inline bool batch_last(const batch_scene &d, int32_t s)
{
    return s == d.substeps - 1 || s % d.graph == d.graph - 1;
}

/* The instantiation launch_cloth picks for this scene: the strain update in the Verlet modes only. */
template <int MODE>
__device__ static void cloth_block_any(const batch_scene &d, const cuda_bufs &b, int32_t seg, int32_t tile)
{
    constexpr bool S = MODE == MODE_VERLET || MODE == MODE_VERLET_LAST;
    const bool strain = S && d.strain, rocks = d.rocks != 0;
    const int32_t tr = d.tile_rows;
    if (strain && rocks) cloth_block<MODE, S, true>(d.sc, b, seg, tile, tr);
    else if (strain) cloth_block<MODE, S, false>(d.sc, b, seg, tile, tr);
    else if (rocks) cloth_block<MODE, false, true>(d.sc, b, seg, tile, tr);
    else cloth_block<MODE, false, false>(d.sc, b, seg, tile, tr);
}

__global__ void __launch_bounds__(TILE_W)
    k_cloth_batch(const batch_scene *__restrict__ tab, const int32_t *__restrict__ start, int32_t n, int32_t s)
{
    uint32_t local;
    const batch_scene *in = batch_block(tab, start, n, s, &local);
    if (!in) return;
    const batch_scene &d = *in;
    const cuda_bufs b = d.cloth[s & 1];
    const int32_t nseg = d.sc->p.nseg, seg = (int32_t)local % nseg, tile = (int32_t)local / nseg;
    const bool last = batch_last(d, s);
    if (d.verlet) {
        if (last) cloth_block_any<MODE_VERLET_LAST>(d, b, seg, tile);
        else cloth_block_any<MODE_VERLET>(d, b, seg, tile);
    } else {
        if (last) cloth_block_any<MODE_EULER_LAST>(d, b, seg, tile);
        else cloth_block_any<MODE_EULER>(d, b, seg, tile);
    }
}

/* Velocity Verlet scenes whose graph starts at substep s (the others have no blocks or exit). */
__global__ void k_drift_batch(const batch_scene *__restrict__ tab, const int32_t *__restrict__ start, int32_t n, int32_t s)
{
    uint32_t local;
    const batch_scene *d = batch_block(tab, start, n, s, &local);
    if (d && batch_first(*d, s)) drift_first_block(d->sc, d->swapped[s & 1], local);
}

__global__ void k_strain_batch(const batch_scene *__restrict__ tab, const int32_t *__restrict__ start, int32_t n, int32_t s)
{
    uint32_t local;
    const batch_scene *d = batch_block(tab, start, n, s, &local);
    if (d) strain_block(d->sc, d->swapped[s & 1], local);
}

__device__ static inline int batch_rock_mode(const batch_scene &d, int32_t s)
{
    return d.verlet ? (batch_last(d, s) ? ROCKS_VERLET_LAST : ROCKS_VERLET) : ROCKS_EULER;
}

/* Up to ROCKS_FUSED rocks: the scene's one block does it all; more: a warp per rock, forces only. */
__global__ void __launch_bounds__(BATCH_ROCK_THREADS)
    k_rocks_batch(const batch_scene *__restrict__ tab, const int32_t *__restrict__ start, int32_t n, int32_t s)
{
    uint32_t local;
    const batch_scene *d = batch_block(tab, start, n, s, &local);
    if (!d) return;
    const cuda_bufs b = d->cloth[s & 1];
    if (d->rocks == 1) rocks_block(d->sc, b, batch_rock_mode(*d, s));
    else rock_force_warp(d->sc, b, (int32_t)(local * (BATCH_ROCK_THREADS / 32) + (threadIdx.x >> 5)));
}

/* ... and their moves, a thread per rock. */
__global__ void k_rock_move_batch(const batch_scene *__restrict__ tab, const int32_t *__restrict__ start, int32_t n,
                                  int32_t s)
{
    uint32_t local;
    const batch_scene *d = batch_block(tab, start, n, s, &local);
    if (d) rock_move_thread(d->sc, d->cloth[s & 1], (int32_t)(local * blockDim.x + threadIdx.x), batch_rock_mode(*d, s));
}

/* The frames a batch's scenes were read for: each job two ranges of 32-bit words (the state's
 * positions and/or velocities, the rocks) copied into the scene's frame buffers, for all scenes in
 * one launch (copy_frame's device copies, batched). */
struct frame_job {
    const uint32_t *src[2];
    uint32_t *dst[2];
    int32_t words[2];
};
static_assert(sizeof(cs_rock_state) % 4 == 0, "a rock is whole 32-bit words");
#define FRAME_WORDS_PER_BLOCK 4096

__global__ void k_frames_batch(const frame_job *__restrict__ jobs, const int32_t *__restrict__ start, int32_t n)
{
    const int32_t k = batch_scene_of(start, n, blockIdx.x);
    const frame_job &j = jobs[k];
    const int64_t first = (int64_t)(blockIdx.x - (uint32_t)start[k]) * FRAME_WORDS_PER_BLOCK;
    for (int r = 0; r < 2; r++)
        for (int64_t w = first + threadIdx.x; w < first + FRAME_WORDS_PER_BLOCK && w < j.words[r]; w += blockDim.x)
            dstore(&j.dst[r][w], dload(&j.src[r][w]));
}

/* ---- host side ---- */

/* A graph's shape: what its kernels are. Pointers and launch sizes can change under it (update). */
struct graph_key {
    int32_t len;          /* substeps */
    int integrator, strain, rocks; /* rocks: 0 none, 1 fused, 2 split */
    int pos, rest;        /* buffer parities at its start */
};
struct graph_entry {
    graph_key key;
    cudaGraphExec_t exec;
    uint64_t epoch;       /* the buffers it was built for */
    int32_t nr;           /* the rock count its launch sizes are for (split kernels) */
    uint64_t used;
};

/* Buffers sized by the cloth (n vertices). */
struct vertex_bufs {
    int32_t n;
    float *state[2], *acc, *rest[2];
    unsigned char *chg, *mask;
    float *frame_dev[2], *frame_host[2]; /* positions and velocities of a read frame (6 n) */
    unsigned char *mask_stage;           /* pageable, for converting the host's mask */
};
/* Buffers sized by the rock capacity and the chunks. */
struct rock_bufs {
    int32_t cap, nchunks, ngroups;
    cs_rock_state *rocks, *frame_rocks_dev[2], *frame_rocks_host[2];
    float *partials, *gsum;
    unsigned long long *hits;
    int *group_done;
};

struct cuda_ctx {
    int dev, sms;
    cudaStream_t stream, copy;
    vertex_bufs vb;
    rock_bufs rb;
    int cur, rest_cur;         /* which state and rest-length buffers hold the state */
    cuda_scene host_sc, *sc;   /* the scene struct and its device copy */
    int *flags, *host_flags;   /* device counters and their pinned host copy */
    /* frames: after a step call, what the host read of the previous frame, copied ahead */
    cudaEvent_t ready[2], copied[2];
    cudaEvent_t queued;        /* a batch waits for what this scene's stream holds ... */
    int pending;               /* ... when something was queued on it since it was last idle */
    int after_batch;           /* a batch's frame copy may still read the state (join_batch) */
    int slot;
    int64_t calls, frame_call; /* step calls so far; the call the frame in `slot` is of */
    unsigned frame_parts;      /* CS_SYNC_* parts in that frame */
    int frame_waited;          /* its copy is known to be done */
    unsigned wanted;           /* parts downloaded since the last step call */
    graph_entry graphs[GRAPHS];
    int n_graphs;
    struct im_work *im;        /* implicit_euler's workspace (see "integrator implicit_euler"), once used */
    uint64_t epoch, uses;
    char device[320];
    char err[256];
};

/* Errors that leave the context unusable: the device state is lost. */
static int sticky(cudaError_t e)
{
    switch (e) {
    case cudaErrorIllegalAddress:
    case cudaErrorLaunchFailure:
    case cudaErrorHardwareStackError:
    case cudaErrorIllegalInstruction:
    case cudaErrorMisalignedAddress:
    case cudaErrorInvalidAddressSpace:
    case cudaErrorInvalidPc:
    case cudaErrorECCUncorrectable:
    case cudaErrorAssert:
    case cudaErrorLaunchTimeout:
    case cudaErrorUnknown: return 1;
    default: return 0;
    }
}

static cs_status cuda_fail(cuda_ctx *c, cudaError_t e, const char *call, int line)
{
    snprintf(c->err, sizeof c->err, "%s (%s) at backend_cuda.cu:%d in %s", cudaGetErrorString(e), cudaGetErrorName(e),
             line, call);
    /* Handled: clear it, or the next launch's cudaGetLastError would report it as its own (a
     * failed cudaMalloc of a refused scene then failed the next step). */
    (void)cudaGetLastError();
    if (sticky(e)) return CS_E_DEVICE;
    return e == cudaErrorMemoryAllocation ? CS_E_NOMEM : CS_E_BACKEND;
}

/* Every CUDA call goes through this: on failure, record where and return the status. */
#define CUDA_CHECK(call)                                                                               \
    do {                                                                                               \
        const cudaError_t e_ = (call);                                                                 \
        if (e_ != cudaSuccess) return cuda_fail(c, e_, #call, __LINE__);                               \
    } while (0)

static int cuda_available(char *why, size_t why_len)
{
    int count = 0;
    const cudaError_t e = cudaGetDeviceCount(&count);
    if (e != cudaSuccess) {
        snprintf(why, why_len, "no usable CUDA device: %s", cudaGetErrorString(e));
        return 0;
    }
    if (count == 0) {
        snprintf(why, why_len, "no CUDA device found");
        return 0;
    }
    if (why_len) why[0] = '\0';
    return 1;
}

static void drop_graphs(cuda_ctx *c)
{
    for (int g = 0; g < c->n_graphs; g++) cudaGraphExecDestroy(c->graphs[g].exec);
    c->n_graphs = 0;
}

static void free_vertex_bufs(vertex_bufs *v)
{
    for (int k = 0; k < 2; k++) {
        cudaFree(v->state[k]);
        cudaFree(v->rest[k]);
        cudaFree(v->frame_dev[k]);
        cudaFreeHost(v->frame_host[k]);
    }
    cudaFree(v->acc);
    cudaFree(v->chg);
    cudaFree(v->mask);
    free(v->mask_stage);
    memset(v, 0, sizeof *v);
}

static void free_rock_bufs(rock_bufs *r)
{
    for (int k = 0; k < 2; k++) {
        cudaFree(r->frame_rocks_dev[k]);
        cudaFreeHost(r->frame_rocks_host[k]);
    }
    cudaFree(r->rocks);
    cudaFree(r->partials);
    cudaFree(r->gsum);
    cudaFree(r->hits);
    cudaFree(r->group_done);
    memset(r, 0, sizeof *r);
}

/* Allocates a new set; on failure frees what it got and leaves *v empty. */
static cudaError_t alloc_vertex_bufs(vertex_bufs *v, int32_t n)
{
    memset(v, 0, sizeof *v);
    const size_t f = sizeof(float) * (size_t)n;
    cudaError_t e = cudaSuccess;
    for (int k = 0; k < 2 && e == cudaSuccess; k++) {
        e = cudaMalloc((void **)&v->state[k], 6 * f);
        if (e == cudaSuccess) e = cudaMalloc((void **)&v->rest[k], CS_NTYPES * f);
        if (e == cudaSuccess) e = cudaMalloc((void **)&v->frame_dev[k], 6 * f);
        if (e == cudaSuccess) e = cudaMallocHost((void **)&v->frame_host[k], 6 * f);
    }
    if (e == cudaSuccess) e = cudaMalloc((void **)&v->acc, 3 * f);
    if (e == cudaSuccess) e = cudaMalloc((void **)&v->chg, (size_t)n);
    if (e == cudaSuccess) e = cudaMalloc((void **)&v->mask, (size_t)n);
    if (e == cudaSuccess && !(v->mask_stage = (unsigned char *)malloc((size_t)n))) e = cudaErrorMemoryAllocation;
    if (e != cudaSuccess) free_vertex_bufs(v);
    else v->n = n;
    return e;
}

static cudaError_t alloc_rock_bufs(rock_bufs *r, int32_t cap, int32_t nchunks)
{
    memset(r, 0, sizeof *r);
    const int32_t ngroups = (nchunks + CS_CHUNK_GROUP - 1) / CS_CHUNK_GROUP;
    cudaError_t e = cudaMalloc((void **)&r->rocks, sizeof(cs_rock_state) * (size_t)cap);
    for (int k = 0; k < 2 && e == cudaSuccess; k++) {
        e = cudaMalloc((void **)&r->frame_rocks_dev[k], sizeof(cs_rock_state) * (size_t)cap);
        if (e == cudaSuccess) e = cudaMallocHost((void **)&r->frame_rocks_host[k], sizeof(cs_rock_state) * (size_t)cap);
    }
    if (e == cudaSuccess) e = cudaMalloc((void **)&r->partials, sizeof(float) * 6 * (size_t)cap * (size_t)nchunks);
    if (e == cudaSuccess) e = cudaMalloc((void **)&r->hits, sizeof(unsigned long long) * (size_t)cap * (size_t)ngroups);
    if (e == cudaSuccess) e = cudaMemset(r->hits, 0, sizeof(unsigned long long) * (size_t)cap * (size_t)ngroups);
    if (e == cudaSuccess) e = cudaMalloc((void **)&r->gsum, sizeof(float) * 6 * (size_t)cap * (size_t)ngroups);
    if (e == cudaSuccess) e = cudaMalloc((void **)&r->group_done, sizeof(int) * (size_t)ngroups);
    if (e == cudaSuccess) e = cudaMemset(r->group_done, 0, sizeof(int) * (size_t)ngroups);
    if (e != cudaSuccess) free_rock_bufs(r);
    else r->cap = cap, r->nchunks = nchunks, r->ngroups = ngroups;
    return e;
}

static void im_free(struct im_work *w);

static void cuda_destroy(void *ctx)
{
    cuda_ctx *c = (cuda_ctx *)ctx;
    if (!c) return;
    drop_graphs(c);
    im_free(c->im);
    free_vertex_bufs(&c->vb);
    free_rock_bufs(&c->rb);
    cudaFree(c->flags);
    cudaFree(c->sc);
    cudaFreeHost(c->host_flags);
    for (int k = 0; k < 2; k++) {
        if (c->ready[k]) cudaEventDestroy(c->ready[k]);
        if (c->copied[k]) cudaEventDestroy(c->copied[k]);
    }
    if (c->queued) cudaEventDestroy(c->queued);
    if (c->stream) cudaStreamDestroy(c->stream);
    if (c->copy) cudaStreamDestroy(c->copy);
    free(c);
}

static cs_status cuda_create(void **out, char *err, size_t err_len)
{
    char why[160];
    if (!cuda_available(why, sizeof why)) {
        snprintf(err, err_len, "%s", why);
        return CS_E_BACKEND;
    }
    cuda_ctx *c = (cuda_ctx *)calloc(1, sizeof *c);
    if (!c) {
        snprintf(err, err_len, "out of memory");
        return CS_E_NOMEM;
    }
    c->frame_call = -1;
    cs_status st = CS_OK;
    cudaDeviceProp prop;
    do {
        cudaError_t e = cudaGetDevice(&c->dev);
        if (e == cudaSuccess) e = cudaGetDeviceProperties(&prop, c->dev);
        if (e == cudaSuccess) e = cudaStreamCreateWithFlags(&c->stream, cudaStreamNonBlocking);
        if (e == cudaSuccess) e = cudaStreamCreateWithFlags(&c->copy, cudaStreamNonBlocking);
        for (int k = 0; k < 2 && e == cudaSuccess; k++) {
            e = cudaEventCreateWithFlags(&c->ready[k], cudaEventDisableTiming);
            if (e == cudaSuccess && k == 0) e = cudaEventCreateWithFlags(&c->queued, cudaEventDisableTiming);
            if (e == cudaSuccess) e = cudaEventCreateWithFlags(&c->copied[k], cudaEventDisableTiming);
        }
        if (e == cudaSuccess) e = cudaMalloc((void **)&c->flags, FLAG_COUNT * sizeof(int));
        if (e == cudaSuccess) e = cudaMallocHost((void **)&c->host_flags, FLAG_COUNT * sizeof(int));
        if (e == cudaSuccess) e = cudaMalloc((void **)&c->sc, sizeof(cuda_scene));
        if (e != cudaSuccess) st = cuda_fail(c, e, "setting up the device", __LINE__);
    } while (0);
    if (st != CS_OK) {
        snprintf(err, err_len, "%s", c->err);
        cuda_destroy(c);
        return st;
    }
    c->sms = prop.multiProcessorCount > 0 ? prop.multiProcessorCount : 1;
    snprintf(c->device, sizeof c->device, "%s (sm_%d%d, %d SMs, %.0f GiB)", prop.name, prop.major, prop.minor,
             prop.multiProcessorCount, (double)prop.totalGlobalMem / (1024.0 * 1024.0 * 1024.0));
    *out = c;
    return CS_OK;
}

/* Cloth blocks of a scene at tr rows a block. */
static int64_t cloth_blocks(const cs_phys *p, int32_t tr) { return (int64_t)p->nseg * ((p->ny + tr - 1) / tr); }

/* Rows of a cloth block: as many as keep about four blocks per SM busy, at most 8 (fewer rows,
 * more blocks: small cloths are latency-bound, large ones bandwidth-bound). A batch applies the
 * same rule to all its scenes' blocks together (batch_run). */
static int32_t tile_rows_for(const cs_phys *p, int sms)
{
    int32_t tr = MAX_TILE_ROWS;
    while (tr > 1 && cloth_blocks(p, tr) < 4 * (int64_t)sms) tr >>= 1;
    return tr;
}

static int32_t rock_cap_for(int32_t nr)
{
    int32_t cap = 8;
    while (cap < nr) cap *= 2;
    return cap < CS_MAX_ROCKS ? cap : CS_MAX_ROCKS;
}

/* Room for this state. New buffers are allocated before the old ones are freed: on failure the
 * device state is as it was. */
static cs_status reserve(cuda_ctx *c, const cs_model *m, const cs_state *s)
{
    const int32_t n = s->n, nchunks = m->phys.nchunks;
    const bool new_v = n != c->vb.n;
    const bool new_r = s->n_rocks > c->rb.cap || (c->rb.cap && nchunks != c->rb.nchunks);
    vertex_bufs v;
    rock_bufs r;
    if (new_v) {
        const cudaError_t e = alloc_vertex_bufs(&v, n);
        if (e != cudaSuccess) return cuda_fail(c, e, "allocating the cloth", __LINE__);
    }
    if (new_r) {
        const cudaError_t e = alloc_rock_bufs(&r, rock_cap_for(s->n_rocks > c->rb.cap ? s->n_rocks : c->rb.cap), nchunks);
        if (e != cudaSuccess) {
            if (new_v) free_vertex_bufs(&v);
            return cuda_fail(c, e, "allocating the rocks", __LINE__);
        }
    }
    if (new_v) {
        free_vertex_bufs(&c->vb);
        c->vb = v;
        c->cur = c->rest_cur = 0;
    }
    if (new_r) {
        free_rock_bufs(&c->rb);
        c->rb = r;
    }
    if (new_v || new_r) c->epoch++; /* graphs take the new pointers at their next use */
    return CS_OK;
}

static cuda_bufs bufs_of(const cuda_ctx *c, int pos, int rest)
{
    cuda_bufs b;
    b.in = c->vb.state[pos];
    b.out = c->vb.state[pos ^ 1];
    b.mask = c->vb.mask;
    b.acc = c->vb.acc;
    b.L0 = c->vb.rest[rest];
    b.L0n = c->vb.rest[rest ^ 1];
    b.chg = c->vb.chg;
    b.rocks = c->rb.rocks;
    b.partials = c->rb.partials;
    b.hits = c->rb.hits;
    b.gsum = c->rb.gsum;
    b.group_done = c->rb.group_done;
    b.flags = c->flags;
    return b;
}

/* ---- batches (host): see "batches" above ----
 *
 * What a batch call needs besides its scenes' own buffers: the descriptor table, the block prefix
 * sums and per-scene flags, on the device and in pinned staging. One per process (the scenes of a
 * process share the device they were created on), grown as batches grow and kept between calls. */
struct batch_ctx {
    cudaStream_t stream, copy;   /* the batch's kernels and frames' device copies; the copies to pinned memory */
    cudaEvent_t frames;          /* recorded on stream after the frames' device copies */
    int32_t cap;                 /* scenes the arrays hold */
    batch_scene *tab, *host_tab; /* [cap] */
    int32_t *start, *host_start; /* [BK_COUNT][scenes + 1] */
    int *flags, *host_flags;     /* [cap][FLAG_COUNT] */
    frame_job *jobs, *host_jobs; /* [cap] */
    int32_t *jstart, *host_jstart; /* [cap + 1]: the frame jobs' block prefix sums */
    int32_t *order;              /* [cap]: the batch's items, most substeps first */
};
static batch_ctx batch;
static std::mutex batch_lock;

/* Before a scene's own stream touches its buffers after a batch: the frame copies the batch
 * queued after it (reading the state) come first. The event may have been recorded again by a
 * later batch since: waiting for that later point is waiting longer, never too little. */
static cs_status join_batch(cuda_ctx *c)
{
    if (!c->after_batch) return CS_OK;
    CUDA_CHECK(cudaStreamWaitEvent(c->stream, batch.frames, 0));
    c->after_batch = 0;
    return CS_OK;
}

static cs_status cuda_upload(void *ctx, const cs_model *m, cs_state *s)
{
    cuda_ctx *c = (cuda_ctx *)ctx;
    c->pending = 1;
    cs_status st = join_batch(c);
    if (st == CS_OK) st = reserve(c, m, s);
    if (st != CS_OK) return st;
    const size_t n = (size_t)s->n, f = sizeof(float) * n;
    cuda_scene k;
    memset(&k, 0, sizeof k);
    k.p = m->phys;
    k.nr = s->n_rocks;
    k.grab = s->grab;
    k.grab_target = s->grab_target;
    k.tile_rows = tile_rows_for(&m->phys, c->sms);
    k.ngroups = (m->phys.nchunks + CS_CHUNK_GROUP - 1) / CS_CHUNK_GROUP;
    c->host_sc = k;
    /* From pageable memory: each copy is done when it returns (after the work queued before it). */
    CUDA_CHECK(cudaMemcpyAsync(c->sc, &k, sizeof k, cudaMemcpyHostToDevice, c->stream));
    const float *parts[] = {s->x, s->y, s->z, s->vx, s->vy, s->vz};
    float *st_dev = c->vb.state[c->cur];
    for (int q = 0; q < 6; q++)
        CUDA_CHECK(cudaMemcpyAsync(st_dev + (size_t)q * n, parts[q], f, cudaMemcpyHostToDevice, c->stream));
    const float *acc[] = {s->ax, s->ay, s->az};
    for (int q = 0; q < 3; q++)
        CUDA_CHECK(cudaMemcpyAsync(c->vb.acc + (size_t)q * n, acc[q], f, cudaMemcpyHostToDevice, c->stream));
    for (size_t v = 0; v < n; v++) c->vb.mask_stage[v] = s->w[v] != 0.0f;
    CUDA_CHECK(cudaMemcpyAsync(c->vb.mask, c->vb.mask_stage, n, cudaMemcpyHostToDevice, c->stream));
    CUDA_CHECK(cudaMemcpyAsync(c->vb.rest[c->rest_cur], s->L0, CS_NTYPES * f, cudaMemcpyHostToDevice, c->stream));
    /* The other rest-length buffer is not a copy of this one: every vertex writes it once. */
    CUDA_CHECK(cudaMemsetAsync(c->vb.chg, 1, n, c->stream));
    if (s->n_rocks)
        CUDA_CHECK(cudaMemcpyAsync(c->rb.rocks, s->rocks, sizeof(cs_rock_state) * (size_t)s->n_rocks,
                                   cudaMemcpyHostToDevice, c->stream));
    c->frame_call = -1; /* a frame copied before this is no longer the state */
    return CS_OK;
}

/* Which rock kernels: 0 none, 1 one fused block, 2 forces then moves. */
static int rock_path(int32_t nr) { return nr == 0 ? 0 : nr <= ROCKS_FUSED ? 1 : 2; }

/* Launches of one kind of cloth kernel. */
template <bool S, bool R>
static void launch_cloth(int mode, dim3 grid, size_t smem, cudaStream_t st, const cuda_scene *sc, const cuda_bufs &b)
{
    switch (mode) {
    case MODE_ACCEL: k_cloth<MODE_ACCEL, false, R><<<grid, TILE_W, smem, st>>>(sc, b); break;
    case MODE_VERLET: k_cloth<MODE_VERLET, S, R><<<grid, TILE_W, smem, st>>>(sc, b); break;
    case MODE_VERLET_LAST: k_cloth<MODE_VERLET_LAST, S, R><<<grid, TILE_W, smem, st>>>(sc, b); break;
    case MODE_EULER: k_cloth<MODE_EULER, false, R><<<grid, TILE_W, smem, st>>>(sc, b); break;
    default: k_cloth<MODE_EULER_LAST, false, R><<<grid, TILE_W, smem, st>>>(sc, b); break;
    }
}

static void cloth(const cuda_ctx *c, int mode, bool strain, int pos, int rest)
{
    const cs_phys *p = &c->host_sc.p;
    const dim3 grid((unsigned)p->nseg, (unsigned)((p->ny + c->host_sc.tile_rows - 1) / c->host_sc.tile_rows));
    const bool rocks = c->host_sc.nr > 0;
    const size_t smem = cloth_smem(rocks ? c->rb.cap : 0);
    const cuda_bufs b = bufs_of(c, pos, rest);
    if (strain && rocks) launch_cloth<true, true>(mode, grid, smem, c->stream, c->sc, b);
    else if (strain) launch_cloth<true, false>(mode, grid, smem, c->stream, c->sc, b);
    else if (rocks) launch_cloth<false, true>(mode, grid, smem, c->stream, c->sc, b);
    else launch_cloth<false, false>(mode, grid, smem, c->stream, c->sc, b);
}

static void rocks(const cuda_ctx *c, int mode, int pos, int rest)
{
    const int32_t nr = c->host_sc.nr;
    const cuda_bufs b = bufs_of(c, pos, rest);
    cudaStream_t st = c->stream;
    if (rock_path(nr) == 1) {
        switch (mode) {
        case ROCKS_ACCEL: k_rocks<ROCKS_ACCEL><<<1, 1024, 0, st>>>(c->sc, b); break;
        case ROCKS_VERLET: k_rocks<ROCKS_VERLET><<<1, 1024, 0, st>>>(c->sc, b); break;
        case ROCKS_VERLET_LAST: k_rocks<ROCKS_VERLET_LAST><<<1, 1024, 0, st>>>(c->sc, b); break;
        default: k_rocks<ROCKS_EULER><<<1, 1024, 0, st>>>(c->sc, b); break;
        }
    } else if (rock_path(nr) == 2) {
        const unsigned fb = (unsigned)((nr + ROCK_WARPS - 1) / ROCK_WARPS), mb = (unsigned)((nr + 255) / 256);
        k_rock_force<<<fb, 32 * ROCK_WARPS, 0, st>>>(c->sc, b);
        switch (mode) {
        case ROCKS_ACCEL: break;
        case ROCKS_VERLET: k_rock_move<ROCKS_VERLET><<<mb, 256, 0, st>>>(c->sc, b); break;
        case ROCKS_VERLET_LAST: k_rock_move<ROCKS_VERLET_LAST><<<mb, 256, 0, st>>>(c->sc, b); break;
        default: k_rock_move<ROCKS_EULER><<<mb, 256, 0, st>>>(c->sc, b); break;
        }
    }
}

/* ---- integrator implicit_euler (kernels/MODEL.md, "The implicit solver") ----
 *
 * The CPU backend's sequence (implicit_cpu.c) with each of its loops a kernel that calls the same
 * functions of clothsim/implicit.h and physics.h per vertex, in the same order, so the state ends
 * bitwise the same. Simple launches on the scene's stream, no graphs: a part of a substep runs
 * the first guess, then Newton (assemble, the multigrid hierarchy, conjugate gradients
 * preconditioned by a V-cycle, a backtracking line search), then the accelerations and the strain
 * pass. The iterate lives in the state buffer a substep writes (state[cur ^ 1]); the part's start
 * (x_n, v_n) is copied aside, so the buffers swap once a part as the explicit substeps do.
 *
 * Sums: a block per chunk (a row's CS_CHUNK columns) sums its terms with cs_tree_sum's tree in
 * shared memory into the chunk's partial; the host copies the partials back and totals them with
 * cs_im_chunk_total, then computes the solver's scalars (residual norms, alpha, beta) in float as
 * the CPU does. A copy back and a wait per dot product: simple, not fast.
 *
 * Rocks (implicit.h, "rock contact" and "the rock steps of a part"): with rocks, each substep
 * first asks how many parts it takes (k_im_fastest_chunks, k_im_fastest: the largest closing
 * rate of cs_im_closing copied back for cs_im_splits); each part advances the rocks without the
 * cloth and shares their mass (k_im_rocks_begin) before the solve, whose assembly adds the carried
 * term (cs_im_carried_at), and after it pushes rocks and cloth apart, stops their approach and
 * applies friction (k_im_rocks_push). The rock steps are serial by design (a fixed order, as the
 * CPU backend runs them): each is a kernel of one thread over the grid (cs_im_rocks_advance, _share, _push of implicit.h, the
 * code the CPU backend runs), the rocks and the workspace staying on the device. One thread
 * scanning the grid is slow on a large cloth; it is what keeps the bits for now. */

/* One level's arrays (device memory); level 0's mask is the state's, as floats. */
struct im_level_bufs {
    int32_t nx, ny, n;
    float *D, *Dinv, *F[4], *mask;
    float *b, *x, *t; /* 3 n each: right side, solution, scratch */
};

struct im_work {
    int32_t nx, ny, n, nchunks, levels;
    float *base;               /* the part's start: x_n, v_n (6 n, the state's layout) */
    float *xo;                 /* the Newton iterate a line search starts from (3 n, x, y, z) */
    float *R, *q, *dx, *r, *z, *p; /* 3 n each (AoS): residual, spring force (then A p), CG vectors */
    float *B[2];               /* bending blocks of level 0 */
    float *part;               /* per-chunk partials of a sum */
    float *host_part;          /* their pinned host copy */
    float *fast;               /* k_im_fastest's answer (1 float) */
    /* the rock steps' workspace (cs_im_rocks): per vertex the mass carried (sh), its normal (sn,
     * 3 n), what a push moved it (sg, 0 between pushes); the rock carried (sr) and the candidates
     * (cand, 2 n); per rock where it would be without the cloth (star), where it started (rx0) and
     * scratch (rf, rt) */
    float *sh, *sn, *sg;
    int32_t *ints;             /* cand, then sr: 3 n, one allocation */
    int32_t *cand, *sr;
    cs_rock_state *star;       /* CS_MAX_ROCKS */
    cs_vec3 *rv3;              /* rx0, rf, rt: CS_MAX_ROCKS each, one allocation */
    im_level_bufs lv[CS_IM_MAX_LEVELS];
    cuda_scene *sc;            /* the scene with the part's phys (its dt is the part's h) */
    cuda_scene host_sc;        /* what sc holds */
    int sc_valid;
    void *mem;                 /* every float array above, in one allocation */
};

#define IM_THREADS 256 /* threads of a per-vertex block */

static void im_free(im_work *w)
{
    if (!w) return;
    cudaFree(w->mem);
    cudaFree(w->ints);
    cudaFree(w->star);
    cudaFree(w->rv3);
    cudaFree(w->sc);
    cudaFreeHost(w->host_part);
    free(w);
}

/* The level as implicit.h's functions read it. */
static cs_im_level im_view(const im_work *w, int l)
{
    const im_level_bufs *v = &w->lv[l];
    cs_im_level L;
    L.nx = v->nx, L.ny = v->ny;
    L.mask = v->mask;
    L.D = v->D, L.Dinv = v->Dinv;
    for (int t = 0; t < 4; t++) L.F[t] = v->F[t];
    L.B[0] = l == 0 ? w->B[0] : NULL, L.B[1] = l == 0 ? w->B[1] : NULL;
    return L;
}

/* The rock steps' view (cs_im_rocks) of the device arrays: the cloth's state S (SoA, 6 n: positions
 * and velocities), the part's start, level 0's mask, the rest lengths L0, the rocks. */
static cs_im_rocks im_rocks(const cuda_ctx *c, float *S, const float *L0)
{
    const im_work *w = c->im;
    const size_t n = (size_t)w->n;
    cs_im_rocks R;
    R.x = S, R.y = S + n, R.z = S + 2 * n, R.vx = S + 3 * n, R.vy = S + 4 * n, R.vz = S + 5 * n;
    R.xb = w->base, R.yb = w->base + n, R.zb = w->base + 2 * n;
    R.w = w->lv[0].mask;
    R.L0 = L0;
    R.rocks = c->rb.rocks;
    R.nr = c->host_sc.nr;
    R.star = w->star;
    R.rx0 = w->rv3, R.F = w->rv3 + CS_MAX_ROCKS, R.T = w->rv3 + 2 * CS_MAX_ROCKS;
    R.cand = w->cand, R.sr = w->sr;
    R.sh = w->sh, R.sn = w->sn, R.sg = w->sg;
    return R;
}

__device__ static inline void im_put3(float *a, int32_t v, cs_vec3 x)
{
    a[3 * (size_t)v] = x.x, a[3 * (size_t)v + 1] = x.y, a[3 * (size_t)v + 2] = x.z;
}
__device__ static inline void im_put_sym(float *a, int32_t v, const cs_mat3 *m)
{
    cs_im_sym_put(a + CS_IM_SYM * (size_t)v, m);
}
__device__ static inline int32_t im_vertex(void) { return (int32_t)(blockIdx.x * blockDim.x + threadIdx.x); }

/* Position and velocity of vertex o of a state (SoA, 6 n). */
#define IM_X(S, n, o) cs_v3((S)[(o)], (S)[(size_t)(n) + (o)], (S)[2 * (size_t)(n) + (o)])
#define IM_V(S, n, o) cs_v3((S)[3 * (size_t)(n) + (o)], (S)[4 * (size_t)(n) + (o)], (S)[5 * (size_t)(n) + (o)])

/* cs_tree_sum's tree over the block (CS_CHUNK threads): buf[t] += buf[t + s], s = CS_CHUNK/2 .. 1.
 * Every thread calls it; the sum is valid in thread 0. */
__device__ static float im_tree(float *buf, float mine)
{
    const int t = (int)threadIdx.x;
    buf[t] = mine;
    for (int s = CS_CHUNK / 2; s > 0; s >>= 1) {
        __syncthreads();
        if (t < s) buf[t] += buf[t + s];
    }
    return buf[0];
}

/* The part's start: x_n, v_n copied aside, level 0's mask as floats and (guess) the first guess
 * into the iterate S: x_n + h v_n + h^2 g for a free vertex, the grabbed one moved at its grab
 * velocity, the others kept; v = (x - x_n)/h. */
__global__ void k_im_begin(const cuda_scene *__restrict__ sc, const float *__restrict__ in, float *S, float *base,
                           const unsigned char *__restrict__ mask, float *mask0, int guess)
{
    const cs_phys *p = &sc->p;
    const int32_t v = im_vertex(), g = sc->grab;
    const size_t n = (size_t)p->n;
    if (v >= p->n) return;
    for (int q = 0; q < 6; q++) base[(size_t)q * n + v] = in[(size_t)q * n + v];
    const float w = (float)mask[v];
    mask0[v] = w;
    if (!guess) return;
    const float h = p->dt, inv_h = 1.0f / h;
    cs_vec3 x = IM_X(in, n, v);
    if (w != 0.0f)
        x = cs_add(x, cs_add(cs_scale(IM_V(in, n, v), h), cs_scale(p->gravity, h * h)));
    else if (v == g)
        x = cs_add(x, cs_scale(cs_grab_velocity(IM_X(in, n, g), sc->grab_target, p), h));
    const float o[6] = {x.x, x.y, x.z, (x.x - base[v]) * inv_h, (x.y - base[n + v]) * inv_h,
                        (x.z - base[2 * n + v]) * inv_h};
    for (int q = 0; q < 6; q++) S[(size_t)q * n + v] = o[q];
}

/* The largest coordinate of chunk blockIdx.x's vertices at the part's start (|x| or |y|, then |z|,
 * as implicit_cpu.c's part takes it; a NaN is never taken), for float's floor (cs_im_float_floor):
 * the chunk's largest into part (a maximum: any order gives the same). */
__global__ void __launch_bounds__(CS_CHUNK) k_im_reach(const cuda_scene *__restrict__ sc, const float *in, float *part)
{
    CS_DYNAMIC_SHARED(float, buf);
    const cs_phys *p = &sc->p;
    const int t = (int)threadIdx.x;
    const int32_t c = (int32_t)blockIdx.x, j = c / p->nseg, i = (c % p->nseg) * CS_CHUNK + t;
    float reach = 0.0f;
    if (i < p->nx) {
        reach = cs_im_reach(IM_X(in, p->n, j * p->nx + i), reach);
    }
    buf[t] = reach;
    for (int s = CS_CHUNK / 2; s > 0; s >>= 1) {
        __syncthreads();
        if (t < s) buf[t] = buf[t + s] > buf[t] ? buf[t + s] : buf[t];
    }
    if (t == 0) part[c] = buf[0];
}

/* The fastest chunk blockIdx.x's vertices close on a rock near them at a substep's start (cs_im_closing,
 * fastest of implicit_cpu.c; a NaN is never taken): the chunk's largest into part (a maximum: any
 * order gives the same). */
__global__ void __launch_bounds__(CS_CHUNK) k_im_fastest_chunks(const cuda_scene *__restrict__ sc, const cs_rock_state *rocks,
                                                               const float *in, float h, float *part)
{
    CS_DYNAMIC_SHARED(float, buf);
    const cs_phys *p = &sc->p;
    const int t = (int)threadIdx.x;
    const int32_t c = (int32_t)blockIdx.x, j = c / p->nseg, i = (c % p->nseg) * CS_CHUNK + t;
    const size_t n = (size_t)p->n;
    float most = 0.0f;
    if (i < p->nx) {
        const float q = cs_im_closing(p, rocks, sc->nr, in, in + n, in + 2 * n, in + 3 * n, in + 4 * n, in + 5 * n,
                                      j * p->nx + i, h);
        most = q > most ? q : most;
    }
    buf[t] = most;
    for (int s = CS_CHUNK / 2; s > 0; s >>= 1) {
        __syncthreads();
        if (t < s) buf[t] = buf[t + s] > buf[t] ? buf[t + s] : buf[t];
    }
    if (t == 0) part[c] = buf[0];
}

/* The chunks' largest closing rates' maximum, into out[0]. One thread. */
__global__ void k_im_fastest(const float *part, int32_t nchunks, float *out)
{
    float most = 0.0f;
    for (int32_t c = 0; c < nchunks; c++) most = part[c] > most ? part[c] : most;
    out[0] = most;
}

/* Step 1 of a part with rocks: the rocks advanced without the cloth, then the mass they lend
 * (cs_im_rocks_advance, cs_im_rocks_share; R.x the part's start). One thread: the rock steps are
 * serial by design (a fixed order, the CPU backend's), so this single-thread kernel scans the grid
 * alone - slow on a large cloth, kept for the bits until a parallel scan with the same order is
 * written. */
__global__ void k_im_rocks_begin(const cuda_scene *__restrict__ sc, cs_im_rocks R, float h)
{
    cs_im_rocks_advance(&sc->p, &R, h);
    cs_im_rocks_share(&sc->p, &R);
}

/* Step 3 of a part with rocks: the rocks follow what their vertices carried, then rocks and cloth
 * pushed apart (cs_im_rocks_push; R.x the solved iterate). One thread, as k_im_rocks_begin. */
__global__ void k_im_rocks_push(const cuda_scene *__restrict__ sc, cs_im_rocks R, float h)
{
    cs_im_rocks_push(&sc->p, &R, h);
}


/* What an assembly writes (device pointers), and the rocks' carried mass it adds (rocks: 1). */
struct im_asm {
    float *R, *q, *D, *F[4], *B[2], *part;
    const float *mask0;
    cs_im_rocks rk;
    int rocks;
};

/* Assembly at the iterate S of chunk blockIdx.x, a thread per vertex (chunk_springs,
 * chunk_contacts, chunk_residual of implicit_cpu.c): the springs, air and gravity, then the
 * contacts - the rock mass the vertex carries (cs_im_carried_at, with rocks), the ground - then the
 * residual R = F - m (v - v_n)/h (0 out of the solve, whose D is the identity); with blocks, level
 * 0's matrix; the chunk's partial of |R|^2. */
__global__ void __launch_bounds__(CS_CHUNK) k_im_assemble(const cuda_scene *__restrict__ sc, const float *S,
                                                         const float *__restrict__ base, const float *__restrict__ L0,
                                                         im_asm a, int blocks)
{
    CS_DYNAMIC_SHARED(float, buf);
    const cs_phys *p = &sc->p;
    const int32_t nx = p->nx, ny = p->ny, c = (int32_t)blockIdx.x;
    const int32_t j = c / p->nseg, i0 = (c % p->nseg) * CS_CHUNK, i = i0 + (int32_t)threadIdx.x;
    const size_t n = (size_t)p->n;
    const float h = p->dt;
    float mine = 0.0f;
    if (i < nx) {
        const int32_t v = j * nx + i;
        cs_vec3 xs[12], vs[12];
        float L0s[12];
        int on[12], slot = 0;
#define IM_GATHER(t, di, dj, fwd)                                                                      \
    {                                                                                                  \
        const int32_t ii = i + (di), jj = j + (dj);                                                    \
        on[slot] = ii >= 0 && ii < nx && jj >= 0 && jj < ny;                                           \
        const int32_t o = on[slot] ? jj * nx + ii : v;                                                 \
        xs[slot] = IM_X(S, n, o), vs[slot] = IM_V(S, n, o);                                            \
        L0s[slot] = L0[(size_t)(t) * n + (size_t)((fwd) ? v : o)];                                     \
        slot++;                                                                                        \
    }
        CS_SPRING_SLOTS(IM_GATHER)
#undef IM_GATHER
        cs_mat3 D, owned[CS_NTYPES];
        const cs_vec3 xi = IM_X(S, n, v), vi = IM_V(S, n, v);
        const cs_vec3 F = cs_im_springs(p, xi, vi, xs, vs, L0s, on, h, &D, owned);
        im_put3(a.q, v, F);
        if (blocks) {
            /* the four forward blocks of level 0, then the two bending ones */
            static_assert(CS_NTYPES == 6, "four forward types, then two bending ones");
            float *const to[CS_NTYPES] = {a.F[0], a.F[1], a.F[2], a.F[3], a.B[0], a.B[1]};
            for (int t = 0; t < CS_NTYPES; t++) {
                cs_mat3 b = owned[t];
                for (int k = 0; k < 9; k++) b.m[k] = -b.m[k];
                im_put_sym(to[t], v, &b);
            }
        }
        /* the contacts: the rock mass carried, then the ground (whose friction reads the
         * springs' resultant F) */
        float f[3] = {F.x, F.y, F.z};
        cs_vec3 Fc;
        cs_mat3 cb;
        if (a.rocks && cs_im_carried_at(&a.rk, v, xi, IM_X(base, n, v), h, &Fc, &cb)) {
            f[0] += Fc.x, f[1] += Fc.y, f[2] += Fc.z;
            if (blocks)
                for (int k = 0; k < 9; k++) D.m[k] += cb.m[k];
        }
        if (p->ground && cs_vertex_ground_contact(xi, vi, F, p, &Fc)) {
            f[0] += Fc.x, f[1] += Fc.y, f[2] += Fc.z;
            if (blocks) {
                const cs_mat3 b = cs_im_ground_block(xi, vi, p, h);
                for (int k = 0; k < 9; k++) D.m[k] += b.m[k];
            }
        }
        cs_vec3 R = cs_im_residual(p, cs_v3(f[0], f[1], f[2]), vi, IM_V(base, n, v), h);
        if (a.mask0[v] == 0.0f) {
            R = cs_v3(0.0f, 0.0f, 0.0f);
            D = cs_m3_diag(1.0f);
        }
        if (blocks) im_put_sym(a.D, v, &D);
        im_put3(a.R, v, R);
        mine = cs_dot(R, R);
    }
    const float sum = im_tree(buf, mine);
    if (threadIdx.x == 0) a.part[c] = sum;
}

/* a . b over level 0: chunk blockIdx.x's partial (cs_im_dot3 terms, the chunk tree). */
__global__ void __launch_bounds__(CS_CHUNK) k_im_dot(const cuda_scene *__restrict__ sc, const float *a, const float *b,
                                                    float *part)
{
    CS_DYNAMIC_SHARED(float, buf);
    const cs_phys *p = &sc->p;
    const int32_t c = (int32_t)blockIdx.x, j = c / p->nseg, i = (c % p->nseg) * CS_CHUNK + (int32_t)threadIdx.x;
    const float mine = i < p->nx ? cs_im_dot3(a, b, j * p->nx + i) : 0.0f;
    const float sum = im_tree(buf, mine);
    if (threadIdx.x == 0) part[c] = sum;
}

/* y = A x on a level (bend: level 0's true operator, bending blocks included). */
__global__ void k_im_apply(cs_im_level L, const float *x, float *y, int bend)
{
    const int32_t v = im_vertex();
    if (v >= L.nx * L.ny) return;
    im_put3(y, v, cs_im_apply(&L, x, v % L.nx, v / L.nx, bend));
}

/* x = x + omega Dinv (b - t), t = A x (first: from x = 0). */
__global__ void k_im_jacobi(cs_im_level L, float *x, const float *b, const float *t, int first)
{
    const int32_t v = im_vertex();
    if (v >= L.nx * L.ny) return;
    const cs_vec3 zero = cs_v3(0.0f, 0.0f, 0.0f);
    const cs_vec3 xv = first ? zero : cs_v3_from(x + 3 * (size_t)v);
    im_put3(x, v, cs_im_jacobi(&L, v, xv, cs_v3_from(b + 3 * (size_t)v), first ? zero : cs_v3_from(t + 3 * (size_t)v)));
}

/* t = b - t over 3 n floats. */
__global__ void k_im_sub(const float *b, float *t, int32_t n3)
{
    const int32_t k = im_vertex();
    if (k < n3) t[k] = b[k] - t[k];
}

/* The coarse right side: the fine residual t restricted to coarse level C. */
__global__ void k_im_restrict(cs_im_level L, const float *t, float *cb, int32_t cnx, int32_t cny)
{
    const int32_t v = im_vertex();
    if (v >= cnx * cny) return;
    im_put3(cb, v, cs_im_restrict(&L, t, v % cnx, v / cnx));
}

/* x += CS_IM_COARSE_SCALE e, e the coarse correction constant over each aggregate. */
__global__ void k_im_prolong(cs_im_level L, float *x, const float *cx, int32_t cnx)
{
    const int32_t v = im_vertex();
    if (v >= L.nx * L.ny || L.mask[v] == 0.0f) return;
    const int32_t i = v % L.nx, j = v / L.nx;
    const cs_vec3 e = cs_v3_from(cx + 3 * (size_t)((j / 2) * cnx + i / 2));
    im_put3(x, v, cs_add(cs_v3_from(x + 3 * (size_t)v), cs_scale(e, CS_IM_COARSE_SCALE)));
}

/* Coarse level c's Galerkin row of each of its vertices from the fine level F. */
__global__ void k_im_galerkin(cs_im_level F, im_level_bufs c)
{
    const int32_t v = im_vertex();
    if (v >= c.n) return;
    float *Fc[4];
    for (int t = 0; t < 4; t++) Fc[t] = c.F[t] + CS_IM_SYM * (size_t)v;
    cs_im_galerkin(&F, v % c.nx, v / c.nx, c.D + CS_IM_SYM * (size_t)v, Fc, c.mask + v);
}

__global__ void k_im_inverse(const float *D, float *Dinv, int32_t n)
{
    const int32_t v = im_vertex();
    if (v >= n) return;
    const cs_mat3 Dv = cs_im_sym_get(D + CS_IM_SYM * (size_t)v), inv = cs_m3_inverse(Dv.m);
    im_put_sym(Dinv, v, &inv);
}

/* dx += alpha p; r -= alpha q. */
__global__ void k_im_cg_step(float *dx, float *r, const float *p, const float *q, float alpha, int32_t n3)
{
    const int32_t k = im_vertex();
    if (k >= n3) return;
    dx[k] += alpha * p[k];
    r[k] -= alpha * q[k];
}

/* p = z + beta p. */
__global__ void k_im_cg_dir(float *p, const float *z, float beta, int32_t n3)
{
    const int32_t k = im_vertex();
    if (k < n3) p[k] = z[k] + beta * p[k];
}

/* The iterate's positions kept for the line search. */
__global__ void k_im_keep(const float *S, float *xo, int32_t n)
{
    const int32_t v = im_vertex();
    if (v >= n) return;
    for (int q = 0; q < 3; q++) xo[(size_t)q * (size_t)n + v] = S[(size_t)q * (size_t)n + v];
}

/* x = x_k + a dx for the vertices in the solve, and v = (x - x_n)/h. */
__global__ void k_im_move(float *S, const float *xo, const float *dx, const float *base, const float *mask0, float a,
                          float inv_h, int32_t n)
{
    const int32_t v = im_vertex();
    if (v >= n || mask0[v] == 0.0f) return;
    const size_t N = (size_t)n;
    for (int q = 0; q < 3; q++) {
        S[q * N + v] = xo[q * N + v] + a * dx[3 * (size_t)v + q];
        S[(3 + q) * N + v] = (S[q * N + v] - base[q * N + v]) * inv_h;
    }
}

/* a = (v - v_n)/h, 0 where the vertex is out of the solve. */
__global__ void k_im_accel(const float *S, const float *base, const float *mask0, float *acc, float inv_h, int32_t n)
{
    const int32_t v = im_vertex();
    if (v >= n) return;
    const size_t N = (size_t)n;
    for (int q = 0; q < 3; q++) acc[q * N + v] = (S[(3 + q) * N + v] - base[(3 + q) * N + v]) * inv_h * mask0[v];
}

/* The refresh's a = F/m: the residual at v = v_n is the force (cs_im_refresh). */
__global__ void k_im_refresh_accel(const cuda_scene *__restrict__ sc, const float *R, const float *mask0, float *acc)
{
    const int32_t v = im_vertex(), n = sc->p.n;
    if (v >= n) return;
    const float k = sc->p.inv_mass * mask0[v];
    for (int q = 0; q < 3; q++) acc[(size_t)q * (size_t)n + v] = R[3 * (size_t)v + q] * k;
}

/* FLAG_NONFINITE where a position or velocity of the state, or a rock's position, velocity or
 * spin, is not finite (the CPU's state_finite). */
__global__ void k_im_finite(const float *S, int32_t n, const cs_rock_state *rocks, int32_t nr, int *flags)
{
    const int32_t v = im_vertex();
    if (v >= n) return;
    int bad = 0;
    for (int q = 0; q < 6; q++) bad |= !isfinite(S[(size_t)q * (size_t)n + v]);
    if (v == 0)
        for (int32_t r = 0; r < nr; r++) bad |= !finite3(rocks[r].x) || !finite3(rocks[r].v) || !finite3(rocks[r].w);
    if (bad) atomicOr(&flags[FLAG_NONFINITE], 1);
}

static unsigned im_blocks(int64_t threads) { return (unsigned)((threads + IM_THREADS - 1) / IM_THREADS); }

/* The workspace for this cloth (kept while its size stays); its arrays zeroed, as the CPU's. */
static cs_status im_fit(cuda_ctx *c, const cs_phys *p)
{
    if (c->im && c->im->nx == p->nx && c->im->ny == p->ny && c->im->nchunks == p->nchunks) return CS_OK;
    im_work *w = (im_work *)calloc(1, sizeof *w);
    if (!w) return CS_E_NOMEM;
    w->nx = p->nx, w->ny = p->ny, w->n = p->n, w->nchunks = p->nchunks;
    size_t floats = (size_t)w->n * (6 + 3 + 18 + 2 * CS_IM_SYM + 5) + (size_t)w->nchunks + 1;
    int32_t lx[CS_IM_MAX_LEVELS], ly[CS_IM_MAX_LEVELS];
    const int L = w->levels = cs_im_levels(p->nx, p->ny, lx, ly);
    for (int l = 0; l < L; l++) {
        w->lv[l].nx = lx[l], w->lv[l].ny = ly[l], w->lv[l].n = lx[l] * ly[l];
        floats += (size_t)w->lv[l].n * CS_IM_LEVEL_FLOATS;
    }
    cudaError_t e = cudaMalloc(&w->mem, sizeof(float) * floats);
    if (e == cudaSuccess) e = cudaMalloc((void **)&w->sc, sizeof(cuda_scene));
    if (e == cudaSuccess) e = cudaMallocHost((void **)&w->host_part, sizeof(float) * (size_t)w->nchunks);
    if (e == cudaSuccess) e = cudaMalloc((void **)&w->ints, sizeof(int32_t) * 3 * (size_t)w->n);
    if (e == cudaSuccess) e = cudaMalloc((void **)&w->star, sizeof(cs_rock_state) * CS_MAX_ROCKS);
    if (e == cudaSuccess) e = cudaMalloc((void **)&w->rv3, sizeof(cs_vec3) * 3 * CS_MAX_ROCKS);
    if (e == cudaSuccess) e = cudaMemsetAsync(w->mem, 0, sizeof(float) * floats, c->stream);
    if (e == cudaSuccess) e = cudaMemsetAsync(w->ints, 0xff, sizeof(int32_t) * 3 * (size_t)w->n, c->stream); /* sr -1 */
    if (e != cudaSuccess) {
        im_free(w);
        return cuda_fail(c, e, "allocating implicit_euler's workspace", __LINE__);
    }
    float *m = (float *)w->mem;
    const size_t n = (size_t)w->n;
#define TAKE(k) (m += (k), m - (k))
    w->base = TAKE(6 * n), w->xo = TAKE(3 * n);
    w->R = TAKE(3 * n), w->q = TAKE(3 * n), w->dx = TAKE(3 * n);
    w->r = TAKE(3 * n), w->z = TAKE(3 * n), w->p = TAKE(3 * n);
    w->B[0] = TAKE(CS_IM_SYM * n), w->B[1] = TAKE(CS_IM_SYM * n);
    w->part = TAKE((size_t)w->nchunks);
    w->sh = TAKE(n), w->sn = TAKE(3 * n), w->sg = TAKE(n);
    w->fast = TAKE(1);
    w->cand = w->ints, w->sr = w->ints + 2 * n;
    for (int l = 0; l < L; l++) {
        im_level_bufs *v = &w->lv[l];
        const size_t k = (size_t)v->n;
        v->D = TAKE(CS_IM_SYM * k), v->Dinv = TAKE(CS_IM_SYM * k);
        for (int t = 0; t < 4; t++) v->F[t] = TAKE(CS_IM_SYM * k);
        v->mask = TAKE(k);
        v->b = TAKE(3 * k), v->x = TAKE(3 * k), v->t = TAKE(3 * k);
    }
#undef TAKE
    im_free(c->im);
    c->im = w;
    return CS_OK;
}

/* The device scene the implicit kernels read: the context's, with the part's phys. */
static cs_status im_scene(cuda_ctx *c, const cs_phys *p)
{
    im_work *w = c->im;
    cuda_scene k = c->host_sc;
    k.p = *p;
    if (w->sc_valid && memcmp(&k, &w->host_sc, sizeof k) == 0) return CS_OK;
    w->host_sc = k;
    /* From pageable memory: done when it returns (after the work queued before it). */
    CUDA_CHECK(cudaMemcpyAsync(w->sc, &w->host_sc, sizeof k, cudaMemcpyHostToDevice, c->stream));
    w->sc_valid = 1;
    return CS_OK;
}

/* The total of the chunk partials in w->part, on the host (cs_im_chunk_total). */
static cs_status im_total(cuda_ctx *c, float *out)
{
    im_work *w = c->im;
    CUDA_CHECK(cudaGetLastError());
    CUDA_CHECK(cudaMemcpyAsync(w->host_part, w->part, sizeof(float) * (size_t)w->nchunks, cudaMemcpyDeviceToHost,
                               c->stream));
    CUDA_CHECK(cudaStreamSynchronize(c->stream));
    *out = cs_im_chunk_total(w->host_part, w->nchunks);
    return CS_OK;
}

/* Assembles at the iterate S (rest lengths L0): R, with blocks level 0's matrix; |R| into r. With
 * rocks (a part's solve), the carried mass the part's rocks_share left in the workspace. */
static cs_status im_assemble(cuda_ctx *c, float *S, const float *L0, int blocks, int rocks, float *r)
{
    im_work *w = c->im;
    im_asm a;
    a.R = w->R, a.q = w->q, a.D = w->lv[0].D, a.part = w->part, a.mask0 = w->lv[0].mask;
    for (int t = 0; t < 4; t++) a.F[t] = w->lv[0].F[t];
    a.B[0] = w->B[0], a.B[1] = w->B[1];
    a.rk = im_rocks(c, S, L0);
    a.rocks = rocks;
    k_im_assemble<<<(unsigned)w->nchunks, CS_CHUNK, sizeof(float) * CS_CHUNK, c->stream>>>(w->sc, S, w->base, L0, a,
                                                                                           blocks);
    float total = 0.0f;
    const cs_status st = im_total(c, &total);
    *r = sqrtf(total);
    return st;
}

/* a . b over level 0. */
static cs_status im_dot(cuda_ctx *c, const float *a, const float *b, float *out)
{
    im_work *w = c->im;
    k_im_dot<<<(unsigned)w->nchunks, CS_CHUNK, sizeof(float) * CS_CHUNK, c->stream>>>(w->sc, a, b, w->part);
    return im_total(c, out);
}

/* The hierarchy from level 0's matrix: the coarse levels' Galerkin products, each level's Dinv. */
static void im_hierarchy(cuda_ctx *c)
{
    im_work *w = c->im;
    for (int l = 0; l < w->levels; l++) {
        im_level_bufs *lv = &w->lv[l];
        if (l > 0) k_im_galerkin<<<im_blocks(lv->n), IM_THREADS, 0, c->stream>>>(im_view(w, l - 1), *lv);
        k_im_inverse<<<im_blocks(lv->n), IM_THREADS, 0, c->stream>>>(lv->D, lv->Dinv, lv->n);
    }
}

/* One V-cycle from level l: x = B b (vcycle of implicit_cpu.c). */
static void im_vcycle(cuda_ctx *c, int l, const float *b, float *x)
{
    im_work *w = c->im;
    const cs_im_level L = im_view(w, l);
    im_level_bufs *lv = &w->lv[l];
    const unsigned nb = im_blocks(lv->n);
    cudaStream_t st = c->stream;
    const int last = l + 1 == w->levels;
    const int sweeps = last ? CS_IM_COARSE_SWEEPS : CS_IM_SMOOTH;
    k_im_jacobi<<<nb, IM_THREADS, 0, st>>>(L, x, b, lv->t, 1);
    for (int k = 1; k < sweeps; k++) {
        k_im_apply<<<nb, IM_THREADS, 0, st>>>(L, x, lv->t, 0);
        k_im_jacobi<<<nb, IM_THREADS, 0, st>>>(L, x, b, lv->t, 0);
    }
    if (last) return;
    k_im_apply<<<nb, IM_THREADS, 0, st>>>(L, x, lv->t, 0);
    k_im_sub<<<im_blocks(3 * (int64_t)lv->n), IM_THREADS, 0, st>>>(b, lv->t, 3 * lv->n);
    im_level_bufs *cl = &w->lv[l + 1];
    k_im_restrict<<<im_blocks(cl->n), IM_THREADS, 0, st>>>(L, lv->t, cl->b, cl->nx, cl->ny);
    im_vcycle(c, l + 1, cl->b, cl->x);
    k_im_prolong<<<nb, IM_THREADS, 0, st>>>(L, x, cl->x, cl->nx);
    for (int k = 0; k < sweeps; k++) {
        k_im_apply<<<nb, IM_THREADS, 0, st>>>(L, x, lv->t, 0);
        k_im_jacobi<<<nb, IM_THREADS, 0, st>>>(L, x, b, lv->t, 0);
    }
}

/* Conjugate gradients on A dx = R preconditioned by a V-cycle (pcg of implicit_cpu.c): stops at
 * |r| <= target or after most iterations; the iterations run into its. */
static cs_status im_pcg(cuda_ctx *c, float target, int most, int *its)
{
    im_work *w = c->im;
    const cs_im_level L0 = im_view(w, 0);
    const int32_t n3 = 3 * w->n;
    const size_t bytes = sizeof(float) * (size_t)n3;
    const unsigned nb = im_blocks(w->n), nb3 = im_blocks(n3);
    cs_status st;
    *its = 0;
    CUDA_CHECK(cudaMemsetAsync(w->dx, 0, bytes, c->stream));
    CUDA_CHECK(cudaMemcpyAsync(w->r, w->R, bytes, cudaMemcpyDeviceToDevice, c->stream));
    im_vcycle(c, 0, w->r, w->z);
    CUDA_CHECK(cudaMemcpyAsync(w->p, w->z, bytes, cudaMemcpyDeviceToDevice, c->stream));
    float rz;
    if ((st = im_dot(c, w->r, w->z, &rz)) != CS_OK) return st;
    int it = 0;
    while (it < most) {
        k_im_apply<<<nb, IM_THREADS, 0, c->stream>>>(L0, w->p, w->q, 1);
        float pq;
        if ((st = im_dot(c, w->p, w->q, &pq)) != CS_OK) return st;
        if (!(pq > 0.0f) || !(rz > 0.0f)) break;
        const float alpha = rz / pq;
        k_im_cg_step<<<nb3, IM_THREADS, 0, c->stream>>>(w->dx, w->r, w->p, w->q, alpha, n3);
        it++;
        float rr;
        if ((st = im_dot(c, w->r, w->r, &rr)) != CS_OK) return st;
        if (!(sqrtf(rr) > target)) break;
        im_vcycle(c, 0, w->r, w->z);
        float rz2;
        if ((st = im_dot(c, w->r, w->z, &rz2)) != CS_OK) return st;
        const float beta = rz2 / rz;
        rz = rz2;
        k_im_cg_dir<<<nb3, IM_THREADS, 0, c->stream>>>(w->p, w->z, beta, n3);
    }
    *its = it;
    CUDA_CHECK(cudaGetLastError());
    return CS_OK;
}

/* One part of a substep, of length h (part of implicit_cpu.c): from state[cur] into state[cur ^ 1],
 * which then holds the state; torn springs counted into the flags. */
static cs_status im_part(cuda_ctx *c, const cs_phys *p0, float h, cs_solver_stats *stats)
{
    im_work *w = c->im;
    cs_phys P = *p0; /* the part's own step */
    const cs_phys *p = &P;
    P.dt = h, P.hdt = 0.5f * h;
    if (P.plastic_rate > 0.0f) P.plastic_f = P.plastic_rate * h < 1.0f ? P.plastic_rate * h : 1.0f;
    cs_status st = im_scene(c, p);
    if (st != CS_OK) return st;
    const int32_t n = p->n;
    const unsigned nb = im_blocks(n);
    float *S = c->vb.state[c->cur ^ 1];
    const float *L0 = c->vb.rest[c->rest_cur];
    const float inv_h = 1.0f / h;
    /* the largest coordinate at the part's start, for float's floor */
    k_im_reach<<<(unsigned)w->nchunks, CS_CHUNK, sizeof(float) * CS_CHUNK, c->stream>>>(w->sc, c->vb.state[c->cur],
                                                                                        w->part);
    CUDA_CHECK(cudaGetLastError());
    CUDA_CHECK(cudaMemcpyAsync(w->host_part, w->part, sizeof(float) * (size_t)w->nchunks, cudaMemcpyDeviceToHost,
                               c->stream));
    k_im_begin<<<nb, IM_THREADS, 0, c->stream>>>(w->sc, c->vb.state[c->cur], S, w->base, c->vb.mask, w->lv[0].mask, 1);
    /* the rocks over the part without the cloth, and the mass they lend, from the part's start
     * (after k_im_begin: it reads level 0's mask) */
    const int rocks = c->host_sc.nr > 0;
    if (rocks) k_im_rocks_begin<<<1, 1, 0, c->stream>>>(w->sc, im_rocks(c, c->vb.state[c->cur], L0), h);
    CUDA_CHECK(cudaStreamSynchronize(c->stream));
    float reach = 0.0f;
    for (int32_t q = 0; q < w->nchunks; q++) reach = w->host_part[q] > reach ? w->host_part[q] : reach;
    const int most = p->solver_iterations;
    float r;
    if ((st = im_assemble(c, S, L0, 1, rocks, &r)) != CS_OK) return st;
    const float r0 = r;
    int k = 0;
    float prev = 2.0f * r0 + 1.0f;
    /* Newton: stops as implicit_cpu.c's does (the tolerance, float rounding's floor,
     * solver_iterations, or an iteration that no longer halves the residual) */
    const float rounding = cs_im_float_floor(p, reach);
    while (k < most && r > p->solver_tolerance * r0 && r > rounding && r < 0.5f * prev) {
        prev = r;
        im_hierarchy(c);
        const float aim = 0.5f * p->solver_tolerance * r0, step = 0.05f * r;
        int its = 0;
        if ((st = im_pcg(c, aim > step ? aim : step, p->cg_iterations, &its)) != CS_OK) return st;
        stats->cg += its;
        /* the backtracking line search: a = 1, 1/2, 1/4, 1/8 while the residual does not fall */
        k_im_keep<<<nb, IM_THREADS, 0, c->stream>>>(S, w->xo, n);
        float a = 1.0f, rn = r;
        for (int tries = 0; tries < 4; tries++, a *= 0.5f) {
            k_im_move<<<nb, IM_THREADS, 0, c->stream>>>(S, w->xo, w->dx, w->base, w->lv[0].mask, a, inv_h, n);
            if ((st = im_assemble(c, S, L0, 1, rocks, &rn)) != CS_OK) return st;
            if (rn < r) break;
        }
        if (!(rn < r)) { /* no step along dx helps: back to x_k, and stop */
            k_im_move<<<nb, IM_THREADS, 0, c->stream>>>(S, w->xo, w->dx, w->base, w->lv[0].mask, 0.0f, inv_h, n);
            if ((st = im_assemble(c, S, L0, 1, rocks, &rn)) != CS_OK) return st;
            prev = rn;
        }
        k++;
        r = rn;
    }
    stats->newton += k;
    const float rel = r0 > 0.0f ? r / r0 : 0.0f;
    stats->residual = rel > stats->residual ? rel : stats->residual;
    stats->substeps++;
    if (rocks) {
        /* the rocks follow their vertices, rocks and cloth pushed apart, the approach stopped,
         * friction */
        k_im_rocks_push<<<1, 1, 0, c->stream>>>(w->sc, im_rocks(c, S, L0), h);
    }
    k_im_accel<<<nb, IM_THREADS, 0, c->stream>>>(S, w->base, w->lv[0].mask, c->vb.acc, inv_h, n);
    c->cur ^= 1;
    if (p->strain_on) {
        /* symplectic Euler's strain pass (cs_strain_update per owned spring, as cs_cpu_strain_row)
         * on the new positions, with the part's phys */
        k_strain<<<nb, 256, 0, c->stream>>>(w->sc, bufs_of(c, c->cur, c->rest_cur));
        c->rest_cur ^= 1;
    }
    CUDA_CHECK(cudaGetLastError());
    return CS_OK;
}

/* Substeps of implicit_euler on the device state (cs_im_step of implicit_cpu.c): the solver's
 * statistics into rep; torn springs and a non-finite state into the flags. */
static cs_status im_step(cuda_ctx *c, const cs_model *m, int32_t substeps, cs_step_report *rep)
{
    const cs_phys *p = &m->phys;
    cs_solver_stats stats;
    memset(&stats, 0, sizeof stats);
    rep->solver = stats;
    cs_status st = im_fit(c, p);
    if (st != CS_OK) return st;
    im_work *w = c->im;
    const int32_t nr = c->host_sc.nr;
    for (int32_t k = 0; k < substeps; k++) {
        /* fastest() of implicit_cpu.c: how fast the cloth closes on a rock near it (0 without rocks) */
        float rate = 0.0f;
        if (nr > 0) {
            k_im_fastest_chunks<<<(unsigned)w->nchunks, CS_CHUNK, sizeof(float) * CS_CHUNK, c->stream>>>(
                c->sc, c->rb.rocks, c->vb.state[c->cur], p->dt, w->part);
            k_im_fastest<<<1, 1, 0, c->stream>>>(w->part, w->nchunks, w->fast);
            CUDA_CHECK(cudaGetLastError());
            CUDA_CHECK(cudaMemcpyAsync(w->host_part, w->fast, sizeof(float), cudaMemcpyDeviceToHost, c->stream));
            CUDA_CHECK(cudaStreamSynchronize(c->stream));
            rate = w->host_part[0];
        }
        const int32_t parts = cs_im_splits(rate, p->dt, p->most_splits);
        const float h = p->dt / (float)parts;
        for (int32_t q = 0; q < parts; q++)
            if ((st = im_part(c, p, h, &stats)) != CS_OK) return st;
    }
    k_im_finite<<<im_blocks(p->n), IM_THREADS, 0, c->stream>>>(c->vb.state[c->cur], p->n, c->rb.rocks, nr, c->flags);
    CUDA_CHECK(cudaGetLastError());
    rep->solver = stats;
    return CS_OK;
}

/* cs_im_refresh: the accelerations a = F/m of the state as it is (the force law at v = v_n). */
static cs_status im_refresh(cuda_ctx *c, const cs_model *m)
{
    const cs_phys *p = &m->phys;
    cs_status st = im_fit(c, p);
    if (st == CS_OK) st = im_scene(c, p);
    if (st != CS_OK) return st;
    im_work *w = c->im;
    float *S = c->vb.state[c->cur];
    k_im_begin<<<im_blocks(p->n), IM_THREADS, 0, c->stream>>>(w->sc, S, NULL, w->base, c->vb.mask, w->lv[0].mask, 0);
    float r;
    /* nothing carried (the rocks are left as they are): the cloth's own force */
    if ((st = im_assemble(c, S, c->vb.rest[c->rest_cur], 0, 0, &r)) != CS_OK) return st;
    k_im_refresh_accel<<<im_blocks(p->n), IM_THREADS, 0, c->stream>>>(w->sc, w->R, w->lv[0].mask, c->vb.acc);
    CUDA_CHECK(cudaGetLastError());
    return CS_OK;
}

/* Accelerations of cloth and rocks from the current state, on the device; nothing waits. */
static cs_status cuda_refresh(void *ctx, const cs_model *m, cs_state *s)
{
    cuda_ctx *c = (cuda_ctx *)ctx;
    (void)m, (void)s;
    c->pending = 1;
    const cs_status st = join_batch(c);
    if (st != CS_OK) return st;
    if (m->phys.integrator == CS_IMPLICIT_EULER) {
        const cs_status is = im_refresh(c, m);
        c->frame_call = -1;
        return is;
    }
    cloth(c, MODE_ACCEL, false, c->cur, c->rest_cur);
    CUDA_CHECK(cudaGetLastError());
    rocks(c, ROCKS_ACCEL, c->cur, c->rest_cur);
    CUDA_CHECK(cudaGetLastError());
    c->frame_call = -1;
    return CS_OK;
}

/* One graph's kernels onto the stream (for capture), from buffer parities pos, rest. */
static void enqueue_graph(const cuda_ctx *c, const graph_key *k)
{
    int pos = k->pos, rest = k->rest;
    const cs_phys *p = &c->host_sc.p;
    const bool strain = k->strain != 0;
    if (k->integrator == CS_VELOCITY_VERLET) {
        const unsigned vblocks = (unsigned)((p->n + 255) / 256);
        k_drift_first<<<vblocks, 256, 0, c->stream>>>(c->sc, bufs_of(c, pos ^ 1, rest)); /* out = state[pos] */
        for (int32_t it = 0; it < k->len; it++) {
            const bool last = it == k->len - 1;
            cloth(c, last ? MODE_VERLET_LAST : MODE_VERLET, strain, pos, rest);
            rocks(c, last ? ROCKS_VERLET_LAST : ROCKS_VERLET, pos, rest);
            pos ^= 1;
            if (strain) rest ^= 1;
        }
    } else {
        for (int32_t it = 0; it < k->len; it++) {
            const bool last = it == k->len - 1;
            cloth(c, last ? MODE_EULER_LAST : MODE_EULER, false, pos, rest);
            rocks(c, ROCKS_EULER, pos, rest);
            pos ^= 1;
            if (strain) {
                const unsigned vblocks = (unsigned)((p->n + 255) / 256);
                k_strain<<<vblocks, 256, 0, c->stream>>>(c->sc, bufs_of(c, pos, rest));
                rest ^= 1;
            }
        }
    }
}

/* Captures a graph of this shape with the current buffers. */
static cs_status capture(cuda_ctx *c, const graph_key *k, cudaGraph_t *out)
{
    CUDA_CHECK(cudaStreamBeginCapture(c->stream, cudaStreamCaptureModeThreadLocal));
    enqueue_graph(c, k);
    const cudaError_t launched = cudaGetLastError();
    const cudaError_t ended = cudaStreamEndCapture(c->stream, out);
    if (launched != cudaSuccess) {
        if (ended == cudaSuccess) cudaGraphDestroy(*out);
        return cuda_fail(c, launched, "a launch while capturing a graph", __LINE__);
    }
    CUDA_CHECK(ended);
    return CS_OK;
}

/* The graph for this shape: kept, updated in place when only pointers or rock launch sizes
 * changed, or built. */
static cs_status graph_for(cuda_ctx *c, const graph_key *k, cudaGraphExec_t *out)
{
    const int32_t nr = c->host_sc.nr;
    graph_entry *e = NULL;
    for (int g = 0; g < c->n_graphs; g++)
        if (memcmp(&c->graphs[g].key, k, sizeof *k) == 0) e = &c->graphs[g];
    if (e && e->epoch == c->epoch && (k->rocks != 2 || e->nr == nr)) {
        e->used = ++c->uses;
        *out = e->exec;
        return CS_OK;
    }
    cudaGraph_t graph;
    cs_status st = capture(c, k, &graph);
    if (st != CS_OK) return st;
    if (e) {
        cudaGraphExecUpdateResultInfo info;
        if (cudaGraphExecUpdate(e->exec, graph, &info) == cudaSuccess) {
            cudaGraphDestroy(graph);
            e->epoch = c->epoch, e->nr = nr, e->used = ++c->uses;
            *out = e->exec;
            return CS_OK;
        }
        (void)cudaGetLastError(); /* the update was refused: build it anew */
        cudaGraphExecDestroy(e->exec);
        *e = c->graphs[--c->n_graphs];
    }
    if (c->n_graphs == GRAPHS) { /* drop the least recently used */
        int old = 0;
        for (int g = 1; g < GRAPHS; g++)
            if (c->graphs[g].used < c->graphs[old].used) old = g;
        cudaGraphExecDestroy(c->graphs[old].exec);
        c->graphs[old] = c->graphs[--c->n_graphs];
    }
    cudaGraphExec_t exec;
    const cudaError_t ie = cudaGraphInstantiate(&exec, graph, 0);
    cudaGraphDestroy(graph);
    if (ie != cudaSuccess) return cuda_fail(c, ie, "cudaGraphInstantiate", __LINE__);
    graph_entry *n = &c->graphs[c->n_graphs++];
    n->key = *k;
    n->exec = exec;
    n->epoch = c->epoch;
    n->nr = nr;
    n->used = ++c->uses;
    *out = exec;
    return CS_OK;
}

/* Substeps of one graph: a frame, at most GRAPH_MAX. */
static int32_t graph_len(const cs_model *m) { return m->substeps < GRAPH_MAX ? m->substeps : GRAPH_MAX; }

/* After a step call: the parts of the state the host read of the last frame, copied on the device
 * (the next call overwrites the state) and then, on the copy stream, into pinned memory. */
static cs_status copy_frame(cuda_ctx *c)
{
    const unsigned parts = c->wanted & (CS_SYNC_POSITIONS | CS_SYNC_VELOCITIES | CS_SYNC_ROCKS);
    c->wanted = 0;
    c->frame_call = -1;
    if (!parts) return CS_OK;
    c->pending = 1;
    const int k = c->slot ^= 1;
    const size_t n = (size_t)c->vb.n, f3 = 3 * sizeof(float) * n;
    const size_t rocks = sizeof(cs_rock_state) * (size_t)c->host_sc.nr;
    /* The copy made two calls ago from this slot must be done before the slot is rewritten. */
    CUDA_CHECK(cudaStreamWaitEvent(c->stream, c->copied[k], 0));
    const float *st = c->vb.state[c->cur];
    if (parts & CS_SYNC_POSITIONS)
        CUDA_CHECK(cudaMemcpyAsync(c->vb.frame_dev[k], st, f3, cudaMemcpyDeviceToDevice, c->stream));
    if (parts & CS_SYNC_VELOCITIES)
        CUDA_CHECK(cudaMemcpyAsync(c->vb.frame_dev[k] + 3 * n, st + 3 * n, f3, cudaMemcpyDeviceToDevice, c->stream));
    if ((parts & CS_SYNC_ROCKS) && rocks)
        CUDA_CHECK(cudaMemcpyAsync(c->rb.frame_rocks_dev[k], c->rb.rocks, rocks, cudaMemcpyDeviceToDevice, c->stream));
    CUDA_CHECK(cudaEventRecord(c->ready[k], c->stream));
    CUDA_CHECK(cudaStreamWaitEvent(c->copy, c->ready[k], 0));
    if (parts & CS_SYNC_POSITIONS)
        CUDA_CHECK(cudaMemcpyAsync(c->vb.frame_host[k], c->vb.frame_dev[k], f3, cudaMemcpyDeviceToHost, c->copy));
    if (parts & CS_SYNC_VELOCITIES)
        CUDA_CHECK(cudaMemcpyAsync(c->vb.frame_host[k] + 3 * n, c->vb.frame_dev[k] + 3 * n, f3, cudaMemcpyDeviceToHost,
                                   c->copy));
    if ((parts & CS_SYNC_ROCKS) && rocks)
        CUDA_CHECK(cudaMemcpyAsync(c->rb.frame_rocks_host[k], c->rb.frame_rocks_dev[k], rocks, cudaMemcpyDeviceToHost,
                                   c->copy));
    CUDA_CHECK(cudaEventRecord(c->copied[k], c->copy));
    c->frame_call = c->calls;
    c->frame_parts = parts;
    c->frame_waited = 0;
    return CS_OK;
}

/* After a step call's substeps are queued: the buffers that now hold the state (each substep
 * swaps the state's; the drift of a graph's first substep is in place), and the frame. */
static void advance(cuda_ctx *c, int32_t substeps, bool strain)
{
    c->cur ^= substeps & 1;
    if (strain) c->rest_cur ^= substeps & 1;
    c->calls++;
}

static cs_status cuda_step(void *ctx, const cs_model *m, cs_state *s, int32_t substeps, cs_step_report *rep)
{
    cuda_ctx *c = (cuda_ctx *)ctx;
    (void)s;
    rep->torn = 0;
    rep->finite = 1;
    if (substeps <= 0) return CS_OK;
    const cs_status js = join_batch(c);
    if (js != CS_OK) return js;
    CUDA_CHECK(cudaMemsetAsync(c->flags, 0, FLAG_COUNT * sizeof(int), c->stream));
    const int strain = m->phys.strain_on != 0;
    const int implicit = m->phys.integrator == CS_IMPLICIT_EULER;
    if (implicit) {
        /* implicit_euler: its own launches, which swap the buffers as they go (no advance) */
        const cs_status is = im_step(c, m, substeps, rep);
        if (is != CS_OK) return is;
        c->calls++;
    }
    for (int32_t left = implicit ? 0 : substeps; left > 0;) {
        graph_key k;
        memset(&k, 0, sizeof k);
        k.len = left < graph_len(m) ? left : graph_len(m);
        k.integrator = m->phys.integrator;
        k.strain = strain;
        k.rocks = rock_path(c->host_sc.nr);
        /* The buffers this graph starts from: each substep before it swapped them. */
        const int32_t done = substeps - left;
        k.pos = c->cur ^ (done & 1);
        k.rest = c->rest_cur ^ (strain ? done & 1 : 0);
        cudaGraphExec_t exec;
        const cs_status st = graph_for(c, &k, &exec);
        if (st != CS_OK) return st;
        CUDA_CHECK(cudaGraphLaunch(exec, c->stream));
        left -= k.len;
    }
    if (!implicit) advance(c, substeps, strain);
    const cs_status fs = copy_frame(c);
    if (fs != CS_OK) return fs;
    CUDA_CHECK(cudaMemcpyAsync(c->host_flags, c->flags, FLAG_COUNT * sizeof(int), cudaMemcpyDeviceToHost, c->stream));
    CUDA_CHECK(cudaStreamSynchronize(c->stream));
    c->pending = 0;
    rep->torn = c->host_flags[FLAG_TORN];
    rep->finite = c->host_flags[FLAG_NONFINITE] == 0;
    return CS_OK;
}

static void free_batch_arrays(batch_ctx *b)
{
    cudaFree(b->tab);
    cudaFree(b->start);
    cudaFree(b->flags);
    cudaFreeHost(b->host_tab);
    cudaFreeHost(b->host_start);
    cudaFreeHost(b->host_flags);
    cudaFree(b->jobs);
    cudaFree(b->jstart);
    cudaFreeHost(b->host_jobs);
    cudaFreeHost(b->host_jstart);
    free(b->order);
}

/* Room for n scenes (and the stream, the first time). New arrays before the old are freed. */
static cs_status batch_reserve(cuda_ctx *c, batch_ctx *b, int32_t n)
{
    if (!b->stream) CUDA_CHECK(cudaStreamCreateWithFlags(&b->stream, cudaStreamNonBlocking));
    if (!b->copy) CUDA_CHECK(cudaStreamCreateWithFlags(&b->copy, cudaStreamNonBlocking));
    if (!b->frames) CUDA_CHECK(cudaEventCreateWithFlags(&b->frames, cudaEventDisableTiming));
    if (n <= b->cap) return CS_OK;
    int32_t cap = 64;
    while (cap < n) cap *= 2;
    batch_ctx g;
    memset(&g, 0, sizeof g);
    g.stream = b->stream, g.copy = b->copy, g.frames = b->frames;
    const size_t starts = sizeof(int32_t) * BK_COUNT * ((size_t)cap + 1), flags = sizeof(int) * FLAG_COUNT * (size_t)cap;
    cudaError_t e = cudaMalloc((void **)&g.tab, sizeof(batch_scene) * (size_t)cap);
    if (e == cudaSuccess) e = cudaMallocHost((void **)&g.host_tab, sizeof(batch_scene) * (size_t)cap);
    if (e == cudaSuccess) e = cudaMalloc((void **)&g.start, starts);
    if (e == cudaSuccess) e = cudaMallocHost((void **)&g.host_start, starts);
    if (e == cudaSuccess) e = cudaMalloc((void **)&g.flags, flags);
    if (e == cudaSuccess) e = cudaMallocHost((void **)&g.host_flags, flags);
    if (e == cudaSuccess) e = cudaMalloc((void **)&g.jobs, sizeof(frame_job) * (size_t)cap);
    if (e == cudaSuccess) e = cudaMallocHost((void **)&g.host_jobs, sizeof(frame_job) * (size_t)cap);
    if (e == cudaSuccess) e = cudaMalloc((void **)&g.jstart, sizeof(int32_t) * ((size_t)cap + 1));
    if (e == cudaSuccess) e = cudaMallocHost((void **)&g.host_jstart, sizeof(int32_t) * ((size_t)cap + 1));
    if (e == cudaSuccess && !(g.order = (int32_t *)malloc(sizeof(int32_t) * (size_t)cap))) e = cudaErrorMemoryAllocation;
    if (e != cudaSuccess) {
        free_batch_arrays(&g);
        return cuda_fail(c, e, "allocating a batch's tables", __LINE__);
    }
    free_batch_arrays(b);
    g.cap = cap;
    *b = g;
    return CS_OK;
}

/* The blocks scene d takes in each batch kernel (BK_*). */
static void batch_blocks(const cuda_ctx *c, const batch_scene *d, int32_t blocks[BK_COUNT])
{
    const cs_phys *p = &c->host_sc.p;
    const int32_t vblocks = (p->n + 255) / 256, nr = c->host_sc.nr;
    blocks[BK_DRIFT] = d->verlet ? vblocks : 0;
    blocks[BK_CLOTH] = (int32_t)cloth_blocks(p, d->tile_rows);
    blocks[BK_ROCKS] = d->rocks == 1 ? 1 : d->rocks == 2 ? (nr + BATCH_ROCK_THREADS / 32 - 1) / (BATCH_ROCK_THREADS / 32) : 0;
    blocks[BK_ROCK_MOVE] = d->rocks == 2 ? (nr + 255) / 256 : 0;
    blocks[BK_STRAIN] = !d->verlet && d->strain ? vblocks : 0;
}

/* copy_frame for the scenes of a batch, m of them in b->order, whose frames were read since their
 * last call: the device copies of all in one launch on the batch's stream, then each scene's copy
 * to its pinned buffer on the batch's copy stream. */
static cs_status batch_frames(cuda_ctx *c, batch_ctx *b, const cs_batch_item *items, int32_t m)
{
    int32_t nj = 0;
    b->host_jstart[0] = 0;
    for (int32_t j = 0; j < m; j++) {
        cuda_ctx *ck = (cuda_ctx *)items[b->order[j]].ctx;
        const unsigned parts = ck->wanted & (CS_SYNC_POSITIONS | CS_SYNC_VELOCITIES | CS_SYNC_ROCKS);
        ck->wanted = 0;
        ck->frame_call = -1;
        if (!parts) continue;
        const int k = ck->slot ^= 1;
        /* The copy made two calls ago from this slot must be done before the slot is rewritten. */
        CUDA_CHECK(cudaStreamWaitEvent(b->stream, ck->copied[k], 0));
        const size_t n = (size_t)ck->vb.n;
        const size_t lo = parts & CS_SYNC_POSITIONS ? 0 : 3 * n, hi = parts & CS_SYNC_VELOCITIES ? 6 * n : 3 * n;
        const size_t rock_words = parts & CS_SYNC_ROCKS ? sizeof(cs_rock_state) / 4 * (size_t)ck->host_sc.nr : 0;
        frame_job *f = &b->host_jobs[nj];
        f->src[0] = (const uint32_t *)(ck->vb.state[ck->cur] + lo);
        f->dst[0] = (uint32_t *)(ck->vb.frame_dev[k] + lo);
        f->words[0] = (int32_t)(hi - lo);
        f->src[1] = (const uint32_t *)ck->rb.rocks;
        f->dst[1] = (uint32_t *)ck->rb.frame_rocks_dev[k];
        f->words[1] = (int32_t)rock_words;
        const int32_t most = f->words[0] > f->words[1] ? f->words[0] : f->words[1];
        b->host_jstart[nj + 1] = b->host_jstart[nj] + (most + FRAME_WORDS_PER_BLOCK - 1) / FRAME_WORDS_PER_BLOCK;
        ck->frame_call = ck->calls;
        ck->frame_parts = parts;
        ck->frame_waited = 0;
        ck->after_batch = 1;
        b->order[nj++] = b->order[j]; /* the scenes with a job, in job order (j >= nj: not read again) */
    }
    if (nj == 0) return CS_OK;
    CUDA_CHECK(cudaMemcpyAsync(b->jobs, b->host_jobs, sizeof(frame_job) * (size_t)nj, cudaMemcpyHostToDevice, b->stream));
    CUDA_CHECK(cudaMemcpyAsync(b->jstart, b->host_jstart, sizeof(int32_t) * ((size_t)nj + 1), cudaMemcpyHostToDevice,
                               b->stream));
    if (b->host_jstart[nj] > 0) k_frames_batch<<<(unsigned)b->host_jstart[nj], 256, 0, b->stream>>>(b->jobs, b->jstart, nj);
    CUDA_CHECK(cudaGetLastError());
    CUDA_CHECK(cudaEventRecord(b->frames, b->stream));
    CUDA_CHECK(cudaStreamWaitEvent(b->copy, b->frames, 0));
    for (int32_t q = 0; q < nj; q++) {
        cuda_ctx *ck = (cuda_ctx *)items[b->order[q]].ctx;
        const frame_job *f = &b->host_jobs[q];
        const int k = ck->slot;
        const size_t lo = (size_t)(f->dst[0] - (uint32_t *)ck->vb.frame_dev[k]);
        if (f->words[0])
            CUDA_CHECK(cudaMemcpyAsync(ck->vb.frame_host[k] + lo, ck->vb.frame_dev[k] + lo, 4 * (size_t)f->words[0],
                                       cudaMemcpyDeviceToHost, b->copy));
        if (f->words[1])
            CUDA_CHECK(cudaMemcpyAsync(ck->rb.frame_rocks_host[k], ck->rb.frame_rocks_dev[k], 4 * (size_t)f->words[1],
                                       cudaMemcpyDeviceToHost, b->copy));
        CUDA_CHECK(cudaEventRecord(ck->copied[k], b->copy));
    }
    return CS_OK;
}

/* One batch on the device: c (the first scene's context) records a CUDA failure; the items' own
 * statuses say what became of each scene that ran. */
static cs_status batch_run(cuda_ctx *c, batch_ctx *b, cs_batch_item *items, int n)
{
    cs_status st = batch_reserve(c, b, n);
    if (st != CS_OK) return st;
    /* Most substeps first: the scenes still running at a substep are a prefix of the table, and
     * the launch covers only theirs blocks. */
    int32_t m = 0;
    for (int k = 0; k < n; k++) {
        if (items[k].m->phys.integrator == CS_IMPLICIT_EULER) continue; /* stepped alone (cuda_step_batch) */
        items[k].rep.torn = 0, items[k].rep.finite = 1, items[k].status = CS_OK;
        if (items[k].substeps <= 0) continue;
        int32_t at = m++;
        while (at > 0 && items[b->order[at - 1]].substeps < items[k].substeps) {
            b->order[at] = b->order[at - 1];
            at--;
        }
        b->order[at] = k;
    }
    if (m == 0) return CS_OK;
    /* Rows of a cloth block: tile_rows_for's rule over every scene's blocks. */
    int32_t tr = MAX_TILE_ROWS;
    for (;; tr >>= 1) {
        int64_t total = 0;
        for (int32_t j = 0; j < m; j++) total += cloth_blocks(&((cuda_ctx *)items[b->order[j]].ctx)->host_sc.p, tr);
        if (tr == 1 || total >= 4 * (int64_t)c->sms) break;
    }
    const size_t stride = (size_t)m + 1;
    int32_t *start = b->host_start;
    for (int q = 0; q < BK_COUNT; q++) start[(size_t)q * stride] = 0;
    size_t smem = cloth_smem(0);
    int32_t gmax[GRAPH_MAX + 1] = {0}; /* Verlet scenes' most substeps, by graph length */
    for (int32_t j = 0; j < m; j++) {
        const cs_batch_item *it = &items[b->order[j]];
        cuda_ctx *ck = (cuda_ctx *)it->ctx;
        const cs_phys *p = &it->m->phys;
        batch_scene *d = &b->host_tab[j];
        memset(d, 0, sizeof *d);
        d->sc = ck->sc;
        d->substeps = it->substeps;
        d->graph = graph_len(it->m);
        d->verlet = p->integrator == CS_VELOCITY_VERLET;
        d->strain = p->strain_on != 0;
        d->rocks = rock_path(ck->host_sc.nr);
        d->tile_rows = tr;
        for (int e = 0; e < 2; e++) {
            const int rest = ck->rest_cur ^ (d->strain ? e : 0);
            d->cloth[e] = bufs_of(ck, ck->cur ^ e, rest);
            d->swapped[e] = bufs_of(ck, ck->cur ^ e ^ 1, rest);
            d->cloth[e].flags = d->swapped[e].flags = b->flags + (size_t)j * FLAG_COUNT;
        }
        int32_t blocks[BK_COUNT];
        batch_blocks(ck, d, blocks);
        for (int q = 0; q < BK_COUNT; q++) start[(size_t)q * stride + (size_t)j + 1] = start[(size_t)q * stride + (size_t)j] + blocks[q];
        const size_t need = cloth_smem(ck->host_sc.nr > 0 ? ck->rb.cap : 0);
        smem = need > smem ? need : smem;
        if (d->verlet && d->substeps > gmax[d->graph]) gmax[d->graph] = d->substeps;
        /* What the scene's own stream holds (an upload, the last frame's copy) comes first. */
        if (ck->pending) {
            CUDA_CHECK(cudaEventRecord(ck->queued, ck->stream));
            CUDA_CHECK(cudaStreamWaitEvent(b->stream, ck->queued, 0));
        }
    }
    CUDA_CHECK(cudaMemcpyAsync(b->tab, b->host_tab, sizeof(batch_scene) * (size_t)m, cudaMemcpyHostToDevice, b->stream));
    CUDA_CHECK(cudaMemcpyAsync(b->start, start, sizeof(int32_t) * BK_COUNT * stride, cudaMemcpyHostToDevice, b->stream));
    CUDA_CHECK(cudaMemsetAsync(b->flags, 0, sizeof(int) * FLAG_COUNT * (size_t)m, b->stream));
    const int32_t *dev_start[BK_COUNT];
    for (int q = 0; q < BK_COUNT; q++) dev_start[q] = b->start + (size_t)q * stride;
    int32_t running = m; /* scenes with substeps left: the table's first `running` */
    for (int32_t s = 0; running > 0; s++) {
        while (running > 0 && b->host_tab[running - 1].substeps <= s) running--;
        if (running == 0) break;
        unsigned blocks[BK_COUNT];
        for (int q = 0; q < BK_COUNT; q++) blocks[q] = (unsigned)start[(size_t)q * stride + (size_t)running];
        int drift = 0;
        for (int32_t g = 1; g <= GRAPH_MAX && !drift; g++) drift = gmax[g] > s && s % g == 0;
        if (drift && blocks[BK_DRIFT]) k_drift_batch<<<blocks[BK_DRIFT], 256, 0, b->stream>>>(b->tab, dev_start[BK_DRIFT], running, s);
        k_cloth_batch<<<blocks[BK_CLOTH], TILE_W, smem, b->stream>>>(b->tab, dev_start[BK_CLOTH], running, s);
        if (blocks[BK_ROCKS])
            k_rocks_batch<<<blocks[BK_ROCKS], BATCH_ROCK_THREADS, 0, b->stream>>>(b->tab, dev_start[BK_ROCKS], running, s);
        if (blocks[BK_ROCK_MOVE])
            k_rock_move_batch<<<blocks[BK_ROCK_MOVE], 256, 0, b->stream>>>(b->tab, dev_start[BK_ROCK_MOVE], running, s);
        if (blocks[BK_STRAIN]) k_strain_batch<<<blocks[BK_STRAIN], 256, 0, b->stream>>>(b->tab, dev_start[BK_STRAIN], running, s);
        CUDA_CHECK(cudaGetLastError());
    }
    CUDA_CHECK(cudaMemcpyAsync(b->host_flags, b->flags, sizeof(int) * FLAG_COUNT * (size_t)m, cudaMemcpyDeviceToHost, b->stream));
    CUDA_CHECK(cudaStreamSynchronize(b->stream));
    /* The batch is done, and what the scenes' streams held before it: what each takes next comes
     * after it. */
    for (int32_t j = 0; j < m; j++) {
        cs_batch_item *it = &items[b->order[j]];
        cuda_ctx *ck = (cuda_ctx *)it->ctx;
        ck->pending = 0;
        it->rep.torn = b->host_flags[(size_t)j * FLAG_COUNT + FLAG_TORN];
        it->rep.finite = b->host_flags[(size_t)j * FLAG_COUNT + FLAG_NONFINITE] == 0;
        advance(ck, it->substeps, b->host_tab[j].strain != 0);
    }
    return batch_frames(c, b, items, m);
}

/* Every scene of the batch advanced by one launch per kernel and substep (step_batch of
 * backend.h); scenes created on another device than the first's step alone. */
static cs_status cuda_step_batch(cs_batch_item *items, int n)
{
    if (n <= 0) return CS_OK;
    cuda_ctx *c = (cuda_ctx *)items[0].ctx;
    for (int k = 1; k < n; k++)
        if (((cuda_ctx *)items[k].ctx)->dev != c->dev) {
            for (int j = 0; j < n; j++)
                items[j].status = cuda_step(items[j].ctx, items[j].m, items[j].s, items[j].substeps, &items[j].rep);
            return CS_OK;
        }
    /* implicit_euler runs its own sequence of launches: those scenes step alone, as the CPU
     * backend's cpu_step_batch does; batch_run leaves them out. */
    for (int k = 0; k < n; k++)
        if (items[k].m->phys.integrator == CS_IMPLICIT_EULER) {
            memset(&items[k].rep, 0, sizeof items[k].rep);
            items[k].status = cuda_step(items[k].ctx, items[k].m, items[k].s, items[k].substeps, &items[k].rep);
        }
    std::lock_guard<std::mutex> hold(batch_lock);
    const cs_status st = batch_run(c, &batch, items, n);
    if (st != CS_OK) {
        (void)cudaStreamSynchronize(batch.stream); /* nothing left running on the staging */
        (void)cudaGetLastError();
        for (int k = 1; k < n; k++) snprintf(((cuda_ctx *)items[k].ctx)->err, sizeof c->err, "%s", c->err);
    }
    return st;
}

static cs_status cuda_download(void *ctx, const cs_model *m, cs_state *s, unsigned what)
{
    cuda_ctx *c = (cuda_ctx *)ctx;
    (void)m;
    const size_t n = (size_t)s->n, f = sizeof(float) * n;
    c->wanted |= what;
    /* What the frame copied ahead holds: wait for that copy only. */
    unsigned from_frame = c->frame_call == c->calls ? what & c->frame_parts : 0;
    if (!(c->host_sc.nr)) from_frame &= ~(unsigned)CS_SYNC_ROCKS;
    if (from_frame) {
        const int k = c->slot;
        if (!c->frame_waited) CUDA_CHECK(cudaEventSynchronize(c->copied[k]));
        c->frame_waited = 1;
        const float *h = c->vb.frame_host[k];
        float *pos[] = {s->x, s->y, s->z}, *vel[] = {s->vx, s->vy, s->vz};
        if (from_frame & CS_SYNC_POSITIONS)
            for (int q = 0; q < 3; q++) memcpy(pos[q], h + (size_t)q * n, f);
        if (from_frame & CS_SYNC_VELOCITIES)
            for (int q = 0; q < 3; q++) memcpy(vel[q], h + (size_t)(3 + q) * n, f);
        if (from_frame & CS_SYNC_ROCKS)
            memcpy(s->rocks, c->rb.frame_rocks_host[k], sizeof(cs_rock_state) * (size_t)s->n_rocks);
        what &= ~from_frame;
    }
    /* The rest from the device's current buffers, into pageable memory: each copy is done when it
     * returns. (A batch's frame copy may still be reading the state too: nothing here writes it.) */
    if (what) c->pending = 1;
    const float *st = c->vb.state[c->cur];
    float *arrays[] = {s->x, s->y, s->z, s->vx, s->vy, s->vz};
    for (int q = 0; q < 6; q++)
        if (what & (q < 3 ? CS_SYNC_POSITIONS : CS_SYNC_VELOCITIES))
            CUDA_CHECK(cudaMemcpyAsync(arrays[q], st + (size_t)q * n, f, cudaMemcpyDeviceToHost, c->stream));
    float *acc[] = {s->ax, s->ay, s->az};
    if (what & CS_SYNC_ACCELERATIONS)
        for (int q = 0; q < 3; q++)
            CUDA_CHECK(cudaMemcpyAsync(acc[q], c->vb.acc + (size_t)q * n, f, cudaMemcpyDeviceToHost, c->stream));
    if (what & CS_SYNC_REST)
        CUDA_CHECK(cudaMemcpyAsync(s->L0, c->vb.rest[c->rest_cur], CS_NTYPES * f, cudaMemcpyDeviceToHost, c->stream));
    if ((what & CS_SYNC_ROCKS) && s->n_rocks)
        CUDA_CHECK(cudaMemcpyAsync(s->rocks, c->rb.rocks, sizeof(cs_rock_state) * (size_t)s->n_rocks,
                                   cudaMemcpyDeviceToHost, c->stream));
    return CS_OK;
}

/* The device's memory bandwidth by its clock and bus (0 where it does not say). */
static double peak_bandwidth(int dev)
{
    int khz = 0, bits = 0;
    if (cudaDeviceGetAttribute(&khz, cudaDevAttrMemoryClockRate, dev) != cudaSuccess ||
        cudaDeviceGetAttribute(&bits, cudaDevAttrGlobalMemoryBusWidth, dev) != cudaSuccess) {
        (void)cudaGetLastError();
        return 0;
    }
    return 2.0 * (double)khz * 1e3 * (double)bits / 8.0; /* double data rate */
}

/* The cost model (backend.h): the distinct bytes each kernel reads and writes per vertex, from the
 * loads and stores written above; tests/gpu/test_datapath.c holds it to what the CPU imitation of
 * CUDA sees the kernels touch. Per vertex of the cloth kernel: the state read (6 floats), the
 * mask (1 byte), the six owned rest lengths, the state written; with strain the change byte (read
 * and, where it flips, written) and the rest lengths of vertices whose springs are changing (none
 * at rest); the acceleration where a graph ends. (A vertex at a border owns fewer springs.) Rock kernels scale with rocks, not vertices. */
/* implicit_euler's rows: its launches scale with the solver's iterations, which depend on the
 * state, so the model takes nominal counts - IM_NEWTON Newton iterations a substep, each with one
 * line-search assembly and IM_CG conjugate-gradient iterations (about what the default cloth takes:
 * MODEL.md's table) - and the bytes per vertex each kernel's loads and stores name (a vertex's
 * own; neighbours' reads come from cache). A V-cycle's coarse levels add about a third of level 0's
 * traffic (2 x 2 aggregation), counted in its rows. Rough by design: what bench measures is the
 * truth; the copies of the partials back to the host (4 bytes a chunk) and the waits for them, one
 * per sum, are not bytes a vertex but they bound a small cloth's speed. */
#define IM_NEWTON 3.0
#define IM_CG 5.0
static void im_cost(const cs_model *m, int32_t n_rocks, cs_cost_model *out)
{
    const cs_phys *p = &m->phys;
    const double F = m->substeps, N = IM_NEWTON, C = IM_CG, levels = 4.0 / 3.0;
    const bool strain = p->strain_on != 0;
    /* A block as stored (its upper triangle: 24 bytes); a level's matrix per vertex: D and the four
     * forward blocks (120 bytes); level 0's bending blocks (48). Rows: bytes a vertex per run, runs
     * a substep, launches a run. */
    const double blk = 4.0 * CS_IM_SYM, blocks = 5 * blk, bend = 2 * blk;
    /* a V-cycle's launches: per level above the coarsest a sweep each way, three products A x, the
     * residual, restriction and prolongation; the coarsest's 16 sweeps (the default 4 levels) */
    const double vcycle_launches = 3.0 * 7.0 + 2.0 * CS_IM_COARSE_SWEEPS - 1.0;
#define IM_ROW(name, rd, wr, runs, launches) cs_cost_add(out, name, rd, wr, 0, runs, (runs) * F * (launches))
    IM_ROW("k_im_reach (the part's largest coordinate)", 12.0, 0.0, 1.0, 1.0);
    IM_ROW("k_im_begin (x_n, v_n kept; the first guess)", 24.0 + 1.0, 24.0 + 4.0 + 24.0, 1.0, 1.0);
    /* the state (24), x_n's velocity (12), rest lengths (24), mask (4); R, the springs' force,
     * level 0's D, forward and bending blocks */
    IM_ROW("k_im_assemble (residual and level 0's matrix)", 64.0, 12.0 + 12.0 + blocks + bend, 1.0 + N, 1.0);
    /* each coarse level's Galerkin product reads the finer level's blocks and writes its own;
     * every level's Dinv */
    IM_ROW("k_im_galerkin, k_im_inverse (the hierarchy)", levels * blk + 0.25 * levels * (blocks + 4.0),
           levels * blk + 0.25 * levels * (blocks + 4.0), N, 7.0);
    /* per CG iteration: A p with bending (the blocks, p, the mask; A p written), three dot
     * products, the two vector updates, a V-cycle (smoothing sweeps, products, residual,
     * restriction, prolongation; the coarse levels a third more than level 0) */
    IM_ROW("k_im_apply (A p, bending included)", blocks + bend + 12.0 + 4.0, 12.0, N * C, 1.0);
    IM_ROW("k_im_dot (chunk partials)", 24.0, 0.0, N * (3.0 * C + 1.0), 1.0);
    IM_ROW("k_im_cg_step, k_im_cg_dir", 48.0 + 24.0, 24.0 + 12.0, N * C, 2.0);
    IM_ROW("V-cycle (k_im_jacobi, k_im_apply, k_im_sub, k_im_restrict, k_im_prolong)",
           levels * (2 * (blk + 40.0) + 3 * (blocks + 16.0) + 24.0 + 12.0 + 24.0),
           levels * (2 * 12.0 + 3 * 12.0 + 12.0 + 3.0 + 12.0), N * (C + 1.0), vcycle_launches);
    IM_ROW("k_im_keep, k_im_move (the line search)", 12.0 + 12.0 + 12.0 + 12.0 + 4.0, 12.0 + 24.0, N, 2.0);
    if (n_rocks > 0) {
        /* With rocks (nominally one part a substep; contact cuts substeps into more): the
         * substep's closing rate (positions and velocities; the rocks), and a part's rock steps -
         * the one-thread kernels scan the cloth twice for each rock for its candidates (positions
         * and, surface model, rest lengths: about 28 bytes a vertex) and twice for its friction
         * (positions, start, velocities, the carried rock, mass and normal, what the push moved:
         * about 60 bytes a vertex, the push's mark cleared: 4), read the rock carried (4) and
         * write it with the mass and normal (20) */
        const double rock = (double)sizeof(cs_rock_state) * n_rocks;
        cs_cost_add(out, "k_im_fastest_chunks, k_im_fastest (a substep's parts)", 24.0, 0.0, rock, 1.0, 2.0 * F);
        cs_cost_add(out, "k_im_rocks_begin, k_im_rocks_push (one thread)",
                    n_rocks * (2.0 * 28.0 + 2.0 * 60.0) + 4.0 + 24.0 + 4.0, 20.0 + 4.0 * n_rocks, 3.0 * rock, 1.0,
                    2.0 * F);
    }
    IM_ROW("k_im_accel", 24.0 + 4.0, 12.0, 1.0, 1.0);
    if (strain) IM_ROW("k_strain", 12.0 + 24.0 + 1.0, 0.0, 1.0, 1.0);
    IM_ROW("k_im_finite (a step call's end)", 24.0, 0.0, 1.0 / F, 1.0);
#undef IM_ROW
    cs_cost_add(out, "frame copy (positions, on the device)", 12.0, 12.0, 0, 1.0 / F, 0);
    out->graphs_per_frame = 0.0; /* plain launches */
    /* every launch waits for the one before */
    out->nodes_per_substep = out->launches_per_frame / F;
    /* stepped alone in a batch (cuda_step_batch): every launch and copy is its own call */
    out->batch_calls_per_scene = out->launches_per_frame;
    out->batch_calls_per_read_scene = out->launches_per_frame + 3.0;
}

static void cuda_cost(const cs_model *m, int32_t n_rocks, cs_cost_model *out)
{
    const cs_phys *p = &m->phys;
    if (p->integrator == CS_IMPLICIT_EULER) {
        memset(out, 0, sizeof *out);
        im_cost(m, n_rocks, out);
        return;
    }
    const double G = graph_len(m), F = m->substeps, graphs = ceil(F / G);
    const bool verlet = p->integrator == CS_VELOCITY_VERLET, strain = p->strain_on != 0;
    const double rock = (double)sizeof(cs_rock_state);
    memset(out, 0, sizeof *out);
    /* A vertex reads the rest lengths of the springs it owns that the grid has. */
    const double nx = p->nx, ny = p->ny;
    const double springs = (nx - 1) * ny + nx * (ny - 1) + 2 * (nx - 1) * (ny - 1) + (nx - 2) * ny + nx * (ny - 2);
    const double cloth_read = 24.0 + 1.0 + 4.0 * springs / (nx * ny) + (verlet && strain ? 1.0 : 0.0);
    const double last = (G - 1.0) / G, once = 1.0 / G;
    const char *name = verlet ? "k_cloth (velocity Verlet)" : "k_cloth (symplectic Euler)";
    const char *name_last = verlet ? "k_cloth (the last substep of a graph)" : "k_cloth (the last substep of a graph, Euler)";
    /* Culling reads each rock's centre and radius, the group sums its word of each chunk group
     * (and 24 bytes for each chunk that touched it: contact-dependent, not modelled). */
    const double ng = ceil((double)p->nchunks / CS_CHUNK_GROUP);
    const double cull = (16.0 + 8.0 * ng) * n_rocks;
    cs_cost_add(out, name, cloth_read, 24.0, cull, last, F - graphs);
    cs_cost_add(out, name_last, cloth_read, 24.0 + 12.0, cull, once, graphs);
    if (verlet) cs_cost_add(out, "k_drift_first (the first substep of a graph)", 36.0, 24.0, 2 * rock * n_rocks, once, graphs);
    if (!verlet && strain) cs_cost_add(out, "k_strain", 12.0 + 24.0 + 1.0, 0.0, 0.0, 1.0, F);
    if (n_rocks > 0) {
        /* Each rock: its state read (by every warp: the same bytes), its hit words read, its state
         * written; plus 24 bytes for each chunk group that touched it (contact-dependent, not
         * modelled). */
        const double nr = n_rocks;
        if (n_rocks <= ROCKS_FUSED)
            cs_cost_add(out, "k_rocks (forces and moves, one block)", 0, 0, nr * (rock + 8.0 * ng + rock), 1.0, F);
        else {
            cs_cost_add(out, "k_rock_force (a warp per rock)", 0, 0, nr * (rock + 8.0 * ng + 24.0), 1.0, F);
            cs_cost_add(out, "k_rock_move", 0, 0, nr * 2 * rock, 1.0, F);
        }
    }
    /* The frame the host reads, copied on the device once per step call. */
    cs_cost_add(out, "frame copy (positions, on the device)", 12.0, 12.0, 0, 1.0 / F, 0);
    out->graphs_per_frame = graphs;
    /* batch_run: nothing for a scene whose stream is idle; batch_frames, its positions read: a
     * wait for the slot's last copy, the copy to pinned memory, an event (the device copies are
     * one launch for the batch). */
    out->batch_calls_per_scene = 0.0;
    out->batch_calls_per_read_scene = 3.0;
    out->nodes_per_substep = 1.0 + (n_rocks > 0 ? (n_rocks <= ROCKS_FUSED ? 1.0 : 2.0) : 0.0) +
                             (!verlet && strain ? 1.0 : 0.0) + (verlet ? 1.0 / G : 0.0);
}

static void cuda_stats(void *ctx, const cs_model *m, cs_backend_stats *out)
{
    cuda_ctx *c = (cuda_ctx *)ctx;
    cs_cost_model cm;
    cuda_cost(m, c->host_sc.nr, &cm);
    out->bytes_per_vertex_substep = cm.bytes_per_vertex_substep;
    out->peak_bandwidth = peak_bandwidth(c->dev);
}

static const char *cuda_device(void *ctx, const cs_model *) { return ((cuda_ctx *)ctx)->device; }
static const char *cuda_error(void *ctx) { return ((cuda_ctx *)ctx)->err; }

static const cs_backend cuda_backend = {
    "cuda", cuda_available, cuda_create, cuda_destroy, cuda_upload, cuda_download, cuda_refresh, cuda_step,
    cuda_device, cuda_error, cuda_stats, cuda_cost, CS_CAP_SURFACE_CONTACT | CS_CAP_IMPLICIT | CS_CAP_IMPLICIT_ROCKS,
    cuda_step_batch,
};

extern "C" const cs_backend *cs_backend_cuda(void) { return &cuda_backend; }
