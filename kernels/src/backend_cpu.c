/* backend_cpu.c - the CPU backend: the physics.h functions looped over the host arrays with
 * OpenMP, in the sequence that backend.h prescribes.
 *
 * The force pass runs over whole rows, each thread a contiguous block of them. For row j it
 * first evaluates the six springs every vertex of the row owns (cs_spring_force, once per
 * spring) into a ring of three rows; a vertex's force is then gathered from the ring in
 * CS_SPRING_SLOTS order, the springs it does not own entering negated - exactly what evaluating
 * them from this end gives, so the result equals a gather that evaluates every spring from both
 * ends (as the CUDA kernels do) at half the cost. Springs missing at a border are evaluated
 * against the vertex itself (zero length, zero force), which keeps one vectorized loop for every
 * column. Contacts follow per chunk, then the accelerations.
 *
 * Nothing a thread computes depends on which thread it is or how many there are: rock forces
 * from the cloth go through per-chunk trees summed in chunk order, and torn-spring counts are
 * integers. So the state is the same bit for bit for any thread count.
 *
 * A batch (step_batch) is shared among the threads by work, vertices x substeps: a scene larger
 * than a thread's fair share is stepped by all of them together, as step() does; the rest each
 * whole by one thread (the same code with its work-sharing constructs run plainly: no barrier that
 * waits on another thread), largest first as threads come free. */
#include <pthread.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#ifdef _OPENMP
#include <omp.h>
#endif

#include "cpu_internal.h"

#if defined(__GNUC__)
#define CS_ALWAYS_INLINE __attribute__((always_inline)) inline
#else
#define CS_ALWAYS_INLINE inline
#endif
/* A loop whose iterations store nothing another reads or overwrites (gcc would otherwise check
 * at run time that rows of a runtime stride do not overlap, and gives up past ten checks). */
#if defined(__GNUC__) && !defined(__clang__)
#define CS_IVDEP _Pragma("GCC ivdep")
#else
#define CS_IVDEP
#endif

#define RING_PAD 2                /* columns -2 .. nx + 1 of a ring row: the bending springs' reach */
#define RING_ROWS (3 * CS_NTYPES) /* x, y, z of each owned spring type */
#define CS_MAX_SEG ((4096 + CS_CHUNK - 1) / CS_CHUNK) /* chunks in the widest row */

/* The stride (floats) of the rows of a thread buffer for a cloth nx wide: columns -RING_PAD ..
 * nx + RING_PAD - 1, in whole 64-byte lines, an odd number of them (so the 18 rows a loop writes
 * fall in different cache sets). */
static int32_t row_stride(int32_t nx) { return 16 * (((nx + 2 * RING_PAD + 15) / 16) | 1); }

typedef struct thread_buf {
    /* Rows of w floats (row_stride) after the struct, laid out for the cloth of the call: */
    float *ring[3]; /* owned-spring forces of rows j, j-1, j-2 (slot j mod 3); component row
                       q = 3 t + c at q w, column i at RING_PAD + i */
    float *f[3];    /* resultant on the vertices of the current row */
    float *ro[3];   /* non-contact resultant Ro (resultant friction) */
    int32_t w;
    size_t bytes;   /* allocated, with the rows */
    float contrib[6][CS_CHUNK];       /* one rock's reaction from the touching vertices of a chunk */
    float col[6][CS_CHUNK + 4];       /* surface contact: the rows j-1 .. j+1 of each column (min
                                         x y z, max x y z; column_bounds) */
    float rbox[6][CS_CHUNK];          /* and the box of the 3 x 3 vertices round each vertex */
    float rows[9][CS_CHUNK + 4];      /* and rows j-1 .. j+1 themselves (near_ring) */
    float rowbox[3][CS_MAX_SEG][6];   /* row_box: the last rows' boxes per chunk column */
    int32_t rowbox_row[3][CS_MAX_SEG]; /* and which row each is (-1: none this pass) */
    uint8_t hit[CS_CHUNK];            /* vertices of a chunk near a rock */
    float rk[4][CS_MAX_ROCKS];        /* the rocks' centres and reach (x, y, z, R + offset), this pass */
    uint8_t cand[CS_CHUNK];           /* surface contact: the vertices of a chunk to gather for a rock */
    uint8_t rhit[CS_MAX_ROCKS];       /* rocks that may reach a chunk */
    uint8_t idx[CS_CHUNK];            /* vertices of a chunk touching a rock */
    int32_t last_row;
    struct thread_buf *next;          /* the pool's free list */
} thread_buf;

typedef struct cpu_ctx {
    float *partials;      /* nchunks x rocks x 6: each chunk's force and torque on each rock */
    size_t partials_cap;  /* floats */
    int64_t torn;         /* springs torn since the last report (atomic adds from the team) */
    char device[160];
    cs_im_work *im;       /* implicit_euler's workspace (implicit_cpu.c), once used */
    cs_sc_work *sc;       /* self_collision's (selfcontact_cpu.c), once used */
} cpu_ctx;

/* The thread buffers, shared by every CPU simulation of the process. Nothing in one outlives the
 * pass that fills it, so a step call takes a buffer for each thread it runs before its parallel
 * region and gives them back after: there are as many as threads have stepped at once, not one
 * per thread per simulation. The last context destroyed frees them. */
static struct {
    pthread_mutex_t lock;
    thread_buf *free; /* buffers no call holds */
    int contexts;     /* CPU contexts alive */
} pool = {PTHREAD_MUTEX_INITIALIZER, NULL, 0};

static int cpu_available(char *why, size_t why_len)
{
    if (why && why_len) why[0] = '\0';
    return 1;
}

static int max_threads(void)
{
#ifdef _OPENMP
    return omp_get_max_threads();
#else
    return 1;
#endif
}

static int thread_id(void)
{
#ifdef _OPENMP
    return omp_get_thread_num();
#else
    return 0;
#endif
}

int cs_cpu_threads(void) { return max_threads(); }

static int threads_of(const cs_model *m) { return m->threads > 0 ? m->threads : max_threads(); }

static cs_status cpu_create(void **out, char *err, size_t err_len)
{
    cpu_ctx *c = calloc(1, sizeof *c);
    if (!c) {
        snprintf(err, err_len, "out of memory");
        return CS_E_NOMEM;
    }
    pthread_mutex_lock(&pool.lock);
    pool.contexts++;
    pthread_mutex_unlock(&pool.lock);
    *out = c;
    return CS_OK;
}

static void cpu_destroy(void *ctx)
{
    cpu_ctx *c = ctx;
    if (!c) return;
    pthread_mutex_lock(&pool.lock);
    if (--pool.contexts == 0) /* no call can hold a buffer: every one is free */
        while (pool.free) {
            thread_buf *b = pool.free;
            pool.free = b->next;
            free(b);
        }
    pthread_mutex_unlock(&pool.lock);
    free(c->partials);
    cs_im_free(c->im);
    cs_sc_free(c->sc);
    free(c);
}

/* Gives the t buffers of b[] back to the pool, and frees b. */
static void scratch_give(thread_buf **b, int t)
{
    pthread_mutex_lock(&pool.lock);
    for (int i = 0; i < t; i++) {
        b[i]->next = pool.free;
        pool.free = b[i];
    }
    pthread_mutex_unlock(&pool.lock);
    free(b);
}

/* Buffer b laid out for a cloth nx wide, or in its place (b freed) a new one where b is NULL or
 * too small; NULL when out of memory (b kept). */
static thread_buf *buf_fit(thread_buf *b, int32_t nx)
{
    const int32_t w = row_stride(nx);
    const size_t head = (sizeof *b + 63) / 64 * 64;
    const size_t bytes = head + sizeof(float) * (size_t)w * (3 * RING_ROWS + 6); /* a multiple of 64 */
    if (!b || b->bytes < bytes) {
        thread_buf *n = aligned_alloc(64, bytes);
        if (!n) return NULL;
        free(b);
        b = memset(n, 0, bytes);
        b->bytes = bytes;
    }
    float *rows = (float *)((char *)b + head);
    b->w = w;
    for (int k = 0; k < 3; k++) {
        b->ring[k] = rows + (size_t)k * RING_ROWS * (size_t)w;
        b->f[k] = rows + (size_t)(3 * RING_ROWS + k) * (size_t)w;
        b->ro[k] = rows + (size_t)(3 * RING_ROWS + 3 + k) * (size_t)w;
    }
    return b;
}

