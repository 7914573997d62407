/* implicit_cuda.cuh - integrator implicit_euler on the device (kernels/MODEL.md, "The implicit
 * solver"), for one scene or a batch of them: its workspace, its kernels (k_im_*) and the host
 * sequence that launches them (im_run: im_step for a scene alone, im_batch_step for a batch;
 * im_refresh). Part of the one translation unit backend_cuda.cu. */
#ifndef CLOTHSIM_CUDA_IMPLICIT_CUDA_CUH
#define CLOTHSIM_CUDA_IMPLICIT_CUDA_CUH

#include <math.h>

#include "clothsim/implicit.h"
#include "batch_kernel_impl.cuh"
#include "memory_cuda.cuh"

/* The CPU backend's sequence (implicit_cpu.c) with each of its loops a kernel that calls the same
 * functions of clothsim/implicit.h and physics.h per vertex, in the same order, so the state ends
 * bitwise the same. A part of a substep runs the first guess, then Newton (assemble, the
 * multigrid hierarchy, conjugate gradients preconditioned by a V-cycle, a backtracking line
 * search), then the accelerations and the strain pass. The iterate lives in the state buffer a
 * substep writes (state[cur ^ 1]); the part's start (x_n, v_n) is copied aside, so the buffers
 * swap once a part as the explicit substeps do.
 *
 * Batches. Every launch covers a batch of scenes (a scene alone is a batch of one): the kernels
 * read a device table of the scenes (im_scene: each one's buffers, its workspace, its levels) and,
 * per launch shape (IS_*, and per level IL_*), the prefix sums of the blocks each scene takes, so a
 * block finds its scene by binary search (batch_scene_of, as the explicit batch's kernels) and
 * works on that scene as a lone launch would. What differs between scenes from one phase to the
 * next - whether a scene takes part (Newton done, a line search that took its step, a substep
 * with fewer parts), its line search's step, its conjugate gradients' target - is a small table
 * (im_dyn) the host writes after each wait; the scalars the host decides on come back in one copy
 * for the whole batch (im_res). So a batch costs the launches and waits of its slowest scene, not
 * their sum, and each scene's bits are those it has alone (the kernels it takes part in, in the
 * same order). The levels of the V-cycle differ with a scene's size: a scene takes part in a
 * level's launches only while that level is above IM_TAIL vertices, and its small levels run in
 * one block (k_im_tail) from the first level at or below it.
 *
 * Sums: a block per chunk (a row's CS_CHUNK columns) sums its terms with cs_tree_sum's tree in
 * shared memory into the chunk's partial, and cs_im_chunk_total totals the partials in the CPU's
 * order, on the device, in one-thread kernels: the residuals Newton decides on (copied back), the
 * conjugate gradients' dot products and scalars (alpha, beta, the stopping test: the CPU's float
 * operations), which the host never waits for. A conjugate-gradient iteration is one graph for the
 * whole batch (im_cg_queue).
 *
 * Rocks (implicit.h, "rock contact" and "the rock steps of a part"): with rocks, each substep
 * first asks how many parts it takes (k_im_fastest_chunks, k_im_fastest: the largest closing
 * rate of cs_im_closing copied back for cs_im_splits); each part advances the rocks without the
 * cloth and shares their mass (k_im_rocks_begin) before the solve, whose assembly adds the carried
 * term (cs_im_carried_at), and after it pushes rocks and cloth apart, stops their approach and
 * applies friction (k_im_rocks_push). The rock steps are serial by design (a fixed order, as the
 * CPU backend runs them): each is a kernel of one thread a scene (cs_im_rocks_advance, _share,
 * _push of implicit.h, the code the CPU backend runs), the rocks and the workspace staying on the
 * device. Before each, k_im_row_boxes (a thread per row) gives it the rows' boxes the CPU backend
 * keeps, so its scans visit the rows within a rock's reach rather than the whole grid (the same
 * bits either way); one thread over those rows is still slow on a large, fine cloth.
 *
 * Self-collision's pass (selfcontact_cuda.cuh) works on one scene: a scene with self_collision on
 * steps alone (a batch of one), its pass after each part. */

/* One level's arrays (device memory); level 0's mask is the state's, as floats. */
struct im_level_bufs {
    int32_t nx, ny, n;
    size_t S; /* the blocks' stride (cs_im_stride) */
    float *D, *Dinv, *F[4], *mask;
    float *b, *x, *t; /* 3 n each: right side, solution, scratch */
};

struct im_batch;

struct im_work {
    int32_t nx, ny, n, nchunks, levels;
    float *base;               /* the part's start: x_n, v_n (6 n, the state's layout) */
    float *xo;                 /* the Newton iterate a line search starts from (3 n, x, y, z) */
    float *R, *q, *dx, *r, *z, *p; /* 3 n each (AoS): residual, spring force (then A p), CG vectors */
    float *B[2];               /* bending blocks of level 0 */
    float *part;               /* per-chunk partials of a sum */
    int cg_last;               /* the iterations the last solve took: queued before its first look */
    /* the rock steps' workspace (cs_im_rocks): per vertex the mass carried (sh), its normal (sn,
     * 3 n), what a push moved it (sg, 0 between pushes); the rock carried (sr) and the candidates
     * (cand, 2 n); per rock where it would be without the cloth (star), where it started (rx0) and
     * scratch (rf, rt) */
    float *sh, *sn, *sg;
    float *rowbox;             /* per grid row the box of it and the next (cs_im_row_box): 6 ny */
    int32_t *ints;             /* cand, then sr, then rows: 3 n + 2 CS_MAX_ROCKS, one allocation */
    int32_t *cand, *sr, *rows; /* rows: the vertices each rock's candidates span (cs_im_rocks) */
    cs_rock_state *star;       /* CS_MAX_ROCKS */
    cs_vec3 *rv3;              /* rx0, rf, rt: CS_MAX_ROCKS each, one allocation */
    im_level_bufs lv[CS_IM_MAX_LEVELS];
    void *mem;                 /* every float array above, in one allocation */
    struct im_batch *one;      /* the batch of one its scene's lone steps run (kept across refits) */
};

