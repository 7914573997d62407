/* selfcontact_cuda.cuh - self_collision on the CUDA backend: the functions of clothsim/selfcontact.h
 * (the ones src/selfcontact_cpu.c loops over) in per-vertex kernels, after every substep of the
 * explicit integrators and every part of an implicit_euler substep, so that the state equals the
 * CPU backend's bit for bit (kernels/MODEL.md, "Self-collision").
 *
 * Every pass gathers its pairs afresh within the cloth's largest reach, where the CPU backend keeps
 * lists of the pairs within each pair's own reach (cs_sc_pair_reach): a pair beyond its reach is
 * safe and never touches, and the CPU's sweep that cuts outright gathers as this one does, so the
 * state is the same. A pass, with the host reading back a few scalars between its launches:
 *   1. d = x - x0 and the largest displacements M and Ma (k_sc_disp, k_sc_far: per-block minima
 *      and maxima, exact in any order, totalled on the host as the CPU's reductions are);
 *   2. the longest intact edge at x0 (k_sc_edge); the hash grid of x0 (k_sc_keys, then the
 *      counting sort in parallel - k_sc_count, k_sc_scan, k_sc_fill, k_sc_order - ending with
 *      cs_sc_sort's start and ids, each cell's vertices in vertex order, as the CPU's);
 *   3. every vertex's list of repelling pairs within self_thickness + 2 M at x0: counted
 *      (cs_sc_pairs with no room), the room laid out on the host (an exact prefix sum; the key
 *      buffer grows to fit, and a failed allocation is an error, never a dropped pair), then
 *      filled and sorted (cs_sc_pairs again); the repulsion (cs_sc_repel) per vertex, added where
 *      a pair touched;
 *   4. the bound: Jacobi sweeps of cs_sc_limit over the grid (pairs within self_thickness +
 *      2 Ma / CS_SC_GAMMA at x0) until no scale changes (at most CS_SC_SWEEPS, then one that cuts
 *      outright), then x = x0 + s d, v = s v.
 * Before each implicit_euler substep sc_part_rate gathers the repelling pairs within reach of the
 * fastest vertex the same way for the parts (cs_sc_near_speed). The statistics differ from the
 * CPU's where it keeps its lists: every pass here is a broad phase. */
#ifndef CLOTHSIM_CUDA_SELFCONTACT_CUDA_CUH
#define CLOTHSIM_CUDA_SELFCONTACT_CUDA_CUH

#include "clothsim/selfcontact.h"

#define SC_THREADS 256

struct sc_work {
    int32_t n;
    uint32_t mask;   /* the hash table's size - 1 */
    float *x0;       /* the substep's start: x, y, z (3 n) */
    float *d;        /* x - x0 (3 n) */
    float *s;        /* the bound's scales, two buffers (2 n) */
    float *push;     /* the repulsion's dx, dv per vertex (6 n, AoS) */
    float *w;        /* 1 free, 0 pinned or grabbed (from the context's byte mask) */
    float *part;     /* per-block partials (8 a block) */
    float *host_part;
    uint32_t *key;
    int32_t *start, *ids, *cc, *count, *touched;
    int32_t *cursor; /* each cell's fill so far (k_sc_fill): size + 1 */
    int64_t *first;  /* each vertex's list in keys */
    int64_t *host_first;
    int32_t *host_count;
    int64_t *keys, cap;
    int *flag, *host_flag; /* a sweep changed a scale; touching pairs; cut vertices */
};

static void sc_free(sc_work *w)
{
    if (!w) return;
    cudaFree(w->x0);
    cudaFree(w->part);
    cudaFree(w->key);
    cudaFree(w->first);
    cudaFree(w->keys);
    cudaFree(w->flag);
    cudaFreeHost(w->host_part);
    cudaFreeHost(w->host_flag);
    free(w->host_first);
    free(w->host_count);
    free(w);
}

static unsigned sc_blocks(int32_t n) { return (unsigned)((n + SC_THREADS - 1) / SC_THREADS); }