/* Buffers for a call's t threads (thread k uses the k-th) stepping a cloth nx wide, from the pool
 * or new; NULL when out of memory. */
static thread_buf **scratch_take(int t, int32_t nx)
{
    thread_buf **b = malloc(sizeof *b * (size_t)t);
    if (!b) return NULL;
    int got = 0;
    pthread_mutex_lock(&pool.lock);
    for (; got < t && pool.free; got++) {
        b[got] = pool.free;
        pool.free = b[got]->next;
    }
    pthread_mutex_unlock(&pool.lock);
    for (int k = 0; k < t; k++) {
        thread_buf *f = buf_fit(k < got ? b[k] : NULL, nx);
        if (!f) {
            scratch_give(b, k > got ? k : got);
            return NULL;
        }
        b[k] = f;
    }
    return b;
}

/* Makes room for this scene's rock partials. */
static cs_status reserve(cpu_ctx *c, const cs_model *m, const cs_state *s)
{
    const size_t need = (size_t)m->phys.nchunks * (size_t)(s->n_rocks > 0 ? s->n_rocks : 1) * 6;
    if (need > c->partials_cap) {
        float *p = realloc(c->partials, need * sizeof(float));
        if (!p) return CS_E_NOMEM;
        c->partials = p;
        c->partials_cap = need;
    }
    return CS_OK;
}

static cs_status cpu_upload(void *ctx, const cs_model *m, cs_state *s)
{
    cpu_ctx *c = ctx;
    cs_sc_forget(c->sc);
    /* the workspaces go with the parameters that use them (cs_scene_memory counts them only then) */
    if (m->phys.integrator != CS_IMPLICIT_EULER) {
        cs_im_free(c->im);
        c->im = NULL;
    }
    if (!m->phys.self_on) {
        cs_sc_free(c->sc);
        c->sc = NULL;
    }
    return reserve(ctx, m, s);
}

static cs_status cpu_download(void *ctx, const cs_model *m, cs_state *s, unsigned what)
{
    (void)ctx, (void)m, (void)s, (void)what;
    return CS_OK;
}

#define LOADX(o) cs_v3(X[(o)], Y[(o)], Z[(o)])
#define LOADV(o) cs_v3(VX[(o)], VY[(o)], VZ[(o)])

/* ---- the force pass ---- */

/* The springs owned by cnt consecutive vertices from v0, each reaching v + off[t] (0 where the
 * grid has no such spring): forces into out (component row 3 t + c, stride w), and with
 * strain the new rest lengths into n0..n5. Returns springs torn. The arrays are restrict
 * parameters, which gcc honours, and out's rows (stride w > cnt) never overlap, so the loop
 * vectorizes. */
static CS_ALWAYS_INLINE int owned_body(const cs_phys *pp, int32_t v0, int32_t cnt, const int32_t *off,
                                      const float *restrict X, const float *restrict Y, const float *restrict Z,
                                      const float *restrict VX, const float *restrict VY, const float *restrict VZ,
                                      const float *restrict L0, float *restrict out, float *restrict n0,
                                      float *restrict n1, float *restrict n2, float *restrict n3,
                                      float *restrict n4, float *restrict n5, const int32_t w, const int strain)
{
    const cs_phys P = *pp; /* a local copy: the stores cannot alias it */
    const cs_phys *p = &P;
    const size_t n = (size_t)p->n;
    int32_t o[CS_NTYPES];
    for (int t = 0; t < CS_NTYPES; t++) o[t] = off[t];
    int torn = 0;
    CS_IVDEP for (int32_t k = 0; k < cnt; k++) {
        const int32_t v = v0 + k;
        const cs_vec3 xi = LOADX(v), vi = LOADV(v);
        float len;
#define NEXT_OF(t) ((t) == 0 ? n0 : (t) == 1 ? n1 : (t) == 2 ? n2 : (t) == 3 ? n3 : (t) == 4 ? n4 : n5)
#define CS_OWNED(t, di, dj)                                                                            \
    {                                                                                                  \
        const int32_t j_ = v + o[t];                                                                   \
        const float l0 = L0[(t) * n + v];                                                              \
        const cs_vec3 F = cs_spring_force(xi, vi, LOADX(j_), LOADV(j_), l0, p->k[t], p->c_spring, &len); \
        out[(3 * (t) + 0) * w + k] = F.x;                                                              \
        out[(3 * (t) + 1) * w + k] = F.y;                                                              \
        out[(3 * (t) + 2) * w + k] = F.z;                                                              \
        if (strain) {                                                                                  \
            const float nl = cs_strain_update(len, l0, p);                                             \
            NEXT_OF(t)[v] = nl;                                                                        \
            torn += (l0 > 0.0f) & (nl <= 0.0f);                                                        \
        }                                                                                              \
    }
        CS_SPRING_TYPES(CS_OWNED)
#undef CS_OWNED
#undef NEXT_OF
    }
    return torn;
}

static int owned_plain(const cs_phys *p, const cs_state *s, int32_t v0, int32_t cnt, const int32_t *off, float *out,
                       int32_t w)
{
    return owned_body(p, v0, cnt, off, s->x, s->y, s->z, s->vx, s->vy, s->vz, s->L0, out, NULL, NULL, NULL, NULL,
                      NULL, NULL, w, 0);
}

static int owned_strain(const cs_phys *p, const cs_state *s, int32_t v0, int32_t cnt, const int32_t *off, float *out,
                        int32_t w)
{
    float *L = s->L0_next;
    const size_t n = (size_t)p->n;
    return owned_body(p, v0, cnt, off, s->x, s->y, s->z, s->vx, s->vy, s->vz, s->L0, out, L, L + n, L + 2 * n,
                      L + 3 * n, L + 4 * n, L + 5 * n, w, 1);
}

/* Offsets of the springs vertex (i, r) owns; 0 where the far end is off the grid. */
static void owned_offsets(const cs_phys *p, int32_t i, int32_t r, int32_t off[CS_NTYPES])
{
    for (int t = 0; t < CS_NTYPES; t++) {
        off[t] = cs_far_end_on_grid(p->nx, p->ny, i, r, cs_type_di[t], cs_type_dj[t]) ? cs_type_di[t] + cs_type_dj[t] * p->nx : 0;
    }
}

/* Forces of the springs owned by row r into a ring row of stride w (zeros for rows above the
 * grid). strain: also their new rest lengths (only for rows this thread owns). */
static int owned_row(const cs_phys *p, const cs_state *s, int32_t r, float *R, int32_t w, int strain)
{
    const int32_t nx = p->nx;
    for (int q = 0; q < RING_ROWS; q++) {
        float *row = R + (size_t)q * (size_t)w;
        if (r < 0) {
            memset(row, 0, sizeof(float) * (size_t)(nx + 2 * RING_PAD));
        } else {
            row[0] = row[1] = row[nx + RING_PAD] = row[nx + RING_PAD + 1] = 0.0f;
        }
    }
    if (r < 0) return 0;
    int (*const run)(const cs_phys *, const cs_state *, int32_t, int32_t, const int32_t *, float *, int32_t) =
        strain ? owned_strain : owned_plain;
    int torn = 0;
    int32_t off[CS_NTYPES];
    /* Columns 1 .. nx-3 have every horizontal neighbour: one run. */
    if (nx > 3) {
        owned_offsets(p, 1, r, off);
        torn += run(p, s, r * nx + 1, nx - 3, off, R + RING_PAD + 1, w);
    }
    for (int32_t i = 0; i < nx; i = (i == 0 && nx > 3) ? nx - 2 : i + 1) {
        owned_offsets(p, i, r, off);
        torn += run(p, s, r * nx + i, 1, off, R + RING_PAD + i, w);
    }
    return torn;
}

/* The 12 springs of row j's vertices from the ring rows of j, j-1, j-2 (stride w), plus air and
 * gravity, into f (and a copy into ro). */
