/* batch_cuda.cuh - batches on the host (the kernels: batch_kernel_impl.cuh): the tables a batch
 * call needs besides its scenes' own buffers, a batch's run (batch_run: the table, the block
 * prefix sums, a launch per kernel per substep) and its frames' copies. Part of the one
 * translation unit backend_cuda.cu. */
#ifndef CLOTHSIM_CUDA_BATCH_CUDA_CUH
#define CLOTHSIM_CUDA_BATCH_CUDA_CUH

#include <mutex>

#include "batch_kernel_impl.cuh"
#include "graphs_cuda.cuh"
#include "implicit_cuda.cuh"

/* What a batch call needs besides its scenes' own buffers: the descriptor table, the block prefix
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
        return cuda_fail(c, e, "allocating a batch's tables", __FILE__, __LINE__);
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

/* The batch's scenes into b->order, most substeps first (the scenes still running at a substep
 * are then a prefix of the table, and a launch covers only their blocks); their reports cleared.
 * implicit_euler's scenes are left out (im_batch_run), and self_collision's (stepped alone:
 * cuda_step_batch). Returns how many. */
static int32_t batch_order(batch_ctx *b, cs_batch_item *items, int n)
{
    int32_t m = 0;
    for (int k = 0; k < n; k++) {
        if (items[k].m->phys.integrator == CS_IMPLICIT_EULER || items[k].m->phys.self_on)
            continue; /* im_batch_run, or stepped alone (cuda_step_batch) */
        items[k].rep.torn = 0, items[k].rep.finite = 1, items[k].status = CS_OK;
        if (items[k].substeps <= 0) continue;
        int32_t at = m++;
        while (at > 0 && items[b->order[at - 1]].substeps < items[k].substeps) {
            b->order[at] = b->order[at - 1];
            at--;
        }
        b->order[at] = k;
    }
    return m;
}

/* Rows of a cloth block for the batch: tile_rows_for's rule over every scene's blocks. */
static int32_t batch_tile_rows(const cuda_ctx *c, const batch_ctx *b, const cs_batch_item *items, int32_t m)
{
    int32_t tr = MAX_TILE_ROWS;
    for (;; tr >>= 1) {
        int64_t total = 0;
        for (int32_t j = 0; j < m; j++) total += cloth_blocks(&((cuda_ctx *)items[b->order[j]].ctx)->host_sc.p, tr);
        if (tr == 1 || total >= 4 * (int64_t)c->sms) break;
    }
    return tr;
}

/* The host table: scene j's descriptor (its buffers for even and odd substeps, its flags in the
 * batch's), each kernel's block prefix sums (start, `stride` a kernel), the cloth kernel's shared
 * memory (the most any scene needs, into *smem) and velocity Verlet's most substeps by graph
 * length (gmax). The batch's stream waits for what a scene's own stream holds. */
static cs_status batch_table(cuda_ctx *c, batch_ctx *b, const cs_batch_item *items, int32_t m, int32_t tr,
                             size_t stride, size_t *smem, int32_t *gmax)
{
    int32_t *start = b->host_start;
    for (int q = 0; q < BK_COUNT; q++) start[(size_t)q * stride] = 0;
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
        *smem = need > *smem ? need : *smem;
        if (d->verlet && d->substeps > gmax[d->graph]) gmax[d->graph] = d->substeps;
        /* What the scene's own stream holds (an upload, the last frame's copy) comes first. */
        if (ck->pending) {
            CUDA_CHECK(cudaEventRecord(ck->queued, ck->stream));
            CUDA_CHECK(cudaStreamWaitEvent(b->stream, ck->queued, 0));
        }
    }
    return CS_OK;
}

/* The table to the device and the batch's launches, substep by substep: each kernel over the
 * blocks of the scenes still running (a prefix of the table); a drift where a Verlet scene's graph
 * starts. */
static cs_status batch_launches(cuda_ctx *c, batch_ctx *b, int32_t m, size_t stride, size_t smem, const int32_t *gmax)
{
    const int32_t *start = b->host_start;
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
    return CS_OK;
}

/* The batch done: each scene's report from its flags, its buffers advanced. The batch is done,
 * and what the scenes' streams held before it: what each takes next comes after it. */