/* The conjugate gradients' scalars of a scene, kept on the device (k_im_cg_*): the host queues
 * iterations without waiting for each sum, and every kernel of an iteration does nothing once done
 * is set, so the iterations that run are the CPU's. */
struct im_cg {
    float rz, alpha, beta, target;
    int32_t it, most, done, pad;
};

/* A scene of a batch (device memory): its buffers, its workspace's (w, by value: its device
 * pointers) and where its flags go. */
struct im_scene {
    const cuda_scene *sc;  /* the part's scene (its dt the part's h): the batch's parts[] */
    const cuda_scene *own; /* the context's scene (the substep's dt): the parts' count */
    float *state[2], *rest[2];
    const unsigned char *mask;
    float *acc;
    cs_rock_state *rocks;
    int32_t nr;
    int *flags;                /* FLAG_*: the context's alone, the batch's in a batch */
    cuda_bufs strain[2][2];    /* k_strain's buffers by [the state's buffer][the rest lengths'] */
    im_work w;
};

/* What changes between a batch's phases, per scene (written by the host after a wait): whether it
 * takes part, its buffers' parity, the line search's step, the conjugate gradients' stop. */
struct im_dyn {
    int32_t on, cur, rest_cur, most;
    float a, target, pad[2];
};

/* What comes back to the host, per scene: a sum's total (cs_im_chunk_total), the largest
 * coordinate (float's floor), the fastest closing rate on a rock, the conjugate gradients. */
struct im_res {
    float total, reach, fast, pad;
    im_cg cg;
};

/* Launch shapes: the blocks a scene takes in a launch. Fixed ones, then per level l
 * (im_shape(l, IL_*)): the level's vertices (3 n of them) where it is above IM_TAIL and not the
 * last, the coarse vertices it restricts to, one block where its small levels start (the tail),
 * the level's vertices where it is above IM_TAIL and the last (the coarsest sweeps), the
 * hierarchy's Galerkin rows (l > 0) and inverses. A scene out of a shape takes 0 blocks. */
enum { IS_CHUNK, IS_VERT, IS_VERT3, IS_ROWS, IS_ONE, IS_ROCKS, IS_STRAIN, IS_FIXED };
enum { IL_LEVEL, IL_LEVEL3, IL_COARSE, IL_TAIL, IL_LAST, IL_GALERKIN, IL_INVERSE, IL_COUNT };
#define IM_SHAPES (IS_FIXED + IL_COUNT * CS_IM_MAX_LEVELS)
static inline int im_shape(int l, int k) { return IS_FIXED + l * IL_COUNT + k; }

#define IM_THREADS 256 /* threads of a per-vertex block */
#define IM_TAIL 1024   /* vertices of the largest level the tail's block takes */
#define IM_TAIL_THREADS 256

/* The device arrays every kernel reads (by value: a graph node holds them). */
struct im_dev {
    const im_scene *tab;
    const im_dyn *dyn;
    im_res *res;
    int32_t m;
};

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

/* The level as implicit.h's functions read it. */
__host__ __device__ static inline cs_im_level im_view(const im_work *w, int l)
{
    const im_level_bufs *v = &w->lv[l];
    cs_im_level L;
    L.nx = v->nx, L.ny = v->ny, L.S = v->S;
    L.mask = v->mask;
    L.D = v->D, L.Dinv = v->Dinv;
    for (int t = 0; t < 4; t++) L.F[t] = v->F[t];
    L.B[0] = l == 0 ? w->B[0] : NULL, L.B[1] = l == 0 ? w->B[1] : NULL;
    return L;
}

/* The rock steps' view (cs_im_rocks) of scene d's device arrays: the cloth's state S (SoA, 6 n:
 * positions and velocities), the part's start, level 0's mask, the rest lengths L0, the rocks. */
__device__ static inline cs_im_rocks im_rocks(const im_scene *d, float *S, const float *L0)
{
    const im_work *w = &d->w;
    const size_t n = (size_t)w->n;
    cs_im_rocks R;
    R.x = S, R.y = S + n, R.z = S + 2 * n, R.vx = S + 3 * n, R.vy = S + 4 * n, R.vz = S + 5 * n;
    R.xb = w->base, R.yb = w->base + n, R.zb = w->base + 2 * n;
    R.w = w->lv[0].mask;
    R.L0 = L0;
    R.rocks = d->rocks;
    R.nr = d->nr;
    R.star = w->star;
    R.rx0 = w->rv3, R.F = w->rv3 + CS_MAX_ROCKS, R.T = w->rv3 + 2 * CS_MAX_ROCKS;
    R.cand = w->cand, R.sr = w->sr;
    R.sh = w->sh, R.sn = w->sn, R.sg = w->sg;
    R.rowbox = w->rowbox, R.rows = w->rows; /* the rows' boxes: k_im_row_boxes */
    return R;
}

