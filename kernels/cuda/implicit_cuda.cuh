/* implicit_cuda.cuh - integrator implicit_euler on the device (kernels/MODEL.md, "The implicit
 * solver"), for one scene or a batch of them: the host sequence that launches its kernels
 * (implicit_kernel_impl.cuh) - im_run, which im_step runs for a scene alone and im_batch_run
 * (batch_cuda.cuh) for a batch - and im_refresh; a batch's tables; the workspace's allocation.
 * Part of the one translation unit backend_cuda.cu.
 *
 * A part of a substep runs the first guess, then Newton (assemble, the multigrid hierarchy,
 * conjugate gradients preconditioned by a V-cycle, a backtracking line search), then the
 * accelerations and the strain pass, as implicit_cpu.c's part. The iterate lives in the state
 * buffer a substep writes (state[cur ^ 1]); the part's start (x_n, v_n) is copied aside, so the
 * buffers swap once a part as the explicit substeps do.
 *
 * Batches. Every launch covers a batch of scenes (a scene alone is a batch of one): the kernels
 * read a device table of the scenes (im_scene: each one's buffers, its workspace, its levels) and,
 * per launch shape (IS_*, and per level IL_*), the prefix sums of the blocks each scene takes.
 * What differs between scenes from one phase to the next - whether a scene takes part (Newton
 * done, a line search that took its step, a substep with fewer parts), its line search's step, its
 * conjugate gradients' target - is a small table (im_dyn) the host writes after each wait; the
 * scalars the host decides on come back in one copy for the whole batch (im_res). So a batch costs
 * the launches and waits of its slowest scene, not their sum, and each scene's bits are those it
 * has alone (the kernels it takes part in, in the same order). The levels of the V-cycle differ
 * with a scene's size: a scene takes part in a level's launches only while that level is above
 * IM_TAIL vertices, and its small levels run in one block (k_im_tail) from the first level at or
 * below it. A conjugate-gradient iteration is one graph for the whole batch (im_cg_queue).
 *
 * Self-collision's pass (selfcontact_cuda.cuh) works on one scene: a scene with self_collision on
 * steps alone (a batch of one), its pass after each part. */
#ifndef CLOTHSIM_CUDA_IMPLICIT_CUDA_CUH
#define CLOTHSIM_CUDA_IMPLICIT_CUDA_CUH

#include "implicit_kernel_impl.cuh"
#include "memory_cuda.cuh"
#include "selfcontact_cuda.cuh"

/* Launch shapes: the blocks a scene takes in a launch. Fixed ones, then per level l
 * (im_shape(l, IL_*)): the level's vertices (3 n of them) where it is above IM_TAIL and not the
 * last, the coarse vertices it restricts to, one block where its small levels start (the tail),
 * the level's vertices where it is above IM_TAIL and the last (the coarsest sweeps), the
 * hierarchy's Galerkin rows (l > 0) and inverses. A scene out of a shape takes 0 blocks. */
enum { IS_CHUNK, IS_VERT, IS_VERT3, IS_ROWS, IS_ONE, IS_ROCKS, IS_STRAIN, IS_FIXED };
enum { IL_LEVEL, IL_LEVEL3, IL_COARSE, IL_TAIL, IL_LAST, IL_GALERKIN, IL_INVERSE, IL_COUNT };
#define IM_SHAPES (IS_FIXED + IL_COUNT * CS_IM_MAX_LEVELS)
static inline int im_shape(int l, int k) { return IS_FIXED + l * IL_COUNT + k; }

/* A batch's tables, device and pinned (the dyn and part tables twice: the host fills one while the
 * copy of the other may still be queued), and the host's state of each scene. One per context for
 * its lone steps, one per process for batches (under batch_lock). */
struct im_host;
struct im_item;
struct im_batch {
    int32_t cap, m;
    cudaStream_t stream;
    im_scene *tab, *host_tab;
    im_dyn *dyn, *host_dyn;       /* host: [2][cap] */
    im_res *res, *host_res;
    cuda_scene *parts, *host_parts; /* host: [2][cap] */
    int32_t *start, *host_start;  /* [IM_SHAPES][cap + 1] */
    im_dyn *dyn_h;                /* [cap]: what the host decides, sent by im_put */
    cuda_scene *parts_h;          /* [cap] */
    struct im_host *hs;           /* [cap] */
    struct im_item *items;        /* [cap]: the run's scenes */
    int half, staged;             /* the staging half sent last; sends since the last wait */
    int table_staged;             /* the table's staging copied since the last wait */
    cudaGraphExec_t cg_exec;      /* one conjugate-gradient iteration of the batch (im_cg_queue) */
    int32_t cg_blocks[IM_SHAPES + 1]; /* the launch sizes (and m) it was captured for */
};

static void im_batch_free(im_batch *b)
{
    if (!b) return;
    cudaFree(b->tab);
    cudaFree(b->dyn);
    cudaFree(b->res);
    cudaFree(b->parts);
    cudaFree(b->start);
    cudaFreeHost(b->host_tab);
    cudaFreeHost(b->host_dyn);
    cudaFreeHost(b->host_res);
    cudaFreeHost(b->host_parts);
    cudaFreeHost(b->host_start);
    free(b->dyn_h);
    free(b->parts_h);
    free(b->hs);
    free(b->items);
    if (b->cg_exec) cudaGraphExecDestroy(b->cg_exec);
    memset(b, 0, sizeof *b);
}

static void im_free(im_work *w)
{
    if (!w) return;
    cudaFree(w->mem);
    cudaFree(w->ints);
    cudaFree(w->star);
    cudaFree(w->rv3);
    im_batch_free(w->one);
    free(w->one);
    free(w);
}


