/* cloth_kernel_impl.cuh - the cloth kernel (k_cloth: springs, air, gravity, contacts and the
 * substep's update of every vertex), velocity Verlet's first drift (k_drift_first) and symplectic
 * Euler's strain pass (k_strain): device code, and the block functions a batch runs too.
 *
 * A block is 256 columns (one chunk wide) and tile_rows rows of the grid, walked
 * row by row. For each row it stores the positions and velocities of the row two below into a
 * ring of four rows in shared memory (r-1 .. r+2, loaded one row ahead, so the loads overlap the work), evaluates the six springs each vertex owns (cs_spring_force once
 * per spring, as the CPU backend does: the far end gets the exact negation), gathers each vertex's
 * 12 springs in CS_SPRING_SLOTS order from its own registers, its neighbours' shared-memory forces
 * and the rows above, adds air and gravity, then contacts, and writes the vertex's next state.
 * The two rows above a tile and the three columns beside it are evaluated again by this block
 * without being written (their owners write them). Contacts: each tile culls the rocks against
 * its bounding box once; for each rock that may touch it and each of its rows, the vertices add
 * the rock's force in rock order, and the row chunk's reactions are summed with cs_tree_sum's tree
 * (shared memory, then warp shuffles) into the chunk's partial, and the chunk's bit set in the
 * rock's word for its chunk group. Surface contact (contact_model surface) instead takes each
 * candidate rock in turn: every vertex gathers its share from its 1-ring (cs_surface_gather, the
 * ring kept in registers from rows r-1 .. r+1 of a four-row ring), then the reactions the row's
 * vertices own go through the same tree. The tile's box then covers the row above and below and
 * the columns beside it (a vertex's triangles reach that far). */
#ifndef CLOTHSIM_CUDA_CLOTH_KERNEL_IMPL_CUH
#define CLOTHSIM_CUDA_CLOTH_KERNEL_IMPL_CUH

#include "cloth_kernel.cuh"

/* Shared memory of the cloth kernel (floats). */

#define RING_SLOTS 4                               /* rows r-1 .. r+2 (surface contact reads r-1) */
#define SM_RING 0                                  /* [RING_SLOTS][6][RING_W] */
#define SM_FROW (SM_RING + RING_SLOTS * 6 * RING_W) /* [SX, BX][3][FORCE_W]; also the tree's [6][TILE_W] */
#define SM_FPREV (SM_FROW + 2 * 3 * FORCE_W)       /* [row parity][D1, D2][3][FORCE_W] */
#define SM_RED (SM_FPREV + 2 * 2 * 3 * FORCE_W)    /* [6][WARPS]: the tile's bounding box */
#define SM_COUNT (SM_RED + 6 * WARPS)              /* [WARPS] ints: candidates per warp */
#define SM_TOUCHED (SM_COUNT + WARPS)              /* [32] bits: candidates a row touches */
#define SM_CAND (SM_TOUCHED + 32)                  /* candidate rocks (ints) */
static_assert(2 * 3 * FORCE_W >= 6 * TILE_W, "the tree scratch fits in the force rows");

static size_t cloth_smem(int32_t rock_cap) { return sizeof(float) * (size_t)(SM_CAND + rock_cap); }

#define RING(sm, slot, q, k) (sm)[SM_RING + ((slot) * 6 + (q)) * RING_W + (k)]
#define FROW(sm, which, c, k) (sm)[SM_FROW + ((which) * 3 + (c)) * FORCE_W + (k)]
#define FPREV(sm, par, which, c, k) (sm)[SM_FPREV + (((par) * 2 + (which)) * 3 + (c)) * FORCE_W + (k)]

__device__ static inline cs_vec3 ring_x(const float *sm, int32_t r, int k)
{
    const int s = r % RING_SLOTS;
    return cs_v3(RING(sm, s, 0, k), RING(sm, s, 1, k), RING(sm, s, 2, k));
}
__device__ static inline cs_vec3 ring_v(const float *sm, int32_t r, int k)
{
    const int s = r % RING_SLOTS;
    return cs_v3(RING(sm, s, 3, k), RING(sm, s, 4, k), RING(sm, s, 5, k));
}

/* A row of the state as one thread carries it to the ring: its column, and for threads 0..5 one
 * of the six columns past the chunk's 256 (the ring holds columns c0 - 3 .. c0 + 258). */
struct row_regs {
    float q[2][6];
};

/* Loads row r's columns of this thread into registers (those that exist). */
__device__ static void fetch_row(const cuda_bufs &b, const cs_phys *p, int32_t r, int32_t c0, row_regs *f)
{
    if (r < 0 || r >= p->ny) return;
    for (int h = 0; h < 2; h++) {
        const int k = (int)threadIdx.x + h * TILE_W;
        const int32_t i = c0 - RING_OFF + k;
        if (k >= RING_W || i < 0 || i >= p->nx) continue;
        const size_t v = (size_t)r * (size_t)p->nx + (size_t)i;
        for (int q = 0; q < 6; q++) f->q[h][q] = dload(&b.in[(size_t)q * (size_t)p->n + v]);
    }
}

