/* backend_cuda.cu - the CUDA backend: the SIM_HD functions of physics.h in kernels, running the
 * substep sequence of backend.h so that its state equals the CPU backend's bit for bit (both built
 * without contraction: -fmad=false here, -ffp-contract=off there).
 *
 * Layout: positions as float4 (x, y, z, w) with w the free-vertex mask, velocities and
 * accelerations as float4; positions and velocities double-buffered, so one kernel per substep can
 * read the current state of every neighbour and write the next state of its own vertex: it
 * evaluates the forces, finishes the substep's kick and - velocity Verlet - starts the next
 * substep's kick and drift. A block is one chunk (a row segment of CS_CHUNK vertices); each rock's
 * reaction is summed over the block with the tree of cs_tree_sum (shared memory, then warp
 * shuffles) into the chunk's partials, which one small kernel sums in chunk order per rock
 * (cs_rock_force) - no float atomics anywhere. The substeps of a step call are captured once in a
 * CUDA graph and replayed.
 *
 * Launches per velocity Verlet substep: the cloth kernel and, with rocks, the rock kernel; one
 * more drift kernel per step call. Symplectic Euler adds a strain kernel when strain is on. */
#include <cuda_runtime.h>

#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "clothsim/backend.h"
#include "clothsim/physics.h"

/* ---- what the kernels read besides the state (one copy per simulation, in device memory) ---- */

