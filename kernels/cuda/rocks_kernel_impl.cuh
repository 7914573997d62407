/* rocks_kernel_impl.cuh - the rocks' kernels: their forces and moves after the cloth kernel
 * (k_rocks, k_rock_force, k_rock_move): device code, and the block functions a batch runs too.
 *
 * A warp per rock sums its partials - only the chunks whose bits are set, in chunk order
 * within a group, then the groups in order, as cs_rock_force does - then the other rocks (tested
 * in parallel, added in order), the ground and gravity. Up to ROCKS_FUSED rocks one block does it
 * all and moves them; beyond, one kernel computes accelerations and another moves. No float
 * atomics anywhere. */
#ifndef CLOTHSIM_CUDA_ROCKS_KERNEL_IMPL_CUH
#define CLOTHSIM_CUDA_ROCKS_KERNEL_IMPL_CUH

#include "cloth_kernel.cuh"

/* Total force and torque on rock r, in cs_rock_force's order, by one warp: the sums of the chunk
 * groups that touched it (group_sums; the others are +0) in group order; then the other rocks
 * (tested by the lanes, added in index order), the ground, gravity. The hit words read are
 * cleared for the next substep. Every lane ends with the same sums. */
__device__ static void rock_force(const cuda_scene *sc, const cuda_bufs &b, int32_t r, cs_vec3 *F_out, cs_vec3 *T_out)
{
    const cs_phys *p = &sc->p;
    const int lane = (int)(threadIdx.x & 31u);
    const int32_t nr = sc->nr, ng = sc->ngroups;
    cs_vec3 F = cs_v3(0.0f, 0.0f, 0.0f), T = F;
    for (int32_t g0 = 0; g0 < ng; g0 += 32) {
        const int32_t g = g0 + lane;
        const size_t rg = (size_t)r * (size_t)ng + (size_t)g;
        unsigned long long bits = 0;
        float q[6] = {0, 0, 0, 0, 0, 0};
        if (g < ng && (bits = dload(&b.hits[rg])) != 0) {
            dstore(&b.hits[rg], 0ull); /* clean for the next substep */
            for (int k = 0; k < 6; k++) q[k] = dload(&b.gsum[rg * 6 + (size_t)k]);
        }
        for (unsigned m = __ballot_sync(FULL, bits != 0); m; m &= m - 1u) {
            const int l = __ffs((int)m) - 1;
            F = cs_add(F, cs_v3(__shfl_sync(FULL, q[0], l), __shfl_sync(FULL, q[1], l), __shfl_sync(FULL, q[2], l)));
            T = cs_add(T, cs_v3(__shfl_sync(FULL, q[3], l), __shfl_sync(FULL, q[4], l), __shfl_sync(FULL, q[5], l)));
        }
    }
    /* Through pointers: these read positions, velocities, spins and radii only, never the
     * accelerations that other warps of k_rock_force write meanwhile. */
    const cs_rock_state *me = &b.rocks[r];
    for (int32_t b0 = 0; b0 < nr; b0 += 32) {
        const int32_t o = b0 + lane;
        cs_vec3 f = cs_v3(0.0f, 0.0f, 0.0f), tq = f;
        int touch = 0;
        if (o < nr && o != r) touch = cs_rock_pair_contact(me, &b.rocks[o], p, &f, &tq);
        for (unsigned m = __ballot_sync(FULL, touch); m; m &= m - 1u) {
            const int l = __ffs((int)m) - 1;
            F = cs_add(F, cs_v3(__shfl_sync(FULL, f.x, l), __shfl_sync(FULL, f.y, l), __shfl_sync(FULL, f.z, l)));
            T = cs_add(T, cs_v3(__shfl_sync(FULL, tq.x, l), __shfl_sync(FULL, tq.y, l), __shfl_sync(FULL, tq.z, l)));
        }
    }
    cs_vec3 f, tq;
    if (cs_rock_ground_contact(me, p, &f, &tq)) {
        F = cs_add(F, f);
        T = cs_add(T, tq);
    }
    *F_out = cs_add(F, cs_scale(p->gravity, me->mass));
    *T_out = T;
}