/* Stores what fetch_row loaded into row r's ring slot. */
__device__ static void put_row(const cs_phys *p, float *sm, int32_t r, int32_t c0, const row_regs *f)
{
    if (r < 0 || r >= p->ny) return;
    for (int h = 0; h < 2; h++) {
        const int k = (int)threadIdx.x + h * TILE_W;
        const int32_t i = c0 - RING_OFF + k;
        if (k >= RING_W || i < 0 || i >= p->nx) continue;
        for (int q = 0; q < 6; q++) RING(sm, r % RING_SLOTS, q, k) = f->q[h][q];
    }
}

/* The springs vertex (i, r) owns, of the types in `types`, from the ring: forces F[t] (zero where
 * the grid has no such spring or the type is not asked for), lengths len[t], rest lengths l0[t]. */
__device__ static void eval_owned(const cuda_bufs &b, const cs_phys *p, const float *sm, int32_t i, int32_t r,
                                  int32_t c0, unsigned types, cs_vec3 *F, float *len, float *l0)
{
    const int k = i - c0 + RING_OFF;
    const cs_vec3 xi = ring_x(sm, r, k), vi = ring_v(sm, r, k);
    const size_t v = (size_t)r * (size_t)p->nx + (size_t)i;
#define CUDA_OWNED(t, di, dj)                                                                          \
    F[t] = cs_v3(0.0f, 0.0f, 0.0f);                                                                    \
    len[t] = 0.0f;                                                                                     \
    l0[t] = CS_TORN;                                                                                   \
    if ((types >> (t) & 1u) && cs_far_end_on_grid(p->nx, p->ny, i, r, (di), (dj))) {                       \
        l0[t] = dload(&b.L0[(size_t)(t) * (size_t)p->n + v]);                                          \
        F[t] = cs_spring_force(xi, vi, ring_x(sm, r + (dj), k + (di)), ring_v(sm, r + (dj), k + (di)), l0[t], \
                               p->k[t], p->c_spring, &len[t]);                                         \
    }
    CS_SPRING_TYPES(CUDA_OWNED)
#undef CUDA_OWNED
}

/* Puts the owned forces other vertices gather into shared memory: SX and BX of this row, D1 and
 * D2 for the next row (at parity r & 1). */
__device__ static void share_owned(float *sm, int32_t r, int k, const cs_vec3 *F)
{
    const int par = r & 1;
    const float sx[3] = {F[CS_SX].x, F[CS_SX].y, F[CS_SX].z}, bx[3] = {F[CS_BX].x, F[CS_BX].y, F[CS_BX].z};
    const float d1[3] = {F[CS_D1].x, F[CS_D1].y, F[CS_D1].z}, d2[3] = {F[CS_D2].x, F[CS_D2].y, F[CS_D2].z};
    for (int c = 0; c < 3; c++) {
        FROW(sm, 0, c, k) = sx[c];
        FROW(sm, 1, c, k) = bx[c];
        FPREV(sm, par, 0, c, k) = d1[c];
        FPREV(sm, par, 1, c, k) = d2[c];
    }
}

__device__ static inline cs_vec3 frow_at(const float *sm, int which, int k)
{
    return cs_v3(FROW(sm, which, 0, k), FROW(sm, which, 1, k), FROW(sm, which, 2, k));
}
__device__ static inline cs_vec3 fprev_at(const float *sm, int par, int which, int k)
{
    return cs_v3(FPREV(sm, par, which, 0, k), FPREV(sm, par, which, 1, k), FPREV(sm, par, which, 2, k));
}

/* Sums each of q[0..5] over the block with cs_tree_sum's tree: buf[t] += buf[t + s] for
 * s = TILE_W/2 .. 1, in shared memory down to s = 32, then by shuffles in the first warp (lane t
 * adds lane t + s exactly as the tree does; the other lanes' sums are never used). Every thread
 * calls it; the sums are valid in thread 0. */
__device__ static void tree_sum6(const float *q, float *buf, float *out)
{
    const int t = (int)threadIdx.x;
    for (int c = 0; c < 6; c++) buf[c * TILE_W + t] = q[c];
    __syncthreads();
    for (int s = TILE_W / 2; s >= 32; s >>= 1) {
        if (t < s)
            for (int c = 0; c < 6; c++) buf[c * TILE_W + t] += buf[c * TILE_W + t + s];
        __syncthreads();
    }
    if (t < 32) {
        float v[6];
        for (int c = 0; c < 6; c++) v[c] = buf[c * TILE_W + t];
        for (int s = 16; s > 0; s >>= 1)
            for (int c = 0; c < 6; c += 2) { /* two floats a shuffle */
                const unsigned long long w = __shfl_down_sync(
                    FULL, (unsigned long long)__float_as_uint(v[c]) | (unsigned long long)__float_as_uint(v[c + 1]) << 32,
                    (unsigned)s);
                v[c] += __uint_as_float((unsigned)w);
                v[c + 1] += __uint_as_float((unsigned)(w >> 32));
            }
        for (int c = 0; c < 6; c++) out[c] = v[c];
    }
}