static void gather_row(const cs_phys *pp, int32_t v0, int32_t cnt, const float *restrict R0,
                       const float *restrict R1, const float *restrict R2, const int32_t w, const float *restrict VX,
                       const float *restrict VY, const float *restrict VZ, float *restrict fx, float *restrict fy,
                       float *restrict fz)
{
    const cs_phys P = *pp;
    const cs_phys *p = &P;
    for (int32_t k = 0; k < cnt; k++) {
        const int32_t c = RING_PAD + k;
        cs_vec3 f = cs_v3(0.0f, 0.0f, 0.0f);
        /* Owned (fwd) springs from row j at column k; the others from row j + dj at k + di,
         * negated. */
#define CS_GATHER(t, di, dj, fwd)                                                                      \
    {                                                                                                  \
        const float *rr = (fwd) ? R0 : (dj) == 0 ? R0 : (dj) == -1 ? R1 : R2;                          \
        const int32_t col = (fwd) ? c : c + (di);                                                      \
        const cs_vec3 F = cs_v3(rr[(3 * (t) + 0) * w + col], rr[(3 * (t) + 1) * w + col],                \
                                rr[(3 * (t) + 2) * w + col]);                                          \
        f = cs_add(f, (fwd) ? F : cs_neg(F));                                                          \
    }
        CS_SPRING_SLOTS(CS_GATHER)
#undef CS_GATHER
        f = cs_add(f, cs_air_gravity(cs_v3(VX[v0 + k], VY[v0 + k], VZ[v0 + k]), p));
        fx[k] = f.x;
        fy[k] = f.y;
        fz[k] = f.z;
    }
}

/* Whether a sphere of radius r at c may touch a point of the box [lo, hi] (never a false no). */
static int sphere_box(cs_vec3 c, float r, cs_vec3 lo, cs_vec3 hi)
{
    const float ax = lo.x - c.x, bx = c.x - hi.x, ay = lo.y - c.y, by = c.y - hi.y, az = lo.z - c.z, bz = c.z - hi.z;
    const float mx = ax > bx ? ax : bx, my = ay > by ? ay : by, mz = az > bz ? az : bz;
    const float dx = mx > 0.0f ? mx : 0.0f, dy = my > 0.0f ? my : 0.0f, dz = mz > 0.0f ? mz : 0.0f;
    const float reach = r * 1.001f + 1e-6f;
    return dx * dx + dy * dy + dz * dz <= reach * reach;
}

/* hit[r] = sphere_box for each of the nr rocks in rk (SoA), vectorized. */
static void rocks_near_box(int32_t nr, const float (*restrict rk)[CS_MAX_ROCKS], cs_vec3 lo, cs_vec3 hi,
                           uint8_t *restrict hit)
{
    const float *cx = rk[0], *cy = rk[1], *cz = rk[2], *rr = rk[3];
    for (int32_t r = 0; r < nr; r++) {
        const float ax = lo.x - cx[r], bx = cx[r] - hi.x, ay = lo.y - cy[r], by = cy[r] - hi.y;
        const float az = lo.z - cz[r], bz = cz[r] - hi.z;
        const float mx = ax > bx ? ax : bx, my = ay > by ? ay : by, mz = az > bz ? az : bz;
        const float dx = mx > 0.0f ? mx : 0.0f, dy = my > 0.0f ? my : 0.0f, dz = mz > 0.0f ? mz : 0.0f;
        const float reach = rr[r] * 1.001f + 1e-6f;
        hit[r] = dx * dx + dy * dy + dz * dz <= reach * reach;
    }
}

/* Sums the written leaves (idx[0..n), distinct, each < CS_CHUNK) of contrib by exactly the tree
 * of cs_tree_sum, treating the others as +0 without reading them: the subtree of the leaves
 * whose low b bits are a given prefix is the sum of its two halves (bit b clear, then set); an
 * empty subtree is +0, and the sums above it are still done, so even signed zeros come out as
 * the full tree gives them. */
void cs_cpu_tree_sum_sparse(const float (*contrib)[CS_CHUNK], const uint8_t *idx, int n, int b, float out[6])
{
    if (n == 0) {
        for (int q = 0; q < 6; q++) out[q] = 0.0f;
        return;
    }
    if (n == 1) { /* the leaf and +0 for every empty subtree on the way up: x + 0 (-0 becomes +0) */
        for (int q = 0; q < 6; q++) out[q] = contrib[q][idx[0]] + 0.0f;
        return;
    }
    uint8_t part[CS_CHUNK];
    int lo = 0, hi = n;
    for (int k = 0; k < n; k++) {
        if (idx[k] >> b & 1) part[--hi] = idx[k];
        else part[lo++] = idx[k];
    }
    float a[6], c[6];
    cs_cpu_tree_sum_sparse(contrib, part, lo, b + 1, a);
    cs_cpu_tree_sum_sparse(contrib, part + lo, n - lo, b + 1, c);
    for (int q = 0; q < 6; q++) out[q] = a[q] + c[q];
}

/* hit[i] = 1 where vertex i may touch a sphere (a superset of the contacts), vectorized. */
static void near_sphere(int32_t cnt, const float *restrict X, const float *restrict Y, const float *restrict Z,
                        cs_vec3 c, float reach2, uint8_t *restrict hit)
{
    for (int32_t i = 0; i < cnt; i++) {
        const float dx = X[i] - c.x, dy = Y[i] - c.y, dz = Z[i] - c.z;
        hit[i] = dx * dx + dy * dy + dz * dz <= reach2;
    }
}

/* The 1-ring of vertex (i, j) (physics.h, cs_ring): slots off the grid repeat the vertex; its own
 * velocity, and its non-contact resultant from tb->ro (resultant friction; zeros otherwise). */
static void load_ring(const cs_phys *p, const cs_state *s, const thread_buf *tb, int32_t i, int32_t j, cs_ring *g)
{
    const int32_t nx = p->nx, ny = p->ny;
    const int32_t v = j * nx + i;
    const float *X = s->x, *Y = s->y, *Z = s->z, *VX = s->vx, *VY = s->vy, *VZ = s->vz;
    for (int k = 0; k < CS_RING; k++) {
        const int32_t ii = i + cs_ring_di(k), jj = j + cs_ring_dj(k);
        const int32_t o = (ii >= 0 && ii < nx && jj >= 0 && jj < ny) ? jj * nx + ii : v;
        g->x[k] = LOADX(o);
    }
    g->v = LOADV(v);
    g->ro = p->friction == CS_FRICTION_RESULTANT ? cs_v3(tb->ro[0][i], tb->ro[1][i], tb->ro[2][i])
                                                 : cs_v3(0.0f, 0.0f, 0.0f);
    g->faces = cs_ring_faces(s->L0, nx, ny, i, j);
}

/* Minima and maxima that vectorize. A min reduction does not, without -ffast-math; with GCC's
 * vector extensions it runs eight lanes at a time (a last block overlapping the one before it:
 * harmless for a min). */
#if defined(__GNUC__)
typedef float v8f __attribute__((vector_size(32)));
typedef int32_t v8i __attribute__((vector_size(32)));
static inline v8f v8_load(const float *a)
{
    v8f x;
    memcpy(&x, a, sizeof x);
    return x;
}
static inline v8f v8_min(v8f a, v8f b)
{
    const v8i lt = a < b;
    return (v8f)(((v8i)a & lt) | ((v8i)b & ~lt));
}
static inline v8f v8_max(v8f a, v8f b)
{
    const v8i gt = a > b;
    return (v8f)(((v8i)a & gt) | ((v8i)b & ~gt));
}
static inline float v8_hmin(v8f m)
{
    float r = m[0];
    for (int l = 1; l < 8; l++) r = m[l] < r ? m[l] : r;
    return r;
}
static inline float v8_hmax(v8f m)
{
    float r = m[0];
    for (int l = 1; l < 8; l++) r = m[l] > r ? m[l] : r;
    return r;
}
#endif

/* The min (sign 1) or the max (sign -1) of a[0 .. n), n >= 1. */
static float extreme(const float *a, int32_t n, float sign)
{
#if defined(__GNUC__)
    if (n >= 8) {
        v8f m = v8_load(a);
        for (int32_t k = 8; k < n; k += 8) {
            const v8f x = v8_load(a + (k + 8 <= n ? k : n - 8));
            m = sign > 0.0f ? v8_min(m, x) : v8_max(m, x);
        }
        return sign > 0.0f ? v8_hmin(m) : v8_hmax(m);
    }
#endif
    float m = a[0];
    for (int32_t k = 1; k < n; k++) m = sign > 0.0f ? (a[k] < m ? a[k] : m) : (a[k] > m ? a[k] : m);
    return m;
}

