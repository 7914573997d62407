/* graphs_cuda.cuh - the explicit integrators' substeps on the host: the launches of the cloth and
 * rock kernels for a substep, the CUDA graphs that hold a frame of them, and which buffers hold
 * the state once they are queued. Part of the one translation unit backend_cuda.cu.
 *
 * A step call runs as CUDA graphs of at most one frame of substeps (GRAPH_MAX), kept per shape and
 * buffer parity and updated in place (cudaGraphExecUpdate) when only pointers or launch sizes
 * change; what changes with commands (parameters, grab, rocks' count) is read from device memory.
 * After a call whose frame was read, the positions (and velocities, rocks) are copied on the
 * device, then to pinned double buffers on a second stream, overlapping whatever comes next; a
 * read waits for that copy only. Everything else (rest lengths, accelerations) is copied when a
 * snapshot, a hash or a command asks. */
#ifndef CLOTHSIM_CUDA_GRAPHS_CUDA_CUH
#define CLOTHSIM_CUDA_GRAPHS_CUDA_CUH

#include "memory_cuda.cuh"
#include "rocks_kernel_impl.cuh"

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
        return cuda_fail(c, launched, "a launch while capturing a graph", __FILE__, __LINE__);
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
    if (ie != cudaSuccess) return cuda_fail(c, ie, "cudaGraphInstantiate", __FILE__, __LINE__);
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

/* After a step call's substeps are queued: the buffers that now hold the state (each substep
 * swaps the state's; the drift of a graph's first substep is in place), and the frame. */
static void advance(cuda_ctx *c, int32_t substeps, bool strain)
{
    c->cur ^= substeps & 1;
    if (strain) c->rest_cur ^= substeps & 1;
    c->calls++;
}

#endif /* CLOTHSIM_CUDA_GRAPHS_CUDA_CUH */