/* Whether a sphere may touch a box (never a false no: the exact test is per vertex). */
__device__ static inline int sphere_may_touch(cs_vec3 c, float r, cs_vec3 lo, cs_vec3 hi)
{
    const float dx = c.x < lo.x ? lo.x - c.x : (c.x > hi.x ? c.x - hi.x : 0.0f);
    const float dy = c.y < lo.y ? lo.y - c.y : (c.y > hi.y ? c.y - hi.y : 0.0f);
    const float dz = c.z < lo.z ? lo.z - c.z : (c.z > hi.z ? c.z - hi.z : 0.0f);
    const float reach = r * 1.001f + 1e-6f;
    return dx * dx + dy * dy + dz * dz <= reach * reach;
}

/* The rocks that may touch the tile (rows j0 .. j1-1, this block's columns), in index order, into
 * shared memory; returns how many. */
__device__ static int cull_rocks(const cuda_scene *sc, const cuda_bufs &b, float *sm, int32_t j0, int32_t j1,
                                 int32_t i)
{
    const cs_phys *p = &sc->p;
    const int t = (int)threadIdx.x, lane = t & 31, warp = t >> 5;
    static_assert(WARPS >= 6, "six warps reduce the box");
    const float big = 3.0e38f;
    float lo[3] = {big, big, big}, hi[3] = {-big, -big, -big};
    /* Surface contact: a vertex's features reach one row and one column past it, so the box holds
     * the rows above and below the tile and the columns beside the chunk too. */
    const bool surface = p->contact_model == CS_CONTACT_SURFACE;
    const int32_t r0 = surface && j0 > 0 ? j0 - 1 : j0, r1 = surface && j1 < p->ny ? j1 + 1 : j1;
    for (int side = 0; side < (surface ? 2 : 1); side++) {
        /* side 1: threads 0 and 1 take columns c0 - 1 and c0 + TILE_W */
        const int32_t ic = side == 0 ? i : t == 0 ? i - 1 : t == 1 ? i - 1 + TILE_W : -1;
        if (ic < 0 || ic >= p->nx) continue;
        for (int32_t r = r0; r < r1; r++) {
            const size_t v = (size_t)r * (size_t)p->nx + (size_t)ic;
            for (int c = 0; c < 3; c++) {
                const float x = dload(&b.in[(size_t)c * (size_t)p->n + v]);
                lo[c] = x < lo[c] ? x : lo[c];
                hi[c] = x > hi[c] ? x : hi[c];
            }
        }
    }
    /* The box over the block: each of six warps reduces one bound (min and max are exact, so the
     * order does not matter). The force rows are free until the row loop. */
    float *box = sm + SM_FROW;
    for (int c = 0; c < 3; c++) {
        box[c * TILE_W + t] = lo[c];
        box[(3 + c) * TILE_W + t] = hi[c];
    }
    __syncthreads();
    if (warp < 6) {
        const bool mx = warp >= 3;
        float e = box[warp * TILE_W + lane];
        for (int k = lane + 32; k < TILE_W; k += 32) {
            const float x = box[warp * TILE_W + k];
            e = mx ? (x > e ? x : e) : (x < e ? x : e);
        }
        for (int s = 16; s > 0; s >>= 1) {
            const float x = __shfl_xor_sync(FULL, e, s);
            e = mx ? (x > e ? x : e) : (x < e ? x : e);
        }
        if (lane == 0) sm[SM_RED + warp] = e;
    }
    __syncthreads();
    const cs_vec3 blo = cs_v3(sm[SM_RED], sm[SM_RED + 1], sm[SM_RED + 2]);
    const cs_vec3 bhi = cs_v3(sm[SM_RED + 3], sm[SM_RED + 4], sm[SM_RED + 5]);
    int *count = reinterpret_cast<int *>(sm + SM_COUNT), *cand = reinterpret_cast<int *>(sm + SM_CAND);
    int total = 0;
    for (int32_t base = 0; base < sc->nr; base += TILE_W) {
        const int32_t k = base + t;
        int near = 0;
        if (k < sc->nr) {
            const cs_vec3 x = dload(&b.rocks[k].x);
            near = sphere_may_touch(x, dload(&b.rocks[k].radius) + p->contact_offset, blo, bhi);
        }
        const unsigned ballot = __ballot_sync(FULL, near);
        if (lane == 0) count[warp] = __popc(ballot);
        __syncthreads();
        int before = total;
        for (int w = 0; w < warp; w++) before += count[w];
        if (near) cand[before + __popc(ballot & ((1u << lane) - 1u))] = k;
        for (int w = 0; w < WARPS; w++) total += count[w];
        __syncthreads(); /* count is rewritten next round; cand is read after the last */
    }
    return total;
}

/* Chunk group g's share of each rock's force: for every rock a chunk of the group touched, its
 * partials in chunk order (cs_rock_group_sum's order; the chunks that did not touch are +0), into
 * gsum. A warp per rock: lanes load 32 chunks' partials at a time, every lane adds them in order.
 * Run by the last block of the cloth kernel to finish its part of the group, so the groups are
 * summed in parallel, as they end. */