static unsigned im_blocks(int64_t threads) { return (unsigned)((threads + IM_THREADS - 1) / IM_THREADS); }

/* The workspace for this cloth (kept while its size stays); its arrays zeroed, as the CPU's. The
 * batch of one its lone steps run moves to the new workspace. */
static cs_status im_fit(cuda_ctx *c, const cs_phys *p)
{
    if (c->im && c->im->nx == p->nx && c->im->ny == p->ny && c->im->nchunks == p->nchunks) return CS_OK;
    im_work *w = (im_work *)calloc(1, sizeof *w);
    if (!w) return CS_E_NOMEM;
    w->nx = p->nx, w->ny = p->ny, w->n = p->n, w->nchunks = p->nchunks;
    const size_t S0 = cs_im_stride((size_t)w->n); /* level 0's, which the bending blocks share */
    size_t floats = (size_t)w->n * (6 + 3 + 18 + 5) + 2 * CS_IM_SYM * S0 + (size_t)w->nchunks + 6 * (size_t)w->ny;
    const size_t ints = 3 * (size_t)w->n + 2 * CS_MAX_ROCKS;
    int32_t lx[CS_IM_MAX_LEVELS], ly[CS_IM_MAX_LEVELS];
    const int L = w->levels = cs_im_levels(p->nx, p->ny, lx, ly);
    for (int l = 0; l < L; l++) {
        w->lv[l].nx = lx[l], w->lv[l].ny = ly[l], w->lv[l].n = lx[l] * ly[l];
        w->lv[l].S = cs_im_stride((size_t)w->lv[l].n);
        floats += cs_im_level_floats((size_t)w->lv[l].n);
    }
    cudaError_t e = cudaMalloc(&w->mem, sizeof(float) * floats);
    if (e == cudaSuccess) e = cudaMalloc((void **)&w->ints, sizeof(int32_t) * ints);
    if (e == cudaSuccess) e = cudaMalloc((void **)&w->star, sizeof(cs_rock_state) * CS_MAX_ROCKS);
    if (e == cudaSuccess) e = cudaMalloc((void **)&w->rv3, sizeof(cs_vec3) * 3 * CS_MAX_ROCKS);
    if (e == cudaSuccess) e = cudaMemsetAsync(w->mem, 0, sizeof(float) * floats, c->stream);
    if (e == cudaSuccess) e = cudaMemsetAsync(w->ints, 0xff, sizeof(int32_t) * ints, c->stream); /* sr -1 */
    if (e != cudaSuccess) {
        im_free(w);
        return cuda_fail(c, e, "allocating implicit_euler's workspace", __FILE__, __LINE__);
    }
    float *m = (float *)w->mem;
    const size_t n = (size_t)w->n;
#define TAKE(k) (m += (k), m - (k))
    w->base = TAKE(6 * n), w->xo = TAKE(3 * n);
    w->R = TAKE(3 * n), w->q = TAKE(3 * n), w->dx = TAKE(3 * n);
    w->r = TAKE(3 * n), w->z = TAKE(3 * n), w->p = TAKE(3 * n);
    w->B[0] = TAKE(CS_IM_SYM * S0), w->B[1] = TAKE(CS_IM_SYM * S0);
    w->part = TAKE((size_t)w->nchunks);
    w->sh = TAKE(n), w->sn = TAKE(3 * n), w->sg = TAKE(n);
    w->rowbox = TAKE(6 * (size_t)w->ny);
    w->cand = w->ints, w->sr = w->ints + 2 * n, w->rows = w->ints + 3 * n;
    for (int l = 0; l < L; l++) {
        im_level_bufs *v = &w->lv[l];
        m = cs_im_carve_level(m, (size_t)v->n, &v->D, &v->Dinv, v->F, &v->mask, &v->b, &v->x, &v->t);
    }
#undef TAKE
    if (c->im) w->one = c->im->one, c->im->one = NULL;
    im_free(c->im);
    c->im = w;
    return CS_OK;
}

/* A scene of a batch run: its context and model, the steps it takes, where its flags and report go. */
struct im_item {
    cuda_ctx *c;
    const cs_model *m;
    int32_t substeps;
    int *flags;
    cs_step_report *rep;
};

/* The host's state of a scene in a run: the part's phys, its parts, Newton's and the line search's
 * scalars (as part of implicit_cpu.c keeps them), what it reports. */
struct im_host {
    cuda_ctx *c;
    const cs_phys *p;
    cs_phys P;
    cs_solver_stats stats;
    int32_t substeps, parts;
    float rate, r, r0, prev, rn, rounding, a;
    int k, on, newton, search;
};

/* Room for m scenes (the tables of a batch; a batch of one's the first time). New arrays before the
 * old are freed; the graph of the old goes with them. */