/* The workspace for n vertices (kept while n stays). */
static cs_status sc_fit(cuda_ctx *c, int32_t n)
{
    if (c->scw && c->scw->n == n) return CS_OK;
    sc_free(c->scw);
    c->scw = NULL;
    sc_work *w = (sc_work *)calloc(1, sizeof *w);
    if (!w) return CS_E_NOMEM;
    uint32_t size = 1;
    while (size < 2u * (uint32_t)n) size <<= 1;
    w->n = n, w->mask = size - 1;
    const size_t N = (size_t)n, blocks = sc_blocks(n);
    /* floats: x0 3n, d 3n, s 2n, push 6n, w n; ints: key n, start size + 2, ids n, cc 3n, count n,
     * touched n, cursor size + 2 */
    cudaError_t e = cudaMalloc((void **)&w->x0, sizeof(float) * 15 * N);
    if (e == cudaSuccess) e = cudaMalloc((void **)&w->part, sizeof(float) * 8 * blocks);
    if (e == cudaSuccess) e = cudaMalloc((void **)&w->key, sizeof(int32_t) * (7 * N + 2 * ((size_t)size + 2)));
    if (e == cudaSuccess) e = cudaMalloc((void **)&w->first, sizeof(int64_t) * N);
    if (e == cudaSuccess) e = cudaMalloc((void **)&w->flag, sizeof(int) * 3);
    if (e == cudaSuccess) e = cudaMallocHost((void **)&w->host_part, sizeof(float) * 8 * blocks);
    if (e == cudaSuccess) e = cudaMallocHost((void **)&w->host_flag, sizeof(int) * 3);
    w->host_first = (int64_t *)malloc(sizeof(int64_t) * N);
    w->host_count = (int32_t *)malloc(sizeof(int32_t) * N);
    if (e == cudaSuccess && (!w->host_first || !w->host_count)) e = cudaErrorMemoryAllocation;
    if (e != cudaSuccess) {
        sc_free(w);
        return cuda_fail(c, e, "allocating self_collision's workspace", __FILE__, __LINE__);
    }
    w->d = w->x0 + 3 * N, w->s = w->d + 3 * N, w->push = w->s + 2 * N, w->w = w->push + 6 * N;
    int32_t *ints = (int32_t *)w->key;
    w->ids = ints + N, w->cc = w->ids + N, w->count = w->cc + 3 * N, w->touched = w->count + N;
    w->start = w->touched + N, w->cursor = w->start + size + 2;
    c->scw = w;
    return CS_OK;
}

/* ---- kernels ---- */

/* x0 = the state's positions, w = its mask as floats. */
__global__ void k_sc_begin(const float *__restrict__ S, const unsigned char *__restrict__ mask, float *x0, float *w,
                           int32_t n)
{
    const int32_t v = (int32_t)(blockIdx.x * blockDim.x + threadIdx.x);
    if (v >= n) return;
    x0[v] = S[v], x0[n + v] = S[(size_t)n + v], x0[2 * (size_t)n + v] = S[2 * (size_t)n + v];
    w[v] = (float)mask[v];
}

/* A block's least and largest of a[] (NaN never taken, as the CPU's loops), into part. */
__device__ static void sc_block_minmax(float *buf, const float lo[3], const float hi[3], float *part)
{
    const int t = (int)threadIdx.x;
    for (int q = 0; q < 3; q++) buf[q * SC_THREADS + t] = lo[q], buf[(3 + q) * SC_THREADS + t] = hi[q];
    for (int s = SC_THREADS / 2; s > 0; s >>= 1) {
        __syncthreads();
        if (t < s)
            for (int q = 0; q < 3; q++) {
                float *l = buf + q * SC_THREADS, *h = buf + (3 + q) * SC_THREADS;
                l[t] = l[t + s] < l[t] ? l[t + s] : l[t];
                h[t] = h[t + s] > h[t] ? h[t + s] : h[t];
            }
    }
    if (t == 0)
        for (int q = 0; q < 6; q++) part[8 * blockIdx.x + q] = buf[q * SC_THREADS];
}

/* d = x - x0, and each block's least and largest d per axis (part[8 b .. 8 b + 5]). */
__global__ void __launch_bounds__(SC_THREADS) k_sc_disp(const float *__restrict__ S, const float *__restrict__ x0,
                                                        float *d, int32_t n, float *part)
{
    CS_DYNAMIC_SHARED(float, buf);
    const int32_t v = (int32_t)(blockIdx.x * blockDim.x + threadIdx.x);
    float lo[3] = {3e38f, 3e38f, 3e38f}, hi[3] = {-3e38f, -3e38f, -3e38f};
    if (v < n)
        for (int q = 0; q < 3; q++) {
            const float dq = S[(size_t)q * n + v] - x0[(size_t)q * n + v];
            d[(size_t)q * n + v] = dq;
            lo[q] = dq < lo[q] ? dq : lo[q];
            hi[q] = dq > hi[q] ? dq : hi[q];
        }
    sc_block_minmax(buf, lo, hi, part);
}

