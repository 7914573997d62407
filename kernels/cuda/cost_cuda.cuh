/* cost_cuda.cuh - the CUDA backend's cost model (backend.h's cost and stats): the bytes each
 * kernel reads and writes, its launches and graphs, and the device's peak bandwidth. Part of the
 * one translation unit backend_cuda.cu. */
#ifndef CLOTHSIM_CUDA_COST_CUDA_CUH
#define CLOTHSIM_CUDA_COST_CUDA_CUH

#include <math.h>

#include "clothsim/implicit.h"
#include "graphs_cuda.cuh"

/* The device's memory bandwidth by its clock and bus (0 where it does not say). */
static double peak_bandwidth(int dev)
{
    int khz = 0, bits = 0;
    if (cudaDeviceGetAttribute(&khz, cudaDevAttrMemoryClockRate, dev) != cudaSuccess ||
        cudaDeviceGetAttribute(&bits, cudaDevAttrGlobalMemoryBusWidth, dev) != cudaSuccess) {
        (void)cudaGetLastError();
        return 0;
    }
    return 2.0 * (double)khz * 1e3 * (double)bits / 8.0; /* double data rate */
}

/* The cost model (backend.h): the distinct bytes each kernel reads and writes per vertex, from the
 * kernels' loads and stores (the *_impl.cuh files, implicit_cuda.cuh); tests/gpu/test_datapath.c
 * holds it to what the CPU imitation of CUDA sees the kernels touch. Per vertex of the cloth
 * kernel: the state read (6 floats), the mask (1 byte), the six owned rest lengths, the state
 * written; with strain the change byte (read and, where it flips, written) and the rest lengths of
 * vertices whose springs are changing (none at rest); the acceleration where a graph ends. (A
 * vertex at a border owns fewer springs.) Rock kernels scale with rocks, not vertices. */
/* implicit_euler's rows: its launches scale with the solver's iterations, which depend on the
 * state, so the model takes nominal counts - IM_NEWTON Newton iterations a substep, each with one
 * line-search assembly and IM_CG conjugate-gradient iterations (about what the default cloth takes:
 * MODEL.md's table) - and the bytes per vertex each kernel's loads and stores name (a vertex's
 * own; neighbours' reads come from cache). A V-cycle's coarse levels add about a third of level 0's
 * traffic (2 x 2 aggregation), counted in its rows. Rough by design: what bench measures is the
 * truth. The host waits for the device at a part's start (its first |R|), for each line-search
 * assembly's |R| (IM_TRIES a Newton iteration) and to learn whether a linear solve is done
 * (IM_LOOKS), with rocks once more a substep for its parts; test_datapath counts them (about 3.9 a
 * Newton iteration with a rock). A batch of such scenes shares its launches and its waits. */