static cs_status im_batch_reserve(cuda_ctx *c, im_batch *b, int32_t m)
{
    if (m <= b->cap) return CS_OK;
    int32_t cap = 1;
    while (cap < m) cap *= 2;
    im_batch g;
    memset(&g, 0, sizeof g);
    const size_t k = (size_t)cap, starts = sizeof(int32_t) * IM_SHAPES * (k + 1);
    cudaError_t e = cudaMalloc((void **)&g.tab, sizeof(im_scene) * k);
    if (e == cudaSuccess) e = cudaMalloc((void **)&g.dyn, sizeof(im_dyn) * k);
    if (e == cudaSuccess) e = cudaMalloc((void **)&g.res, sizeof(im_res) * k);
    if (e == cudaSuccess) e = cudaMalloc((void **)&g.parts, sizeof(cuda_scene) * k);
    if (e == cudaSuccess) e = cudaMalloc((void **)&g.start, starts);
    if (e == cudaSuccess) e = cudaMallocHost((void **)&g.host_tab, sizeof(im_scene) * k);
    if (e == cudaSuccess) e = cudaMallocHost((void **)&g.host_dyn, sizeof(im_dyn) * 2 * k);
    if (e == cudaSuccess) e = cudaMallocHost((void **)&g.host_res, sizeof(im_res) * k);
    if (e == cudaSuccess) e = cudaMallocHost((void **)&g.host_parts, sizeof(cuda_scene) * 2 * k);
    if (e == cudaSuccess) e = cudaMallocHost((void **)&g.host_start, starts);
    if (e == cudaSuccess) {
        g.dyn_h = (im_dyn *)calloc(k, sizeof(im_dyn));
        g.parts_h = (cuda_scene *)calloc(k, sizeof(cuda_scene));
        g.hs = (im_host *)calloc(k, sizeof(im_host));
        g.items = (im_item *)calloc(k, sizeof(im_item));
        if (!g.dyn_h || !g.parts_h || !g.hs || !g.items) e = cudaErrorMemoryAllocation;
    }
    if (e != cudaSuccess) {
        im_batch_free(&g);
        return cuda_fail(c, e, "allocating a batch's implicit_euler tables", __FILE__, __LINE__);
    }
    im_batch_free(b);
    g.cap = cap;
    *b = g;
    return CS_OK;
}

/* The device arrays of the batch's kernels, and a shape's block prefix sums. */
static im_dev im_dev_of(const im_batch *b)
{
    im_dev B;
    B.tab = b->tab, B.dyn = b->dyn, B.res = b->res, B.m = b->m;
    return B;
}
static const int32_t *im_start(const im_batch *b, int shape) { return b->start + (size_t)shape * ((size_t)b->cap + 1); }
/* The blocks a shape's launch takes over the batch. */
static unsigned im_total(const im_batch *b, int shape)
{
    return (unsigned)b->host_start[(size_t)shape * ((size_t)b->cap + 1) + (size_t)b->m];
}

/* A launch of kernel over the batch's blocks of shape (none where no scene takes one). */
#define IM_LAUNCH(b, shape, kernel, threads, smem, ...)                                                \
    do {                                                                                               \
        const unsigned nb_ = im_total((b), (shape));                                                   \
        if (nb_) kernel<<<nb_, (threads), (smem), (b)->stream>>>(im_dev_of(b), im_start((b), (shape)), __VA_ARGS__); \
    } while (0)
#define IM_LAUNCH0(b, shape, kernel, threads, smem)                                                    \
    do {                                                                                               \
        const unsigned nb_ = im_total((b), (shape));                                                   \
        if (nb_) kernel<<<nb_, (threads), (smem), (b)->stream>>>(im_dev_of(b), im_start((b), (shape))); \
    } while (0)
#define IM_CHUNK_SMEM (sizeof(float) * CS_CHUNK)

/* The blocks scene w (of phys p, nr rocks) takes in each shape (IS_*, im_shape). */
static void im_shapes(const im_work *w, const cs_phys *p, int32_t nr, int32_t blocks[IM_SHAPES])
{
    for (int s = 0; s < IM_SHAPES; s++) blocks[s] = 0;
    const int64_t n = w->n;
    blocks[IS_CHUNK] = w->nchunks;
    blocks[IS_VERT] = (int32_t)im_blocks(n);
    blocks[IS_VERT3] = (int32_t)im_blocks(3 * n);
    blocks[IS_ROWS] = (int32_t)im_blocks(w->ny);
    blocks[IS_ONE] = 1;
    blocks[IS_ROCKS] = nr > 0;
    blocks[IS_STRAIN] = p->strain_on ? (int32_t)im_blocks(n) : 0;
    for (int l = 0; l < w->levels; l++) {
        const int64_t nl = w->lv[l].n;
        const int big = nl > IM_TAIL, last = l + 1 == w->levels;
        if (big && !last) {
            blocks[im_shape(l, IL_LEVEL)] = (int32_t)im_blocks(nl);
            blocks[im_shape(l, IL_LEVEL3)] = (int32_t)im_blocks(3 * nl);
            blocks[im_shape(l, IL_COARSE)] = (int32_t)im_blocks(w->lv[l + 1].n);
        }
        if (big && last) blocks[im_shape(l, IL_LAST)] = (int32_t)im_blocks(nl);
        blocks[im_shape(l, IL_TAIL)] = !big && (l == 0 || w->lv[l - 1].n > IM_TAIL);
        if (l > 0) blocks[im_shape(l, IL_GALERKIN)] = (int32_t)im_blocks(nl);
        blocks[im_shape(l, IL_INVERSE)] = (int32_t)im_blocks(nl);
    }
}

/* The batch's table, from its items (each one's workspace fitted): each scene's descriptor and its
 * blocks in each shape, to the device (from pinned staging that no copy still reads: im_begin). */