__device__ static inline void im_put3(float *a, int32_t v, cs_vec3 x)
{
    a[3 * (size_t)v] = x.x, a[3 * (size_t)v + 1] = x.y, a[3 * (size_t)v + 2] = x.z;
}
/* Block m as vertex v's of an array of blocks of S vertices (implicit.h: element major). */
__device__ static inline void im_put_sym(float *a, size_t S, int32_t v, const cs_mat3 *m)
{
    cs_im_sym_put(a + v, S, m);
}

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

/* This block's scene in a batch launch (start: the shape's block prefix sums) and the block's index
 * in the scene's own launch, blk; the block returns, whole, where its scene takes no part now. */
#define IM_ENTER(B, start)                                                                             \
    const int32_t j_ = batch_scene_of((start), (B).m, blockIdx.x);                                     \
    const uint32_t blk = blockIdx.x - (uint32_t)(start)[j_];                                           \
    const im_scene *const d = &(B).tab[j_];                                                            \
    const im_dyn *const dn = &(B).dyn[j_];                                                             \
    if (!dn->on) return
/* Whether the scene's conjugate gradients are done (stop: the launch is one of theirs). */
#define IM_STOPPED(B, stop) ((stop) && (B).res[j_].cg.done)
#define IM_INDEX() ((int32_t)(blk * blockDim.x + threadIdx.x))

/* Level l's right side and solution in the V-cycle: level 0's are the conjugate gradients' r, z. */
__device__ static inline const float *im_lb(const im_work *w, int l) { return l == 0 ? w->r : w->lv[l].b; }
__device__ static inline float *im_lx(const im_work *w, int l) { return l == 0 ? w->z : w->lv[l].x; }

/* The part's start: x_n, v_n copied aside, level 0's mask as floats and (guess) the first guess
 * into the iterate S: x_n + h v_n + h^2 a for a free vertex (a from its last acceleration acc:
 * cs_im_guess_accel), the grabbed one moved at its grab velocity, the others kept; v = (x - x_n)/h. */
__global__ void k_im_begin(im_dev B, const int32_t *start, int guess)
{
    IM_ENTER(B, start);
    const cuda_scene *sc = d->sc;
    const cs_phys *p = &sc->p;
    const int32_t v = IM_INDEX(), g = sc->grab;
    const size_t n = (size_t)p->n;
    if (v >= p->n) return;
    const float *in = d->state[dn->cur];
    float *S = d->state[dn->cur ^ 1], *base = d->w.base;
    for (int q = 0; q < 6; q++) base[(size_t)q * n + v] = in[(size_t)q * n + v];
    const float w = (float)d->mask[v];
    d->w.lv[0].mask[v] = w;
    if (!guess) return;
    const float *acc = d->acc;
    const float h = p->dt, inv_h = 1.0f / h;
    cs_vec3 x = IM_X(in, n, v);
    if (w != 0.0f)
        x = cs_add(x, cs_add(cs_scale(IM_V(in, n, v), h),
                             cs_scale(cs_im_guess_accel(p, cs_v3(acc[v], acc[n + v], acc[2 * n + v])), h * h)));
    else if (v == g)
        x = cs_add(x, cs_scale(cs_grab_velocity(IM_X(in, n, g), sc->grab_target, p), h));
    const float o[6] = {x.x, x.y, x.z, (x.x - base[v]) * inv_h, (x.y - base[n + v]) * inv_h,
                        (x.z - base[2 * n + v]) * inv_h};
    for (int q = 0; q < 6; q++) S[(size_t)q * n + v] = o[q];
}

/* The largest of the block's values (CS_CHUNK threads; any order gives the same), in thread 0. */
__device__ static float im_tree_max(float *buf, float mine)
{
    const int t = (int)threadIdx.x;
    buf[t] = mine;
    for (int s = CS_CHUNK / 2; s > 0; s >>= 1) {
        __syncthreads();
        if (t < s) buf[t] = buf[t + s] > buf[t] ? buf[t + s] : buf[t];
    }
    return buf[0];
}

/* The largest coordinate of chunk blk's vertices at the part's start (|x| or |y|, then |z|, as
 * implicit_cpu.c's part takes it; a NaN is never taken), for float's floor (cs_im_float_floor):
 * the chunk's largest into part. */
__global__ void __launch_bounds__(CS_CHUNK) k_im_reach(im_dev B, const int32_t *start)
{
    CS_DYNAMIC_SHARED(float, buf);
    IM_ENTER(B, start);
    const cs_phys *p = &d->sc->p;
    const int32_t c = (int32_t)blk, j = c / p->nseg, i = (c % p->nseg) * CS_CHUNK + (int32_t)threadIdx.x;
    const float reach = i < p->nx ? cs_im_reach(IM_X(d->state[dn->cur], p->n, j * p->nx + i), 0.0f) : 0.0f;
    const float most = im_tree_max(buf, reach);
    if (threadIdx.x == 0) d->w.part[c] = most;
}

/* The fastest chunk blk's vertices close on a rock near them at a substep's start (cs_im_closing:
 * fastest of implicit_cpu.c; a NaN is never taken), over the substep dn->a: the chunk's largest into
 * part. */