__device__ static void group_sums(const cuda_scene *sc, const cuda_bufs &b, int32_t g)
{
    const cs_phys *p = &sc->p;
    const int lane = (int)(threadIdx.x & 31u), warp = (int)(threadIdx.x >> 5);
    const int32_t gc = g * CS_CHUNK_GROUP;
    for (int32_t r = warp; r < sc->nr; r += WARPS) {
        const size_t rg = (size_t)r * (size_t)sc->ngroups + (size_t)g;
        unsigned long long left = dload_cg(&b.hits[rg]); /* written by other blocks' atomics */
        if (!left) continue;                             /* warp-uniform */
        cs_vec3 f = cs_v3(0.0f, 0.0f, 0.0f), tq = f;
        while (left) {
            const int cnt = __popcll(left) < 32 ? __popcll(left) : 32;
            unsigned long long mine = left;
            for (int k = 0; k < lane && mine; k++) mine &= mine - 1ull;
            float q[6] = {0, 0, 0, 0, 0, 0};
            if (lane < cnt) {
                const int32_t c = gc + __ffsll((long long)mine) - 1;
                const float *src = b.partials + ((size_t)r * (size_t)p->nchunks + (size_t)c) * 6;
                for (int k = 0; k < 6; k++) q[k] = dload_cg(&src[k]);
            }
            for (int m = 0; m < cnt; m++) {
                f = cs_add(f, cs_v3(__shfl_sync(FULL, q[0], m), __shfl_sync(FULL, q[1], m), __shfl_sync(FULL, q[2], m)));
                tq = cs_add(tq, cs_v3(__shfl_sync(FULL, q[3], m), __shfl_sync(FULL, q[4], m), __shfl_sync(FULL, q[5], m)));
            }
            for (int m = 0; m < cnt; m++) left &= left - 1ull;
        }
        if (lane == 0) {
            const float o[6] = {f.x, f.y, f.z, tq.x, tq.y, tq.z};
            for (int k = 0; k < 6; k++) dstore(&b.gsum[rg * 6 + (size_t)k], o[k]);
        }
    }
}

/* After a block's rows: it counts its chunks into each chunk group they belong to; the block that
 * completes a group sums it (the pattern of cuda-samples' threadFenceReduction). */
__device__ static void finish_groups(const cuda_scene *sc, const cuda_bufs &b, float *sm, int32_t j0, int32_t j1,
                                     int32_t seg)
{
    const cs_phys *p = &sc->p;
    int *last = reinterpret_cast<int *>(sm + SM_COUNT);
    const int32_t g0 = (j0 * p->nseg + seg) / CS_CHUNK_GROUP, g1 = ((j1 - 1) * p->nseg + seg) / CS_CHUNK_GROUP;
    __threadfence(); /* this block's partials and hit words, before it counts itself */
    __syncthreads();
    if (threadIdx.x == 0)
        for (int32_t g = g0; g < g0 + 4; g++) {
            last[g - g0] = -1;
            if (g > g1) continue;
            int mine = 0;
            for (int32_t r = j0; r < j1; r++) mine += (r * p->nseg + seg) / CS_CHUNK_GROUP == g;
            const int size = p->nchunks - g * CS_CHUNK_GROUP < CS_CHUNK_GROUP ? p->nchunks - g * CS_CHUNK_GROUP : CS_CHUNK_GROUP;
            if (atomicAdd(&b.group_done[g], mine) + mine == size) last[g - g0] = g;
        }
    __syncthreads();
    for (int k = 0; k < 4; k++) {
        const int32_t g = last[k]; /* block-uniform */
        if (g < 0) continue;
        __threadfence();
        group_sums(sc, b, g);
        if (threadIdx.x == 0) b.group_done[g] = 0; /* every block of this launch has counted */
    }
}

/* The types of spring a vertex of row r evaluates: all in the tile's rows; above them only what
 * rows j0, j0+1 gather: BY of row j0-2; SY, D1, D2, BY of j0-1. */
__device__ static inline unsigned row_types(int32_t r, int32_t j0)
{
    return r >= j0 ? 0x3fu : r == j0 - 1 ? (1u << CS_SY) | (1u << CS_D1) | (1u << CS_D2) | (1u << CS_BY) : (1u << CS_BY);
}

/* The two rows above the tile into the ring; the tile's first row in flight in registers, so its
 * loads overlap a row's work (each row of the walk stores row r+2 and fetches row r+3). */
__device__ __forceinline__ static void ring_start(const cuda_bufs &b, const cs_phys *p, float *sm, int32_t j0, int32_t c0,
                                                  row_regs *next)
{
    for (int32_t r = j0 - 2; r < j0; r++) {
        fetch_row(b, p, r, c0, next);
        put_row(p, sm, r, c0, next);
    }
    fetch_row(b, p, j0, c0, next);
}

/* What a thread holds of its vertex in a row: the springs it owns (forces, lengths, rest lengths),
 * its position and velocity, and for surface contact its 1-ring (cs_ring, from rows r-1 .. r+1). */
struct vertex_row {
    cs_vec3 F[CS_NTYPES];
    float len[CS_NTYPES], l0[CS_NTYPES];
    cs_vec3 xi, vi;
    cs_ring g;
};

/* Vertex (i, r)'s owned springs of the types asked, shared for the gathers (zero where the vertex
 * is past the grid); with `ring` its 1-ring too, read now: the next row's load overwrites row r-1
 * after the barrier that follows. */