static cs_status im_table(cuda_ctx *c, im_batch *b)
{
    const size_t stride = (size_t)b->cap + 1;
    for (int s = 0; s < IM_SHAPES; s++) b->host_start[(size_t)s * stride] = 0;
    for (int32_t j = 0; j < b->m; j++) {
        const im_item *it = &b->items[j];
        cuda_ctx *ck = it->c;
        im_scene *d = &b->host_tab[j];
        memset(d, 0, sizeof *d);
        d->sc = b->parts + j, d->own = ck->sc;
        for (int e = 0; e < 2; e++) d->state[e] = ck->vb.state[e], d->rest[e] = ck->vb.rest[e];
        d->mask = ck->vb.mask, d->acc = ck->vb.acc;
        d->rocks = ck->rb.rocks, d->nr = ck->host_sc.nr;
        d->flags = it->flags;
        for (int pos = 0; pos < 2; pos++)
            for (int rest = 0; rest < 2; rest++) {
                d->strain[pos][rest] = bufs_of(ck, pos, rest);
                d->strain[pos][rest].flags = it->flags;
            }
        d->w = *ck->im;
        int32_t blocks[IM_SHAPES];
        im_shapes(ck->im, &it->m->phys, d->nr, blocks);
        for (int s = 0; s < IM_SHAPES; s++)
            b->host_start[(size_t)s * stride + (size_t)j + 1] = b->host_start[(size_t)s * stride + (size_t)j] + blocks[s];
    }
    CUDA_CHECK(cudaMemcpyAsync(b->tab, b->host_tab, sizeof(im_scene) * (size_t)b->m, cudaMemcpyHostToDevice, b->stream));
    CUDA_CHECK(cudaMemcpyAsync(b->start, b->host_start, sizeof(int32_t) * IM_SHAPES * stride, cudaMemcpyHostToDevice,
                               b->stream));
    b->table_staged = 1;
    return CS_OK;
}

/* The host's dyn table (with parts, the part scenes too) to the device, through the staging half
 * the copy two sends ago read: after a wait since then, or a wait now. */
static cs_status im_put(cuda_ctx *c, im_batch *b, int parts)
{
    if (b->staged >= 2) {
        CUDA_CHECK(cudaStreamSynchronize(b->stream));
        b->staged = 0;
    }
    b->half ^= 1;
    const size_t m = (size_t)b->m, at = (size_t)b->half * (size_t)b->cap;
    memcpy(b->host_dyn + at, b->dyn_h, sizeof(im_dyn) * m);
    CUDA_CHECK(cudaMemcpyAsync(b->dyn, b->host_dyn + at, sizeof(im_dyn) * m, cudaMemcpyHostToDevice, b->stream));
    if (parts) {
        memcpy(b->host_parts + at, b->parts_h, sizeof(cuda_scene) * m);
        CUDA_CHECK(cudaMemcpyAsync(b->parts, b->host_parts + at, sizeof(cuda_scene) * m, cudaMemcpyHostToDevice,
                                   b->stream));
    }
    b->staged++;
    return CS_OK;
}

/* What the batch's scenes report (im_res) to the host, and the wait for it. */
static cs_status im_wait(cuda_ctx *c, im_batch *b)
{
    CUDA_CHECK(cudaGetLastError());
    CUDA_CHECK(cudaMemcpyAsync(b->host_res, b->res, sizeof(im_res) * (size_t)b->m, cudaMemcpyDeviceToHost, b->stream));
    CUDA_CHECK(cudaStreamSynchronize(b->stream));
    b->staged = b->table_staged = 0;
    return CS_OK;
}

/* A run of m scenes on stream st begins: the staging no copy still reads (a wait where one may: a
 * refresh's, or a failed run's). */
static cs_status im_begin(cuda_ctx *c, im_batch *b, int32_t m, cudaStream_t st)
{
    b->stream = st;
    if (b->staged || b->table_staged) {
        CUDA_CHECK(cudaStreamSynchronize(st));
        b->staged = b->table_staged = 0;
    }
    b->m = m;
    return CS_OK;
}

/* Sets each scene's dyn on from its host state's flag (the member `on`, `newton`, `search`). */
#define IM_ON(b, field)                                                                                \
    do {                                                                                               \
        for (int32_t j_ = 0; j_ < (b)->m; j_++) (b)->dyn_h[j_].on = (b)->hs[j_].field;                 \
    } while (0)

/* Whether a scene has its host state's flag. */
static int im_any(const im_batch *b, int im_host::*field)
{
    for (int32_t j = 0; j < b->m; j++)
        if (b->hs[j].*field) return 1;
    return 0;
}

/* The hierarchy from level 0's matrix: the coarse levels' Galerkin products, each level's Dinv. */
static void im_hierarchy(im_batch *b)
{
    for (int l = 0; l < CS_IM_MAX_LEVELS; l++) {
        if (l > 0) IM_LAUNCH(b, im_shape(l, IL_GALERKIN), k_im_galerkin, IM_THREADS, 0, l);
        IM_LAUNCH(b, im_shape(l, IL_INVERSE), k_im_inverse, IM_THREADS, 0, l);
    }
}

/* One V-cycle from level l: x = B b (vcycle of implicit_cpu.c; level 0's b and x the conjugate
 * gradients' r and z); with stop, nothing for a scene whose solve is done. Each scene takes the
 * launches its own V-cycle takes: its levels above IM_TAIL, then its tail. */