__global__ void __launch_bounds__(CS_CHUNK) k_im_fastest_chunks(im_dev B, const int32_t *start)
{
    CS_DYNAMIC_SHARED(float, buf);
    IM_ENTER(B, start);
    const cs_phys *p = &d->own->p;
    const int32_t c = (int32_t)blk, j = c / p->nseg, i = (c % p->nseg) * CS_CHUNK + (int32_t)threadIdx.x;
    const size_t n = (size_t)p->n;
    const float *in = d->state[dn->cur];
    float most = 0.0f;
    if (i < p->nx) {
        const float q = cs_im_closing(p, d->rocks, d->nr, in, in + n, in + 2 * n, in + 3 * n, in + 4 * n,
                                      in + 5 * n, j * p->nx + i, dn->a);
        most = q > most ? q : most;
    }
    most = im_tree_max(buf, most);
    if (threadIdx.x == 0) d->w.part[c] = most;
}

/* From the chunks' partials, one thread a scene, into its im_res: what 0 their total
 * (cs_im_chunk_total), 1 their largest (the part's reach), 2 their largest (the closing rate). */
__global__ void k_im_total(im_dev B, const int32_t *start, int what)
{
    IM_ENTER(B, start);
    (void)blk;
    const float *part = d->w.part;
    const int32_t nc = d->w.nchunks;
    if (what == 0) {
        B.res[j_].total = cs_im_chunk_total(part, nc);
        return;
    }
    float most = 0.0f;
    for (int32_t c = 0; c < nc; c++) most = part[c] > most ? part[c] : most;
    if (what == 1) B.res[j_].reach = most;
    else B.res[j_].fast = most;
}

/* The rows' boxes of the cloth (the part's start, or with iter the iterate), a thread per grid row
 * (cs_im_row_box, as row_boxes of implicit_cpu.c): before each of the rock steps below, so that
 * their scans skip the rows no rock can reach. */
__global__ void k_im_row_boxes(im_dev B, const int32_t *start, int iter)
{
    IM_ENTER(B, start);
    const cs_phys *p = &d->sc->p;
    const int32_t j = IM_INDEX();
    if (j >= p->ny) return;
    const size_t n = (size_t)p->n;
    const float *S = d->state[dn->cur ^ (iter ? 1 : 0)];
    cs_im_row_box(p, S, S + n, S + 2 * n, j, d->w.rowbox + 6 * (size_t)j);
}

/* Step 1 of a part with rocks: the rocks advanced without the cloth, then the mass they lend
 * (cs_im_rocks_advance, cs_im_rocks_share; R.x the part's start). One thread a scene: the rock
 * steps are serial by design (a fixed order, the CPU backend's). Its scans visit only the rows
 * whose box (k_im_row_boxes, just before) comes within a rock's reach, so a rock costs the rows it
 * spans, not the grid; still one thread over those rows. */
__global__ void k_im_rocks_begin(im_dev B, const int32_t *start)
{
    IM_ENTER(B, start);
    (void)blk;
    cs_im_rocks R = im_rocks(d, d->state[dn->cur], d->rest[dn->rest_cur]);
    cs_im_rocks_advance(&d->sc->p, &R, d->sc->p.dt);
    cs_im_rocks_share(&d->sc->p, &R);
}

/* Step 3 of a part with rocks: the rocks follow what their vertices carried, then rocks and cloth
 * pushed apart (cs_im_rocks_push; R.x the solved iterate). One thread a scene, as k_im_rocks_begin. */
__global__ void k_im_rocks_push(im_dev B, const int32_t *start)
{
    IM_ENTER(B, start);
    (void)blk;
    cs_im_rocks R = im_rocks(d, d->state[dn->cur ^ 1], d->rest[dn->rest_cur]);
    cs_im_rocks_push(&d->sc->p, &R, d->sc->p.dt);
}

/* Assembly of chunk blk at the iterate (iter) or the part's start, a thread per vertex
 * (chunk_springs, chunk_contacts, chunk_residual of implicit_cpu.c): the springs, air and gravity,
 * then the contacts - the rock mass the vertex carries (cs_im_carried_at, with rocks), the ground -
 * then the residual R = F - m (v - v_n)/h (0 out of the solve, whose D is the identity); with
 * blocks, level 0's matrix; the chunk's partial of |R|^2. */
__global__ void __launch_bounds__(CS_CHUNK) k_im_assemble(im_dev B, const int32_t *start, int blocks, int with_rocks,
                                                         int iter)
{
    CS_DYNAMIC_SHARED(float, buf);
    IM_ENTER(B, start);
    const im_work *w = &d->w;
    const cs_phys *p = &d->sc->p;
    const int32_t nx = p->nx, ny = p->ny, c = (int32_t)blk;
    const int32_t j = c / p->nseg, i0 = (c % p->nseg) * CS_CHUNK, i = i0 + (int32_t)threadIdx.x;
    const size_t n = (size_t)p->n;
    const float h = p->dt;
    float *S = d->state[dn->cur ^ (iter ? 1 : 0)];
    const float *base = w->base, *L0 = d->rest[dn->rest_cur];
    const int rocks = with_rocks && d->nr > 0;
    const im_level_bufs *l0 = &w->lv[0];
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
        im_put3(w->q, v, F);
        if (blocks) {
            /* the four forward blocks of level 0, then the two bending ones */
            static_assert(CS_NTYPES == 6, "four forward types, then two bending ones");
            float *const to[CS_NTYPES] = {l0->F[0], l0->F[1], l0->F[2], l0->F[3], w->B[0], w->B[1]};
            for (int t = 0; t < CS_NTYPES; t++) {
                cs_mat3 b = owned[t];
                for (int k = 0; k < 9; k++) b.m[k] = -b.m[k];
                im_put_sym(to[t], l0->S, v, &b);
            }
        }
        /* the contacts: the rock mass carried, then the ground (whose friction reads the
         * springs' resultant F) */
        float f[3] = {F.x, F.y, F.z};
        cs_vec3 Fc;
        cs_mat3 cb;
        if (rocks) {
            const cs_im_rocks rk = im_rocks(d, S, L0);
            if (cs_im_carried_at(&rk, v, xi, IM_X(base, n, v), h, &Fc, &cb)) {
                f[0] += Fc.x, f[1] += Fc.y, f[2] += Fc.z;
                if (blocks)
                    for (int k = 0; k < 9; k++) D.m[k] += cb.m[k];
            }
        }
        if (p->ground && cs_vertex_ground_contact(xi, vi, F, p, &Fc)) {
            f[0] += Fc.x, f[1] += Fc.y, f[2] += Fc.z;
            if (blocks) {
                const cs_mat3 b = cs_im_ground_block(xi, vi, p, h);
                for (int k = 0; k < 9; k++) D.m[k] += b.m[k];
            }
        }
        cs_vec3 R = cs_im_residual(p, cs_v3(f[0], f[1], f[2]), vi, IM_V(base, n, v), h);
        if (l0->mask[v] == 0.0f) {
            R = cs_v3(0.0f, 0.0f, 0.0f);
            D = cs_m3_diag(1.0f);
        }
        if (blocks) im_put_sym(l0->D, l0->S, v, &D);
        im_put3(w->R, v, R);
        mine = cs_dot(R, R);
    }
    const float sum = im_tree(buf, mine);
    if (threadIdx.x == 0) w->part[c] = sum;
}