__device__ __forceinline__ static void own_springs(const cuda_bufs &b, const cs_phys *p, float *sm, int32_t i, int32_t r,
                                                   int32_t c0, unsigned types, bool live, bool ring, vertex_row *w)
{
    const int t = (int)threadIdx.x;
    const int32_t nx = p->nx;
    if (live) {
        eval_owned(b, p, sm, i, r, c0, types, w->F, w->len, w->l0);
        w->xi = ring_x(sm, r, t + RING_OFF);
        w->vi = ring_v(sm, r, t + RING_OFF);
        if (ring) {
            for (int q = 0; q < CS_RING; q++) {
                const int32_t ii = i + cs_ring_di(q), jj = r + cs_ring_dj(q);
                const bool in = ii >= 0 && ii < nx && jj >= 0 && jj < p->ny;
                w->g.x[q] = in ? ring_x(sm, jj, t + RING_OFF + cs_ring_di(q)) : w->xi;
            }
            w->g.faces = cs_ring_faces(b.L0, nx, p->ny, i, r);
        }
    } else {
        for (int q = 0; q < CS_NTYPES; q++) w->F[q] = cs_v3(0.0f, 0.0f, 0.0f);
    }
    share_owned(sm, r, t + FORCE_OFF, w->F);
}

/* The three columns beside the chunk, c0-2, c0-1 (left) and c0+256 (right): threads 0..2 evaluate
 * their owned springs of row r again and share them (their owners write them). */
__device__ __forceinline__ static void beside_springs(const cuda_bufs &b, const cs_phys *p, float *sm, int32_t r,
                                                      int32_t c0, unsigned types)
{
    const int t = (int)threadIdx.x;
    if (t >= 3) return;
    const int32_t ih = t < 2 ? c0 - 2 + t : c0 + TILE_W;
    cs_vec3 Fh[CS_NTYPES];
    float lh[CS_NTYPES], l0h[CS_NTYPES];
    if (ih >= 0 && ih < p->nx) eval_owned(b, p, sm, ih, r, c0, types, Fh, lh, l0h);
    else
        for (int q = 0; q < CS_NTYPES; q++) Fh[q] = cs_v3(0.0f, 0.0f, 0.0f);
    share_owned(sm, r, ih - c0 + FORCE_OFF, Fh);
}

/* The strain update of vertex v's owned springs (cs_strain_update), written into the other
 * rest-length buffer where they change now or changed in the last update; returns how many tore. */
__device__ __forceinline__ static int strain_vertex(const cuda_bufs &b, const cs_phys *p, size_t v, const float *len,
                                                    const float *l0)
{
    const size_t n = (size_t)p->n;
    float nl[CS_NTYPES];
    int changed = 0, torn = 0;
    for (int q = 0; q < CS_NTYPES; q++) {
        nl[q] = l0[q] > 0.0f ? cs_strain_update(len[q], l0[q], p) : l0[q];
        torn += l0[q] > 0.0f && nl[q] <= 0.0f;
        changed |= nl[q] != l0[q];
    }
    const unsigned char before = dload(&b.chg[v]);
    if (changed || before)
        for (int q = 0; q < CS_NTYPES; q++) dstore(&b.L0n[(size_t)q * n + v], nl[q]);
    if ((unsigned char)changed != before) dstore(&b.chg[v], (unsigned char)changed);
    return torn;
}

/* A live vertex's spring force in row r: its 12 springs in CS_SPRING_SLOTS order - its own from F,
 * a neighbour's negated: SX, BX of this row from the force rows, D1, D2 of the row above from the
 * previous rows, SY of the row above and BY of the row two above from registers - then air and
 * gravity. */
__device__ __forceinline__ static cs_vec3 gather_springs(const cs_phys *p, const float *sm, int32_t r, int kf,
                                                         const cs_vec3 *F, cs_vec3 sy_prev, cs_vec3 by2, cs_vec3 vi)
{
    const int par = (r - 1) & 1;
    cs_vec3 f = cs_v3(0.0f, 0.0f, 0.0f);
#define CUDA_BACK(t, di, dj)                                                                           \
    ((dj) == 0 ? frow_at(sm, (t) == CS_SX ? 0 : 1, kf + (di))                                          \
               : (dj) == -2 ? by2 : (t) == CS_SY ? sy_prev : fprev_at(sm, par, (t) == CS_D1 ? 0 : 1, kf + (di)))
#define CUDA_GATHER(t, di, dj, fwd) f = cs_add(f, (fwd) ? F[t] : cs_neg(CUDA_BACK(t, di, dj)));
    CS_SPRING_SLOTS(CUDA_GATHER)
#undef CUDA_GATHER
#undef CUDA_BACK
    return cs_add(f, cs_air_gravity(vi, p));
}

/* A row chunk's reaction on rock rk - each vertex's force R and torque T on it, zero where it has
 * none - summed by the tree into the chunk's partial, and the chunk's bit set in the rock's word
 * for its chunk group. Every thread calls it. */