#define IM_NEWTON 2.0
#define IM_CG 5.0
#define IM_TRIES 1.3
#define IM_LOOKS 2.0
static void im_cost(const cs_model *m, int32_t n_rocks, cs_cost_model *out)
{
    const cs_phys *p = &m->phys;
    const double F = m->substeps, N = IM_NEWTON, C = IM_CG, levels = 4.0 / 3.0;
    const bool strain = p->strain_on != 0;
    /* A block as stored (its upper triangle: 24 bytes); a level's matrix per vertex: D and the four
     * forward blocks (120 bytes); level 0's bending blocks (48). Rows: bytes a vertex per run, runs
     * a substep, launches a run. */
    const double blk = 4.0 * CS_IM_SYM, blocks = 5 * blk, bend = 2 * blk;
    /* a V-cycle's launches: per level of more than IM_TAIL vertices a sweep each way, two products
     * A x, the residual, restriction and prolongation; the levels below in one block (k_im_tail) */
    int32_t lx[CS_IM_MAX_LEVELS], ly[CS_IM_MAX_LEVELS];
    const int nlev = cs_im_levels(p->nx, p->ny, lx, ly);
    double vcycle_launches = 0.0;
    for (int l = 0; l < nlev; l++) {
        if ((int64_t)lx[l] * ly[l] <= IM_TAIL) {
            vcycle_launches += 1.0;
            break;
        }
        vcycle_launches += l + 1 == nlev ? 2.0 * CS_IM_COARSE_SWEEPS - 1.0 : 7.0;
    }
#define IM_ROW(name, rd, wr, runs, launches) cs_cost_add(out, name, rd, wr, 0, runs, (runs) * F * (launches))
    IM_ROW("k_im_reach (the part's largest coordinate)", 12.0, 0.0, 1.0, 1.0);
    IM_ROW("k_im_begin (x_n, v_n kept; the first guess)", 24.0 + 1.0 + 12.0, 24.0 + 4.0 + 24.0, 1.0, 1.0);
    /* the state (24), x_n's velocity (12), rest lengths (24), mask (4); R, the springs' force,
     * level 0's D, forward and bending blocks */
    IM_ROW("k_im_assemble (residual and level 0's matrix)", 64.0, 12.0 + 12.0 + blocks + bend, 1.0 + N, 1.0);
    /* each coarse level's Galerkin product reads the finer level's blocks and writes its own;
     * every level's Dinv */
    IM_ROW("k_im_galerkin, k_im_inverse (the hierarchy)", levels * blk + 0.25 * levels * (blocks + 4.0),
           levels * blk + 0.25 * levels * (blocks + 4.0), N, 7.0);
    /* per CG iteration: A p with bending (the blocks, p, the mask; A p written), three dot
     * products, the two vector updates, a V-cycle (smoothing sweeps, products, residual,
     * restriction, prolongation; the coarse levels a third more than level 0) */
    IM_ROW("k_im_apply (A p, bending included)", blocks + bend + 12.0 + 4.0, 12.0, N * C, 1.0);
    IM_ROW("k_im_dot (chunk partials)", 24.0, 0.0, N * (3.0 * C + 1.0), 1.0);
    IM_ROW("k_im_cg_step, k_im_cg_dir", 48.0 + 24.0, 24.0 + 12.0, N * C, 2.0);
    /* the scalars (k_im_cg_begin a solve; _alpha, _check, _beta an iteration): a chunk's partial
     * each, read by one thread */
    cs_cost_add(out, "k_im_cg_begin, _alpha, _check, _beta (one thread)", 0, 0, 4.0 * p->nchunks, N * (3.0 * C + 1.0),
                N * (3.0 * C + 1.0) * F);
    IM_ROW("V-cycle (k_im_jacobi, k_im_apply, k_im_sub, k_im_restrict, k_im_prolong)",
           levels * (2 * (blk + 40.0) + 3 * (blocks + 16.0) + 24.0 + 12.0 + 24.0),
           levels * (2 * 12.0 + 3 * 12.0 + 12.0 + 3.0 + 12.0), N * (C + 1.0), vcycle_launches);
    IM_ROW("k_im_keep, k_im_move (the line search)", 12.0 + 12.0 + 12.0 + 12.0 + 4.0, 12.0 + 24.0, N, 2.0);
    if (n_rocks > 0) {
        /* With rocks (nominally one part a substep; contact cuts substeps into more): the
         * substep's closing rate (positions and velocities; the rocks), the rows' boxes before
         * each rock step (positions), and a part's rock steps - the one-thread kernels scan the
         * cloth twice for each rock for its candidates (positions and, surface model, rest
         * lengths: about 28 bytes a vertex) and twice for its friction (positions, start,
         * velocities, the carried rock, mass and normal, what the push moved: about 60 bytes a
         * vertex, the push's mark cleared: 4), read the rock carried (4) and write it with the
         * mass and normal (20). The scans visit only the rows within a rock's reach (the rows'
         * boxes), so the whole grid counted here is their bound, not their traffic. */
        const double rock = (double)sizeof(cs_rock_state) * n_rocks;
        cs_cost_add(out, "k_im_fastest_chunks, k_im_fastest (a substep's parts)", 24.0, 0.0, rock, 1.0, 2.0 * F);
        cs_cost_add(out, "k_im_row_boxes (before each rock step)", 12.0, 24.0 / p->nx, 0, 2.0, 2.0 * F);
        cs_cost_add(out, "k_im_rocks_begin, k_im_rocks_push (one thread)",
                    n_rocks * (2.0 * 28.0 + 2.0 * 60.0) + 4.0 + 24.0 + 4.0, 20.0 + 4.0 * n_rocks, 3.0 * rock, 1.0,
                    2.0 * F);
    }
    IM_ROW("k_im_accel", 24.0 + 4.0, 12.0, 1.0, 1.0);
    if (strain) IM_ROW("k_strain", 12.0 + 24.0 + 1.0, 0.0, 1.0, 1.0);
    IM_ROW("k_im_finite (a step call's end)", 36.0, 0.0, 1.0 / F, 1.0);
#undef IM_ROW
    cs_cost_add(out, "frame copy (positions, on the device)", 12.0, 12.0, 0, 1.0 / F, 0);
    out->graphs_per_frame = N * C * F; /* a CG iteration's launches in one; the rest plain */
    out->waits_per_substep = 1.0 + N * (IM_TRIES + IM_LOOKS) + (n_rocks > 0 ? 1.0 : 0.0);
    /* every launch waits for the one before */
    out->nodes_per_substep = out->launches_per_frame / F;
    /* in a batch (im_batch_run): the batch's stream waits for the scene's (an event recorded and
     * waited for); its frame read, batch_frames' three calls (the tables and waits are the batch's) */
    out->batch_calls_per_scene = 2.0;
    out->batch_calls_per_read_scene = 5.0;
}