/* mn[1 + k], mx[1 + k] = the min and max of A over rows r0 .. r1-1 (1 to 3 of them) of column
 * c0 + k, for k in 0 .. w-1; mn[0], mx[0] and mn[w + 1], mx[w + 1] repeat the ends. Vectorized. */
static void column_bounds(const float *restrict A, int32_t nx, int32_t r0, int32_t r1, int32_t c0, int32_t w,
                          float *restrict mn, float *restrict mx)
{
    const float *a0 = A + (size_t)r0 * (size_t)nx + c0;
    const float *a1 = r1 - r0 > 1 ? a0 + nx : a0, *a2 = r1 - r0 > 2 ? a0 + 2 * (size_t)nx : a1;
    for (int32_t k = 0; k < w; k++) {
        const float m01 = a1[k] < a0[k] ? a1[k] : a0[k], M01 = a1[k] > a0[k] ? a1[k] : a0[k];
        mn[1 + k] = a2[k] < m01 ? a2[k] : m01;
        mx[1 + k] = a2[k] > M01 ? a2[k] : M01;
    }
    mn[0] = mn[1], mx[0] = mx[1];
    mn[w + 1] = mn[w], mx[w + 1] = mx[w];
}

/* The box (min x y z, max x y z) of row r over columns c0 .. c0+w-1, for chunk column g: kept per
 * thread for the three rows last asked (the force pass resets the tags), so each row's is found
 * once where a thread's rows run in order. */
static const float *row_box(const cs_state *s, thread_buf *tb, int32_t nx, int32_t r, int32_t g, int32_t c0,
                            int32_t w)
{
    float *b = tb->rowbox[r % 3][g];
    if (tb->rowbox_row[r % 3][g] != r) {
        const float *A[3] = {s->x, s->y, s->z};
        for (int q = 0; q < 3; q++) {
            const float *a = A[q] + (size_t)r * (size_t)nx + c0;
            b[q] = extreme(a, w, 1.0f);
            b[3 + q] = extreme(a, w, -1.0f);
        }
        tb->rowbox_row[r % 3][g] = r;
    }
    return b;
}

/* box[l] = the min (max) of col over the three columns around column c0 + off + l, l < cnt. */
static void ring_bounds(const float *restrict mn, const float *restrict mx, int32_t off, int32_t cnt,
                        float *restrict bmn, float *restrict bmx)
{
    for (int32_t l = 0; l < cnt; l++) {
        const float *m = mn + off + l, *M = mx + off + l;
        const float a = m[0] < m[1] ? m[0] : m[1], b = M[0] > M[1] ? M[0] : M[1];
        bmn[l] = a < m[2] ? a : m[2];
        bmx[l] = b > M[2] ? b : M[2];
    }
}

/* hit[l] = 1 where the sphere (c, reach) may touch box l (never a false no), vectorized. */
static void near_boxes(int32_t cnt, const float (*restrict box)[CS_CHUNK], cs_vec3 c, float reach,
                       uint8_t *restrict hit)
{
    const float r = reach * 1.001f + 1e-6f, r2 = r * r;
    const float *lx = box[0], *ly = box[1], *lz = box[2], *hx = box[3], *hy = box[4], *hz = box[5];
    for (int32_t l = 0; l < cnt; l++) {
        const float ax = lx[l] - c.x, bx = c.x - hx[l], ay = ly[l] - c.y, by = c.y - hy[l];
        const float az = lz[l] - c.z, bz = c.z - hz[l];
        const float dx = ax > bx ? ax : bx, dy = ay > by ? ay : by, dz = az > bz ? az : bz;
        const float ex = dx > 0.0f ? dx : 0.0f, ey = dy > 0.0f ? dy : 0.0f, ez = dz > 0.0f ? dz : 0.0f;
        hit[l] = ex * ex + ey * ey + ez * ez <= r2;
    }
}

/* Whether the sphere (c, reach) may touch the ring of vertex l: for u the direction from c to the
 * vertex, every point p of a ring triangle has |p - c| >= (p - c) . u, and that is smallest at a
 * vertex of the triangle; so a ring all of whose slots have (x - c) . u beyond reach cannot be
 * touched (never a false no). R[3 r + d][1 + l]: coordinate d of row r (0: j-1, 1: j, 2: j+1) at
 * column i0 + l (column i0 - 1 at index 0), ends repeated. */
static int near_ring(const float (*R)[CS_CHUNK + 4], int32_t l, cs_vec3 c, float reach)
{
    const float ux = R[3][1 + l] - c.x, uy = R[4][1 + l] - c.y, uz = R[5][1 + l] - c.z;
    const float len = sqrtf(ux * ux + uy * uy + uz * uz);
    if (!(len > 1e-6f)) return 1;
    const float lim = reach * 1.001f + 1e-6f;
    if (len <= lim) return 1;
    const float nx = ux / len, ny = uy / len, nz = uz / len;
    /* the other slots as (row, column offset): (1, +1), (2, +1), (2, 0), (1, -1), (0, -1), (0, 0) */
    const int row[6] = {1, 2, 2, 1, 0, 0}, off[6] = {1, 1, 0, -1, -1, 0};
    for (int k = 0; k < 6; k++) {
        const int q = 3 * row[k], i = 1 + l + off[k];
        if ((R[q][i] - c.x) * nx + (R[q + 1][i] - c.y) * ny + (R[q + 2][i] - c.z) * nz <= lim) return 1;
    }
    return 0;
}

/* Surface contacts of chunk (row j, columns i0 .. i1) with every rock: shares onto tb->f, each
 * rock's reactions from the features this chunk's vertices own into the chunk's partials. A vertex
 * is gathered for a rock only when the rock can reach the bounding box of the 3 x 3 vertices
 * around it (which holds every feature of its ring) and passes near_ring, and the chunk only when
 * the rock can reach the box of all of those. Gathering more vertices than touch changes nothing:
 * one out of reach adds nothing and writes no lane. Returns the lowest z of that box. */