/* A block's largest |d - centre| and |d| into part[8 b], part[8 b + 1]. */
__global__ void __launch_bounds__(SC_THREADS) k_sc_far(const float *__restrict__ d, int32_t n, cs_vec3 centre,
                                                       float *part)
{
    CS_DYNAMIC_SHARED(float, buf);
    const int t = (int)threadIdx.x;
    const int32_t v = (int32_t)(blockIdx.x * blockDim.x + threadIdx.x);
    float most = 0.0f, abs_most = 0.0f;
    if (v < n) {
        const cs_vec3 dv = cs_v3(d[v], d[(size_t)n + v], d[2 * (size_t)n + v]);
        const float l = cs_len(cs_sub(dv, centre)), a = cs_len(dv);
        most = l > most ? l : most;
        abs_most = a > abs_most ? a : abs_most;
    }
    buf[t] = most, buf[SC_THREADS + t] = abs_most;
    for (int s = SC_THREADS / 2; s > 0; s >>= 1) {
        __syncthreads();
        if (t < s) {
            buf[t] = buf[t + s] > buf[t] ? buf[t + s] : buf[t];
            buf[SC_THREADS + t] = buf[SC_THREADS + t + s] > buf[SC_THREADS + t] ? buf[SC_THREADS + t + s] : buf[SC_THREADS + t];
        }
    }
    if (t == 0) part[8 * blockIdx.x] = buf[0], part[8 * blockIdx.x + 1] = buf[SC_THREADS];
}

/* A block's longest intact render edge at x0 (cs_sc_own_reach, as longest_edge of selfcontact_cpu.c)
 * into part[8 b]. */
__global__ void __launch_bounds__(SC_THREADS) k_sc_edge(const cuda_scene *__restrict__ sc, const float *__restrict__ x0,
                                                        const float *__restrict__ L0, float *part)
{
    CS_DYNAMIC_SHARED(float, buf);
    const cs_phys *p = &sc->p;
    const int t = (int)threadIdx.x;
    const int32_t v = (int32_t)(blockIdx.x * blockDim.x + threadIdx.x), n = p->n;
    float most = 0.0f;
    if (v < n) most = cs_sc_own_reach(p, L0, x0, x0 + n, x0 + 2 * (size_t)n, v);
    buf[t] = most;
    for (int s = SC_THREADS / 2; s > 0; s >>= 1) {
        __syncthreads();
        if (t < s) buf[t] = buf[t + s] > buf[t] ? buf[t + s] : buf[t];
    }
    if (t == 0) part[8 * blockIdx.x] = buf[0];
}

/* Each vertex's cell and key at x0. */
__global__ void k_sc_keys(const float *__restrict__ x0, int32_t n, float cell, uint32_t mask, uint32_t *key, int32_t *cc)
{
    const int32_t v = (int32_t)(blockIdx.x * blockDim.x + threadIdx.x);
    if (v >= n) return;
    key[v] = cs_sc_cell_of(cs_sc_at(x0, x0 + n, x0 + 2 * (size_t)n, v), cell, mask, cc + 3 * (size_t)v);
}

/* The counting sort of cs_sc_sort in parallel, ending with its start and ids (a cell's vertices
 * in vertex order): the cells counted (integer atomics, exact in any order), their sums in one
 * block, each vertex placed in its cell by an atomic cursor, then each cell put back in vertex
 * order. start and cursor zeroed before. */
__global__ void k_sc_count(int32_t n, const uint32_t *key, int32_t *start)
{
    const int32_t v = (int32_t)(blockIdx.x * blockDim.x + threadIdx.x);
    if (v < n) atomicAdd(&start[key[v] + 1], 1);
}

#define SC_SCAN_THREADS 1024
/* start[k] = start[0] + .. + start[k] over `entries`, one block: each thread a run of them. */
__global__ void __launch_bounds__(SC_SCAN_THREADS) k_sc_scan(int32_t *start, uint32_t entries)
{
    __shared__ int32_t before[SC_SCAN_THREADS];
    const uint32_t t = threadIdx.x, per = (entries + blockDim.x - 1) / blockDim.x;
    const uint32_t a = t * per < entries ? t * per : entries, b = a + per < entries ? a + per : entries;
    int32_t sum = 0;
    for (uint32_t k = a; k < b; k++) start[k] = sum += start[k];
    before[t] = sum;
    __syncthreads();
    if (t == 0) /* each run's total into what comes before it */
        for (uint32_t q = 0, run = 0; q < blockDim.x; q++) {
            const int32_t x = before[q];
            before[q] = (int32_t)run;
            run += (uint32_t)x;
        }
    __syncthreads();
    for (uint32_t k = a; k < b; k++) start[k] += before[t];
}