static void im_vcycle(im_batch *b, int l, int stop)
{
    if (l >= CS_IM_MAX_LEVELS) return;
    IM_LAUNCH(b, im_shape(l, IL_TAIL), k_im_tail, IM_TAIL_THREADS, 0, l, stop);
    const int last = im_shape(l, IL_LAST), lv = im_shape(l, IL_LEVEL);
    if (im_total(b, last)) { /* a coarsest level above IM_TAIL (the levels capped): its sweeps */
        IM_LAUNCH(b, last, k_im_jacobi, IM_THREADS, 0, l, 1, stop);
        for (int k = 1; k < CS_IM_COARSE_SWEEPS; k++) {
            IM_LAUNCH(b, last, k_im_apply, IM_THREADS, 0, l, 0, stop);
            IM_LAUNCH(b, last, k_im_jacobi, IM_THREADS, 0, l, 0, stop);
        }
    }
    if (!im_total(b, lv)) return;
    IM_LAUNCH(b, lv, k_im_jacobi, IM_THREADS, 0, l, 1, stop);
    for (int k = 1; k < CS_IM_SMOOTH; k++) {
        IM_LAUNCH(b, lv, k_im_apply, IM_THREADS, 0, l, 0, stop);
        IM_LAUNCH(b, lv, k_im_jacobi, IM_THREADS, 0, l, 0, stop);
    }
    IM_LAUNCH(b, lv, k_im_apply, IM_THREADS, 0, l, 0, stop);
    IM_LAUNCH(b, im_shape(l, IL_LEVEL3), k_im_sub, IM_THREADS, 0, l, stop);
    IM_LAUNCH(b, im_shape(l, IL_COARSE), k_im_restrict, IM_THREADS, 0, l, stop);
    im_vcycle(b, l + 1, stop);
    IM_LAUNCH(b, lv, k_im_prolong, IM_THREADS, 0, l, stop);
    for (int k = 0; k < CS_IM_SMOOTH; k++) {
        IM_LAUNCH(b, lv, k_im_apply, IM_THREADS, 0, l, 0, stop);
        IM_LAUNCH(b, lv, k_im_jacobi, IM_THREADS, 0, l, 0, stop);
    }
}

/* One iteration of the conjugate gradients, queued (pcg of implicit_cpu.c's loop body): every
 * scalar stays on the device, and once a scene's solve is done each launch does nothing for it. */
static void im_cg_iteration(im_batch *b)
{
    IM_LAUNCH(b, IS_VERT, k_im_apply, IM_THREADS, 0, 0, 1, 1);
    IM_LAUNCH(b, IS_CHUNK, k_im_dot, CS_CHUNK, IM_CHUNK_SMEM, IM_DOT_PQ, 1);
    IM_LAUNCH0(b, IS_ONE, k_im_cg_alpha, 1, 0);
    IM_LAUNCH0(b, IS_VERT3, k_im_cg_step, IM_THREADS, 0);
    IM_LAUNCH(b, IS_CHUNK, k_im_dot, CS_CHUNK, IM_CHUNK_SMEM, IM_DOT_RR, 1);
    IM_LAUNCH0(b, IS_ONE, k_im_cg_check, 1, 0);
    im_vcycle(b, 0, 1);
    IM_LAUNCH(b, IS_CHUNK, k_im_dot, CS_CHUNK, IM_CHUNK_SMEM, IM_DOT_RZ, 1);
    IM_LAUNCH0(b, IS_ONE, k_im_cg_beta, 1, 0);
    IM_LAUNCH0(b, IS_VERT3, k_im_cg_dir, IM_THREADS, 0);
}

/* Queues one iteration of the conjugate gradients: a graph of im_cg_iteration's launches, captured
 * for the batch's launch sizes (its kernels read the tables on the device, so it holds while the
 * batch's arrays and sizes stay: a scene's lone steps capture it once). */
static cs_status im_cg_queue(cuda_ctx *c, im_batch *b)
{
    int32_t key[IM_SHAPES + 1];
    for (int s = 0; s < IM_SHAPES; s++) key[s] = (int32_t)im_total(b, s);
    key[IM_SHAPES] = b->m;
    if (b->cg_exec && memcmp(key, b->cg_blocks, sizeof key) != 0) {
        cudaGraphExecDestroy(b->cg_exec);
        b->cg_exec = NULL;
    }
    if (!b->cg_exec) {
        CUDA_CHECK(cudaStreamBeginCapture(b->stream, cudaStreamCaptureModeThreadLocal));
        im_cg_iteration(b);
        const cudaError_t launched = cudaGetLastError();
        cudaGraph_t graph;
        const cudaError_t ended = cudaStreamEndCapture(b->stream, &graph);
        if (launched != cudaSuccess) {
            if (ended == cudaSuccess) cudaGraphDestroy(graph);
            return cuda_fail(c, launched, "a launch while capturing a graph", __FILE__, __LINE__);
        }
        CUDA_CHECK(ended);
        const cudaError_t ie = cudaGraphInstantiate(&b->cg_exec, graph, 0);
        cudaGraphDestroy(graph);
        if (ie != cudaSuccess) {
            b->cg_exec = NULL;
            return cuda_fail(c, ie, "cudaGraphInstantiate", __FILE__, __LINE__);
        }
        memcpy(b->cg_blocks, key, sizeof key);
    }
    CUDA_CHECK(cudaGraphLaunch(b->cg_exec, b->stream));
    return CS_OK;
}

/* Conjugate gradients on A dx = R preconditioned by a V-cycle (pcg of implicit_cpu.c) for the
 * scenes in a Newton iteration (dyn on; their targets and most iterations in dyn): each stops at
 * |r| <= its target or after its most iterations; the iterations into its statistics. The host
 * queues as many iterations as the slowest scene's last solve took before it first reads whether
 * the solves are done, then one at a time: about two waits a solve rather than three an iteration,
 * and an iteration queued past a scene's end costs it launches that return at once. (In
 * test_datapath's scene, with a part's first residual then waited for apart from its reach: as
 * many less one, 4.8 waits a Newton iteration and 198 graphs for 170 iterations; as many, 4.2 and
 * 215; one more, 3.8 and 239. As many, now: 3.9 and 215.) */