static float surface_contacts(const cs_phys *p, const cs_state *s, thread_buf *tb, int32_t j, int32_t i0, int32_t i1,
                              int32_t chunk, float *partials)
{
    const int32_t nx = p->nx, ny = p->ny, nr = s->n_rocks, cnt = i1 - i0;
    const int32_t c0 = i0 > 0 ? i0 - 1 : 0, c1 = i1 < nx ? i1 + 1 : nx, w = c1 - c0;
    const int32_t r0 = j > 0 ? j - 1 : 0, r1 = j + 1 < ny ? j + 2 : ny;
    const float *A[3] = {s->x, s->y, s->z};
    /* the box of rows r0 .. r1-1 over columns c0 .. c1-1: its rows' boxes, each found once per
     * pass by this thread (row_box) */
    const int32_t g = chunk - j * p->nseg;
    float e[6];
    memcpy(e, row_box(s, tb, nx, r0, g, c0, w), sizeof e);
    for (int32_t r = r0 + 1; r < r1; r++) {
        const float *b = row_box(s, tb, nx, r, g, c0, w);
        for (int q = 0; q < 3; q++) {
            e[q] = b[q] < e[q] ? b[q] : e[q];
            e[3 + q] = b[3 + q] > e[3 + q] ? b[3 + q] : e[3 + q];
        }
    }
    const cs_vec3 lo = cs_v3(e[0], e[1], e[2]), hi = cs_v3(e[3], e[4], e[5]);
    int boxes = 0;
    rocks_near_box(nr, (const float(*)[CS_MAX_ROCKS])tb->rk, lo, hi, tb->rhit);
    for (int32_t r = 0; r < nr; r++) {
        const cs_rock_state *rock = &s->rocks[r];
        float *out = partials + ((size_t)chunk * nr + r) * 6;
        const float reach = rock->radius + p->contact_offset;
        if (!tb->rhit[r]) {
            for (int q = 0; q < 6; q++) out[q] = 0.0f;
            continue;
        }
        if (!boxes) {
            boxes = 1;
            for (int q = 0; q < 3; q++) column_bounds(A[q], nx, r0, r1, c0, w, tb->col[q], tb->col[3 + q]);
            /* column c0 + k is at col index 1 + k; vertex i0 + l's left neighbour column at
             * 1 + (i0 - c0) + l - 1 (the repeated end at the border) */
            for (int q = 0; q < 3; q++)
                ring_bounds(tb->col[q], tb->col[3 + q], i0 - c0, cnt, tb->rbox[q], tb->rbox[3 + q]);
            /* rows j-1, j, j+1 (the row itself past an edge) of columns i0-1 .. i1 */
            const int32_t rows[3] = {j > 0 ? j - 1 : j, j, j + 1 < ny ? j + 1 : j};
            for (int r3 = 0; r3 < 3; r3++)
                for (int q = 0; q < 3; q++) {
                    const float *src = A[q] + (size_t)rows[r3] * (size_t)nx;
                    float *dst = tb->rows[3 * r3 + q];
                    memcpy(dst + 1, src + i0, sizeof(float) * (size_t)cnt);
                    dst[0] = src[i0 > 0 ? i0 - 1 : i0];
                    dst[cnt + 1] = src[i1 < nx ? i1 : i1 - 1];
                }
        }
        near_boxes(cnt, (const float(*)[CS_CHUNK])tb->rbox, rock->x, reach, tb->hit);
        for (int32_t l = cnt; l < ((cnt + 7) & ~7); l++) tb->hit[l] = 0;
        /* the vertices to gather */
        int n_cand = 0;
        for (int32_t l = 0; l < cnt; l++) {
            if ((l & 7) == 0) { /* eight at a time past the misses */
                uint64_t word;
                memcpy(&word, tb->hit + l, sizeof word);
                if (!word) {
                    l += 7;
                    continue;
                }
            }
            if (tb->hit[l] && near_ring((const float(*)[CS_CHUNK + 4])tb->rows, l, rock->x, reach))
                tb->cand[n_cand++] = (uint8_t)l;
        }
        /* Their triangles, each found once for the vertices of this row that share it (the gather
         * would find each for each of them; cs_surface_triangle gives every one the same bits). */
        int n_idx = 0;
        for (int k = 0; k < n_cand; k++) {
            const int32_t l = tb->cand[k];
            cs_ring g;
            cs_surface_out o;
            load_ring(p, s, tb, i0 + l, j, &g);
            const cs_vec3 Fsum = cs_v3(tb->f[0][i0 + l], tb->f[1][i0 + l], tb->f[2][i0 + l]);
            cs_surface_gather(&g, rock, p, Fsum, s->w[j * nx + i0 + l], &o);
            if (o.touches) {
                tb->f[0][i0 + l] += o.share.x;
                tb->f[1][i0 + l] += o.share.y;
                tb->f[2][i0 + l] += o.share.z;
            }
            if (o.owns) {
                tb->contrib[0][l] = o.force.x;
                tb->contrib[1][l] = o.force.y;
                tb->contrib[2][l] = o.force.z;
                tb->contrib[3][l] = o.torque.x;
                tb->contrib[4][l] = o.torque.y;
                tb->contrib[5][l] = o.torque.z;
                tb->idx[n_idx++] = (uint8_t)l;
            }
        }
        cs_cpu_tree_sum_sparse((const float(*)[CS_CHUNK])tb->contrib, tb->idx, n_idx, 0, out);
    }
    return lo.z;
}

/* Contacts of chunk (row j, columns i0 .. i1) with rocks and the ground, added onto tb->f in
 * rock order then the ground; each rock's reaction summed with the chunk tree into the chunk's
 * partials (zeros for a rock that cannot touch the chunk: what the tree of +0 gives). With
 * resultant friction, tb->ro keeps each vertex's non-contact resultant for its contacts to read. */
static void chunk_contacts(const cs_phys *p, const cs_state *s, thread_buf *tb, int32_t j, int32_t i0, int32_t i1,
                           int32_t chunk, float *partials)
{
    const float *X = s->x, *Y = s->y, *Z = s->z, *VX = s->vx, *VY = s->vy, *VZ = s->vz;
    const int32_t nr = s->n_rocks, base = j * p->nx, cnt = i1 - i0;
    const int need_ro = p->friction == CS_FRICTION_RESULTANT;
#define RO_OF(i) (need_ro ? cs_v3(tb->ro[0][i], tb->ro[1][i], tb->ro[2][i]) : cs_v3(0.0f, 0.0f, 0.0f))
    int ground;
    if (p->contact_model == CS_CONTACT_SURFACE && nr) {
        /* the ground test from the lowest z of the rows around (no lower than this row's) */
        if (need_ro)
            for (int q = 0; q < 3; q++) memcpy(&tb->ro[q][i0], &tb->f[q][i0], sizeof(float) * (size_t)cnt);
        const float zlo = surface_contacts(p, s, tb, j, i0, i1, chunk, partials);
        ground = p->ground && zlo < p->ground_z + p->contact_offset;
    } else {
        const cs_vec3 lo = cs_v3(extreme(X + base + i0, cnt, 1.0f), extreme(Y + base + i0, cnt, 1.0f),
                                 extreme(Z + base + i0, cnt, 1.0f));
        const cs_vec3 hi = cs_v3(extreme(X + base + i0, cnt, -1.0f), extreme(Y + base + i0, cnt, -1.0f),
                                 extreme(Z + base + i0, cnt, -1.0f));
        ground = p->ground && lo.z < p->ground_z + p->contact_offset;
        if (need_ro && (nr || ground))
            for (int q = 0; q < 3; q++) memcpy(&tb->ro[q][i0], &tb->f[q][i0], sizeof(float) * (size_t)cnt);
        for (int32_t r = 0; r < nr; r++) {
            const cs_rock_state *rock = &s->rocks[r];
            float *out = partials + ((size_t)chunk * nr + r) * 6;
            const float reach = rock->radius + p->contact_offset;
            if (!sphere_box(rock->x, reach, lo, hi)) {
                for (int q = 0; q < 6; q++) out[q] = 0.0f;
                continue;
            }
            near_sphere(cnt, X + base + i0, Y + base + i0, Z + base + i0, rock->x, reach * reach * 1.001f + 1e-12f,
                        tb->hit);
            int n_idx = 0;
            for (int32_t l = 0; l < cnt; l++) {
                if (!tb->hit[l]) continue;
                const int32_t i = i0 + l;
                cs_vec3 F, arm;
                if (cs_vertex_rock_contact(LOADX(base + i), LOADV(base + i), RO_OF(i), rock, p, &F, &arm)) {
                    tb->f[0][i] += F.x;
                    tb->f[1][i] += F.y;
                    tb->f[2][i] += F.z;
                    const cs_vec3 R = cs_neg(F), T = cs_cross(arm, R);
                    tb->contrib[0][l] = R.x;
                    tb->contrib[1][l] = R.y;
                    tb->contrib[2][l] = R.z;
                    tb->contrib[3][l] = T.x;
                    tb->contrib[4][l] = T.y;
                    tb->contrib[5][l] = T.z;
                    tb->idx[n_idx++] = (uint8_t)l;
                }
            }
            cs_cpu_tree_sum_sparse((const float(*)[CS_CHUNK])tb->contrib, tb->idx, n_idx, 0, out);
        }
    }
    if (ground) {
        for (int32_t i = i0; i < i1; i++) {
            cs_vec3 F;
            if (cs_vertex_ground_contact(LOADX(base + i), LOADV(base + i), RO_OF(i), p, &F)) {
                tb->f[0][i] += F.x;
                tb->f[1][i] += F.y;
                tb->f[2][i] += F.z;
            }
        }
    }
#undef RO_OF
}

/* a = F (inv_mass w) over cnt vertices. */
static void accel(int32_t cnt, float inv_mass, const float *restrict W, const float *restrict FX,
                  const float *restrict FY, const float *restrict FZ, float *restrict AX, float *restrict AY,
                  float *restrict AZ)
{
    for (int32_t i = 0; i < cnt; i++) {
        const float k = inv_mass * W[i];
        AX[i] = FX[i] * k;
        AY[i] = FY[i] * k;
        AZ[i] = FZ[i] * k;
    }
}

/* The non-contact forces of row j (springs, air, gravity) into tb->f, and strain updates of its
 * springs; returns the springs torn. Rows j-2 and j-1 must already be in the ring (this thread's
 * previous rows). */