__global__ void k_sc_fill(int32_t n, const uint32_t *key, const int32_t *start, int32_t *cursor, int32_t *ids)
{
    const int32_t v = (int32_t)(blockIdx.x * blockDim.x + threadIdx.x);
    if (v >= n) return;
    const uint32_t k = key[v];
    ids[start[k] + atomicAdd(&cursor[k], 1)] = v;
}

/* Cell k's vertices in vertex order (insertion sort: a cell holds a few). */
__global__ void k_sc_order(uint32_t cells, const int32_t *start, int32_t *ids)
{
    const uint32_t k = blockIdx.x * blockDim.x + threadIdx.x;
    if (k >= cells) return;
    for (int32_t i = start[k] + 1; i < start[k + 1]; i++) {
        const int32_t v = ids[i];
        int32_t j = i;
        for (; j > start[k] && ids[j - 1] > v; j--) ids[j] = ids[j - 1];
        ids[j] = v;
    }
}

/* Each block's least and largest of a (3 n, SoA) per axis (part[8 b .. 8 b + 5]). */
__global__ void __launch_bounds__(SC_THREADS) k_sc_box(const float *__restrict__ a, int32_t n, float *part)
{
    CS_DYNAMIC_SHARED(float, buf);
    const int32_t v = (int32_t)(blockIdx.x * blockDim.x + threadIdx.x);
    float lo[3] = {3e38f, 3e38f, 3e38f}, hi[3] = {-3e38f, -3e38f, -3e38f};
    if (v < n)
        for (int q = 0; q < 3; q++) {
            const float x = a[(size_t)q * n + v];
            lo[q] = x < lo[q] ? x : lo[q];
            hi[q] = x > hi[q] ? x : hi[q];
        }
    sc_block_minmax(buf, lo, hi, part);
}

/* Vertex v's repelling pairs within rad at x0: counted (keys NULL), or written into its room. */
__global__ void k_sc_pairs(const cuda_scene *__restrict__ sc, cs_sc_grid G, const float *__restrict__ L0,
                           const float *__restrict__ x0, float reach, float rad, int32_t *count,
                           const int64_t *__restrict__ first, int64_t *keys)
{
    const cs_phys *p = &sc->p;
    const int32_t v = (int32_t)(blockIdx.x * blockDim.x + threadIdx.x), n = p->n;
    if (v >= n) return;
    const float *y0 = x0 + n, *z0 = y0 + n;
    if (!keys) count[v] = cs_sc_pairs(p, &G, L0, x0, y0, z0, reach, rad, v, NULL, 0);
    else if (count[v]) cs_sc_pairs(p, &G, L0, x0, y0, z0, reach, rad, v, keys + first[v], count[v]);
}

/* Each block's fastest closing of a repelling pair that may touch within h (cs_sc_near_speed over
 * each vertex's list) into part[8 b]. */
__global__ void __launch_bounds__(SC_THREADS) k_sc_near(const cuda_scene *__restrict__ sc, const float *__restrict__ S,
                                                        float h, const int32_t *__restrict__ count,
                                                        const int64_t *__restrict__ first,
                                                        const int64_t *__restrict__ keys, float *part)
{
    CS_DYNAMIC_SHARED(float, buf);
    const cs_phys *p = &sc->p;
    const int t = (int)threadIdx.x;
    const int32_t v = (int32_t)(blockIdx.x * blockDim.x + threadIdx.x), n = p->n;
    const size_t N = (size_t)n;
    float most = 0.0f;
    if (v < n && count[v])
        most = cs_sc_near_speed(p, S, S + N, S + 2 * N, S + 3 * N, S + 4 * N, S + 5 * N, h, keys + first[v], count[v]);
    buf[t] = most;
    for (int s = SC_THREADS / 2; s > 0; s >>= 1) {
        __syncthreads();
        if (t < s) buf[t] = buf[t + s] > buf[t] ? buf[t + s] : buf[t];
    }
    if (t == 0) part[8 * blockIdx.x] = buf[0];
}