/* The dot products the conjugate gradients take, over level 0: p . q, r . r, r . z. */
enum { IM_DOT_PQ, IM_DOT_RR, IM_DOT_RZ };

/* A dot product (IM_DOT_*) over level 0: chunk blk's partial (cs_im_dot3 terms, the chunk tree). */
__global__ void __launch_bounds__(CS_CHUNK) k_im_dot(im_dev B, const int32_t *start, int which, int stop)
{
    CS_DYNAMIC_SHARED(float, buf);
    IM_ENTER(B, start);
    if (IM_STOPPED(B, stop)) return;
    const im_work *w = &d->w;
    const cs_phys *p = &d->sc->p;
    const float *a = which == IM_DOT_PQ ? w->p : w->r, *b = which == IM_DOT_PQ ? w->q : which == IM_DOT_RR ? w->r : w->z;
    const int32_t c = (int32_t)blk, j = c / p->nseg, i = (c % p->nseg) * CS_CHUNK + (int32_t)threadIdx.x;
    const float mine = i < p->nx ? cs_im_dot3(a, b, j * p->nx + i) : 0.0f;
    const float sum = im_tree(buf, mine);
    if (threadIdx.x == 0) w->part[c] = sum;
}

/* Level l's t = A x (bend: level 0's true operator, bending blocks included, on the conjugate
 * gradients' q = A p). */
__global__ void k_im_apply(im_dev B, const int32_t *start, int l, int bend, int stop)
{
    IM_ENTER(B, start);
    const cs_im_level L = im_view(&d->w, l);
    const int32_t v = IM_INDEX();
    if (v >= L.nx * L.ny || IM_STOPPED(B, stop)) return;
    const float *x = bend ? d->w.p : im_lx(&d->w, l);
    im_put3(bend ? d->w.q : d->w.lv[l].t, v, cs_im_apply(&L, x, v % L.nx, v / L.nx, bend));
}

/* Vertex v's x = x + omega Dinv (b - t), t = A x (first: from x = 0): k_im_jacobi's, k_im_tail's. */
__device__ static inline void im_jacobi_at(const cs_im_level *L, float *x, const float *b, const float *t, int first,
                                           int32_t v)
{
    const cs_vec3 zero = cs_v3(0.0f, 0.0f, 0.0f);
    const cs_vec3 xv = first ? zero : cs_v3_from(x + 3 * (size_t)v);
    im_put3(x, v, cs_im_jacobi(L, v, xv, cs_v3_from(b + 3 * (size_t)v), first ? zero : cs_v3_from(t + 3 * (size_t)v)));
}

/* Vertex v's x += CS_IM_COARSE_SCALE e, e the coarse correction (cx, cnx wide) constant over each
 * aggregate: k_im_prolong's, k_im_tail's. */
__device__ static inline void im_prolong_at(const cs_im_level *L, float *x, const float *cx, int32_t cnx, int32_t v)
{
    if (L->mask[v] == 0.0f) return;
    const int32_t i = v % L->nx, j = v / L->nx;
    const cs_vec3 e = cs_v3_from(cx + 3 * (size_t)((j / 2) * cnx + i / 2));
    im_put3(x, v, cs_add(cs_v3_from(x + 3 * (size_t)v), cs_scale(e, CS_IM_COARSE_SCALE)));
}

/* Level l's x = x + omega Dinv (b - t), t = A x (first: from x = 0). */
__global__ void k_im_jacobi(im_dev B, const int32_t *start, int l, int first, int stop)
{
    IM_ENTER(B, start);
    const cs_im_level L = im_view(&d->w, l);
    const int32_t v = IM_INDEX();
    if (v >= L.nx * L.ny || IM_STOPPED(B, stop)) return;
    im_jacobi_at(&L, im_lx(&d->w, l), im_lb(&d->w, l), d->w.lv[l].t, first, v);
}