static int spring_row(const cs_phys *p, cs_state *s, thread_buf *tb, int32_t j, int strain)
{
    const int32_t nx = p->nx, v0 = j * nx;
    if (tb->last_row != j - 1) {
        /* The first row of this thread's block: the two rows above, without owning them. */
        owned_row(p, s, j - 2, tb->ring[(j + 1) % 3], tb->w, 0);
        owned_row(p, s, j - 1, tb->ring[(j + 2) % 3], tb->w, 0);
    }
    tb->last_row = j;
    const int torn = owned_row(p, s, j, tb->ring[j % 3], tb->w, strain);
    gather_row(p, v0, nx, tb->ring[j % 3], tb->ring[(j + 2) % 3], tb->ring[(j + 1) % 3], tb->w, s->vx, s->vy,
               s->vz, tb->f[0], tb->f[1], tb->f[2]);
    return torn;
}

/* Row j's contacts onto tb->f, its chunks' partials, then a for its vertices. */
static void contact_row(const cs_phys *p, cs_state *s, thread_buf *tb, int32_t j, float *partials)
{
    const int32_t nx = p->nx, v0 = j * nx;
    for (int32_t g = 0; g < p->nseg; g++) {
        const int32_t i0 = g * CS_CHUNK, i1 = i0 + CS_CHUNK < nx ? i0 + CS_CHUNK : nx;
        chunk_contacts(p, s, tb, j, i0, i1, j * p->nseg + g, partials);
    }
    accel(nx, p->inv_mass, s->w + v0, tb->f[0], tb->f[1], tb->f[2], s->ax + v0, s->ay + v0, s->az + v0);
}

/* New rest lengths from the current positions (symplectic Euler, after the update). */
int cs_cpu_strain_row(const cs_phys *p, cs_state *s, int32_t r)
{
    const float *X = s->x, *Y = s->y, *Z = s->z, *L0 = s->L0;
    float *L0n = s->L0_next;
    const size_t n = (size_t)p->n;
    int torn = 0;
    for (int32_t i = 0; i < p->nx; i++) {
        const int32_t v = r * p->nx + i;
        int32_t off[CS_NTYPES];
        owned_offsets(p, i, r, off);
        for (int t = 0; t < CS_NTYPES; t++) {
            const float l0 = L0[t * n + v];
            const float nl = cs_strain_update(cs_len(cs_sub(LOADX(v + off[t]), LOADX(v))), l0, p);
            L0n[t * n + v] = nl;
            torn += (l0 > 0.0f) & (nl <= 0.0f);
        }
    }
    return torn;
}

/* ---- streaming passes ---- */

/* v += h a over cnt vertices (restrict parameters, so gcc vectorizes). */
static void kick(int32_t cnt, float h, float *restrict VX, float *restrict VY, float *restrict VZ,
                 const float *restrict AX, const float *restrict AY, const float *restrict AZ)
{
    for (int32_t i = 0; i < cnt; i++) {
        VX[i] = VX[i] + h * AX[i];
        VY[i] = VY[i] + h * AY[i];
        VZ[i] = VZ[i] + h * AZ[i];
    }
}

/* v += h a; x += dt v over cnt vertices. */
static void kick_drift(int32_t cnt, float h, float dt, float *restrict X, float *restrict Y, float *restrict Z,
                       float *restrict VX, float *restrict VY, float *restrict VZ, const float *restrict AX,
                       const float *restrict AY, const float *restrict AZ)
{
    for (int32_t i = 0; i < cnt; i++) {
        VX[i] = VX[i] + h * AX[i];
        VY[i] = VY[i] + h * AY[i];
        VZ[i] = VZ[i] + h * AZ[i];
        X[i] = X[i] + dt * VX[i];
        Y[i] = Y[i] + dt * VY[i];
        Z[i] = Z[i] + dt * VZ[i];
    }
}

/* Row j: when finish, v += h a (the end of the previous substep); then v += h a, x += dt v. */
static void move_row(cs_state *s, const cs_phys *p, int32_t j, int finish, float h, float dt)
{
    const size_t v0 = (size_t)j * (size_t)p->nx;
    if (finish) kick(p->nx, h, s->vx + v0, s->vy + v0, s->vz + v0, s->ax + v0, s->ay + v0, s->az + v0);
    kick_drift(p->nx, h, dt, s->x + v0, s->y + v0, s->z + v0, s->vx + v0, s->vy + v0, s->vz + v0, s->ax + v0,
               s->ay + v0, s->az + v0);
}

static void kick_row(cs_state *s, const cs_phys *p, int32_t j, float h)
{
    const size_t v0 = (size_t)j * (size_t)p->nx;
    kick(p->nx, h, s->vx + v0, s->vy + v0, s->vz + v0, s->ax + v0, s->ay + v0, s->az + v0);
}

/* ---- rocks (few: one thread) ---- */

static void rocks_forces(const cs_phys *p, cs_state *s, const float *partials, float kick)
{
    /* Safe to store as we go: a rock's force reads other rocks' x, v, w, never their a. */
    for (int32_t r = 0; r < s->n_rocks; r++) {
        cs_vec3 F, T;
        cs_rock_force(s->rocks, s->n_rocks, r, partials, p->nchunks, p, &F, &T);
        cs_rock_accel(&s->rocks[r], F, T);
    }
    if (kick != 0.0f)
        for (int32_t r = 0; r < s->n_rocks; r++) cs_rock_kick(&s->rocks[r], kick);
}

static void rocks_move(cs_state *s, float h, float dt)
{
    for (int32_t r = 0; r < s->n_rocks; r++) {
        cs_rock_kick(&s->rocks[r], h);
        cs_rock_drift(&s->rocks[r], dt);
    }
}

static void grab_motion(const cs_phys *p, cs_state *s)
{
    const int32_t g = s->grab;
    if (g < 0) return;
    const cs_vec3 v = cs_grab_velocity(cs_v3(s->x[g], s->y[g], s->z[g]), s->grab_target, p);
    s->vx[g] = v.x;
    s->vy[g] = v.y;
    s->vz[g] = v.z;
}

static void swap_rest(cs_state *s)
{
    float *t = s->L0;
    s->L0 = s->L0_next;
    s->L0_next = t;
}

/* Rows per block handed to a thread at a time. Blocks are taken as threads come free (dynamic):
 * a thread the OS preempts holds up one block, not half the cloth. Each block starts by
 * evaluating the two rows above it again (16 rows: 12% more spring work than static halves, for
 * robustness on a busy machine; no slower on an idle one, as measured). */
#define ROW_BLOCK 16

/* The work sharing of a step: a team shares each loop over rows (the OpenMP construct named) and
 * one of its threads runs each section; a thread stepping a scene alone (solo) runs them plainly,
 * without the constructs' bookkeeping and barriers. */
#define TEAM_ROWS(solo, construct, j, ny, ...)                                                     \
    do {                                                                                          \
        if (solo) {                                                                               \
            for (int32_t j = 0; j < (ny); j++) __VA_ARGS__;                                        \
        } else {                                                                                  \
            _Pragma(construct) for (int32_t j = 0; j < (ny); j++) __VA_ARGS__;                      \
        }                                                                                         \
    } while (0)
#define TEAM_ONE(solo, ...)                                                                        \
    do {                                                                                          \
        if (solo) {                                                                               \
            __VA_ARGS__;                                                                          \
        } else {                                                                                  \
            _Pragma("omp single") { __VA_ARGS__; }                                                \
        }                                                                                         \
    } while (0)

/* Counts springs torn (rare: no atomic at all where none tore). */
static void count_torn(cpu_ctx *c, int torn)
{
    if (torn) {
#pragma omp atomic
        c->torn += torn;
    }
}

/* The force pass over every row, by the team of the innermost parallel region (or solo), each
 * thread with its buffer tb. */
static void force_pass(cpu_ctx *c, thread_buf *tb, const cs_phys *p, cs_state *s, int strain, int solo)
{
    tb->last_row = -3;
    for (int k = 0; k < 3; k++)
        for (int g = 0; g < CS_MAX_SEG; g++) tb->rowbox_row[k][g] = -1;
    for (int32_t r = 0; r < s->n_rocks; r++) {
        tb->rk[0][r] = s->rocks[r].x.x, tb->rk[1][r] = s->rocks[r].x.y, tb->rk[2][r] = s->rocks[r].x.z;
        tb->rk[3][r] = s->rocks[r].radius + p->contact_offset;
    }
    TEAM_ROWS(solo, "omp for schedule(dynamic, ROW_BLOCK)", j, p->ny, {
        count_torn(c, spring_row(p, s, tb, j, strain));
        contact_row(p, s, tb, j, c->partials);
    });
}

