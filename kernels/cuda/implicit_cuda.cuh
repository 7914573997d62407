/* implicit_cuda.cuh - integrator implicit_euler on the device (kernels/MODEL.md, "The implicit
 * solver"): its workspace, its kernels (k_im_*) and the host sequence that launches them (im_step,
 * im_refresh). Part of the one translation unit backend_cuda.cu. */
#ifndef CLOTHSIM_CUDA_IMPLICIT_CUDA_CUH
#define CLOTHSIM_CUDA_IMPLICIT_CUDA_CUH

#include <math.h>

#include "clothsim/implicit.h"
#include "memory_cuda.cuh"

/* The CPU backend's sequence (implicit_cpu.c) with each of its loops a kernel that calls the same
 * functions of clothsim/implicit.h and physics.h per vertex, in the same order, so the state ends
 * bitwise the same. Launches on the scene's stream (a conjugate-gradient iteration is one graph:
 * im_cg_queue): a part of a substep runs
 * the first guess, then Newton (assemble, the multigrid hierarchy, conjugate gradients
 * preconditioned by a V-cycle, a backtracking line search), then the accelerations and the strain
 * pass. The iterate lives in the state buffer a substep writes (state[cur ^ 1]); the part's start
 * (x_n, v_n) is copied aside, so the buffers swap once a part as the explicit substeps do.
 *
 * Sums: a block per chunk (a row's CS_CHUNK columns) sums its terms with cs_tree_sum's tree in
 * shared memory into the chunk's partial, and cs_im_chunk_total totals the partials in the CPU's
 * order: on the host for the residuals Newton decides on (a copy back and a wait each), on the
 * device, in one-thread kernels, for the conjugate gradients' dot products and scalars (alpha,
 * beta, the stopping test: the CPU's float operations), which the host never waits for.
 *
 * Rocks (implicit.h, "rock contact" and "the rock steps of a part"): with rocks, each substep
 * first asks how many parts it takes (k_im_fastest_chunks, k_im_fastest: the largest closing
 * rate of cs_im_closing copied back for cs_im_splits); each part advances the rocks without the
 * cloth and shares their mass (k_im_rocks_begin) before the solve, whose assembly adds the carried
 * term (cs_im_carried_at), and after it pushes rocks and cloth apart, stops their approach and
 * applies friction (k_im_rocks_push). The rock steps are serial by design (a fixed order, as the
 * CPU backend runs them): each is a kernel of one thread (cs_im_rocks_advance, _share, _push of
 * implicit.h, the code the CPU backend runs), the rocks and the workspace staying on the device.
 * Before each, k_im_row_boxes (a thread per row) gives it the rows' boxes the CPU backend keeps,
 * so its scans visit the rows within a rock's reach rather than the whole grid (the same bits
 * either way); one thread over those rows is still slow on a large, fine cloth. */

/* One level's arrays (device memory); level 0's mask is the state's, as floats. */
struct im_level_bufs {
    int32_t nx, ny, n;
    size_t S; /* the blocks' stride (cs_im_stride) */
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
    struct im_cg *cg, *host_cg; /* the conjugate gradients' scalars (device) and their pinned copy */
    int cg_last;               /* the iterations the last solve took: queued before its first look */
    cudaGraphExec_t cg_exec;   /* one iteration of them (im_cg_iteration), captured once */
    float *fast;               /* k_im_fastest's answer (1 float) */
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
    cuda_scene *sc;            /* the scene with the part's phys (its dt is the part's h) */
    cuda_scene host_sc;        /* what sc holds */
    int sc_valid;
    void *mem;                 /* every float array above, in one allocation */
};

#define IM_THREADS 256 /* threads of a per-vertex block */

/* The conjugate gradients' scalars, kept on the device (k_im_cg_*): the host queues iterations
 * without waiting for each sum, and every kernel of an iteration does nothing once done is set
 * (IM_STOPPED), so the iterations that run are the CPU's. */
struct im_cg {
    float rz, alpha, beta, target;
    int32_t it, most, done, pad;
};
#define IM_STOPPED(cg) ((cg) != NULL && (cg)->done)