/* Level l's t = b - t (3 n floats). */
__global__ void k_im_sub(im_dev B, const int32_t *start, int l, int stop)
{
    IM_ENTER(B, start);
    const int32_t k = IM_INDEX();
    if (k >= 3 * d->w.lv[l].n || IM_STOPPED(B, stop)) return;
    float *t = d->w.lv[l].t;
    t[k] = im_lb(&d->w, l)[k] - t[k];
}

/* Level l + 1's right side: level l's residual t restricted. */
__global__ void k_im_restrict(im_dev B, const int32_t *start, int l, int stop)
{
    IM_ENTER(B, start);
    const im_level_bufs *cl = &d->w.lv[l + 1];
    const int32_t v = IM_INDEX();
    if (v >= cl->n || IM_STOPPED(B, stop)) return;
    const cs_im_level L = im_view(&d->w, l);
    im_put3(cl->b, v, cs_im_restrict(&L, d->w.lv[l].t, v % cl->nx, v / cl->nx));
}

/* Level l's x += CS_IM_COARSE_SCALE e, e level l + 1's correction constant over each aggregate. */
__global__ void k_im_prolong(im_dev B, const int32_t *start, int l, int stop)
{
    IM_ENTER(B, start);
    const cs_im_level L = im_view(&d->w, l);
    const int32_t v = IM_INDEX();
    if (v >= L.nx * L.ny || IM_STOPPED(B, stop)) return;
    im_prolong_at(&L, im_lx(&d->w, l), d->w.lv[l + 1].x, d->w.lv[l + 1].nx, v);
}

/* x = x + omega Dinv (b - t) over level L's vertices (first: from x = 0); then a barrier. */
__device__ static void im_tail_jacobi(const cs_im_level *L, float *x, const float *b, const float *t, int first)
{
    for (int32_t v = (int32_t)threadIdx.x; v < L->nx * L->ny; v += (int32_t)blockDim.x)
        im_jacobi_at(L, x, b, t, first, v);
    __syncthreads();
}

/* t = A x over level L's vertices; then a barrier. */
__device__ static void im_tail_apply(const cs_im_level *L, const float *x, float *t)
{
    for (int32_t v = (int32_t)threadIdx.x; v < L->nx * L->ny; v += (int32_t)blockDim.x)
        im_put3(t, v, cs_im_apply(L, x, v % L->nx, v / L->nx, 0));
    __syncthreads();
}

/* The V-cycle's small levels in one block a scene: from level `first` (at most IM_TAIL vertices)
 * down to the coarsest and back up, each step of im_vcycle's launches a loop over the level's
 * vertices (the same functions, each vertex computed as alone: the same bits) followed by a
 * barrier. At 64 x 64 this is four levels of the five, 52 launches of a V-cycle's 59 (the
 * coarsest's 16 sweeps alone 31). */
__global__ void __launch_bounds__(IM_TAIL_THREADS) k_im_tail(im_dev B, const int32_t *start, int first, int stop)
{
    IM_ENTER(B, start);
    (void)blk;
    if (IM_STOPPED(B, stop)) return; /* the whole block alike */
    const im_work *w = &d->w;
    const int last = w->levels - 1;
    /* down: smooth, the residual, restricted */
    for (int l = first; l <= last; l++) {
        const cs_im_level L = im_view(w, l);
        const float *b = im_lb(w, l);
        float *x = im_lx(w, l), *t = w->lv[l].t;
        const int sweeps = l == last ? CS_IM_COARSE_SWEEPS : CS_IM_SMOOTH;
        im_tail_jacobi(&L, x, b, t, 1);
        for (int k = 1; k < sweeps; k++) {
            im_tail_apply(&L, x, t);
            im_tail_jacobi(&L, x, b, t, 0);
        }
        if (l == last) break;
        im_tail_apply(&L, x, t);
        const int32_t n = L.nx * L.ny, cnx = w->lv[l + 1].nx, cny = w->lv[l + 1].ny;
        for (int32_t k = (int32_t)threadIdx.x; k < 3 * n; k += (int32_t)blockDim.x) t[k] = b[k] - t[k];
        __syncthreads();
        for (int32_t v = (int32_t)threadIdx.x; v < cnx * cny; v += (int32_t)blockDim.x)
            im_put3(w->lv[l + 1].b, v, cs_im_restrict(&L, t, v % cnx, v / cnx));
        __syncthreads();
    }
    /* up: the coarse correction, interpolated and scaled, then smooth */
    for (int l = last - 1; l >= first; l--) {
        const cs_im_level L = im_view(w, l);
        const float *b = im_lb(w, l);
        float *x = im_lx(w, l), *t = w->lv[l].t;
        for (int32_t v = (int32_t)threadIdx.x; v < L.nx * L.ny; v += (int32_t)blockDim.x)
            im_prolong_at(&L, x, w->lv[l + 1].x, w->lv[l + 1].nx, v);
        __syncthreads();
        for (int k = 0; k < CS_IM_SMOOTH; k++) {
            im_tail_apply(&L, x, t);
            im_tail_jacobi(&L, x, b, t, 0);
        }
    }
}

/* Level l's Galerkin row of each of its vertices from level l - 1. */
__global__ void k_im_galerkin(im_dev B, const int32_t *start, int l)
{
    IM_ENTER(B, start);
    const im_level_bufs *c = &d->w.lv[l];
    const int32_t v = IM_INDEX();
    if (v >= c->n) return;
    const cs_im_level F = im_view(&d->w, l - 1);
    float *Fc[4];
    for (int t = 0; t < 4; t++) Fc[t] = c->F[t] + v;
    cs_im_galerkin(&F, v % c->nx, v / c->nx, c->D + v, Fc, c->S, c->mask + v);
}