__device__ __forceinline__ static void chunk_reaction(const cuda_scene *sc, const cuda_bufs &b, float *sm, int32_t rk,
                                                      int32_t chunk, cs_vec3 R, cs_vec3 T)
{
    const cs_phys *p = &sc->p;
    const float q[6] = {R.x, R.y, R.z, T.x, T.y, T.z};
    float s6[6];
    tree_sum6(q, sm + SM_FROW, s6);
    if (threadIdx.x == 0) {
        float *out = b.partials + ((size_t)rk * (size_t)p->nchunks + (size_t)chunk) * 6;
        for (int k = 0; k < 6; k++) dstore(&out[k], s6[k]);
        atomicOr(&b.hits[(size_t)rk * (size_t)sc->ngroups + (size_t)(chunk / CS_CHUNK_GROUP)],
                 1ull << (chunk % CS_CHUNK_GROUP));
    }
}

/* Surface contact: rock by rock in index order (as the CPU backend adds them), each vertex
 * gathers its share from its ring (cs_surface_gather, with the force so far, f); the reactions the
 * row's vertices own go through the chunk tree. Returns f with the shares added. */
__device__ __forceinline__ static cs_vec3 surface_contacts(const cuda_scene *sc, const cuda_bufs &b, float *sm,
                                                           int32_t i, int32_t r, int32_t chunk, bool live, int ncand,
                                                           cs_ring *g, cs_vec3 vi, cs_vec3 ro, cs_vec3 f)
{
    const cs_phys *p = &sc->p;
    const int *cand = reinterpret_cast<const int *>(sm + SM_CAND);
    const float w = live ? (float)dload(&b.mask[(size_t)r * (size_t)p->nx + (size_t)i]) : 0.0f;
    g->v = vi;
    g->ro = p->friction == CS_FRICTION_RESULTANT ? ro : cs_v3(0.0f, 0.0f, 0.0f);
    for (int c = 0; c < ncand; c++) {
        const int32_t rk = cand[c];
        cs_surface_out o;
        int owns = 0;
        if (live) {
            cs_surface_gather(g, &b.rocks[rk], p, f, w, &o);
            if (o.touches) f = cs_add(f, o.share);
            owns = o.owns != 0;
        }
        if (!__syncthreads_or(owns)) continue; /* block-uniform */
        const cs_vec3 zero = cs_v3(0.0f, 0.0f, 0.0f);
        chunk_reaction(sc, b, sm, rk, chunk, owns ? o.force : zero, owns ? o.torque : zero);
    }
    return f;
}

/* Vertex contact with the ncand candidate rocks: each vertex adds their forces in rock order and
 * marks the ones it touches; then, for each rock the row touched, the chunk's reactions go through
 * the tree. Returns f with the forces added. */
__device__ __forceinline__ static cs_vec3 vertex_contacts(const cuda_scene *sc, const cuda_bufs &b, float *sm,
                                                          int32_t chunk, bool live, int ncand, cs_vec3 xi, cs_vec3 vi,
                                                          cs_vec3 ro, cs_vec3 f)
{
    const cs_phys *p = &sc->p;
    const int *cand = reinterpret_cast<const int *>(sm + SM_CAND);
    unsigned *touched = reinterpret_cast<unsigned *>(sm + SM_TOUCHED);
    for (int c32 = 0; c32 < ncand; c32 += 32) {
        unsigned mine = 0;
        for (int k = 0; k < 32 && c32 + k < ncand; k++) {
            cs_vec3 Fc, arm;
            if (live && cs_vertex_rock_contact(xi, vi, ro, &b.rocks[cand[c32 + k]], p, &Fc, &arm)) {
                f = cs_add(f, Fc);
                mine |= 1u << k;
            }
        }
        if (mine) atomicOr(&touched[c32 / 32], mine);
    }
    if (ncand) __syncthreads(); /* every vertex has marked what it touches */
    for (int c32 = 0; c32 < ncand; c32 += 32)
        for (unsigned hits = touched[c32 / 32]; hits; hits &= hits - 1u) {
            const int32_t rk = cand[c32 + __ffs((int)hits) - 1];
            cs_vec3 Fc = cs_v3(0.0f, 0.0f, 0.0f), arm = Fc;
            const int hit = live && cs_vertex_rock_contact(xi, vi, ro, &b.rocks[rk], p, &Fc, &arm);
            const cs_vec3 R = hit ? cs_neg(Fc) : cs_v3(0.0f, 0.0f, 0.0f);
            const cs_vec3 T = hit ? cs_cross(arm, R) : cs_v3(0.0f, 0.0f, 0.0f);
            chunk_reaction(sc, b, sm, rk, chunk, R, T);
        }
    return f;
}

/* Vertex (i, r)'s ground contact, acceleration and MODE's update: a stored where MODE says (a
 * graph's last substep, or MODE_ACCEL alone), the next state written. Returns 1 where a last
 * substep wrote a state that is not finite. */
