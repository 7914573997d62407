/* batch_kernel_impl.cuh - a batch's kernels: many scenes, one launch per kernel per substep, each
 * block running the block function of cloth_kernel_impl.cuh or rocks_kernel_impl.cuh for its
 * scene; and the launch that copies the batch's frames on the device. Device code.
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
 * A block finds its scene by binary search, and its place within the scene's launch, and runs the
 * block function with the same arguments a lone launch gives it. Scenes past their substeps exit. */
#ifndef CLOTHSIM_CUDA_BATCH_KERNEL_IMPL_CUH
#define CLOTHSIM_CUDA_BATCH_KERNEL_IMPL_CUH

#include "cloth_kernel_impl.cuh"
#include "rocks_kernel_impl.cuh"

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

#endif /* CLOTHSIM_CUDA_BATCH_KERNEL_IMPL_CUH */