/* Level l's Dinv from its D. */
__global__ void k_im_inverse(im_dev B, const int32_t *start, int l)
{
    IM_ENTER(B, start);
    const im_level_bufs *c = &d->w.lv[l];
    const int32_t v = IM_INDEX();
    if (v >= c->n) return;
    const cs_mat3 Dv = cs_im_sym_get(c->D + v, c->S), inv = cs_m3_inverse(Dv.m);
    im_put_sym(c->Dinv, c->S, v, &inv);
}

/* The solve's start: dx = 0, r = R (3 n floats); with copy, p = z instead. */
__global__ void k_im_vectors(im_dev B, const int32_t *start, int copy)
{
    IM_ENTER(B, start);
    const im_work *w = &d->w;
    const int32_t k = IM_INDEX();
    if (k >= 3 * w->n) return;
    if (copy) {
        w->p[k] = w->z[k];
        return;
    }
    w->dx[k] = 0.0f;
    w->r[k] = w->R[k];
}

/* The conjugate gradients' scalars, one thread a scene (pcg of implicit_cpu.c, the same float
 * operations in the same order: the chunk partials totalled by cs_im_chunk_total): rz = r . z
 * from the partials, the stopping |r| and the most iterations (the host's, in dn). */
__global__ void k_im_cg_begin(im_dev B, const int32_t *start)
{
    IM_ENTER(B, start);
    (void)blk;
    im_cg *cg = &B.res[j_].cg;
    cg->rz = cs_im_chunk_total(d->w.part, d->w.nchunks);
    cg->alpha = cg->beta = 0.0f;
    cg->target = dn->target;
    cg->most = dn->most;
    cg->it = 0;
    cg->done = dn->most <= 0;
}

/* alpha = rz / p . q from the partials of p . q; the end once the iterations are spent or the
 * direction has no descent. */
__global__ void k_im_cg_alpha(im_dev B, const int32_t *start)
{
    IM_ENTER(B, start);
    (void)blk;
    im_cg *cg = &B.res[j_].cg;
    if (cg->done) return;
    const float pq = cs_im_chunk_total(d->w.part, d->w.nchunks);
    if (cg->it >= cg->most || !(pq > 0.0f) || !(cg->rz > 0.0f)) {
        cg->done = 1;
        return;
    }
    cg->alpha = cg->rz / pq;
}

/* An iteration more, and the end once |r| (from the partials of r . r) is down to the target. */
__global__ void k_im_cg_check(im_dev B, const int32_t *start)
{
    IM_ENTER(B, start);
    (void)blk;
    im_cg *cg = &B.res[j_].cg;
    if (cg->done) return;
    cg->it++;
    if (!(sqrtf(cs_im_chunk_total(d->w.part, d->w.nchunks)) > cg->target)) cg->done = 1;
}

/* beta = rz' / rz from the partials of r . z (the new rz). */
__global__ void k_im_cg_beta(im_dev B, const int32_t *start)
{
    IM_ENTER(B, start);
    (void)blk;
    im_cg *cg = &B.res[j_].cg;
    if (cg->done) return;
    const float rz2 = cs_im_chunk_total(d->w.part, d->w.nchunks);
    cg->beta = rz2 / cg->rz;
    cg->rz = rz2;
}

/* dx += alpha p; r -= alpha q. */
__global__ void k_im_cg_step(im_dev B, const int32_t *start)
{
    IM_ENTER(B, start);
    const im_cg *cg = &B.res[j_].cg;
    const im_work *w = &d->w;
    const int32_t k = IM_INDEX();
    if (k >= 3 * w->n || cg->done) return;
    const float alpha = cg->alpha;
    w->dx[k] += alpha * w->p[k];
    w->r[k] -= alpha * w->q[k];
}

/* p = z + beta p. */
__global__ void k_im_cg_dir(im_dev B, const int32_t *start)
{
    IM_ENTER(B, start);
    const im_cg *cg = &B.res[j_].cg;
    const im_work *w = &d->w;
    const int32_t k = IM_INDEX();
    if (k < 3 * w->n && !cg->done) w->p[k] = w->z[k] + cg->beta * w->p[k];
}

/* The iterate's positions kept for the line search. */
__global__ void k_im_keep(im_dev B, const int32_t *start)
{
    IM_ENTER(B, start);
    const int32_t v = IM_INDEX(), n = d->w.n;
    if (v >= n) return;
    const float *S = d->state[dn->cur ^ 1];
    for (int q = 0; q < 3; q++) d->w.xo[(size_t)q * (size_t)n + v] = S[(size_t)q * (size_t)n + v];
}

/* x = x_k + a dx for the vertices in the solve (a: the line search's step, dn->a), and
 * v = (x - x_n)/h. */
__global__ void k_im_move(im_dev B, const int32_t *start)
{
    IM_ENTER(B, start);
    const im_work *w = &d->w;
    const int32_t v = IM_INDEX(), n = w->n;
    if (v >= n || w->lv[0].mask[v] == 0.0f) return;
    const size_t N = (size_t)n;
    const float a = dn->a, inv_h = 1.0f / d->sc->p.dt;
    float *S = d->state[dn->cur ^ 1];
    for (int q = 0; q < 3; q++) {
        S[q * N + v] = w->xo[q * N + v] + a * w->dx[3 * (size_t)v + q];
        S[(3 + q) * N + v] = (S[q * N + v] - w->base[q * N + v]) * inv_h;
    }
}