/* Vertex v's repulsion (cs_sc_repel) from its list into push; touched[v] its touching pairs. */
__global__ void k_sc_repel(const cuda_scene *__restrict__ sc, const float *__restrict__ S, const float *__restrict__ x0,
                           const float *__restrict__ w,
                           const int32_t *__restrict__ count, const int64_t *__restrict__ first,
                           const int64_t *__restrict__ keys, float *push, int32_t *touched, int *flags)
{
    const cs_phys *p = &sc->p;
    const int32_t v = (int32_t)(blockIdx.x * blockDim.x + threadIdx.x), n = p->n;
    if (v >= n) return;
    int32_t t = 0;
    if (count[v]) {
        const size_t N = (size_t)n;
        cs_vec3 dx = cs_v3(0.0f, 0.0f, 0.0f), dv = dx;
        t = cs_sc_repel(p, S, S + N, S + 2 * N, S + 3 * N, S + 4 * N, S + 5 * N, w, x0, x0 + N, x0 + 2 * N,
                        keys + first[v], count[v], v, &dx, &dv);
        float *q = push + 6 * (size_t)v;
        q[0] = dx.x, q[1] = dx.y, q[2] = dx.z, q[3] = dv.x, q[4] = dv.y, q[5] = dv.z;
        if (t) atomicAdd(&flags[1], t);
    }
    touched[v] = t;
}

/* The repulsion added where a pair touched. */
__global__ void k_sc_push(float *S, const float *__restrict__ push, const int32_t *__restrict__ touched, int32_t n)
{
    const int32_t v = (int32_t)(blockIdx.x * blockDim.x + threadIdx.x);
    if (v >= n || !touched[v]) return;
    const float *q = push + 6 * (size_t)v;
    for (int k = 0; k < 6; k++) S[(size_t)k * n + v] += q[k];
}

__global__ void k_sc_ones(float *s, int32_t n)
{
    const int32_t v = (int32_t)(blockIdx.x * blockDim.x + threadIdx.x);
    if (v < n) s[v] = s[(size_t)n + v] = 1.0f;
}

/* One sweep of the bound: b[v] = cs_sc_limit over the grid; flags[0] set when a scale changes. */
__global__ void k_sc_limit(const cuda_scene *__restrict__ sc, cs_sc_grid G, const float *__restrict__ L0,
                           const float *__restrict__ x0, const float *__restrict__ d, const float *__restrict__ a,
                           float *b, float r, float reach, int outright, int *flags)
{
    const cs_phys *p = &sc->p;
    const int32_t v = (int32_t)(blockIdx.x * blockDim.x + threadIdx.x), n = p->n;
    if (v >= n) return;
    const size_t N = (size_t)n;
    float dall;
    int32_t nk;
    b[v] = cs_sc_limit(p, &G, L0, x0, x0 + N, x0 + 2 * N, d, d + N, d + 2 * N, a, r, reach, v, outright, &dall, NULL, 0,
                       &nk);
    if (b[v] != a[v]) atomicOr(&flags[0], 1);
}

/* x = x0 + s d and v = s v where the bound cut (s < 1); flags[2] counts them. */
__global__ void k_sc_cut(float *S, const float *__restrict__ x0, const float *__restrict__ d,
                         const float *__restrict__ s, int32_t n, int *flags)
{
    const int32_t v = (int32_t)(blockIdx.x * blockDim.x + threadIdx.x);
    if (v >= n) return;
    const float k = s[v];
    if (!(k < 1.0f)) return;
    const size_t N = (size_t)n;
    for (int q = 0; q < 3; q++) S[q * N + v] = x0[q * N + v] + k * d[q * N + v];
    for (int q = 3; q < 6; q++) S[q * N + v] *= k;
    atomicAdd(&flags[2], 1);
}

/* ---- the host's sequence ---- */

/* Before a substep (a part): x0 and w from the state now. */
static cs_status sc_begin(cuda_ctx *c, int32_t n)
{
    const cs_status st = sc_fit(c, n);
    if (st != CS_OK) return st;
    sc_work *w = c->scw;
    k_sc_begin<<<sc_blocks(n), SC_THREADS, 0, c->stream>>>(c->vb.state[c->cur], c->vb.mask, w->x0, w->w, n);
    CUDA_CHECK(cudaGetLastError());
    return CS_OK;
}

/* Waits for the stream and copies back k floats a block (of `blocks`) from part. */
static cs_status sc_partials(cuda_ctx *c, unsigned blocks)
{
    sc_work *w = c->scw;
    CUDA_CHECK(cudaGetLastError());
    CUDA_CHECK(cudaMemcpyAsync(w->host_part, w->part, sizeof(float) * 8 * blocks, cudaMemcpyDeviceToHost, c->stream));
    CUDA_CHECK(cudaStreamSynchronize(c->stream));
    return CS_OK;
}