/* The springs torn since the last call. */
static int64_t take_torn(cpu_ctx *c)
{
    const int64_t t = c->torn;
    c->torn = 0;
    return t;
}

/* A refresh (one force evaluation, at creation, a load or a change from outside) runs on the
 * calling thread alone: a thread that opens an OpenMP team keeps a pool of workers, and once a
 * process has more pool threads than cores libgomp spins only briefly at its barriers and sleeps in
 * the kernel instead - the daemon, which creates its first scene on its main thread and steps on
 * its sim thread, paid that at every barrier of every step (docs/developing.md, "The daemon's
 * threads"). Steps are the only parallel regions. */
static cs_status cpu_refresh(void *ctx, const cs_model *m, cs_state *s)
{
    cpu_ctx *c = ctx;
    const cs_phys *p = &m->phys;
    cs_sc_forget(c->sc);
    if (p->integrator == CS_IMPLICIT_EULER) {
        if (reserve(c, m, s) != CS_OK) return CS_E_NOMEM;
        const cs_status st = cs_im_refresh(&c->im, m, s, 1);
        take_torn(c);
        return st;
    }
    thread_buf **tb = reserve(c, m, s) == CS_OK ? scratch_take(1, m->phys.nx) : NULL;
    if (!tb) return CS_E_NOMEM;
    force_pass(c, tb[0], p, s, 0, 1);
    scratch_give(tb, 1);
    rocks_forces(p, s, c->partials, 0.0f);
    take_torn(c);
    return CS_OK;
}

/* Whether the state's positions and velocities, and the rocks', are finite; with rates (implicit_euler,
 * whose accelerations are (v - v_n) / h rather than forces the next substep meets) its accelerations
 * and the rocks' too, so that a step reported finite leaves a state that saves (snapshot.c). */
static int state_finite(const cs_state *s, int rates)
{
    int ok = 1;
    const float *arrays[] = {s->x, s->y, s->z, s->vx, s->vy, s->vz, s->ax, s->ay, s->az};
    for (int a = 0; a < (rates ? 9 : 6); a++) {
        const float *q = arrays[a];
        float acc = 0.0f;
        for (int32_t v = 0; v < s->n; v++) acc += q[v] - q[v]; /* NaN for any NaN or infinity */
        ok &= acc == 0.0f;
    }
    for (int32_t r = 0; r < s->n_rocks; r++) ok &= cs_rock_finite(&s->rocks[r], rates);
    return ok;
}

/* One step call's substeps, run by the team of the innermost parallel region (every thread of it
 * calls this, with the same arguments but its own buffer tb), or by one thread alone (solo). */
static void step_team(cpu_ctx *c, thread_buf *tb, const cs_model *m, cs_state *s, int32_t substeps, int solo)
{
    const cs_phys *p = &m->phys;
    const int verlet = p->integrator == CS_VELOCITY_VERLET, strain = p->strain_on != 0;
    const int32_t ny = p->ny;
    if (substeps <= 0) return;
    /* Velocity Verlet's steps 1 and 2 for the rocks and the grab (backend.h) run in the single
     * section that ends the previous substep: one barrier fewer per substep. */
    if (verlet) TEAM_ONE(solo, grab_motion(p, s), rocks_move(s, p->hdt, p->dt));
    for (int32_t it = 0; it < substeps; it++) {
        if (verlet) {
            TEAM_ROWS(solo, "omp for schedule(dynamic, ROW_BLOCK)", j, ny, move_row(s, p, j, it > 0, p->hdt, p->dt));
            force_pass(c, tb, p, s, strain, solo);
            TEAM_ONE(solo, {
                rocks_forces(p, s, c->partials, p->hdt);
                if (strain) swap_rest(s);
                if (it + 1 < substeps) {
                    grab_motion(p, s);
                    rocks_move(s, p->hdt, p->dt);
                }
            });
        } else {
            force_pass(c, tb, p, s, 0, solo);
            TEAM_ONE(solo, rocks_forces(p, s, c->partials, 0.0f), rocks_move(s, p->dt, p->dt), grab_motion(p, s));
            TEAM_ROWS(solo, "omp for schedule(static)", j, ny, move_row(s, p, j, 0, p->dt, p->dt));
            if (strain) {
                TEAM_ROWS(solo, "omp for schedule(static)", j, ny, count_torn(c, cs_cpu_strain_row(p, s, j)));
                TEAM_ONE(solo, swap_rest(s));
            }
        }
    }
    if (verlet) TEAM_ROWS(solo, "omp for schedule(static)", j, ny, kick_row(s, p, j, p->hdt));
}

/* What a step call reports, once its team is done. */
static void step_report(cpu_ctx *c, const cs_model *m, const cs_state *s, cs_step_report *rep)
{
    rep->torn = take_torn(c);
    rep->finite = state_finite(s, m->phys.integrator == CS_IMPLICIT_EULER);
}

static cs_status cpu_step(void *ctx, const cs_model *m, cs_state *s, int32_t substeps, cs_step_report *rep)
{
    cpu_ctx *c = ctx;
    const int threads = threads_of(m);
    if (m->phys.integrator == CS_IMPLICIT_EULER) {
        int64_t torn = 0;
        if (reserve(c, m, s) != CS_OK) return CS_E_NOMEM;
        const cs_status st = cs_im_step(&c->im, m, s, substeps, threads, rep, &torn, &c->sc);
        if (st != CS_OK) return st;
        c->torn += torn;
        step_report(c, m, s, rep);
        return CS_OK;
    }
    thread_buf **tb = reserve(c, m, s) == CS_OK ? scratch_take(threads, m->phys.nx) : NULL;
    if (!tb) return CS_E_NOMEM;
    /* self_collision: one substep at a time, each followed by its passes (the same arithmetic as
     * substeps run together: velocity Verlet's last half kick and the next first one are the two
     * half kicks between substeps) */
    const int self = m->phys.self_on != 0;
    for (int32_t done = 0; done < substeps;) {
        const int32_t run = self ? 1 : substeps;
        if (self && cs_sc_begin(&c->sc, s) != CS_OK) {
            scratch_give(tb, threads);
            return CS_E_NOMEM;
        }
        const int64_t torn = c->torn;
        if (threads == 1) {
            step_team(c, tb[0], m, s, run, 1);
        } else {
#pragma omp parallel num_threads(threads)
            step_team(c, tb[thread_id()], m, s, run, 0);
        }
        if (self && c->torn != torn) cs_sc_forget(c->sc); /* its lists may hold torn triangles */
        if (self) cs_sc_end(c->sc, &m->phys, s, threads, &rep->self);
        done += run;
    }
    scratch_give(tb, threads);
    step_report(c, m, s, rep);
    return CS_OK;
}

/* ---- batches ---- */

/* What a substep's barriers cost a team, in vertex-substeps of one thread's work: a scene shared
 * by the team pays it every substep, one stepped whole by a thread nothing. Measured on the build
 * machine (2 vCPUs shared with other work, load 3-4): a 64 x 64 scene's substep took 103-123 us on
 * one thread and 78-84 us on two, about 25 us more than half, some 900 vertex-substeps' work. On
 * a busy machine it is far more (a descheduled thread holds up every barrier), so the planner
 * errs towards stepping scenes whole. */
#define TEAM_SUBSTEP_COST 1024.0
/* Most scenes the planner moves from one thread to the team beyond those too large for a share. */
#define PLAN_PROMOTE_MAX 8

typedef struct batch_job {
    cs_batch_item *it;
    double work; /* vertices x substeps */
} batch_job;

static int by_work_desc(const void *a, const void *b)
{
    const batch_job *x = a, *y = b;
    if (x->work != y->work) return x->work < y->work ? 1 : -1;
    return x->it < y->it ? -1 : x->it > y->it; /* a stable order: the same plan for the same batch */
}

/* The time (in vertex-substeps) that list scheduling of jobs[0 .. n), largest first, takes on t
 * threads taking the next job as they come free: the most any thread gets. load[] has t slots. */