/* a = (v - v_n)/h, 0 where the vertex is out of the solve. */
__global__ void k_im_accel(im_dev B, const int32_t *start)
{
    IM_ENTER(B, start);
    const im_work *w = &d->w;
    const int32_t v = IM_INDEX(), n = w->n;
    if (v >= n) return;
    const size_t N = (size_t)n;
    const float inv_h = 1.0f / d->sc->p.dt, *S = d->state[dn->cur ^ 1];
    for (int q = 0; q < 3; q++)
        d->acc[q * N + v] = (S[(3 + q) * N + v] - w->base[(3 + q) * N + v]) * inv_h * w->lv[0].mask[v];
}

/* The refresh's a = F/m: the residual at v = v_n is the force (cs_im_refresh). */
__global__ void k_im_refresh_accel(im_dev B, const int32_t *start)
{
    IM_ENTER(B, start);
    const int32_t v = IM_INDEX(), n = d->w.n;
    if (v >= n) return;
    const float k = d->sc->p.inv_mass * d->w.lv[0].mask[v];
    for (int q = 0; q < 3; q++) d->acc[(size_t)q * (size_t)n + v] = d->w.R[3 * (size_t)v + q] * k;
}

/* Symplectic Euler's strain pass (cs_strain_update per owned spring, as cs_cpu_strain_row) on the
 * part's new positions (the state the part wrote), with the part's phys. */
__global__ void k_im_strain(im_dev B, const int32_t *start)
{
    IM_ENTER(B, start);
    strain_block(d->sc, d->strain[dn->cur ^ 1][dn->rest_cur], blk);
}

/* FLAG_NONFINITE where a position, velocity or acceleration of the state, or a rock's position,
 * velocity, spin or their rates, is not finite (the CPU's state_finite with rates: a step reported
 * finite leaves a state that saves). */
__global__ void k_im_finite(im_dev B, const int32_t *start)
{
    IM_ENTER(B, start);
    const int32_t v = IM_INDEX(), n = d->w.n;
    if (v >= n) return;
    const float *S = d->state[dn->cur];
    int bad = 0;
    for (int q = 0; q < 6; q++) bad |= !isfinite(S[(size_t)q * (size_t)n + v]);
    for (int q = 0; q < 3; q++) bad |= !isfinite(d->acc[(size_t)q * (size_t)n + v]);
    if (v == 0)
        for (int32_t r = 0; r < d->nr; r++) bad |= !cs_rock_finite(&d->rocks[r], 1);
    if (bad) atomicOr(&d->flags[FLAG_NONFINITE], 1);
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
 * and an iteration queued past a scene's end costs it launches that return at once. (As many less
 * one: 4.8 waits a Newton iteration and 198 graphs for 170 iterations in test_datapath's scene;
 * as many, 4.2 and 215; one more, 3.8 and 239.) */
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
        b->dyn_h[j].cur = h->c->cur, b->dyn_h[j].rest_cur = h->c->rest_cur;
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
            b->dyn_h[j].a = 0.0f;
        }
        if (im_any(b, &im_host::search)) {
            IM_ON(b, search);
            if ((st = im_put(c, b, 0)) != CS_OK) return st;
            IM_LAUNCH0(b, IS_VERT, k_im_move, IM_THREADS, 0);
            if ((st = im_residuals(c, b)) != CS_OK) return st;
            for (int32_t j = 0; j < b->m; j++)
                if (b->hs[j].search) b->hs[j].prev = b->hs[j].rn;
        }
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
            const float hp = h->p->dt / (float)h->parts; /* the part's own step */
            h->P = *h->p;
            h->P.dt = hp, h->P.hdt = 0.5f * hp;
            if (h->P.plastic_rate > 0.0f) h->P.plastic_f = h->P.plastic_rate * hp < 1.0f ? h->P.plastic_rate * hp : 1.0f;
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

/* The batch of one a context's lone steps run (in its workspace, created with it). */
static cs_status im_one(cuda_ctx *c, const cs_phys *p, im_batch **out)
{
    cs_status st = im_fit(c, p);
    if (st != CS_OK) return st;
    if (!c->im->one && !(c->im->one = (im_batch *)calloc(1, sizeof(im_batch)))) return CS_E_NOMEM;
    if ((st = im_batch_reserve(c, c->im->one, 1)) != CS_OK) return st;
    *out = c->im->one;
    return CS_OK;
}

/* Substeps of implicit_euler on the device state (cs_im_step of implicit_cpu.c), the scene alone:
 * the solver's statistics into rep; torn springs and a non-finite state into the flags. */
static cs_status im_step(cuda_ctx *c, const cs_model *m, int32_t substeps, cs_step_report *rep)
{
    im_batch *b;
    const cs_status st = im_one(c, &m->phys, &b);
    if (st != CS_OK) return st;
    b->items[0].c = c, b->items[0].m = m, b->items[0].substeps = substeps;
    b->items[0].flags = c->flags, b->items[0].rep = rep;
    return im_run(c, b, 1, c->stream);
}

/* cs_im_refresh: the accelerations a = F/m of the state as it is (the force law at v = v_n). */
static cs_status im_refresh(cuda_ctx *c, const cs_model *m)
{
    im_batch *b;
    cs_status st = im_one(c, &m->phys, &b);
    if (st != CS_OK) return st;
    cs_step_report unused;
    b->items[0].c = c, b->items[0].m = m, b->items[0].substeps = 0;
    b->items[0].flags = c->flags, b->items[0].rep = &unused;
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