/* self_collision's pass (selfcontact_cuda.cuh) after each substep (a part: nominally one a
 * substep). The candidate scans dominate: a vertex reads each vertex within reach (its position,
 * cell and id: 28 bytes), about pi (reach / h)^2 of them on a flat cloth (more where it is folded,
 * and twice the substep's motion wider: contact-dependent, not modelled), with reach
 * self_thickness plus two edges; counted, filled and once each sweep of the bound (nominally
 * two). Each pass also waits for the device about seven times (scalars read back: SC_WAITS), and
 * under implicit_euler the gather for each substep's parts five more (SC_RATE_WAITS). */
#define SC_SWEEPS 2.0
#define SC_WAITS 7.0
#define SC_RATE_WAITS 5.0
static void sc_cost(const cs_model *m, cs_cost_model *out)
{
    const cs_phys *p = &m->phys;
    if (!p->self_on) return;
    const double F = m->substeps, h = p->self_hx < p->self_hy ? p->self_hx : p->self_hy;
    const double reach = p->self_thickness + 2.0 * h, near = 3.14159265 * (reach / h) * (reach / h);
    const double cand = 28.0 * (near < p->n ? near : p->n);
    cs_cost_add(out, "k_sc_begin (x0, the mask as floats)", 12.0 + 1.0, 12.0 + 4.0, 0, 1.0, F);
    cs_cost_add(out, "k_sc_disp, k_sc_far (the displacements)", 24.0 + 12.0, 12.0, 0, 1.0, 2.0 * F);
    cs_cost_add(out, "k_sc_edge (the longest edge)", 12.0 + 36.0 + 12.0, 0, 0, 1.0, F);
    /* the grid: keys; the counting sort's count, scan, fill and order (start and the cursor about
     * two cells a vertex, each read and zeroed) */
    cs_cost_add(out, "k_sc_keys, k_sc_count, _scan, _fill, _order (the grid)", 12.0 + 4.0 + 8.0 + 20.0,
                4.0 + 12.0 + 8.0 + 16.0, 0, 1.0, 5.0 * F);
    cs_cost_add(out, "k_sc_pairs (counted, then filled)", 2.0 * (24.0 + cand), 4.0 + 8.0, 0, 1.0, 2.0 * F);
    cs_cost_add(out, "k_sc_repel, k_sc_push", 24.0 + 8.0 + 4.0 + 24.0, 24.0 + 4.0, 0, 1.0, 2.0 * F);
    cs_cost_add(out, "k_sc_limit (the bound's sweeps)", SC_SWEEPS * (48.0 + cand), SC_SWEEPS * 4.0, 0, 1.0,
                SC_SWEEPS * F);
    cs_cost_add(out, "k_sc_cut", 12.0 + 12.0 + 4.0, 0, 0, 1.0, F);
    out->waits_per_substep += SC_WAITS;
    if (p->integrator == CS_IMPLICIT_EULER) {
        /* before each substep, the pairs for its parts (sc_part_rate): x0, the velocities' box and
         * spread, the longest edge, the grid, the repelling pairs within the fastest's reach
         * (nominally the pass's), each vertex's closing speeds; five waits */
        cs_cost_add(out, "sc_part_rate: k_sc_begin, k_sc_box, k_sc_far, k_sc_edge", 13.0 + 12.0 + 12.0 + 60.0, 16.0, 0,
                    1.0, 4.0 * F);
        cs_cost_add(out, "sc_part_rate: the grid, k_sc_pairs", 44.0 + 2.0 * (24.0 + cand), 40.0 + 12.0, 0, 1.0, 7.0 * F);
        cs_cost_add(out, "sc_part_rate: k_sc_near", 12.0 + 24.0 + 8.0, 0, 0, 1.0, F);
        out->waits_per_substep += SC_RATE_WAITS;
    }
}