static cs_status batch_reports(cuda_ctx *c, batch_ctx *b, cs_batch_item *items, int32_t m)
{
    CUDA_CHECK(cudaMemcpyAsync(b->host_flags, b->flags, sizeof(int) * FLAG_COUNT * (size_t)m, cudaMemcpyDeviceToHost, b->stream));
    CUDA_CHECK(cudaStreamSynchronize(b->stream));
    for (int32_t j = 0; j < m; j++) {
        cs_batch_item *it = &items[b->order[j]];
        cuda_ctx *ck = (cuda_ctx *)it->ctx;
        ck->pending = 0;
        it->rep.torn = b->host_flags[(size_t)j * FLAG_COUNT + FLAG_TORN];
        it->rep.finite = b->host_flags[(size_t)j * FLAG_COUNT + FLAG_NONFINITE] == 0;
        advance(ck, it->substeps, b->host_tab[j].strain != 0);
    }
    return CS_OK;
}

/* One batch on the device: c (the first scene's context) records a CUDA failure; the items' own
 * statuses say what became of each scene that ran. */
static cs_status batch_run(cuda_ctx *c, batch_ctx *b, cs_batch_item *items, int n)
{
    cs_status st = batch_reserve(c, b, n);
    if (st != CS_OK) return st;
    const int32_t m = batch_order(b, items, n);
    if (m == 0) return CS_OK;
    const int32_t tr = batch_tile_rows(c, b, items, m);
    const size_t stride = (size_t)m + 1;
    size_t smem = cloth_smem(0);
    int32_t gmax[GRAPH_MAX + 1] = {0}; /* Verlet scenes' most substeps, by graph length */
    if ((st = batch_table(c, b, items, m, tr, stride, &smem, gmax)) != CS_OK) return st;
    if ((st = batch_launches(c, b, m, stride, smem, gmax)) != CS_OK) return st;
    if ((st = batch_reports(c, b, items, m)) != CS_OK) return st;
    return batch_frames(c, b, items, m);
}

/* implicit_euler's tables for batches (im_run), one per process as batch is, under batch_lock. */
static im_batch im_shared;

/* The batch's implicit_euler scenes (self_collision off: those with it step alone), stepped
 * together on the batch's stream (im_run) after its explicit ones: each scene's report from the
 * batch's flags, its frame copied as theirs. A scene whose workspace cannot be had fails alone;
 * c records another CUDA failure (the batch's). */
static cs_status im_batch_run(cuda_ctx *c, batch_ctx *b, cs_batch_item *items, int n)
{
    int32_t m = 0;
    for (int k = 0; k < n; k++) {
        cs_batch_item *it = &items[k];
        if (it->m->phys.integrator != CS_IMPLICIT_EULER || it->m->phys.self_on) continue;
        memset(&it->rep, 0, sizeof it->rep);
        it->rep.finite = 1, it->status = CS_OK;
        if (it->substeps <= 0) continue;
        if ((it->status = im_fit((cuda_ctx *)it->ctx, &it->m->phys)) == CS_OK) b->order[m++] = k;
    }
    if (m == 0) return CS_OK;
    cs_status st = im_batch_reserve(c, &im_shared, m);
    if (st != CS_OK) return st;
    for (int32_t q = 0; q < m; q++) {
        cs_batch_item *it = &items[b->order[q]];
        im_item *d = &im_shared.items[q];
        d->c = (cuda_ctx *)it->ctx, d->m = it->m, d->substeps = it->substeps;
        d->flags = b->flags + (size_t)q * FLAG_COUNT, d->rep = &it->rep;
    }
    /* (the explicit scenes' flags were read: batch_reports waited) */
    CUDA_CHECK(cudaMemsetAsync(b->flags, 0, sizeof(int) * FLAG_COUNT * (size_t)m, b->stream));
    if ((st = im_run(c, &im_shared, m, b->stream)) != CS_OK) return st;
    CUDA_CHECK(cudaMemcpyAsync(b->host_flags, b->flags, sizeof(int) * FLAG_COUNT * (size_t)m, cudaMemcpyDeviceToHost,
                               b->stream));
    CUDA_CHECK(cudaStreamSynchronize(b->stream));
    for (int32_t q = 0; q < m; q++) {
        cs_batch_item *it = &items[b->order[q]];
        cuda_ctx *ck = (cuda_ctx *)it->ctx;
        ck->pending = 0;
        ck->calls++; /* (im_run swapped its buffers as it went) */
        it->rep.torn = b->host_flags[(size_t)q * FLAG_COUNT + FLAG_TORN];
        it->rep.finite = b->host_flags[(size_t)q * FLAG_COUNT + FLAG_NONFINITE] == 0;
    }
    /* (the explicit scenes' frame jobs were copied to the device before the waits above) */
    return batch_frames(c, b, items, m);
}

#endif /* CLOTHSIM_CUDA_BATCH_CUDA_CUH */