/* The centre of the box the blocks' least and largest (part[8 b .. 8 b + 5], read back) make. */
static cs_vec3 sc_box_centre(const sc_work *w, unsigned nb)
{
    float lo[3] = {3e38f, 3e38f, 3e38f}, hi[3] = {-3e38f, -3e38f, -3e38f};
    for (unsigned b = 0; b < nb; b++)
        for (int q = 0; q < 3; q++) {
            const float l = w->host_part[8 * b + q], h = w->host_part[8 * b + 3 + q];
            lo[q] = l < lo[q] ? l : lo[q];
            hi[q] = h > hi[q] ? h : hi[q];
        }
    return cs_sc_centre(lo, hi);
}

/* displacements() of selfcontact_cpu.c: d = x - x0; M (from the centre of all the displacements)
 * and *Ma (the largest). */
static cs_status sc_displacements(cuda_ctx *c, const float *S, int32_t n, float *M, float *Ma)
{
    sc_work *w = c->scw;
    const unsigned nb = sc_blocks(n);
    k_sc_disp<<<nb, SC_THREADS, sizeof(float) * 6 * SC_THREADS, c->stream>>>(S, w->x0, w->d, n, w->part);
    cs_status st = sc_partials(c, nb);
    if (st != CS_OK) return st;
    const cs_vec3 centre = sc_box_centre(w, nb);
    k_sc_far<<<nb, SC_THREADS, sizeof(float) * 2 * SC_THREADS, c->stream>>>(w->d, n, centre, w->part);
    if ((st = sc_partials(c, nb)) != CS_OK) return st;
    float most = 0.0f, abs_most = 0.0f;
    for (unsigned b = 0; b < nb; b++) {
        const float l = w->host_part[8 * b], a = w->host_part[8 * b + 1];
        most = l > most ? l : most;
        abs_most = a > abs_most ? a : abs_most;
    }
    *M = n > 0 ? most : 0.0f;
    *Ma = abs_most;
    return CS_OK;
}

/* The hash grid of x0 with cells of `cell`. */
static cs_status sc_grid(cuda_ctx *c, int32_t n, float cell, cs_sc_grid *G)
{
    sc_work *w = c->scw;
    k_sc_keys<<<sc_blocks(n), SC_THREADS, 0, c->stream>>>(w->x0, n, cell, w->mask, w->key, w->cc);
    const uint32_t cells = w->mask + 1;
    CUDA_CHECK(cudaMemsetAsync(w->start, 0, sizeof(int32_t) * 2 * ((size_t)cells + 1), c->stream)); /* and cursor */
    k_sc_count<<<sc_blocks(n), SC_THREADS, 0, c->stream>>>(n, w->key, w->start);
    k_sc_scan<<<1, SC_SCAN_THREADS, 0, c->stream>>>(w->start, cells + 1);
    k_sc_fill<<<sc_blocks(n), SC_THREADS, 0, c->stream>>>(n, w->key, w->start, w->cursor, w->ids);
    k_sc_order<<<sc_blocks((int32_t)cells), SC_THREADS, 0, c->stream>>>(cells, w->start, w->ids);
    CUDA_CHECK(cudaGetLastError());
    G->start = w->start, G->ids = w->ids, G->cc = w->cc, G->mask = w->mask, G->cell = cell;
    return CS_OK;
}

/* Every vertex's list of repelling pairs within rad at x0 (cs_sc_pairs over grid G, whose cells are
 * the candidates' reach): counted, laid out on the host (an exact prefix sum; the key buffer grows
 * to fit, and a failed allocation is an error, never a dropped pair), filled and sorted; the total
 * into *total. */