struct cuda_consts {
    cs_phys p;
    int32_t nr;          /* rocks */
    int32_t grab;        /* grabbed vertex or -1 */
    cs_vec3 grab_target;
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

__device__ static inline cs_vec3 xyz(float4 q) { return cs_v3(q.x, q.y, q.z); }

__device__ static inline int finite3(cs_vec3 v) { return isfinite(v.x) && isfinite(v.y) && isfinite(v.z); }

/* Sums val over the block (CS_CHUNK threads) with cs_tree_sum's tree: buf[t] += buf[t + s] for
 * s = CS_CHUNK/2 .. 1. Shared memory down to s = 32, then shuffles within the first warp (a lane
 * t < s adds lane t + s exactly as the tree does; the other lanes' sums are never used).
 * Every thread of the block must call it; the result is valid in thread 0. */
__device__ static float block_tree_sum(float val, float *sh)
{
    const int t = threadIdx.x;
    sh[t] = val;
    __syncthreads();
    for (int s = CS_CHUNK / 2; s >= 32; s >>= 1) {
        if (t < s) sh[t] += sh[t + s];
        __syncthreads();
    }
    float v = t < 32 ? sh[t] : 0.0f;
    __syncthreads(); /* sh may be reused by the caller */
    if (t < 32) {
        for (int s = 16; s > 0; s >>= 1) v += __shfl_down_sync(0xffffffffu, v, s);
    }
    return v;
}

/* The cloth kernel: one thread per vertex, one block per chunk. */
template <int MODE, bool STRAIN>
__global__ void __launch_bounds__(CS_CHUNK)
    k_cloth(const cuda_consts *__restrict__ kc, const float4 *__restrict__ pos, const float4 *__restrict__ vel, float4 *__restrict__ pos_out,
            float4 *__restrict__ vel_out, float4 *__restrict__ acc, const float *__restrict__ L0,
            float *__restrict__ L0n, const cs_rock_state *__restrict__ rocks, float *__restrict__ partials,
            int *__restrict__ flags)
{
    __shared__ float sh[CS_CHUNK];
    const cs_phys *p = &kc->p;
    const int32_t nx = p->nx, ny = p->ny, n = p->n, nr = kc->nr;
    const int32_t chunk = (int32_t)blockIdx.x, j = chunk / p->nseg;
    const int32_t i = (chunk - j * p->nseg) * CS_CHUNK + (int32_t)threadIdx.x;
    const bool live = i < nx;
    const int32_t v = j * nx + i;

    cs_vec3 xi = cs_v3(0.0f, 0.0f, 0.0f), vi = xi, F = xi;
    float w = 0.0f;
    int torn = 0;
    if (live) {
        const float4 P = pos[v], V = vel[v];
        xi = xyz(P);
        vi = xyz(V);
        w = P.w;
        float len;
#define CUDA_SLOT(t, di, dj, fwd)                                                                      \
    {                                                                                                  \
        const size_t li = (size_t)(t) * n + ((fwd) ? v : v + (di) + (dj) * nx);                        \
        if (i + (di) >= 0 && i + (di) < nx && j + (dj) >= 0 && j + (dj) < ny) {                        \
            const int32_t o = v + (di) + (dj) * nx;                                                    \
            const float l0 = L0[li];                                                                   \
            F = cs_add(F, cs_spring_force(xi, vi, xyz(pos[o]), xyz(vel[o]), l0, p->k[t], p->c_spring, &len)); \
            if ((fwd) && STRAIN) {                                                                     \
                const float nl = cs_strain_update(len, l0, p);                                         \
                L0n[li] = nl;                                                                          \
                torn += l0 > 0.0f && nl <= 0.0f;                                                       \
            }                                                                                          \
        } else if ((fwd) && STRAIN) {                                                                  \
            L0n[li] = L0[li];                                                                          \
        }                                                                                              \
    }
        CS_SPRING_SLOTS(CUDA_SLOT)
#undef CUDA_SLOT
        F = cs_add(F, cs_air_gravity(vi, p));
    }
    const cs_vec3 ro = F;
    for (int32_t r = 0; r < nr; r++) {
        cs_vec3 Fc = cs_v3(0.0f, 0.0f, 0.0f), arm = Fc;
        const int hit = live && cs_vertex_rock_contact(xi, vi, ro, &rocks[r], p, &Fc, &arm);
        if (hit) F = cs_add(F, Fc);
        float *out = partials + ((size_t)chunk * nr + r) * 6;
        if (__syncthreads_or(hit)) {
            const cs_vec3 R = hit ? cs_neg(Fc) : cs_v3(0.0f, 0.0f, 0.0f);
            const cs_vec3 T = hit ? cs_cross(arm, R) : cs_v3(0.0f, 0.0f, 0.0f);
            const float q[6] = {R.x, R.y, R.z, T.x, T.y, T.z};
#pragma unroll
            for (int k = 0; k < 6; k++) {
                const float s = block_tree_sum(q[k], sh);
                if (threadIdx.x == 0) out[k] = s;
            }
        } else if (threadIdx.x < 6) {
            out[threadIdx.x] = 0.0f; /* what the tree of +0 gives */
        }
    }
    if (torn) atomicAdd(&flags[FLAG_TORN], torn);
    if (!live) return;
    cs_vec3 Fg;
    if (cs_vertex_ground_contact(xi, vi, ro, p, &Fg)) F = cs_add(F, Fg);
    const cs_vec3 a = cs_scale(F, p->inv_mass * w);

    if (MODE == MODE_ACCEL) {
        acc[v] = make_float4(a.x, a.y, a.z, 0.0f);
        return;
    }
    const bool euler = MODE == MODE_EULER || MODE == MODE_EULER_LAST;
    const float h = euler ? p->dt : p->hdt;
    cs_vec3 vv = vi, xx = xi;
    if (MODE == MODE_VERLET_LAST) {
        vv = cs_add(vv, cs_scale(a, h)); /* the last substep's kick */
    } else {
        if (v == kc->grab) vv = cs_grab_velocity(xi, kc->grab_target, p);
        vv = cs_add(vv, cs_scale(a, h)); /* Verlet: finish; Euler: the update */
        if (MODE == MODE_VERLET) vv = cs_add(vv, cs_scale(a, h)); /* the next substep's half kick */
        xx = cs_add(xi, cs_scale(vv, p->dt));
    }
    pos_out[v] = make_float4(xx.x, xx.y, xx.z, w);
    vel_out[v] = make_float4(vv.x, vv.y, vv.z, 0.0f);
    if (MODE == MODE_VERLET_LAST || MODE == MODE_EULER_LAST) {
        acc[v] = make_float4(a.x, a.y, a.z, 0.0f);
        if (!finite3(xx) || !finite3(vv)) atomicOr(&flags[FLAG_NONFINITE], 1);
    }
}

/* Velocity Verlet's first substep of a step call: grab, kick, drift (no kick to finish). */
__global__ void k_drift_first(const cuda_consts *__restrict__ kc, const float4 *__restrict__ pos, const float4 *__restrict__ vel,
                              const float4 *__restrict__ acc, float4 *__restrict__ pos_out,
                              float4 *__restrict__ vel_out)
{
    const cs_phys *p = &kc->p;
    const int32_t v = (int32_t)(blockIdx.x * blockDim.x + threadIdx.x);
    if (v >= p->n) return;
    const float4 P = pos[v], V = vel[v], A = acc[v];
    const cs_vec3 xi = xyz(P);
    cs_vec3 vv = v == kc->grab ? cs_grab_velocity(xi, kc->grab_target, p) : xyz(V);
    vv = cs_add(vv, cs_scale(xyz(A), p->hdt));
    const cs_vec3 xx = cs_add(xi, cs_scale(vv, p->dt));
    pos_out[v] = make_float4(xx.x, xx.y, xx.z, P.w);
    vel_out[v] = make_float4(vv.x, vv.y, vv.z, 0.0f);
}

/* What the rock kernel does after the forces. */
enum { ROCKS_ACCEL, ROCKS_VERLET, ROCKS_VERLET_LAST, ROCKS_EULER, ROCKS_FIRST };

/* One block, a thread per rock: forces from the chunk partials (cs_rock_force), then the moves. */
template <int MODE>
__global__ void k_rocks(const cuda_consts *__restrict__ kc, cs_rock_state *__restrict__ rocks,
                        const float *__restrict__ partials, int *__restrict__ flags)
{
    const cs_phys *p = &kc->p;
    const int32_t r = (int32_t)threadIdx.x, nr = kc->nr;
    cs_vec3 F = cs_v3(0.0f, 0.0f, 0.0f), T = F;
    if (MODE != ROCKS_FIRST && r < nr) cs_rock_force(rocks, nr, r, partials, p->nchunks, p, &F, &T);
    __syncthreads(); /* every rock's force read the others' state before any changes */
    if (r >= nr) return;
    cs_rock_state *k = &rocks[r];
    switch (MODE) {
    case ROCKS_ACCEL: cs_rock_accel(k, F, T); break;
    case ROCKS_FIRST:
        cs_rock_kick(k, p->hdt);
        cs_rock_drift(k, p->dt);
        break;
    case ROCKS_VERLET:
        cs_rock_accel(k, F, T);
        cs_rock_kick(k, p->hdt);
        cs_rock_kick(k, p->hdt);
        cs_rock_drift(k, p->dt);
        break;
    case ROCKS_VERLET_LAST:
        cs_rock_accel(k, F, T);
        cs_rock_kick(k, p->hdt);
        break;
    case ROCKS_EULER:
        cs_rock_accel(k, F, T);
        cs_rock_kick(k, p->dt);
        cs_rock_drift(k, p->dt);
        break;
    }
    if (MODE == ROCKS_VERLET_LAST || MODE == ROCKS_EULER) {
        if (!finite3(k->x) || !finite3(k->v) || !finite3(k->w)) atomicOr(&flags[FLAG_NONFINITE], 1);
    }
}

/* Symplectic Euler's strain pass on the new positions. */
__global__ void k_strain(const cuda_consts *__restrict__ kc, const float4 *__restrict__ pos,
                         const float *__restrict__ L0, float *__restrict__ L0n, int *__restrict__ flags)
{
    const cs_phys *p = &kc->p;
    const int32_t v = (int32_t)(blockIdx.x * blockDim.x + threadIdx.x);
    if (v >= p->n) return;
    const int32_t nx = p->nx, ny = p->ny, i = v % nx, j = v / nx;
    const cs_vec3 xi = xyz(pos[v]);
    int torn = 0;
#define CUDA_STRAIN(t, di, dj)                                                                         \
    {                                                                                                  \
        const size_t li = (size_t)(t) * p->n + v;                                                      \
        float nl = L0[li];                                                                             \
        if (i + (di) >= 0 && i + (di) < nx && j + (dj) < ny) {                                         \
            nl = cs_strain_update(cs_len(cs_sub(xyz(pos[v + (di) + (dj) * nx]), xi)), L0[li], p);      \
            torn += L0[li] > 0.0f && nl <= 0.0f;                                                       \
        }                                                                                              \
        L0n[li] = nl;                                                                                  \
    }
    CS_SPRING_TYPES(CUDA_STRAIN)
#undef CUDA_STRAIN
    if (torn) atomicAdd(&flags[FLAG_TORN], torn);
}

/* ---- host side ---- */

#define GRAPHS 4

struct graph_entry {
    cudaGraphExec_t exec;
    int32_t substeps, nr, integrator, strain;
    int pos_cur, rest_cur;
};

struct cuda_ctx {
    int dev;
    cudaStream_t stream;
    int32_t n, nchunks;          /* sizes allocated for */
    float4 *pos[2], *vel[2], *acc;
    int cur;                     /* which pos/vel buffer holds the state */
    float *rest[2];
    int rest_cur;
    cs_rock_state *rocks;
    int32_t rock_cap, nr;
    float *partials;
    size_t partials_cap;
    int *flags, *host_flags;     /* device counters and their pinned host copy */
    cuda_consts *consts;         /* device copy of what the kernels read */
    float4 *stage;               /* pinned staging for uploads and downloads */
    graph_entry graphs[GRAPHS];
    int n_graphs;
    double copy_bandwidth;       /* measured once, bytes/s */
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

static void free_state(cuda_ctx *c)
{
    drop_graphs(c);
    for (int b = 0; b < 2; b++) {
        cudaFree(c->pos[b]);
        cudaFree(c->vel[b]);
        cudaFree(c->rest[b]);
        c->pos[b] = c->vel[b] = NULL;
        c->rest[b] = NULL;
    }
    cudaFree(c->acc);
    cudaFreeHost(c->stage);
    c->acc = c->stage = NULL;
    c->n = 0;
}

static void cuda_destroy(void *ctx)
{
    cuda_ctx *c = (cuda_ctx *)ctx;
    if (!c) return;
    free_state(c);
    cudaFree(c->rocks);
    cudaFree(c->partials);
    cudaFree(c->flags);
    cudaFree(c->consts);
    cudaFreeHost(c->host_flags);
    if (c->stream) cudaStreamDestroy(c->stream);
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
    cs_status st = CS_OK;
    cudaDeviceProp prop;
    do {
        cudaError_t e = cudaGetDevice(&c->dev);
        if (e == cudaSuccess) e = cudaGetDeviceProperties(&prop, c->dev);
        if (e == cudaSuccess) e = cudaStreamCreateWithFlags(&c->stream, cudaStreamNonBlocking);
        if (e == cudaSuccess) e = cudaMalloc((void **)&c->flags, FLAG_COUNT * sizeof(int));
        if (e == cudaSuccess) e = cudaMallocHost((void **)&c->host_flags, FLAG_COUNT * sizeof(int));
        if (e == cudaSuccess) e = cudaMalloc((void **)&c->consts, sizeof(cuda_consts));
        if (e != cudaSuccess) st = cuda_fail(c, e, "setting up the device", __LINE__);
    } while (0);
    if (st != CS_OK) {
        snprintf(err, err_len, "%s", c->err);
        cuda_destroy(c);
        return st;
    }
    snprintf(c->device, sizeof c->device, "%s (sm_%d%d, %d SMs, %.0f GiB)", prop.name, prop.major, prop.minor,
             prop.multiProcessorCount, (double)prop.totalGlobalMem / (1024.0 * 1024.0 * 1024.0));
    *out = c;
    return CS_OK;
}

static cs_status reserve(cuda_ctx *c, const cs_model *m, const cs_state *s)
{
    const int32_t n = s->n, nr = s->n_rocks;
    if (n != c->n) {
        free_state(c);
        for (int b = 0; b < 2; b++) {
            CUDA_CHECK(cudaMalloc((void **)&c->pos[b], sizeof(float4) * (size_t)n));
            CUDA_CHECK(cudaMalloc((void **)&c->vel[b], sizeof(float4) * (size_t)n));
            CUDA_CHECK(cudaMalloc((void **)&c->rest[b], sizeof(float) * (size_t)n * CS_NTYPES));
        }
        CUDA_CHECK(cudaMalloc((void **)&c->acc, sizeof(float4) * (size_t)n));
        CUDA_CHECK(cudaMallocHost((void **)&c->stage, sizeof(float4) * (size_t)n));
        c->n = n;
    }
    if (nr > c->rock_cap) {
        drop_graphs(c);
        cudaFree(c->rocks);
        c->rocks = NULL;
        c->rock_cap = 0;
        CUDA_CHECK(cudaMalloc((void **)&c->rocks, sizeof(cs_rock_state) * (size_t)nr));
        c->rock_cap = nr;
    }
    const size_t need = (size_t)m->phys.nchunks * (size_t)(nr > 0 ? nr : 1) * 6;
    if (need > c->partials_cap) {
        drop_graphs(c);
        cudaFree(c->partials);
        c->partials = NULL;
        c->partials_cap = 0;
        CUDA_CHECK(cudaMalloc((void **)&c->partials, sizeof(float) * need));
        c->partials_cap = need;
    }
    return CS_OK;
}

/* Host arrays -> one float4 array on the device, through the pinned stage. */
static cs_status put4(cuda_ctx *c, float4 *dst, const float *a, const float *b, const float *d, const float *w)
{
    for (int32_t v = 0; v < c->n; v++) c->stage[v] = make_float4(a[v], b[v], d[v], w ? w[v] : 0.0f);
    CUDA_CHECK(cudaMemcpyAsync(dst, c->stage, sizeof(float4) * (size_t)c->n, cudaMemcpyHostToDevice, c->stream));
    CUDA_CHECK(cudaStreamSynchronize(c->stream));
    return CS_OK;
}

static cs_status get4(cuda_ctx *c, const float4 *src, float *a, float *b, float *d)
{
    CUDA_CHECK(cudaMemcpyAsync(c->stage, src, sizeof(float4) * (size_t)c->n, cudaMemcpyDeviceToHost, c->stream));
    CUDA_CHECK(cudaStreamSynchronize(c->stream));
    for (int32_t v = 0; v < c->n; v++) {
        a[v] = c->stage[v].x;
        b[v] = c->stage[v].y;
        d[v] = c->stage[v].z;
    }
    return CS_OK;
}

static cs_status cuda_upload(void *ctx, const cs_model *m, cs_state *s)
{
    cuda_ctx *c = (cuda_ctx *)ctx;
    cs_status st = reserve(c, m, s);
    if (st != CS_OK) return st;
    cuda_consts k;
    memset(&k, 0, sizeof k);
    k.p = m->phys;
    k.nr = s->n_rocks;
    k.grab = s->grab;
    k.grab_target = s->grab_target;
    CUDA_CHECK(cudaMemcpyAsync(c->consts, &k, sizeof k, cudaMemcpyHostToDevice, c->stream));
    c->cur = 0;
    c->rest_cur = 0;
    if ((st = put4(c, c->pos[0], s->x, s->y, s->z, s->w)) != CS_OK) return st;
    if ((st = put4(c, c->vel[0], s->vx, s->vy, s->vz, NULL)) != CS_OK) return st;
    if ((st = put4(c, c->acc, s->ax, s->ay, s->az, NULL)) != CS_OK) return st;
    CUDA_CHECK(cudaMemcpyAsync(c->rest[0], s->L0, sizeof(float) * (size_t)s->n * CS_NTYPES, cudaMemcpyHostToDevice,
                               c->stream));
    if (s->n_rocks)
        CUDA_CHECK(cudaMemcpyAsync(c->rocks, s->rocks, sizeof(cs_rock_state) * (size_t)s->n_rocks,
                                   cudaMemcpyHostToDevice, c->stream));
    CUDA_CHECK(cudaStreamSynchronize(c->stream));
    c->nr = s->n_rocks;
    c->nchunks = m->phys.nchunks;
    /* Graphs hold buffer parities and sizes; start afresh after any upload. */
    drop_graphs(c);
    return CS_OK;
}

static cs_status cuda_download(void *ctx, const cs_model *m, cs_state *s, unsigned what)
{
    cuda_ctx *c = (cuda_ctx *)ctx;
    (void)m;
    cs_status st = get4(c, c->pos[c->cur], s->x, s->y, s->z);
    if (st != CS_OK || what == CS_SYNC_POSITIONS) return st;
    if ((st = get4(c, c->vel[c->cur], s->vx, s->vy, s->vz)) != CS_OK) return st;
    if ((st = get4(c, c->acc, s->ax, s->ay, s->az)) != CS_OK) return st;
    CUDA_CHECK(cudaMemcpyAsync(s->L0, c->rest[c->rest_cur], sizeof(float) * (size_t)s->n * CS_NTYPES,
                               cudaMemcpyDeviceToHost, c->stream));
    if (s->n_rocks)
        CUDA_CHECK(cudaMemcpyAsync(s->rocks, c->rocks, sizeof(cs_rock_state) * (size_t)s->n_rocks,
                                   cudaMemcpyDeviceToHost, c->stream));
    CUDA_CHECK(cudaStreamSynchronize(c->stream));
    return CS_OK;
}

static int rock_threads(int32_t nr) { return (nr + 31) / 32 * 32; }

/* Accelerations on the device; the core reads them back when it needs the host copy. */
static cs_status cuda_refresh(void *ctx, const cs_model *m, cs_state *s)
{
    cuda_ctx *c = (cuda_ctx *)ctx;
    (void)s;
    const int cur = c->cur;
    k_cloth<MODE_ACCEL, false><<<m->phys.nchunks, CS_CHUNK, 0, c->stream>>>(
        c->consts, c->pos[cur], c->vel[cur], NULL, NULL, c->acc, c->rest[c->rest_cur], NULL, c->rocks, c->partials,
        c->flags);
    CUDA_CHECK(cudaGetLastError());
    if (c->nr) {
        k_rocks<ROCKS_ACCEL><<<1, rock_threads(c->nr), 0, c->stream>>>(c->consts, c->rocks, c->partials, c->flags);
        CUDA_CHECK(cudaGetLastError());
    }
    CUDA_CHECK(cudaStreamSynchronize(c->stream));
    return CS_OK;
}

/* Enqueues one step call's kernels on the stream (for capture), from buffer parities pc, rc. */
static cs_status enqueue_step(cuda_ctx *c, const cs_model *m, int32_t substeps, int pc, int rc)
{
    const cs_phys *p = &m->phys;
    const int32_t nr = c->nr, blocks = p->nchunks, vblocks = (p->n + 255) / 256;
    const int rt = rock_threads(nr);
    const bool strain = p->strain_on != 0;
    cudaStream_t st = c->stream;
    CUDA_CHECK(cudaMemsetAsync(c->flags, 0, FLAG_COUNT * sizeof(int), st));
    if (p->integrator == CS_VELOCITY_VERLET) {
        k_drift_first<<<vblocks, 256, 0, st>>>(c->consts, c->pos[pc], c->vel[pc], c->acc, c->pos[pc ^ 1], c->vel[pc ^ 1]);
        if (nr) k_rocks<ROCKS_FIRST><<<1, rt, 0, st>>>(c->consts, c->rocks, c->partials, c->flags);
        pc ^= 1;
        for (int32_t it = 0; it < substeps; it++) {
            const bool last = it == substeps - 1;
            float4 *po = c->pos[pc ^ 1], *vo = c->vel[pc ^ 1];
            const float *L = c->rest[rc];
            float *Ln = c->rest[rc ^ 1];
            if (last) {
                if (strain)
                    k_cloth<MODE_VERLET_LAST, true><<<blocks, CS_CHUNK, 0, st>>>(c->consts, c->pos[pc], c->vel[pc], po, vo, c->acc, L,
                                                                                 Ln, c->rocks, c->partials, c->flags);
                else
                    k_cloth<MODE_VERLET_LAST, false><<<blocks, CS_CHUNK, 0, st>>>(c->consts, c->pos[pc], c->vel[pc], po, vo, c->acc,
                                                                                  L, Ln, c->rocks, c->partials, c->flags);
                if (nr) k_rocks<ROCKS_VERLET_LAST><<<1, rt, 0, st>>>(c->consts, c->rocks, c->partials, c->flags);
            } else {
                if (strain)
                    k_cloth<MODE_VERLET, true><<<blocks, CS_CHUNK, 0, st>>>(c->consts, c->pos[pc], c->vel[pc], po, vo, c->acc, L, Ln,
                                                                            c->rocks, c->partials, c->flags);
                else
                    k_cloth<MODE_VERLET, false><<<blocks, CS_CHUNK, 0, st>>>(c->consts, c->pos[pc], c->vel[pc], po, vo, c->acc, L,
                                                                             Ln, c->rocks, c->partials, c->flags);
                if (nr) k_rocks<ROCKS_VERLET><<<1, rt, 0, st>>>(c->consts, c->rocks, c->partials, c->flags);
            }
            pc ^= 1;
            if (strain) rc ^= 1;
        }
    } else {
        for (int32_t it = 0; it < substeps; it++) {
            const bool last = it == substeps - 1;
            float4 *po = c->pos[pc ^ 1], *vo = c->vel[pc ^ 1];
            if (last)
                k_cloth<MODE_EULER_LAST, false><<<blocks, CS_CHUNK, 0, st>>>(c->consts, c->pos[pc], c->vel[pc], po, vo, c->acc,
                                                                             c->rest[rc], NULL, c->rocks, c->partials,
                                                                             c->flags);
            else
                k_cloth<MODE_EULER, false><<<blocks, CS_CHUNK, 0, st>>>(c->consts, c->pos[pc], c->vel[pc], po, vo, c->acc,
                                                                        c->rest[rc], NULL, c->rocks, c->partials,
                                                                        c->flags);
            if (nr) k_rocks<ROCKS_EULER><<<1, rt, 0, st>>>(c->consts, c->rocks, c->partials, c->flags);
            pc ^= 1;
            if (strain) {
                k_strain<<<vblocks, 256, 0, st>>>(c->consts, c->pos[pc], c->rest[rc], c->rest[rc ^ 1], c->flags);
                rc ^= 1;
            }
        }
    }
    CUDA_CHECK(cudaMemcpyAsync(c->host_flags, c->flags, FLAG_COUNT * sizeof(int), cudaMemcpyDeviceToHost, st));
    CUDA_CHECK(cudaGetLastError()); /* a bad launch configuration */
    return CS_OK;
}

/* The graph for this call, captured on first use. */
static cs_status graph_for(cuda_ctx *c, const cs_model *m, int32_t substeps, cudaGraphExec_t *out)
{
    const int32_t integ = m->phys.integrator, strain = m->phys.strain_on;
    for (int g = 0; g < c->n_graphs; g++) {
        const graph_entry *e = &c->graphs[g];
        if (e->substeps == substeps && e->nr == c->nr && e->integrator == integ && e->strain == strain &&
            e->pos_cur == c->cur && e->rest_cur == c->rest_cur) {
            *out = e->exec;
            return CS_OK;
        }
    }
    if (c->n_graphs == GRAPHS) {
        cudaGraphExecDestroy(c->graphs[0].exec);
        memmove(&c->graphs[0], &c->graphs[1], sizeof c->graphs[0] * (GRAPHS - 1));
        c->n_graphs--;
    }
    cudaGraph_t graph;
    CUDA_CHECK(cudaStreamBeginCapture(c->stream, cudaStreamCaptureModeThreadLocal));
    const cs_status queued = enqueue_step(c, m, substeps, c->cur, c->rest_cur);
    const cudaError_t ended = cudaStreamEndCapture(c->stream, &graph);
    if (queued != CS_OK) {
        if (ended == cudaSuccess) cudaGraphDestroy(graph);
        return queued;
    }
    CUDA_CHECK(ended);
    cudaGraphExec_t exec;
    const cudaError_t e = cudaGraphInstantiate(&exec, graph, 0);
    cudaGraphDestroy(graph);
    if (e != cudaSuccess) return cuda_fail(c, e, "cudaGraphInstantiate", __LINE__);
    graph_entry *n = &c->graphs[c->n_graphs++];
    n->exec = exec;
    n->substeps = substeps, n->nr = c->nr, n->integrator = integ, n->strain = strain;
    n->pos_cur = c->cur, n->rest_cur = c->rest_cur;
    *out = exec;
    return CS_OK;
}

static cs_status cuda_step(void *ctx, const cs_model *m, cs_state *s, int32_t substeps, cs_step_report *rep)
{
    cuda_ctx *c = (cuda_ctx *)ctx;
    (void)s;
    rep->torn = 0;
    rep->finite = 1;
    if (substeps <= 0) return CS_OK;
    cudaGraphExec_t exec;
    cs_status st = graph_for(c, m, substeps, &exec);
    if (st != CS_OK) return st;
    CUDA_CHECK(cudaGraphLaunch(exec, c->stream));
    CUDA_CHECK(cudaStreamSynchronize(c->stream));
    /* Buffer parities after the call: Verlet moves positions substeps + 1 times, Euler substeps. */
    const int moves = m->phys.integrator == CS_VELOCITY_VERLET ? substeps + 1 : substeps;
    c->cur ^= moves & 1;
    if (m->phys.strain_on) c->rest_cur ^= substeps & 1;
    rep->torn = c->host_flags[FLAG_TORN];
    rep->finite = c->host_flags[FLAG_NONFINITE] == 0;
    return CS_OK;
}

/* Device-to-device copy of 256 MiB, best of 5 after a warm-up: the bandwidth the kernels can
 * hope for (each byte read once and written once). */
static cs_status copy_bandwidth(cuda_ctx *c, void *a, void *b, cudaEvent_t e0, cudaEvent_t e1, size_t bytes,
                                double *best)
{
    for (int k = 0; k < 6; k++) {
        float ms = 0;
        CUDA_CHECK(cudaEventRecord(e0, c->stream));
        CUDA_CHECK(cudaMemcpyAsync(b, a, bytes, cudaMemcpyDeviceToDevice, c->stream));
        CUDA_CHECK(cudaEventRecord(e1, c->stream));
        CUDA_CHECK(cudaEventSynchronize(e1));
        CUDA_CHECK(cudaEventElapsedTime(&ms, e0, e1));
        const double bw = 2.0 * (double)bytes / (ms * 1e-3);
        if (k > 0 && bw > *best) *best = bw;
    }
    return CS_OK;
}

static double measure_copy_bandwidth(cuda_ctx *c)
{
    const size_t bytes = (size_t)256 << 20;
    void *a = NULL, *b = NULL;
    cudaEvent_t e0 = NULL, e1 = NULL;
    double best = 0;
    if (cudaMalloc(&a, bytes) == cudaSuccess && cudaMalloc(&b, bytes) == cudaSuccess &&
        cudaEventCreate(&e0) == cudaSuccess && cudaEventCreate(&e1) == cudaSuccess)
        copy_bandwidth(c, a, b, e0, e1, bytes, &best);
    if (e0) cudaEventDestroy(e0);
    if (e1) cudaEventDestroy(e1);
    cudaFree(a);
    cudaFree(b);
    return best;
}

/* Memory traffic per vertex and substep of the kernels above, counting each vertex's own data
 * once (its neighbours' reads hit in cache): the cloth kernel reads position, velocity (16 B
 * each) and its six rest lengths (24 B), writes position and velocity (32 B), and with strain
 * the new rest lengths (24 B); once per step call, Verlet's first drift (80 B) and the final
 * acceleration (16 B); Euler's strain kernel reads positions and rest lengths and writes rest
 * lengths (64 B). */
static void cuda_stats(void *ctx, const cs_model *m, cs_backend_stats *out)
{
    cuda_ctx *c = (cuda_ctx *)ctx;
    const cs_phys *p = &m->phys;
    const double per_call = (p->integrator == CS_VELOCITY_VERLET ? 80.0 : 0.0) + 16.0;
    double bytes = 56.0 + 32.0 + per_call / m->substeps;
    if (p->strain_on) bytes += p->integrator == CS_VELOCITY_VERLET ? 24.0 : 64.0;
    if (c->copy_bandwidth == 0) c->copy_bandwidth = measure_copy_bandwidth(c);
    out->bytes_per_vertex_substep = bytes;
    out->copy_bandwidth = c->copy_bandwidth;
}

static const char *cuda_device(void *ctx, const cs_model *) { return ((cuda_ctx *)ctx)->device; }
static const char *cuda_error(void *ctx) { return ((cuda_ctx *)ctx)->err; }

static const cs_backend cuda_backend = {
    "cuda", cuda_available, cuda_create, cuda_destroy, cuda_upload, cuda_download, cuda_refresh, cuda_step,
    cuda_device, cuda_error, cuda_stats,
};

extern "C" const cs_backend *cs_backend_cuda(void) { return &cuda_backend; }