template <int MODE>
__device__ __forceinline__ static int update_vertex(const cuda_scene *sc, const cuda_bufs &b, int32_t i, int32_t r,
                                                    cs_vec3 xi, cs_vec3 vi, cs_vec3 ro, cs_vec3 f)
{
    const cs_phys *p = &sc->p;
    cs_vec3 Fg;
    if (cs_vertex_ground_contact(xi, vi, ro, p, &Fg)) f = cs_add(f, Fg);
    const size_t v = (size_t)r * (size_t)p->nx + (size_t)i, n = (size_t)p->n;
    const float w = (float)dload(&b.mask[v]);
    const cs_vec3 a = cs_scale(f, p->inv_mass * w);
    if (MODE == MODE_ACCEL || MODE == MODE_VERLET_LAST || MODE == MODE_EULER_LAST) {
        dstore(&b.acc[v], a.x);
        dstore(&b.acc[n + v], a.y);
        dstore(&b.acc[2 * n + v], a.z);
    }
    if (MODE == MODE_ACCEL) return 0;
    const bool euler = MODE == MODE_EULER || MODE == MODE_EULER_LAST;
    const float h = euler ? p->dt : p->hdt;
    cs_vec3 vv = vi, xx = xi;
    if (MODE == MODE_VERLET_LAST) {
        vv = cs_add(vv, cs_scale(a, h)); /* the last substep's kick */
    } else {
        if ((int32_t)v == sc->grab) vv = cs_grab_velocity(xi, sc->grab_target, p);
        vv = cs_add(vv, cs_scale(a, h)); /* Verlet: finish; Euler: the update */
        if (MODE == MODE_VERLET) vv = cs_add(vv, cs_scale(a, h)); /* the next half kick */
        xx = cs_add(xi, cs_scale(vv, p->dt));
    }
    const float o[6] = {xx.x, xx.y, xx.z, vv.x, vv.y, vv.z};
    for (int q = 0; q < 6; q++) dstore(&b.out[(size_t)q * n + v], o[q]);
    return (MODE == MODE_VERLET_LAST || MODE == MODE_EULER_LAST) && (!finite3(xx) || !finite3(vv));
}

/* One block of the cloth kernel (see the top of the file): chunk column seg of rows tile_rows
 * tile .. on, TILE_W threads. k_cloth runs it for one scene, k_cloth_batch for the block's scene of
 * a batch. What a vertex ends with does not depend on the tiling: every sum is in a fixed order
 * (its springs, the rocks, a row chunk's tree, the chunks of a group, the groups). */
template <int MODE, bool STRAIN, bool ROCKS>
__device__ static void cloth_block(const cuda_scene *__restrict__ sc, const cuda_bufs &b, int32_t seg, int32_t tile,
                                   int32_t tile_rows)
{
    CS_DYNAMIC_SHARED(float, sm);
    const cs_phys *p = &sc->p;
    const int t = (int)threadIdx.x;
    const int32_t nx = p->nx, c0 = seg * TILE_W, i = c0 + t;
    const int32_t j0 = tile * tile_rows;
    const int32_t j1 = j0 + tile_rows < p->ny ? j0 + tile_rows : p->ny;
    const bool live = i < nx;
    const bool surface = ROCKS && p->contact_model == CS_CONTACT_SURFACE;
    /* Rows above row 0 have no springs: their forces read as zeros. */
    for (int k = t; k < 2 * 2 * 3 * FORCE_W; k += TILE_W) sm[SM_FPREV + k] = 0.0f;
    const int ncand = ROCKS ? cull_rocks(sc, b, sm, j0, j1, i) : 0;
    row_regs next;
    ring_start(b, p, sm, j0, c0, &next);
    cs_vec3 sy_prev = cs_v3(0.0f, 0.0f, 0.0f), by1 = sy_prev, by2 = sy_prev; /* SY of row r-1; BY of r-1, r-2 */
    int torn = 0, bad = 0;
    for (int32_t r = j0 - 2; r < j1; r++) {
        put_row(p, sm, r + 2, c0, &next);
        if (r + 3 < j1 + 2) fetch_row(b, p, r + 3, c0, &next);
        __syncthreads(); /* rows r .. r+2 are in the ring */
        const bool own = r >= 0 && r >= j0; /* (j0 >= 0: said so the compiler sees w.F is set) */
        vertex_row w;
        w.xi = cs_v3(0.0f, 0.0f, 0.0f), w.vi = w.xi;
        if (r >= 0) {
            own_springs(b, p, sm, i, r, c0, row_types(r, j0), live, surface && own, &w);
            beside_springs(b, p, sm, r, c0, row_types(r, j0));
            if (ROCKS && own && t < (ncand + 31) / 32) reinterpret_cast<unsigned *>(sm + SM_TOUCHED)[t] = 0u;
            if (STRAIN && own && live) torn += strain_vertex(b, p, (size_t)r * (size_t)nx + (size_t)i, w.len, w.l0);
        }
        __syncthreads(); /* the owned forces are shared */
        if (own) {
            cs_vec3 f = live ? gather_springs(p, sm, r, t + FORCE_OFF, w.F, sy_prev, by2, w.vi) : cs_v3(0.0f, 0.0f, 0.0f);
            const cs_vec3 ro = f;
            const int32_t chunk = r * p->nseg + seg;
            if (surface) f = surface_contacts(sc, b, sm, i, r, chunk, live, ncand, &w.g, w.vi, ro, f);
            f = vertex_contacts(sc, b, sm, chunk, live, surface ? 0 : ncand, w.xi, w.vi, ro, f);
            if (live) bad |= update_vertex<MODE>(sc, b, i, r, w.xi, w.vi, ro, f);
        }
        /* Registers for the rows below: SY of this row, BY of this row and the one above. */
        if (r >= 0) {
            sy_prev = w.F[CS_SY];
            by2 = by1;
            by1 = w.F[CS_BY];
        }
    }
    if (ROCKS) finish_groups(sc, b, sm, j0, j1, seg);
    if (torn) atomicAdd(&b.flags[FLAG_TORN], torn);
    if (bad) atomicOr(&b.flags[FLAG_NONFINITE], 1);
}