static void cuda_cost(const cs_model *m, int32_t n_rocks, cs_cost_model *out)
{
    const cs_phys *p = &m->phys;
    if (p->integrator == CS_IMPLICIT_EULER) {
        memset(out, 0, sizeof *out);
        im_cost(m, n_rocks, out);
        sc_cost(m, out);
        return;
    }
    const double G = graph_len(m), F = m->substeps, graphs = ceil(F / G);
    const bool verlet = p->integrator == CS_VELOCITY_VERLET, strain = p->strain_on != 0;
    const double rock = (double)sizeof(cs_rock_state);
    memset(out, 0, sizeof *out);
    /* A vertex reads the rest lengths of the springs it owns that the grid has. */
    const double nx = p->nx, ny = p->ny;
    const double springs = (nx - 1) * ny + nx * (ny - 1) + 2 * (nx - 1) * (ny - 1) + (nx - 2) * ny + nx * (ny - 2);
    const double cloth_read = 24.0 + 1.0 + 4.0 * springs / (nx * ny) + (verlet && strain ? 1.0 : 0.0);
    const double last = (G - 1.0) / G, once = 1.0 / G;
    const char *name = verlet ? "k_cloth (velocity Verlet)" : "k_cloth (symplectic Euler)";
    const char *name_last = verlet ? "k_cloth (the last substep of a graph)" : "k_cloth (the last substep of a graph, Euler)";
    /* Culling reads each rock's centre and radius, the group sums its word of each chunk group
     * (and 24 bytes for each chunk that touched it: contact-dependent, not modelled). */
    const double ng = ceil((double)p->nchunks / CS_CHUNK_GROUP);
    const double cull = (16.0 + 8.0 * ng) * n_rocks;
    cs_cost_add(out, name, cloth_read, 24.0, cull, last, F - graphs);
    cs_cost_add(out, name_last, cloth_read, 24.0 + 12.0, cull, once, graphs);
    if (verlet) cs_cost_add(out, "k_drift_first (the first substep of a graph)", 36.0, 24.0, 2 * rock * n_rocks, once, graphs);
    if (!verlet && strain) cs_cost_add(out, "k_strain", 12.0 + 24.0 + 1.0, 0.0, 0.0, 1.0, F);
    if (n_rocks > 0) {
        /* Each rock: its state read (by every warp: the same bytes), its hit words read, its state
         * written; plus 24 bytes for each chunk group that touched it (contact-dependent, not
         * modelled). */
        const double nr = n_rocks;
        if (n_rocks <= ROCKS_FUSED)
            cs_cost_add(out, "k_rocks (forces and moves, one block)", 0, 0, nr * (rock + 8.0 * ng + rock), 1.0, F);
        else {
            cs_cost_add(out, "k_rock_force (a warp per rock)", 0, 0, nr * (rock + 8.0 * ng + 24.0), 1.0, F);
            cs_cost_add(out, "k_rock_move", 0, 0, nr * 2 * rock, 1.0, F);
        }
    }
    /* The frame the host reads, copied on the device once per step call. */
    cs_cost_add(out, "frame copy (positions, on the device)", 12.0, 12.0, 0, 1.0 / F, 0);
    out->graphs_per_frame = graphs;
    if (p->self_on) { /* a pass after every substep: graphs of one substep, and the pass's launches */
        out->graphs_per_frame = F;
        sc_cost(m, out);
    }
    /* batch_run: nothing for a scene whose stream is idle; batch_frames, its positions read: a
     * wait for the slot's last copy, the copy to pinned memory, an event (the device copies are
     * one launch for the batch). */
    out->batch_calls_per_scene = 0.0;
    out->batch_calls_per_read_scene = 3.0;
    out->nodes_per_substep = 1.0 + (n_rocks > 0 ? (n_rocks <= ROCKS_FUSED ? 1.0 : 2.0) : 0.0) +
                             (!verlet && strain ? 1.0 : 0.0) + (verlet ? 1.0 / G : 0.0);
}

static void cuda_stats(void *ctx, const cs_model *m, cs_backend_stats *out)
{
    cuda_ctx *c = (cuda_ctx *)ctx;
    cs_cost_model cm;
    cuda_cost(m, c->host_sc.nr, &cm);
    out->bytes_per_vertex_substep = cm.bytes_per_vertex_substep;
    out->peak_bandwidth = peak_bandwidth(c->dev);
}

#endif /* CLOTHSIM_CUDA_COST_CUDA_CUH */