/* A rock's velocity and position steps after its accelerations are stored (backend.h). */
__device__ static void rock_move(int mode, cs_rock_state *k, const cs_phys *p, int *flags)
{
    switch (mode) {
    case ROCKS_VERLET:
        cs_rock_kick(k, p->hdt);
        cs_rock_kick(k, p->hdt);
        cs_rock_drift(k, p->dt);
        break;
    case ROCKS_VERLET_LAST: cs_rock_kick(k, p->hdt); break;
    case ROCKS_EULER:
        cs_rock_kick(k, p->dt);
        cs_rock_drift(k, p->dt);
        break;
    default: break;
    }
    if ((mode == ROCKS_VERLET_LAST || mode == ROCKS_EULER) && !cs_rock_finite(k, 0))
        atomicOr(&flags[FLAG_NONFINITE], 1);
}

/* Up to ROCKS_FUSED rocks: one block of 32 warps, a warp per rock (two rounds), then the moves. */
__device__ static void rocks_block(const cuda_scene *__restrict__ sc, const cuda_bufs &b, int mode)
{
    const int warp = (int)(threadIdx.x >> 5), lane = (int)(threadIdx.x & 31u);
    cs_vec3 F[2] = {cs_v3(0.0f, 0.0f, 0.0f), cs_v3(0.0f, 0.0f, 0.0f)}, T[2] = {F[0], F[1]};
    for (int k = 0; k < 2; k++) {
        const int32_t r = warp + 32 * k;
        if (r < sc->nr) rock_force(sc, b, r, &F[k], &T[k]); /* warp-uniform */
    }
    __syncthreads(); /* every force read the other rocks before any moves */
    if (lane == 0)
        for (int k = 0; k < 2; k++) {
            const int32_t r = warp + 32 * k;
            if (r >= sc->nr) continue;
            cs_rock_state rk = dload(&b.rocks[r]);
            cs_rock_accel(&rk, F[k], T[k]);
            rock_move(mode, &rk, &sc->p, b.flags);
            dstore(&b.rocks[r], rk);
        }
}

template <int MODE> __global__ void __launch_bounds__(1024) k_rocks(const cuda_scene *__restrict__ sc, cuda_bufs b)
{
    rocks_block(sc, b, MODE);
}

/* More rocks: accelerations (a warp per rock; a rock's force never reads another's a) ... */
__device__ static void rock_force_warp(const cuda_scene *__restrict__ sc, const cuda_bufs &b, int32_t r)
{
    if (r >= sc->nr) return; /* warp-uniform */
    cs_vec3 F, T;
    rock_force(sc, b, r, &F, &T);
    if ((threadIdx.x & 31u) == 0) {
        cs_vec3 a = cs_scale(F, dload(&b.rocks[r].inv_mass)), al = cs_scale(T, dload(&b.rocks[r].inv_inertia));
        dstore(&b.rocks[r].a, a);
        dstore(&b.rocks[r].alpha, al);
    }
}

__global__ void __launch_bounds__(32 * ROCK_WARPS) k_rock_force(const cuda_scene *__restrict__ sc, cuda_bufs b)
{
    rock_force_warp(sc, b, (int32_t)(blockIdx.x * ROCK_WARPS + (threadIdx.x >> 5)));
}

/* ... then the moves, a thread per rock. */
__device__ static void rock_move_thread(const cuda_scene *__restrict__ sc, const cuda_bufs &b, int32_t r, int mode)
{
    if (r >= sc->nr) return;
    cs_rock_state k = dload(&b.rocks[r]);
    rock_move(mode, &k, &sc->p, b.flags);
    dstore(&b.rocks[r], k);
}

template <int MODE> __global__ void k_rock_move(const cuda_scene *__restrict__ sc, cuda_bufs b)
{
    rock_move_thread(sc, b, (int32_t)(blockIdx.x * blockDim.x + threadIdx.x), MODE);
}

#endif /* CLOTHSIM_CUDA_ROCKS_KERNEL_IMPL_CUH */