static cs_status im_pcg(cuda_ctx *c, im_batch *b)
{
    IM_LAUNCH(b, IS_VERT3, k_im_vectors, IM_THREADS, 0, 0);
    im_vcycle(b, 0, 0);
    IM_LAUNCH(b, IS_VERT3, k_im_vectors, IM_THREADS, 0, 1);
    IM_LAUNCH(b, IS_CHUNK, k_im_dot, CS_CHUNK, IM_CHUNK_SMEM, IM_DOT_RZ, 0);
    IM_LAUNCH0(b, IS_ONE, k_im_cg_begin, 1, 0);
    int most = 0, group = 1;
    for (int32_t j = 0; j < b->m; j++) {
        if (!b->hs[j].newton) continue;
        most = b->dyn_h[j].most > most ? b->dyn_h[j].most : most;
        group = b->hs[j].c->im->cg_last > group ? b->hs[j].c->im->cg_last : group;
    }
    int queued = 0;
    while (queued < most) {
        const int k = group < most - queued ? group : most - queued;
        for (int q = 0; q < k; q++) {
            const cs_status st = im_cg_queue(c, b);
            if (st != CS_OK) return st;
        }
        queued += k;
        const cs_status st = im_wait(c, b);
        if (st != CS_OK) return st;
        int done = 1;
        for (int32_t j = 0; j < b->m && done; j++) done = !b->hs[j].newton || b->host_res[j].cg.done;
        if (done) break;
        group = 1;
    }
    for (int32_t j = 0; j < b->m; j++) {
        if (!b->hs[j].newton) continue;
        const int its = queued > 0 ? b->host_res[j].cg.it : 0;
        b->hs[j].stats.cg += its;
        b->hs[j].c->im->cg_last = its;
    }
    CUDA_CHECK(cudaGetLastError());
    return CS_OK;
}

/* Assembles at the iterate of the scenes in dyn, and waits for each one's |R| (into rn). */
static cs_status im_residuals(cuda_ctx *c, im_batch *b)
{
    IM_LAUNCH(b, IS_CHUNK, k_im_assemble, CS_CHUNK, IM_CHUNK_SMEM, 1, 1, 1);
    IM_LAUNCH(b, IS_ONE, k_im_total, 1, 0, 0);
    const cs_status st = im_wait(c, b);
    if (st != CS_OK) return st;
    for (int32_t j = 0; j < b->m; j++)
        if (b->dyn_h[j].on) b->hs[j].rn = sqrtf(b->host_res[j].total);
    return CS_OK;
}

/* One part of a substep for the scenes with `on`, each of its own length (P.dt) (part of
 * implicit_cpu.c): from state[cur] into state[cur ^ 1], which then holds the state; torn springs
 * counted into the flags. */
