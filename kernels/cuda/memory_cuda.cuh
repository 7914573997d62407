/* memory_cuda.cuh - the CUDA backend's host side for one scene: its context (streams, events, the
 * graphs it keeps), its device and pinned buffers, allocated, grown and freed; the device's errors
 * (CUDA_CHECK); creating and destroying a context; the launch arrays (cuda_bufs) of its buffers.
 * Part of the one translation unit backend_cuda.cu. */
#ifndef CLOTHSIM_CUDA_MEMORY_CUDA_CUH
#define CLOTHSIM_CUDA_MEMORY_CUDA_CUH

#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "cloth_kernel_impl.cuh"

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
    struct im_work *im;        /* implicit_euler's workspace (implicit_cuda.cuh), once used */
    struct sc_work *scw;       /* self_collision's (selfcontact_cuda.cuh), once used */
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

/* Records the failure of `call` at file:line (its name only, not its directory). */
static cs_status cuda_fail(cuda_ctx *c, cudaError_t e, const char *call, const char *file, int line)
{
    const char *base = strrchr(file, '/');
    snprintf(c->err, sizeof c->err, "%s (%s) at %s:%d in %s", cudaGetErrorString(e), cudaGetErrorName(e),
             base ? base + 1 : file, line, call);
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
        if (e_ != cudaSuccess) return cuda_fail(c, e_, #call, __FILE__, __LINE__);                     \
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
static void sc_free(struct sc_work *w);

static void cuda_destroy(void *ctx)
{
    cuda_ctx *c = (cuda_ctx *)ctx;
    if (!c) return;
    drop_graphs(c);
    im_free(c->im);
    sc_free(c->scw);
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
        if (e != cudaSuccess) st = cuda_fail(c, e, "setting up the device", __FILE__, __LINE__);
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
        if (e != cudaSuccess) return cuda_fail(c, e, "allocating the cloth", __FILE__, __LINE__);
    }
    if (new_r) {
        const cudaError_t e = alloc_rock_bufs(&r, rock_cap_for(s->n_rocks > c->rb.cap ? s->n_rocks : c->rb.cap), nchunks);
        if (e != cudaSuccess) {
            if (new_v) free_vertex_bufs(&v);
            return cuda_fail(c, e, "allocating the rocks", __FILE__, __LINE__);
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

#endif /* CLOTHSIM_CUDA_MEMORY_CUDA_CUH */
