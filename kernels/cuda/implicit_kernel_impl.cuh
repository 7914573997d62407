/* implicit_kernel_impl.cuh - integrator implicit_euler's kernels (k_im_*: device code) and what
 * they and the host share: a scene's workspace (im_work), a batch's per-scene table (im_scene),
 * what the host writes before a phase (im_dyn) and reads after it (im_res). The host sequence that
 * launches them: implicit_cuda.cuh. Part of the one translation unit backend_cuda.cu.
 *
 * The CPU backend's sequence (implicit_cpu.c) with each of its loops a kernel that calls the same
 * functions of clothsim/implicit.h and physics.h per vertex, in the same order, so the state ends
 * bitwise the same. Every launch covers a batch of scenes: a block finds its scene by binary search
 * over the launch's block prefix sums (batch_scene_of, as the explicit batch's kernels), returns
 * whole where its scene takes no part in the phase (im_dyn), and works on that scene as a lone
 * launch would.
 *
 * Sums: a block per chunk (a row's CS_CHUNK columns) sums its terms with cs_tree_sum's tree in
 * shared memory into the chunk's partial, and cs_im_chunk_total totals the partials in the CPU's
 * order, on the device, in one-thread kernels: the residuals Newton decides on (copied back), the
 * conjugate gradients' dot products and scalars (alpha, beta, the stopping test: the CPU's float
 * operations), which the host never waits for.
 *
 * Rocks (implicit.h, "rock contact" and "the rock steps of a part"): with rocks, each substep
 * first asks how many parts it takes (k_im_fastest_chunks, then k_im_total: the largest closing
 * rate of cs_im_closing copied back for cs_im_splits); each part advances the rocks without the
 * cloth and shares their mass (k_im_rocks_begin) before the solve, whose assembly adds the carried
 * term (cs_im_carried_at), and after it pushes rocks and cloth apart, stops their approach and
 * applies friction (k_im_rocks_push). The rock steps are serial by design (a fixed order, as the
 * CPU backend runs them): each is a kernel of one thread a scene (cs_im_rocks_advance, _share,
 * _push of implicit.h, the code the CPU backend runs), the rocks and the workspace staying on the
 * device. Before each, k_im_row_boxes (a thread per row) gives it the rows' boxes the CPU backend
 * keeps, so its scans visit the rows within a rock's reach rather than the whole grid (the same
 * bits either way); one thread over those rows is still slow on a large, fine cloth. */
#ifndef CLOTHSIM_CUDA_IMPLICIT_KERNEL_IMPL_CUH
#define CLOTHSIM_CUDA_IMPLICIT_KERNEL_IMPL_CUH

#include <math.h>

#include "clothsim/implicit.h"
#include "batch_kernel_impl.cuh"

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
 * takes part, its buffers' parity, the line search's step, the conjugate gradients' stop, and
 * whether its next assembly is after its last Newton iteration allowed (then the residual alone,
 * as implicit_cpu.c: the same bits). */
struct im_dyn {
    int32_t on, cur, rest_cur, most;
    float a, target;
    int32_t last, pad;
};

/* What comes back to the host, per scene: a sum's total (cs_im_chunk_total), the largest
 * coordinate (float's floor), the fastest closing rate on a rock, the conjugate gradients. */
struct im_res {
    float total, reach, fast, pad;
    im_cg cg;
};

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
    blocks = blocks && !dn->last;
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

#endif /* CLOTHSIM_CUDA_IMPLICIT_KERNEL_IMPL_CUH */