static void im_free(im_work *w)
{
    if (!w) return;
    cudaFree(w->mem);
    cudaFree(w->ints);
    cudaFree(w->star);
    cudaFree(w->rv3);
    cudaFree(w->sc);
    cudaFree(w->cg);
    if (w->cg_exec) cudaGraphExecDestroy(w->cg_exec);
    cudaFreeHost(w->host_part);
    cudaFreeHost(w->host_cg);
    free(w);
}

/* The level as implicit.h's functions read it. */
static cs_im_level im_view(const im_work *w, int l)
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
 * into the iterate S: x_n + h v_n + h^2 a for a free vertex (a from its last acceleration acc:
 * cs_im_guess_accel), the grabbed one moved at its grab velocity, the others kept; v = (x - x_n)/h. */
__global__ void k_im_begin(const cuda_scene *__restrict__ sc, const float *__restrict__ in, float *S, float *base,
                           const unsigned char *__restrict__ mask, float *mask0, const float *__restrict__ acc,
                           int guess)
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
        x = cs_add(x, cs_add(cs_scale(IM_V(in, n, v), h),
                             cs_scale(cs_im_guess_accel(p, cs_v3(acc[v], acc[n + v], acc[2 * n + v])), h * h)));
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

/* The fastest chunk blockIdx.x's vertices close on a rock near them at a substep's start (cs_im_closing:
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
        const float q = cs_im_closing(p, rocks, sc->nr, in, in + n, in + 2 * n, in + 3 * n, in + 4 * n,
                                      in + 5 * n, j * p->nx + i, h);
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

/* The rows' boxes of the cloth at S (SoA: x, y, z first), a thread per grid row (cs_im_row_box,
 * as row_boxes of implicit_cpu.c): before each of the rock steps below, so that their scans skip
 * the rows no rock can reach. */
__global__ void k_im_row_boxes(const cuda_scene *__restrict__ sc, const float *S, float *rowbox)
{
    const cs_phys *p = &sc->p;
    const int32_t j = (int32_t)(blockIdx.x * blockDim.x + threadIdx.x);
    if (j >= p->ny) return;
    const size_t n = (size_t)p->n;
    cs_im_row_box(p, S, S + n, S + 2 * n, j, rowbox + 6 * (size_t)j);
}

/* Step 1 of a part with rocks: the rocks advanced without the cloth, then the mass they lend
 * (cs_im_rocks_advance, cs_im_rocks_share; R.x the part's start). One thread: the rock steps are
 * serial by design (a fixed order, the CPU backend's). Its scans visit only the rows whose box
 * (k_im_row_boxes, just before) comes within a rock's reach, so a rock costs the rows it spans,
 * not the grid; still one thread over those rows. */
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
    size_t S0; /* level 0's blocks' stride */
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
                im_put_sym(to[t], a.S0, v, &b);
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
        if (blocks) im_put_sym(a.D, a.S0, v, &D);
        im_put3(a.R, v, R);
        mine = cs_dot(R, R);
    }
    const float sum = im_tree(buf, mine);
    if (threadIdx.x == 0) a.part[c] = sum;
}

/* a . b over level 0: chunk blockIdx.x's partial (cs_im_dot3 terms, the chunk tree). */
__global__ void __launch_bounds__(CS_CHUNK) k_im_dot(const cuda_scene *__restrict__ sc, const float *a, const float *b,
                                                    float *part, const im_cg *stop)
{
    CS_DYNAMIC_SHARED(float, buf);
    if (IM_STOPPED(stop)) return;
    const cs_phys *p = &sc->p;
    const int32_t c = (int32_t)blockIdx.x, j = c / p->nseg, i = (c % p->nseg) * CS_CHUNK + (int32_t)threadIdx.x;
    const float mine = i < p->nx ? cs_im_dot3(a, b, j * p->nx + i) : 0.0f;
    const float sum = im_tree(buf, mine);
    if (threadIdx.x == 0) part[c] = sum;
}