static cs_status im_part(cuda_ctx *c, im_batch *b)
{
    cs_status st;
    int rocks = 0;
    for (int32_t j = 0; j < b->m; j++) {
        im_host *h = &b->hs[j];
        b->dyn_h[j].cur = h->c->cur, b->dyn_h[j].rest_cur = h->c->rest_cur, b->dyn_h[j].last = 0;
        if (!h->on) continue;
        b->parts_h[j] = h->c->host_sc;
        b->parts_h[j].p = h->P;
        rocks |= h->c->host_sc.nr > 0;
    }
    IM_ON(b, on);
    if ((st = im_put(c, b, 1)) != CS_OK) return st;
    /* the largest coordinate at the part's start, for float's floor; the first guess; the rocks
     * over the part without the cloth, and the mass they lend, from the part's start (after
     * k_im_begin: it reads level 0's mask); then the residual at the first guess */
    IM_LAUNCH0(b, IS_CHUNK, k_im_reach, CS_CHUNK, IM_CHUNK_SMEM);
    IM_LAUNCH(b, IS_ONE, k_im_total, 1, 0, 1);
    IM_LAUNCH(b, IS_VERT, k_im_begin, IM_THREADS, 0, 1);
    if (rocks) {
        IM_LAUNCH(b, IS_ROWS, k_im_row_boxes, IM_THREADS, 0, 0);
        IM_LAUNCH0(b, IS_ROCKS, k_im_rocks_begin, 1, 0);
    }
    if ((st = im_residuals(c, b)) != CS_OK) return st;
    for (int32_t j = 0; j < b->m; j++) {
        im_host *h = &b->hs[j];
        h->newton = 0;
        if (!h->on) continue;
        h->r = h->r0 = h->rn;
        h->k = 0;
        h->prev = 2.0f * h->r0 + 1.0f;
        /* Newton: stops as implicit_cpu.c's does (cs_im_newton_more) */
        h->rounding = cs_im_float_floor(&h->P, b->host_res[j].reach);
        h->newton = cs_im_newton_more(&h->P, h->k, h->r, h->r0, h->prev, h->rounding);
    }
    while (im_any(b, &im_host::newton)) {
        for (int32_t j = 0; j < b->m; j++) {
            im_host *h = &b->hs[j];
            if (!h->newton) continue;
            h->prev = h->r;
            b->dyn_h[j].target = cs_im_cg_target(&h->P, h->r0, h->r);
            b->dyn_h[j].most = h->P.cg_iterations;
        }
        IM_ON(b, newton);
        if ((st = im_put(c, b, 0)) != CS_OK) return st;
        im_hierarchy(b);
        if ((st = im_pcg(c, b)) != CS_OK) return st;
        /* the backtracking line search: a = 1, 1/2, 1/4, 1/8 while the residual does not fall */
        IM_LAUNCH0(b, IS_VERT, k_im_keep, IM_THREADS, 0);
        for (int32_t j = 0; j < b->m; j++) {
            im_host *h = &b->hs[j];
            h->search = h->newton, h->a = 1.0f, h->rn = h->r;
        }
        /* (the matrix only where another iteration may follow) */
        for (int32_t j = 0; j < b->m; j++) b->dyn_h[j].last = !(b->hs[j].k + 1 < b->hs[j].P.solver_iterations);
        for (int tries = 0; tries < 4 && im_any(b, &im_host::search); tries++) {
            IM_ON(b, search);
            for (int32_t j = 0; j < b->m; j++) b->dyn_h[j].a = b->hs[j].a;
            if ((st = im_put(c, b, 0)) != CS_OK) return st;
            IM_LAUNCH0(b, IS_VERT, k_im_move, IM_THREADS, 0);
            if ((st = im_residuals(c, b)) != CS_OK) return st;
            for (int32_t j = 0; j < b->m; j++) {
                im_host *h = &b->hs[j];
                if (!h->search) continue;
                if (h->rn < h->r) h->search = 0;
                else h->a *= 0.5f;
            }
        }
        /* no step along dx helps: back to x_k, and stop */
        for (int32_t j = 0; j < b->m; j++) {
            im_host *h = &b->hs[j];
            h->search = h->newton && !(h->rn < h->r);
            b->dyn_h[j].a = 0.0f, b->dyn_h[j].last = 1;
        }
        if (im_any(b, &im_host::search)) {
            IM_ON(b, search);
            if ((st = im_put(c, b, 0)) != CS_OK) return st;
            IM_LAUNCH0(b, IS_VERT, k_im_move, IM_THREADS, 0);
            if ((st = im_residuals(c, b)) != CS_OK) return st;
            for (int32_t j = 0; j < b->m; j++)
                if (b->hs[j].search) b->hs[j].prev = b->hs[j].rn;
        }
        for (int32_t j = 0; j < b->m; j++) b->dyn_h[j].last = 0;
        for (int32_t j = 0; j < b->m; j++) {
            im_host *h = &b->hs[j];
            if (!h->newton) continue;
            h->k++;
            h->r = h->rn;
            h->newton = cs_im_newton_more(&h->P, h->k, h->r, h->r0, h->prev, h->rounding);
        }
    }
    for (int32_t j = 0; j < b->m; j++) {
        im_host *h = &b->hs[j];
        if (!h->on) continue;
        h->stats.newton += h->k;
        const float rel = h->r0 > 0.0f ? h->r / h->r0 : 0.0f;
        h->stats.residual = rel > h->stats.residual ? rel : h->stats.residual;
        h->stats.substeps++;
    }
    IM_ON(b, on);
    if ((st = im_put(c, b, 0)) != CS_OK) return st;
    if (rocks) {
        /* the rocks follow their vertices, rocks and cloth pushed apart, the approach stopped,
         * friction */
        IM_LAUNCH(b, IS_ROWS, k_im_row_boxes, IM_THREADS, 0, 1);
        IM_LAUNCH0(b, IS_ROCKS, k_im_rocks_push, 1, 0);
    }
    IM_LAUNCH0(b, IS_VERT, k_im_accel, IM_THREADS, 0);
    IM_LAUNCH0(b, IS_STRAIN, k_im_strain, 256, 0); /* with the part's phys, on the new positions */
    for (int32_t j = 0; j < b->m; j++) {
        im_host *h = &b->hs[j];
        if (!h->on) continue;
        h->c->cur ^= 1;
        if (h->P.strain_on) h->c->rest_cur ^= 1;
    }
    CUDA_CHECK(cudaGetLastError());
    return CS_OK;
}

/* A run of implicit_euler over the batch's items (b->items[0 .. m)) on stream st (cs_im_step of
 * implicit_cpu.c for each): substep by substep, each scene's parts (the most of any; a scene with
 * fewer, or fewer substeps, sits out), the solver's statistics into each report; torn springs and
 * a non-finite state into each one's flags. A scene with self_collision on runs alone (m 1): its
 * pass after each part. c records a CUDA failure. */