static double lpt_makespan(const batch_job *jobs, int n, int t, double *load)
{
    for (int k = 0; k < t; k++) load[k] = 0.0;
    /* load[] as a min-heap */
    for (int i = 0; i < n; i++) {
        load[0] += jobs[i].work;
        for (int k = 0;;) {
            const int l = 2 * k + 1, r = l + 1;
            int m = k;
            if (l < t && load[l] < load[m]) m = l;
            if (r < t && load[r] < load[m]) m = r;
            if (m == k) break;
            const double tmp = load[k];
            load[k] = load[m];
            load[m] = tmp;
            k = m;
        }
    }
    double most = 0.0;
    for (int k = 0; k < t; k++) most = load[k] > most ? load[k] : most;
    return most;
}

/* The simulations of a batch shared among t threads by work: returns how many of jobs[] (sorted
 * largest first) the whole team steps, one after the other (as cpu_step does); the rest are each
 * stepped whole by one thread, largest first as threads come free. A scene goes to the team
 * when it alone is more than a thread's fair share of the batch, or when the estimate of the
 * whole (team time plus list-scheduling time) says so: a few large scenes that would leave
 * threads idle. */
static int plan_batch(batch_job *jobs, int n, int t, double *load)
{
    double total = 0.0;
    for (int i = 0; i < n; i++) total += jobs[i].work;
    int team = 0;
    while (team < n && jobs[team].work * t > total) team++;
    if (t <= 1) return 0;
    double team_time = 0.0;
    for (int i = 0; i < team; i++) team_time += jobs[i].work / t + TEAM_SUBSTEP_COST * jobs[i].it->substeps;
    double best = team_time + lpt_makespan(jobs + team, n - team, t, load);
    for (int k = 0; k < PLAN_PROMOTE_MAX && team < n; k++) {
        const double tt = team_time + jobs[team].work / t + TEAM_SUBSTEP_COST * jobs[team].it->substeps;
        const double est = tt + lpt_makespan(jobs + team + 1, n - team - 1, t, load);
        if (!(est < best)) break;
        best = est, team_time = tt, team++;
    }
    return team;
}

/* Steps a batch (backend.h): the plan above, in one parallel region of the most threads any of
 * its models asks for. A scene stepped by one thread runs step_team solo: the very sequence of
 * cpu_step without a barrier that waits on anyone else, and no nested parallel region (so nothing
 * runs more threads than the one team). The results equal cpu_step's: no sum depends on how the
 * threads share the work (the header's comment). */
static cs_status cpu_step_batch(cs_batch_item *items, int n)
{
    if (n <= 0) return CS_OK;
    int t = 1;
    int32_t nx = 0; /* the widest cloth */
    for (int i = 0; i < n; i++) {
        const int ti = threads_of(items[i].m);
        t = ti > t ? ti : t;
        nx = items[i].m->phys.nx > nx ? items[i].m->phys.nx : nx;
    }
    batch_job *jobs = malloc(sizeof *jobs * (size_t)n);
    double *load = malloc(sizeof *load * (size_t)t);
    if (!jobs || !load) {
        free(jobs);
        free(load);
        return CS_E_NOMEM;
    }
    int nj = 0;
    for (int i = 0; i < n; i++) {
        if (items[i].substeps <= 0) continue;
        if (items[i].m->phys.integrator == CS_IMPLICIT_EULER || items[i].m->phys.self_on) {
            /* implicit_euler and self_collision run their own parallel loops: stepped alone, as
             * cpu_step does */
            items[i].status = cpu_step(items[i].ctx, items[i].m, items[i].s, items[i].substeps, &items[i].rep);
            continue;
        }
        jobs[nj++] = (batch_job){&items[i], (double)items[i].s->n * (double)items[i].substeps};
    }
    qsort(jobs, (size_t)nj, sizeof *jobs, by_work_desc);
    const int team = plan_batch(jobs, nj, t, load);
    /* A simulation that cannot have its partials fails alone; the t thread buffers, for the widest
     * cloth, serve every simulation of the batch (a thread steps one at a time). */
    for (int i = 0; i < nj; i++) {
        cs_batch_item *it = jobs[i].it;
        if (reserve(it->ctx, it->m, it->s) != CS_OK) it->status = CS_E_NOMEM;
    }
    thread_buf **tb = scratch_take(t, nx);
    if (!tb) {
        free(jobs);
        free(load);
        return CS_E_NOMEM;
    }
    int next = team;
#pragma omp parallel num_threads(t)
    {
        thread_buf *mine = tb[thread_id()];
        for (int i = 0; i < team; i++) {
            cs_batch_item *it = jobs[i].it;
            if (it->status != CS_OK) continue;
            step_team(it->ctx, mine, it->m, it->s, it->substeps, 0);
#pragma omp single nowait
            step_report(it->ctx, it->m, it->s, &it->rep);
        }
        for (;;) {
            int k;
#pragma omp atomic capture
            k = next++;
            if (k >= nj) break;
            cs_batch_item *it = jobs[k].it;
            if (it->status != CS_OK) continue;
            step_team(it->ctx, mine, it->m, it->s, it->substeps, 1);
            step_report(it->ctx, it->m, it->s, &it->rep);
        }
    }
    scratch_give(tb, t);
    free(jobs);
    free(load);
    return CS_OK;
}

static const char *cpu_device(void *ctx, const cs_model *m)
{
    cpu_ctx *c = ctx;
#ifdef _OPENMP
    const int t = threads_of(m);
    snprintf(c->device, sizeof c->device, "cpu (OpenMP, %d thread%s)", t, t == 1 ? "" : "s");
#else
    (void)m;
    snprintf(c->device, sizeof c->device, "cpu (1 thread, built without OpenMP)");
#endif
    return c->device;
}

static const char *cpu_error(void *ctx)
{
    (void)ctx;
    return "out of memory for the CPU backend's scratch buffers";
}

/* The cost model (backend.h): the arrays each parallel pass above streams, per vertex (rows a
 * block re-evaluates come from cache). Velocity Verlet: move_row reads x, v, a and writes x, v;
 * the force pass reads x, v, the six rest lengths and w, writes a and, with strain, the six new
 * rest lengths; the last kick of a call reads v, a and writes v. Symplectic Euler: the force pass,
 * then move_row, then with strain strain_row (x and rest lengths in, rest lengths out). Rocks run
 * on one thread: each reads every chunk's partial (24 bytes) and every other rock. */
static void cpu_cost(const cs_model *m, int32_t n_rocks, cs_cost_model *out)
{
    const cs_phys *p = &m->phys;
    const double F = m->substeps, rock = (double)sizeof(cs_rock_state);
    const int verlet = p->integrator == CS_VELOCITY_VERLET, strain = p->strain_on != 0;
    memset(out, 0, sizeof *out);
    cs_cost_add(out, "move_row (kick, drift)", 36.0, 24.0, 0, 1.0, F);
    cs_cost_add(out, "force pass (springs, air, contacts)", 52.0, 12.0 + (verlet && strain ? 24.0 : 0.0),
                24.0 * p->nchunks * n_rocks, 1.0, F);
    if (!verlet && strain) cs_cost_add(out, "strain_row", 36.0, 24.0, 0, 1.0, F);
    if (verlet) cs_cost_add(out, "kick_row (the last kick of a call)", 24.0, 12.0, 0, 1.0 / F, 1.0);
    if (n_rocks) cs_cost_add(out, "rocks (one thread)", 0, 0, (24.0 * p->nchunks + rock * n_rocks) * n_rocks, 1.0, 0);
    out->nodes_per_substep = verlet ? 2.0 : 2.0 + strain;
}

static void cpu_stats(void *ctx, const cs_model *m, cs_backend_stats *out)
{
    (void)ctx, (void)m;
    out->bytes_per_vertex_substep = 0;
    out->peak_bandwidth = 0;
}

const cs_backend cs_backend_cpu = {
    "cpu", cpu_available, cpu_create, cpu_destroy, cpu_upload, cpu_download, cpu_refresh, cpu_step, cpu_device,
    cpu_error, cpu_stats, cpu_cost, CS_CAP_SURFACE_CONTACT | CS_CAP_IMPLICIT | CS_CAP_IMPLICIT_ROCKS | CS_CAP_SELF_COLLISION,
    cpu_step_batch,
};