static cs_status sc_pair_lists(cuda_ctx *c, int32_t n, const cs_sc_grid *G, const float *L0, float rad, int64_t *total)
{
    sc_work *w = c->scw;
    const unsigned nb = sc_blocks(n);
    k_sc_pairs<<<nb, SC_THREADS, 0, c->stream>>>(c->sc, *G, L0, w->x0, G->cell, rad, w->count, NULL, NULL);
    CUDA_CHECK(cudaGetLastError());
    CUDA_CHECK(cudaMemcpyAsync(w->host_count, w->count, sizeof(int32_t) * (size_t)n, cudaMemcpyDeviceToHost, c->stream));
    CUDA_CHECK(cudaStreamSynchronize(c->stream));
    int64_t all = 0;
    for (int32_t v = 0; v < n; v++) w->host_first[v] = all, all += w->host_count[v];
    if (all > w->cap) {
        const int64_t cap = all > 2 * w->cap ? all : 2 * w->cap;
        cudaFree(w->keys);
        w->keys = NULL, w->cap = 0;
        CUDA_CHECK(cudaMalloc((void **)&w->keys, sizeof(int64_t) * (size_t)cap));
        w->cap = cap;
    }
    if (all > 0) {
        CUDA_CHECK(cudaMemcpyAsync(w->first, w->host_first, sizeof(int64_t) * (size_t)n, cudaMemcpyHostToDevice, c->stream));
        k_sc_pairs<<<nb, SC_THREADS, 0, c->stream>>>(c->sc, *G, L0, w->x0, G->cell, rad, w->count, w->first, w->keys);
        CUDA_CHECK(cudaGetLastError());
    }
    *total = all;
    return CS_OK;
}

/* The longest intact edge at x0 (k_sc_edge, its blocks' maxima totalled here). */
static cs_status sc_longest(cuda_ctx *c, int32_t n, const float *L0, float *L)
{
    sc_work *w = c->scw;
    const unsigned nb = sc_blocks(n);
    k_sc_edge<<<nb, SC_THREADS, sizeof(float) * SC_THREADS, c->stream>>>(c->sc, w->x0, L0, w->part);
    const cs_status st = sc_partials(c, nb);
    if (st != CS_OK) return st;
    float most = 0.0f;
    for (unsigned b = 0; b < nb; b++) most = w->host_part[8 * b] > most ? w->host_part[8 * b] : most;
    *L = most;
    return CS_OK;
}

/* cs_sc_part_rate of selfcontact_cpu.c on the state the context holds (x0 set to its positions):
 * the fastest vertex of a repelling pair that may touch within h, about the velocities' centre,
 * over CS_SC_PART self_thickness, into *rate (0 where none may). The pairs from every vertex's
 * gathered list within the fastest's reach (the CPU's lists hold them all too). */
static cs_status sc_part_rate(cuda_ctx *c, const cs_phys *p, float h, float *rate)
{
    const int32_t n = p->n;
    cs_status st = sc_begin(c, n);
    if (st != CS_OK) return st;
    sc_work *w = c->scw;
    const float *S = c->vb.state[c->cur], *L0 = c->vb.rest[c->rest_cur];
    const unsigned nb = sc_blocks(n);
    k_sc_box<<<nb, SC_THREADS, sizeof(float) * 6 * SC_THREADS, c->stream>>>(S + 3 * (size_t)n, n, w->part);
    if ((st = sc_partials(c, nb)) != CS_OK) return st;
    const cs_vec3 cv = sc_box_centre(w, nb);
    k_sc_far<<<nb, SC_THREADS, sizeof(float) * 2 * SC_THREADS, c->stream>>>(S + 3 * (size_t)n, n, cv, w->part);
    if ((st = sc_partials(c, nb)) != CS_OK) return st;
    float Vm = 0.0f; /* the largest cs_sc_speed: the largest |v - cv|, then gravity's part */
    for (unsigned b = 0; b < nb; b++) Vm = w->host_part[8 * b] > Vm ? w->host_part[8 * b] : Vm;
    Vm += cs_len(p->gravity) * h;
    *rate = 0.0f;
    if (!(Vm < 3.0e38f)) return CS_OK; /* not finite: the step reports it */
    float L;
    if ((st = sc_longest(c, n, L0, &L)) != CS_OK) return st;
    const float rad = cs_sc_near_reach(p->self_thickness, h, Vm);
    cs_sc_grid G;
    if ((st = sc_grid(c, n, rad + 2.0f * L, &G)) != CS_OK) return st;
    int64_t total;
    if ((st = sc_pair_lists(c, n, &G, L0, rad, &total)) != CS_OK) return st;
    if (total == 0) return CS_OK;
    k_sc_near<<<nb, SC_THREADS, sizeof(float) * SC_THREADS, c->stream>>>(c->sc, S, h, w->count, w->first, w->keys, w->part);
    if ((st = sc_partials(c, nb)) != CS_OK) return st;
    float most = 0.0f;
    for (unsigned b = 0; b < nb; b++) most = w->host_part[8 * b] > most ? w->host_part[8 * b] : most;
    *rate = most / (CS_SC_PART * p->self_thickness);
    return CS_OK;
}

/* cs_sc_end of selfcontact_cpu.c, every pass a full one: after a substep (a part) that began at
 * sc_begin, on the state the context holds now. */