static cs_status im_run(cuda_ctx *c, im_batch *b, int32_t m, cudaStream_t st)
{
    cs_status s = im_begin(c, b, m, st);
    if (s != CS_OK) return s;
    int32_t most = 0;
    for (int32_t j = 0; j < m; j++) {
        const im_item *it = &b->items[j];
        im_host *h = &b->hs[j];
        memset(h, 0, sizeof *h);
        h->c = it->c, h->p = &it->m->phys, h->substeps = it->substeps;
        memset(&it->rep->solver, 0, sizeof it->rep->solver);
        if ((s = im_fit(it->c, h->p)) != CS_OK) return s;
        if (it->c->stream != st) { /* what the scene's stream holds (its workspace's zeroing) first */
            CUDA_CHECK(cudaEventRecord(it->c->queued, it->c->stream));
            CUDA_CHECK(cudaStreamWaitEvent(st, it->c->queued, 0));
        }
        most = h->substeps > most ? h->substeps : most;
    }
    if ((s = im_table(c, b)) != CS_OK) return s;
    for (int32_t k = 0; k < most; k++) {
        /* fastest() of implicit_cpu.c: how fast the cloth closes on a rock near it (0 without
         * one), and with self_collision how fast layers that may meet move (sc_part_rate) */
        int rates = 0;
        for (int32_t j = 0; j < m; j++) {
            im_host *h = &b->hs[j];
            h->on = h->substeps > k;
            h->rate = 0.0f;
            b->dyn_h[j].on = h->on && h->c->host_sc.nr > 0;
            b->dyn_h[j].cur = h->c->cur, b->dyn_h[j].rest_cur = h->c->rest_cur;
            b->dyn_h[j].a = h->p->dt;
            rates |= b->dyn_h[j].on;
        }
        if (rates) {
            if ((s = im_put(c, b, 0)) != CS_OK) return s;
            IM_LAUNCH0(b, IS_CHUNK, k_im_fastest_chunks, CS_CHUNK, IM_CHUNK_SMEM);
            IM_LAUNCH(b, IS_ROCKS, k_im_total, 1, 0, 2);
            if ((s = im_wait(c, b)) != CS_OK) return s;
            for (int32_t j = 0; j < m; j++)
                if (b->dyn_h[j].on) b->hs[j].rate = b->host_res[j].fast;
        }
        int32_t parts = 0;
        for (int32_t j = 0; j < m; j++) {
            im_host *h = &b->hs[j];
            if (!h->on) continue;
            float layers = 0.0f;
            if (h->p->self_on && (s = sc_part_rate(h->c, h->p, h->p->dt, &layers)) != CS_OK) return s;
            const float rate = layers > h->rate ? layers : h->rate;
            h->parts = cs_im_splits(rate, h->p->dt, h->p->most_splits);
            h->P = cs_im_part_phys(h->p, h->p->dt / (float)h->parts); /* the part's own step */
            parts = h->parts > parts ? h->parts : parts;
        }
        for (int32_t q = 0; q < parts; q++) {
            for (int32_t j = 0; j < m; j++) b->hs[j].on = b->hs[j].substeps > k && q < b->hs[j].parts;
            for (int32_t j = 0; j < m; j++)
                if (b->hs[j].on && b->hs[j].p->self_on && (s = sc_begin(b->hs[j].c, b->hs[j].p->n)) != CS_OK) return s;
            if ((s = im_part(c, b)) != CS_OK) return s;
            for (int32_t j = 0; j < m; j++)
                if (b->hs[j].on && b->hs[j].p->self_on &&
                    (s = sc_end(b->hs[j].c, b->hs[j].p, &b->items[j].rep->self)) != CS_OK)
                    return s;
        }
    }
    for (int32_t j = 0; j < m; j++) {
        b->hs[j].on = b->hs[j].substeps > 0;
        b->dyn_h[j].cur = b->hs[j].c->cur, b->dyn_h[j].rest_cur = b->hs[j].c->rest_cur;
    }
    IM_ON(b, on);
    if ((s = im_put(c, b, 0)) != CS_OK) return s;
    IM_LAUNCH0(b, IS_VERT, k_im_finite, IM_THREADS, 0);
    CUDA_CHECK(cudaGetLastError());
    for (int32_t j = 0; j < m; j++) b->items[j].rep->solver = b->hs[j].stats;
    b->staged = b->table_staged = 0; /* (each caller waits for the stream next: the flags' copy) */
    return CS_OK;
}

/* The batch of one a context's lone steps run (in its workspace, created with it), its item the
 * scene: m, substeps and rep (NULL for a refresh, which reports nothing). */
static cs_status im_one(cuda_ctx *c, const cs_model *m, int32_t substeps, cs_step_report *rep, im_batch **out)
{
    cs_status st = im_fit(c, &m->phys);
    if (st != CS_OK) return st;
    if (!c->im->one && !(c->im->one = (im_batch *)calloc(1, sizeof(im_batch)))) return CS_E_NOMEM;
    im_batch *b = c->im->one;
    if ((st = im_batch_reserve(c, b, 1)) != CS_OK) return st;
    b->items[0].c = c, b->items[0].m = m, b->items[0].substeps = substeps;
    b->items[0].flags = c->flags, b->items[0].rep = rep;
    *out = b;
    return CS_OK;
}

/* Substeps of implicit_euler on the device state (cs_im_step of implicit_cpu.c), the scene alone:
 * the solver's statistics into rep; torn springs and a non-finite state into the flags. */
static cs_status im_step(cuda_ctx *c, const cs_model *m, int32_t substeps, cs_step_report *rep)
{
    im_batch *b;
    const cs_status st = im_one(c, m, substeps, rep, &b);
    return st != CS_OK ? st : im_run(c, b, 1, c->stream);
}

/* cs_im_refresh: the accelerations a = F/m of the state as it is (the force law at v = v_n). */
static cs_status im_refresh(cuda_ctx *c, const cs_model *m)
{
    im_batch *b;
    cs_status st = im_one(c, m, 0, NULL, &b); /* (no step: nothing to report) */
    if (st != CS_OK) return st;
    if ((st = im_begin(c, b, 1, c->stream)) != CS_OK || (st = im_table(c, b)) != CS_OK) return st;
    memset(b->dyn_h, 0, sizeof *b->dyn_h);
    b->dyn_h[0].on = 1, b->dyn_h[0].cur = c->cur, b->dyn_h[0].rest_cur = c->rest_cur;
    b->parts_h[0] = c->host_sc;
    b->parts_h[0].p = m->phys;
    if ((st = im_put(c, b, 1)) != CS_OK) return st;
    IM_LAUNCH(b, IS_VERT, k_im_begin, IM_THREADS, 0, 0);
    /* nothing carried (the rocks are left as they are): the cloth's own force */
    IM_LAUNCH(b, IS_CHUNK, k_im_assemble, CS_CHUNK, IM_CHUNK_SMEM, 0, 0, 0);
    IM_LAUNCH0(b, IS_VERT, k_im_refresh_accel, IM_THREADS, 0);
    CUDA_CHECK(cudaGetLastError());
    return CS_OK;
}

#endif /* CLOTHSIM_CUDA_IMPLICIT_CUDA_CUH */