/* y = A x on a level (bend: level 0's true operator, bending blocks included). */
__global__ void k_im_apply(cs_im_level L, const float *x, float *y, int bend, const im_cg *stop)
{
    const int32_t v = im_vertex();
    if (v >= L.nx * L.ny || IM_STOPPED(stop)) return;
    im_put3(y, v, cs_im_apply(&L, x, v % L.nx, v / L.nx, bend));
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

/* x = x + omega Dinv (b - t), t = A x (first: from x = 0). */
__global__ void k_im_jacobi(cs_im_level L, float *x, const float *b, const float *t, int first, const im_cg *stop)
{
    const int32_t v = im_vertex();
    if (v >= L.nx * L.ny || IM_STOPPED(stop)) return;
    im_jacobi_at(&L, x, b, t, first, v);
}

/* t = b - t over 3 n floats. */
__global__ void k_im_sub(const float *b, float *t, int32_t n3, const im_cg *stop)
{
    const int32_t k = im_vertex();
    if (k < n3 && !IM_STOPPED(stop)) t[k] = b[k] - t[k];
}

/* The coarse right side: the fine residual t restricted to coarse level C. */
__global__ void k_im_restrict(cs_im_level L, const float *t, float *cb, int32_t cnx, int32_t cny, const im_cg *stop)
{
    const int32_t v = im_vertex();
    if (v >= cnx * cny || IM_STOPPED(stop)) return;
    im_put3(cb, v, cs_im_restrict(&L, t, v % cnx, v / cnx));
}

/* x += CS_IM_COARSE_SCALE e, e the coarse correction constant over each aggregate. */
__global__ void k_im_prolong(cs_im_level L, float *x, const float *cx, int32_t cnx, const im_cg *stop)
{
    const int32_t v = im_vertex();
    if (v >= L.nx * L.ny || IM_STOPPED(stop)) return;
    im_prolong_at(&L, x, cx, cnx, v);
}

/* The V-cycle's small levels in one block: from level `first` (at most IM_TAIL vertices) down to the
 * coarsest and back up, each step of im_vcycle's launches a loop over the level's vertices
 * (the same functions, each vertex computed as alone: the same bits) followed by a barrier.
 * At 64 x 64 this is four levels of the five, 52 launches of a V-cycle's 59 (the coarsest's 16
 * sweeps alone 31). */
#define IM_TAIL 1024  /* vertices of the largest level the block takes */
#define IM_TAIL_THREADS 256
struct im_tail {
    cs_im_level L[CS_IM_MAX_LEVELS];
    float *b[CS_IM_MAX_LEVELS], *x[CS_IM_MAX_LEVELS], *t[CS_IM_MAX_LEVELS];
    int first, levels;
};

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

__global__ void __launch_bounds__(IM_TAIL_THREADS) k_im_tail(im_tail T, const float *b0, float *x0, const im_cg *stop)
{
    if (IM_STOPPED(stop)) return; /* the whole block alike */
    const int last = T.levels - 1;
    /* down: smooth, the residual, restricted */
    for (int l = T.first; l <= last; l++) {
        const cs_im_level *L = &T.L[l];
        const float *b = l == T.first ? b0 : T.b[l];
        float *x = l == T.first ? x0 : T.x[l], *t = T.t[l];
        const int sweeps = l == last ? CS_IM_COARSE_SWEEPS : CS_IM_SMOOTH;
        im_tail_jacobi(L, x, b, t, 1);
        for (int k = 1; k < sweeps; k++) {
            im_tail_apply(L, x, t);
            im_tail_jacobi(L, x, b, t, 0);
        }
        if (l == last) break;
        im_tail_apply(L, x, t);
        const int32_t n = L->nx * L->ny, cnx = T.L[l + 1].nx, cny = T.L[l + 1].ny;
        for (int32_t k = (int32_t)threadIdx.x; k < 3 * n; k += (int32_t)blockDim.x) t[k] = b[k] - t[k];
        __syncthreads();
        for (int32_t v = (int32_t)threadIdx.x; v < cnx * cny; v += (int32_t)blockDim.x)
            im_put3(T.b[l + 1], v, cs_im_restrict(L, t, v % cnx, v / cnx));
        __syncthreads();
    }
    /* up: the coarse correction, interpolated and scaled, then smooth */
    for (int l = last - 1; l >= T.first; l--) {
        const cs_im_level *L = &T.L[l];
        const float *b = l == T.first ? b0 : T.b[l];
        float *x = l == T.first ? x0 : T.x[l], *t = T.t[l];
        for (int32_t v = (int32_t)threadIdx.x; v < L->nx * L->ny; v += (int32_t)blockDim.x)
            im_prolong_at(L, x, T.x[l + 1], T.L[l + 1].nx, v);
        __syncthreads();
        for (int k = 0; k < CS_IM_SMOOTH; k++) {
            im_tail_apply(L, x, t);
            im_tail_jacobi(L, x, b, t, 0);
        }
    }
}

/* Coarse level c's Galerkin row of each of its vertices from the fine level F. */
__global__ void k_im_galerkin(cs_im_level F, im_level_bufs c)
{
    const int32_t v = im_vertex();
    if (v >= c.n) return;
    float *Fc[4];
    for (int t = 0; t < 4; t++) Fc[t] = c.F[t] + v;
    cs_im_galerkin(&F, v % c.nx, v / c.nx, c.D + v, Fc, c.S, c.mask + v);
}

__global__ void k_im_inverse(const float *D, float *Dinv, int32_t n, size_t S)
{
    const int32_t v = im_vertex();
    if (v >= n) return;
    const cs_mat3 Dv = cs_im_sym_get(D + v, S), inv = cs_m3_inverse(Dv.m);
    im_put_sym(Dinv, S, v, &inv);
}

/* The conjugate gradients' scalars, one thread each (pcg of implicit_cpu.c, the same float
 * operations in the same order: the chunk partials totalled by cs_im_chunk_total): rz = r . z
 * from the partials, the stopping |r| and the most iterations. */
__global__ void k_im_cg_begin(const float *part, int32_t nchunks, im_cg *cg, float target, int32_t most)
{
    cg->rz = cs_im_chunk_total(part, nchunks);
    cg->alpha = cg->beta = 0.0f;
    cg->target = target;
    cg->most = most;
    cg->it = 0;
    cg->done = most <= 0;
}

/* alpha = rz / p . q from the partials of p . q; the end once the iterations are spent or the
 * direction has no descent. */
__global__ void k_im_cg_alpha(const float *part, int32_t nchunks, im_cg *cg)
{
    if (cg->done) return;
    const float pq = cs_im_chunk_total(part, nchunks);
    if (cg->it >= cg->most || !(pq > 0.0f) || !(cg->rz > 0.0f)) {
        cg->done = 1;
        return;
    }
    cg->alpha = cg->rz / pq;
}

/* An iteration more, and the end once |r| (from the partials of r . r) is down to the target. */
__global__ void k_im_cg_check(const float *part, int32_t nchunks, im_cg *cg)
{
    if (cg->done) return;
    cg->it++;
    if (!(sqrtf(cs_im_chunk_total(part, nchunks)) > cg->target)) cg->done = 1;
}

/* beta = rz' / rz from the partials of r . z (the new rz). */
__global__ void k_im_cg_beta(const float *part, int32_t nchunks, im_cg *cg)
{
    if (cg->done) return;
    const float rz2 = cs_im_chunk_total(part, nchunks);
    cg->beta = rz2 / cg->rz;
    cg->rz = rz2;
}

/* dx += alpha p; r -= alpha q. */
__global__ void k_im_cg_step(float *dx, float *r, const float *p, const float *q, const im_cg *cg, int32_t n3)
{
    const int32_t k = im_vertex();
    if (k >= n3 || cg->done) return;
    const float alpha = cg->alpha;
    dx[k] += alpha * p[k];
    r[k] -= alpha * q[k];
}

/* p = z + beta p. */
__global__ void k_im_cg_dir(float *p, const float *z, const im_cg *cg, int32_t n3)
{
    const int32_t k = im_vertex();
    if (k < n3 && !cg->done) p[k] = z[k] + cg->beta * p[k];
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

/* FLAG_NONFINITE where a position, velocity or acceleration of the state, or a rock's position,
 * velocity, spin or their rates, is not finite (the CPU's state_finite with rates: a step reported
 * finite leaves a state that saves). */
__global__ void k_im_finite(const float *S, const float *acc, int32_t n, const cs_rock_state *rocks, int32_t nr,
                            int *flags)
{
    const int32_t v = im_vertex();
    if (v >= n) return;
    int bad = 0;
    for (int q = 0; q < 6; q++) bad |= !isfinite(S[(size_t)q * (size_t)n + v]);
    for (int q = 0; q < 3; q++) bad |= !isfinite(acc[(size_t)q * (size_t)n + v]);
    if (v == 0)
        for (int32_t r = 0; r < nr; r++) bad |= !cs_rock_finite(&rocks[r], 1);
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
    const size_t S0 = cs_im_stride((size_t)w->n); /* level 0's, which the bending blocks share */
    size_t floats = (size_t)w->n * (6 + 3 + 18 + 5) + 2 * CS_IM_SYM * S0 + (size_t)w->nchunks + 1 + 6 * (size_t)w->ny;
    const size_t ints = 3 * (size_t)w->n + 2 * CS_MAX_ROCKS;
    int32_t lx[CS_IM_MAX_LEVELS], ly[CS_IM_MAX_LEVELS];
    const int L = w->levels = cs_im_levels(p->nx, p->ny, lx, ly);
    for (int l = 0; l < L; l++) {
        w->lv[l].nx = lx[l], w->lv[l].ny = ly[l], w->lv[l].n = lx[l] * ly[l];
        w->lv[l].S = cs_im_stride((size_t)w->lv[l].n);
        floats += cs_im_level_floats((size_t)w->lv[l].n);
    }
    cudaError_t e = cudaMalloc(&w->mem, sizeof(float) * floats);
    if (e == cudaSuccess) e = cudaMalloc((void **)&w->sc, sizeof(cuda_scene));
    if (e == cudaSuccess) e = cudaMallocHost((void **)&w->host_part, sizeof(float) * (size_t)w->nchunks);
    if (e == cudaSuccess) e = cudaMalloc((void **)&w->cg, sizeof(im_cg));
    if (e == cudaSuccess) e = cudaMallocHost((void **)&w->host_cg, sizeof(im_cg));
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
    w->fast = TAKE(1);
    w->rowbox = TAKE(6 * (size_t)w->ny);
    w->cand = w->ints, w->sr = w->ints + 2 * n, w->rows = w->ints + 3 * n;
    for (int l = 0; l < L; l++) {
        im_level_bufs *v = &w->lv[l];
        m = cs_im_carve_level(m, (size_t)v->n, &v->D, &v->Dinv, v->F, &v->mask, &v->b, &v->x, &v->t);
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
    a.R = w->R, a.q = w->q, a.D = w->lv[0].D, a.part = w->part, a.mask0 = w->lv[0].mask, a.S0 = w->lv[0].S;
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

/* The chunk partials of a . b over level 0 into w->part (nothing once stop is done). */
static void im_dot(cuda_ctx *c, const float *a, const float *b, const im_cg *stop)
{
    im_work *w = c->im;
    k_im_dot<<<(unsigned)w->nchunks, CS_CHUNK, sizeof(float) * CS_CHUNK, c->stream>>>(w->sc, a, b, w->part, stop);
}

/* The hierarchy from level 0's matrix: the coarse levels' Galerkin products, each level's Dinv. */
static void im_hierarchy(cuda_ctx *c)
{
    im_work *w = c->im;
    for (int l = 0; l < w->levels; l++) {
        im_level_bufs *lv = &w->lv[l];
        if (l > 0) k_im_galerkin<<<im_blocks(lv->n), IM_THREADS, 0, c->stream>>>(im_view(w, l - 1), *lv);
        k_im_inverse<<<im_blocks(lv->n), IM_THREADS, 0, c->stream>>>(lv->D, lv->Dinv, lv->n, lv->S);
    }
}

/* One V-cycle from level l: x = B b (vcycle of implicit_cpu.c); nothing once stop (when not NULL)
 * is done. */
static void im_vcycle(cuda_ctx *c, int l, const float *b, float *x, const im_cg *stop)
{
    im_work *w = c->im;
    const cs_im_level L = im_view(w, l);
    im_level_bufs *lv = &w->lv[l];
    const unsigned nb = im_blocks(lv->n);
    cudaStream_t st = c->stream;
    const int last = l + 1 == w->levels;
    const int sweeps = last ? CS_IM_COARSE_SWEEPS : CS_IM_SMOOTH;
    if (lv->n <= IM_TAIL) { /* this level and those below: one block */
        im_tail T;
        memset(&T, 0, sizeof T);
        for (int k = l; k < w->levels; k++)
            T.L[k] = im_view(w, k), T.b[k] = w->lv[k].b, T.x[k] = w->lv[k].x, T.t[k] = w->lv[k].t;
        T.first = l, T.levels = w->levels;
        k_im_tail<<<1, IM_TAIL_THREADS, 0, st>>>(T, b, x, stop);
        return;
    }
    k_im_jacobi<<<nb, IM_THREADS, 0, st>>>(L, x, b, lv->t, 1, stop);
    for (int k = 1; k < sweeps; k++) {
        k_im_apply<<<nb, IM_THREADS, 0, st>>>(L, x, lv->t, 0, stop);
        k_im_jacobi<<<nb, IM_THREADS, 0, st>>>(L, x, b, lv->t, 0, stop);
    }
    if (last) return;
    k_im_apply<<<nb, IM_THREADS, 0, st>>>(L, x, lv->t, 0, stop);
    k_im_sub<<<im_blocks(3 * (int64_t)lv->n), IM_THREADS, 0, st>>>(b, lv->t, 3 * lv->n, stop);
    im_level_bufs *cl = &w->lv[l + 1];
    k_im_restrict<<<im_blocks(cl->n), IM_THREADS, 0, st>>>(L, lv->t, cl->b, cl->nx, cl->ny, stop);
    im_vcycle(c, l + 1, cl->b, cl->x, stop);
    k_im_prolong<<<nb, IM_THREADS, 0, st>>>(L, x, cl->x, cl->nx, stop);
    for (int k = 0; k < sweeps; k++) {
        k_im_apply<<<nb, IM_THREADS, 0, st>>>(L, x, lv->t, 0, stop);
        k_im_jacobi<<<nb, IM_THREADS, 0, st>>>(L, x, b, lv->t, 0, stop);
    }
}

/* One iteration of the conjugate gradients, queued (pcg of implicit_cpu.c's loop body): every
 * scalar stays on the device, and once the solve is done each launch does nothing. */
static void im_cg_iteration(cuda_ctx *c)
{
    im_work *w = c->im;
    const cs_im_level L0 = im_view(w, 0);
    const int32_t n3 = 3 * w->n;
    const unsigned nb = im_blocks(w->n), nb3 = im_blocks(n3);
    const im_cg *cg = w->cg;
    k_im_apply<<<nb, IM_THREADS, 0, c->stream>>>(L0, w->p, w->q, 1, cg);
    im_dot(c, w->p, w->q, cg);
    k_im_cg_alpha<<<1, 1, 0, c->stream>>>(w->part, w->nchunks, w->cg);
    k_im_cg_step<<<nb3, IM_THREADS, 0, c->stream>>>(w->dx, w->r, w->p, w->q, cg, n3);
    im_dot(c, w->r, w->r, cg);
    k_im_cg_check<<<1, 1, 0, c->stream>>>(w->part, w->nchunks, w->cg);
    im_vcycle(c, 0, w->r, w->z, cg);
    im_dot(c, w->r, w->z, cg);
    k_im_cg_beta<<<1, 1, 0, c->stream>>>(w->part, w->nchunks, w->cg);
    k_im_cg_dir<<<nb3, IM_THREADS, 0, c->stream>>>(w->p, w->z, cg, n3);
}

/* Queues one iteration of the conjugate gradients: a graph of im_cg_iteration's launches, captured
 * the first time (its arguments are the workspace's buffers and the scalars it reads on the
 * device, so it holds while the workspace lives). */
static cs_status im_cg_queue(cuda_ctx *c)
{
    im_work *w = c->im;
    if (!w->cg_exec) {
        CUDA_CHECK(cudaStreamBeginCapture(c->stream, cudaStreamCaptureModeThreadLocal));
        im_cg_iteration(c);
        const cudaError_t launched = cudaGetLastError();
        cudaGraph_t graph;
        const cudaError_t ended = cudaStreamEndCapture(c->stream, &graph);
        if (launched != cudaSuccess) {
            if (ended == cudaSuccess) cudaGraphDestroy(graph);
            return cuda_fail(c, launched, "a launch while capturing a graph", __FILE__, __LINE__);
        }
        CUDA_CHECK(ended);
        const cudaError_t ie = cudaGraphInstantiate(&w->cg_exec, graph, 0);
        cudaGraphDestroy(graph);
        if (ie != cudaSuccess) {
            w->cg_exec = NULL;
            return cuda_fail(c, ie, "cudaGraphInstantiate", __FILE__, __LINE__);
        }
    }
    CUDA_CHECK(cudaGraphLaunch(w->cg_exec, c->stream));
    return CS_OK;
}

/* Conjugate gradients on A dx = R preconditioned by a V-cycle (pcg of implicit_cpu.c): stops at
 * |r| <= target or after most iterations; the iterations run into its. The host queues as many
 * iterations as the last solve took before it first reads whether the solve is done, then one at
 * a time: about two waits a solve rather than three an iteration, and an iteration queued past
 * the end costs a graph of launches that return at once. (As many less one: 4.8 waits a Newton
 * iteration and 198 graphs for 170 iterations in test_datapath's scene; as many, 4.2 and 215;
 * one more, 3.8 and 239.) */
static cs_status im_pcg(cuda_ctx *c, float target, int most, int *its)
{
    im_work *w = c->im;
    const size_t bytes = sizeof(float) * (size_t)(3 * w->n);
    *its = 0;
    CUDA_CHECK(cudaMemsetAsync(w->dx, 0, bytes, c->stream));
    CUDA_CHECK(cudaMemcpyAsync(w->r, w->R, bytes, cudaMemcpyDeviceToDevice, c->stream));
    im_vcycle(c, 0, w->r, w->z, NULL);
    CUDA_CHECK(cudaMemcpyAsync(w->p, w->z, bytes, cudaMemcpyDeviceToDevice, c->stream));
    im_dot(c, w->r, w->z, NULL);
    k_im_cg_begin<<<1, 1, 0, c->stream>>>(w->part, w->nchunks, w->cg, target, most);
    int queued = 0, group = w->cg_last > 1 ? w->cg_last : 1;
    while (queued < most) {
        const int k = group < most - queued ? group : most - queued;
        for (int q = 0; q < k; q++) {
            const cs_status st = im_cg_queue(c);
            if (st != CS_OK) return st;
        }
        queued += k;
        CUDA_CHECK(cudaGetLastError());
        CUDA_CHECK(cudaMemcpyAsync(w->host_cg, w->cg, sizeof(im_cg), cudaMemcpyDeviceToHost, c->stream));
        CUDA_CHECK(cudaStreamSynchronize(c->stream));
        if (w->host_cg->done) break;
        group = 1;
    }
    if (queued > 0) *its = w->host_cg->it;
    w->cg_last = *its;
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
    k_im_begin<<<nb, IM_THREADS, 0, c->stream>>>(w->sc, c->vb.state[c->cur], S, w->base, c->vb.mask, w->lv[0].mask, c->vb.acc, 1);
    /* the rocks over the part without the cloth, and the mass they lend, from the part's start
     * (after k_im_begin: it reads level 0's mask) */
    const int rocks = c->host_sc.nr > 0;
    if (rocks) {
        k_im_row_boxes<<<im_blocks(p->ny), IM_THREADS, 0, c->stream>>>(w->sc, c->vb.state[c->cur], w->rowbox);
        k_im_rocks_begin<<<1, 1, 0, c->stream>>>(w->sc, im_rocks(c, c->vb.state[c->cur], L0), h);
    }
    CUDA_CHECK(cudaStreamSynchronize(c->stream));
    float reach = 0.0f;
    for (int32_t q = 0; q < w->nchunks; q++) reach = w->host_part[q] > reach ? w->host_part[q] : reach;
    float r;
    if ((st = im_assemble(c, S, L0, 1, rocks, &r)) != CS_OK) return st;
    const float r0 = r;
    int k = 0;
    float prev = 2.0f * r0 + 1.0f;
    /* Newton: stops as implicit_cpu.c's does (cs_im_newton_more) */
    const float rounding = cs_im_float_floor(p, reach);
    while (cs_im_newton_more(p, k, r, r0, prev, rounding)) {
        prev = r;
        im_hierarchy(c);
        int its = 0;
        if ((st = im_pcg(c, cs_im_cg_target(p, r0, r), p->cg_iterations, &its)) != CS_OK) return st;
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
        k_im_row_boxes<<<im_blocks(p->ny), IM_THREADS, 0, c->stream>>>(w->sc, S, w->rowbox);
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
        /* fastest() of implicit_cpu.c: how fast the cloth closes on a rock near it (0 without
         * one), and with self_collision how fast layers that may meet move (sc_part_rate) */
        float rate = 0.0f, layers = 0.0f;
        if (nr > 0) {
            k_im_fastest_chunks<<<(unsigned)w->nchunks, CS_CHUNK, sizeof(float) * CS_CHUNK, c->stream>>>(
                c->sc, c->rb.rocks, c->vb.state[c->cur], p->dt, w->part);
            k_im_fastest<<<1, 1, 0, c->stream>>>(w->part, w->nchunks, w->fast);
            CUDA_CHECK(cudaGetLastError());
            CUDA_CHECK(cudaMemcpyAsync(w->host_part, w->fast, sizeof(float), cudaMemcpyDeviceToHost, c->stream));
            CUDA_CHECK(cudaStreamSynchronize(c->stream));
            rate = w->host_part[0];
        }
        if (p->self_on && (st = sc_part_rate(c, p, p->dt, &layers)) != CS_OK) return st;
        rate = layers > rate ? layers : rate;
        const int32_t parts = cs_im_splits(rate, p->dt, p->most_splits);
        const float h = p->dt / (float)parts;
        for (int32_t q = 0; q < parts; q++) {
            if (p->self_on && (st = sc_begin(c, p->n)) != CS_OK) return st;
            if ((st = im_part(c, p, h, &stats)) != CS_OK) return st;
            if (p->self_on && (st = sc_end(c, p, &rep->self)) != CS_OK) return st;
        }
    }
    k_im_finite<<<im_blocks(p->n), IM_THREADS, 0, c->stream>>>(c->vb.state[c->cur], c->vb.acc, p->n, c->rb.rocks, nr, c->flags);
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
    k_im_begin<<<im_blocks(p->n), IM_THREADS, 0, c->stream>>>(w->sc, S, NULL, w->base, c->vb.mask, w->lv[0].mask, NULL, 0);
    float r;
    /* nothing carried (the rocks are left as they are): the cloth's own force */
    if ((st = im_assemble(c, S, c->vb.rest[c->rest_cur], 0, 0, &r)) != CS_OK) return st;
    k_im_refresh_accel<<<im_blocks(p->n), IM_THREADS, 0, c->stream>>>(w->sc, w->R, w->lv[0].mask, c->vb.acc);
    CUDA_CHECK(cudaGetLastError());
    return CS_OK;
}

#endif /* CLOTHSIM_CUDA_IMPLICIT_CUDA_CUH */