static cs_status sc_end(cuda_ctx *c, const cs_phys *p, cs_self_stats *stats)
{
    sc_work *w = c->scw;
    const int32_t n = p->n;
    float *S = c->vb.state[c->cur];
    const float *L0 = c->vb.rest[c->rest_cur];
    const unsigned nb = sc_blocks(n);
    float M, Ma;
    cs_status st = sc_displacements(c, S, n, &M, &Ma);
    if (st != CS_OK) return st;
    if (!(M < 3.0e38f)) return CS_OK; /* not finite: the step reports it */
    CUDA_CHECK(cudaMemsetAsync(w->flag, 0, sizeof(int) * 3, c->stream));
    /* the longest edge at x0, the grid, the lists (selfcontact_cpu.c's path without lists) */
    float L;
    if ((st = sc_longest(c, n, L0, &L)) != CS_OK) return st;
    /* the pairs that may touch at x1: within self_thickness + 2 M at x0 (the CPU looks wider, for
     * lists it keeps; the pairs that touch, and so the bits, are the same) */
    const float Rl = p->self_thickness + 2.0f * M;
    float cell = Rl + 2.0f * L;
    cs_sc_grid G;
    if ((st = sc_grid(c, n, cell, &G)) != CS_OK) return st;
    int64_t total;
    if ((st = sc_pair_lists(c, n, &G, L0, Rl, &total)) != CS_OK) return st;
    if (total > 0) {
        k_sc_repel<<<nb, SC_THREADS, 0, c->stream>>>(c->sc, S, w->x0, w->w, w->count, w->first, w->keys, w->push,
                                                    w->touched, w->flag);
    } else {
        CUDA_CHECK(cudaMemsetAsync(w->touched, 0, sizeof(int32_t) * (size_t)n, c->stream));
    }
    CUDA_CHECK(cudaGetLastError());
    CUDA_CHECK(cudaMemcpyAsync(w->host_flag, w->flag, sizeof(int) * 3, cudaMemcpyDeviceToHost, c->stream));
    CUDA_CHECK(cudaStreamSynchronize(c->stream));
    const int touching = w->host_flag[1];
    if (touching > 0) {
        k_sc_push<<<nb, SC_THREADS, 0, c->stream>>>(S, w->push, w->touched, n);
        if ((st = sc_displacements(c, S, n, &M, &Ma)) != CS_OK) return st;
    }
    /* the bound, from scales of 1, every vertex looking at its pairs within r (the CPU's lists
     * hold those within their own reach: a pair beyond it is safe, so the cuts, and the bits, are
     * the same) */
    const float R = p->self_thickness + 2.0f * Ma / CS_SC_GAMMA, reach = R + 2.0f * L;
    if (!(cell >= reach) && (st = sc_grid(c, n, cell = reach, &G)) != CS_OK) return st;
    k_sc_ones<<<nb, SC_THREADS, 0, c->stream>>>(w->s, n);
    float *a = w->s, *b = w->s + n;
    int changed = 1;
    for (int sweep = 0; changed && sweep <= CS_SC_SWEEPS; sweep++) {
        CUDA_CHECK(cudaMemsetAsync(w->flag, 0, sizeof(int), c->stream));
        k_sc_limit<<<nb, SC_THREADS, 0, c->stream>>>(c->sc, G, L0, w->x0, w->d, a, b, R, reach, sweep == CS_SC_SWEEPS,
                                                    w->flag);
        CUDA_CHECK(cudaGetLastError());
        CUDA_CHECK(cudaMemcpyAsync(w->host_flag, w->flag, sizeof(int), cudaMemcpyDeviceToHost, c->stream));
        CUDA_CHECK(cudaStreamSynchronize(c->stream));
        changed = w->host_flag[0];
        float *t = a;
        a = b, b = t;
    }
    k_sc_cut<<<nb, SC_THREADS, 0, c->stream>>>(S, w->x0, w->d, a, n, w->flag);
    CUDA_CHECK(cudaGetLastError());
    CUDA_CHECK(cudaMemcpyAsync(w->host_flag, w->flag, sizeof(int) * 3, cudaMemcpyDeviceToHost, c->stream));
    CUDA_CHECK(cudaStreamSynchronize(c->stream));
    if (stats) {
        stats->passes++;
        stats->broad++;
        stats->pairs += total;
        stats->contacts += touching;
        stats->cut += w->host_flag[2];
    }
    return CS_OK;
}

#endif /* CLOTHSIM_CUDA_SELFCONTACT_CUDA_CUH */