/* The cloth kernel of one scene. Grid: (chunks per row, tiles). */
template <int MODE, bool STRAIN, bool ROCKS>
__global__ void __launch_bounds__(TILE_W) k_cloth(const cuda_scene *__restrict__ sc, cuda_bufs b)
{
    cloth_block<MODE, STRAIN, ROCKS>(sc, b, (int32_t)blockIdx.x, (int32_t)blockIdx.y, sc->tile_rows);
}

/* Velocity Verlet's first substep of a graph: grab, kick, drift of every vertex (no kick to
 * finish: a is complete) in place, and of every rock (block 0). Block blk of 256 threads. */
__device__ static void drift_first_block(const cuda_scene *__restrict__ sc, const cuda_bufs &b, uint32_t blk)
{
    const cs_phys *p = &sc->p;
    if (blk == 0)
        for (int32_t r = (int32_t)threadIdx.x; r < sc->nr; r += (int32_t)blockDim.x) {
            cs_rock_state k = dload(&b.rocks[r]);
            cs_rock_kick(&k, p->hdt);
            cs_rock_drift(&k, p->dt);
            dstore(&b.rocks[r], k);
        }
    const size_t v = (size_t)blk * blockDim.x + threadIdx.x, n = (size_t)p->n;
    if (v >= n) return;
    float *s = b.out; /* in place: in == out */
    const cs_vec3 xi = cs_v3(dload(&s[v]), dload(&s[n + v]), dload(&s[2 * n + v]));
    const cs_vec3 a = cs_v3(dload(&b.acc[v]), dload(&b.acc[n + v]), dload(&b.acc[2 * n + v]));
    cs_vec3 vv = (int32_t)v == sc->grab ? cs_grab_velocity(xi, sc->grab_target, p)
                                        : cs_v3(dload(&s[3 * n + v]), dload(&s[4 * n + v]), dload(&s[5 * n + v]));
    vv = cs_add(vv, cs_scale(a, p->hdt));
    const cs_vec3 xx = cs_add(xi, cs_scale(vv, p->dt));
    const float o[6] = {xx.x, xx.y, xx.z, vv.x, vv.y, vv.z};
    for (int q = 0; q < 6; q++) dstore(&s[(size_t)q * n + v], o[q]);
}

__global__ void k_drift_first(const cuda_scene *__restrict__ sc, cuda_bufs b) { drift_first_block(sc, b, blockIdx.x); }

/* Symplectic Euler's strain pass on the new positions (b.in), rest lengths as in k_cloth. Block
 * blk of 256 threads. */
__device__ static void strain_block(const cuda_scene *__restrict__ sc, const cuda_bufs &b, uint32_t blk)
{
    const cs_phys *p = &sc->p;
    const int32_t v = (int32_t)(blk * blockDim.x + threadIdx.x);
    if (v >= p->n) return;
    const int32_t nx = p->nx, ny = p->ny, i = v % nx, j = v / nx;
    const size_t n = (size_t)p->n;
    const cs_vec3 xi = cs_v3(dload(&b.in[v]), dload(&b.in[n + v]), dload(&b.in[2 * n + v]));
    float nl[CS_NTYPES], l0[CS_NTYPES];
    int torn = 0, changed = 0;
#define CUDA_STRAIN(t, di, dj)                                                                         \
    l0[t] = dload(&b.L0[(size_t)(t) * n + v]);                                                         \
    nl[t] = l0[t];                                                                                     \
    if (l0[t] > 0.0f && cs_far_end_on_grid(nx, ny, i, j, (di), (dj))) {                                    \
        const size_t o = (size_t)(v + (di) + (dj) * nx);                                               \
        const cs_vec3 xo = cs_v3(dload(&b.in[o]), dload(&b.in[n + o]), dload(&b.in[2 * n + o]));       \
        nl[t] = cs_strain_update(cs_len(cs_sub(xo, xi)), l0[t], p);                                    \
        torn += nl[t] <= 0.0f;                                                                         \
        changed |= nl[t] != l0[t];                                                                     \
    }
    CS_SPRING_TYPES(CUDA_STRAIN)
#undef CUDA_STRAIN
    const unsigned char before = dload(&b.chg[v]);
    if (changed || before)
        for (int q = 0; q < CS_NTYPES; q++) dstore(&b.L0n[(size_t)q * n + v], nl[q]);
    if ((unsigned char)changed != before) dstore(&b.chg[v], (unsigned char)changed);
    if (torn) atomicAdd(&b.flags[FLAG_TORN], torn);
}

__global__ void k_strain(const cuda_scene *__restrict__ sc, cuda_bufs b) { strain_block(sc, b, blockIdx.x); }

#endif /* CLOTHSIM_CUDA_CLOTH_KERNEL_IMPL_CUH */
