/* selfcontact_cpu.c - self_collision on the CPU backend: the functions of clothsim/selfcontact.h
 * looped over the grid with OpenMP (kernels/MODEL.md, "Self-collision"). After a substep (a part
 * under implicit_euler) that began at x0 (cs_sc_begin):
 *   1. d = x - x0, M the farthest a vertex moves from the centre of all the displacements (what
 *      the lists need) and Ma the farthest a vertex moves (what the bound needs): pairs within
 *      r = self_thickness + 2 Ma / CS_SC_GAMMA at x0 are the ones that may meet;
 *   2. repulsion (cs_sc_repel) per vertex into scratch, then added: from each vertex's list of
 *      repelling pairs while the lists provably hold every pair that can touch, else from new
 *      lists at x0 (within self_thickness + 2 M and a margin);
 *   3. the bound (cs_sc_limit) over a hash grid of x0 (cells of the reach plus twice the longest
 *      edge; keys in parallel, the counting sort on one thread), or over each vertex's list of its
 *      pairs at the reference while that provably holds them all, in Jacobi sweeps of the scales
 *      until none changes (at most CS_SC_SWEEPS, then one sweep that cuts every near pair
 *      outright); x = x0 + s d, v = s v.
 * Every maximum is exact in any order and every vertex writes only its own entries, so the result
 * does not depend on the thread count. The lists a full pass builds find each pair once, by the
 * vertex that owns it (cs_sc_owned), and hand it to its four vertices (owned_lists): the same
 * pairs the per-vertex gathers (cs_sc_pairs, cs_sc_limit) find, which the CUDA backend runs.
 *
 * Passes that provably change nothing are skipped. A full pass of the bound finds each vertex's
 * least pair distance at x0 within a wider reach and rebuilds the lists there, keeping x0 as the
 * reference. While every vertex has moved less than C from it (from the centre of all the
 * motions), no pair is nearer than that least distance less 2 C: a vertex for which that leaves
 * every pair safe for this substep's motion is not looked at. So the reference only saves time:
 * the result is the same bits whenever it was taken. */
#include <math.h>
#include <stdint.h>
#include <stdlib.h>
#include <string.h>

#include "cpu_internal.h"
#include "clothsim/selfcontact.h"

/* Lists of pairs, one per vertex, built a chunk of CHUNK vertices at a time, each chunk into its
 * own buffer, grown as it needs: no pair is left out for want of room, and the lists are the same
 * whatever thread built each chunk. */
#define CHUNK 64

typedef struct sc_lists {
    int64_t **chunk;   /* each chunk's lists, one after another */
    int64_t *cap;      /* the room in each */
    int64_t *first;    /* where each vertex's list starts in its chunk's */
    int32_t *count;    /* and how many pairs it has */
    int32_t nchunks;
} sc_lists;

static int32_t chunks(int32_t n) { return (n + CHUNK - 1) / CHUNK; }

static void lists_free(sc_lists *l, int32_t n)
{
    if (l->chunk)
        for (int32_t c = 0; c < chunks(n); c++) free(l->chunk[c]);
    free(l->chunk);
    free(l->cap);
    free(l->first);
    free(l->count);
}

static int lists_alloc(sc_lists *l, int32_t n)
{
    l->chunk = calloc((size_t)chunks(n) + 1, sizeof(int64_t *));
    l->cap = calloc((size_t)chunks(n) + 1, sizeof(int64_t));
    l->first = malloc(sizeof(int64_t) * ((size_t)n + 1));
    l->count = malloc(sizeof(int32_t) * ((size_t)n + 1));
    l->nchunks = chunks(n);
    return l->chunk && l->cap && l->first && l->count;
}

/* The most keys a chunk's list may hold: CS_SC_LIST_KEYS a vertex on average (the same on every
 * thread count). A cloth finer than its thickness finds thousands of pairs a vertex within a
 * list's radius (a flat 512 x 512 cloth of the default size asked for more than 20 GB and was
 * killed for it); past this the lists are given up as when memory runs out - the bound finds the
 * vertices' pairs in the grid instead, reported as lost - so that what a step holds stays bounded,
 * and cs_scene_memory counts it (cs_sc_work_bytes). */
#define CS_SC_LIST_KEYS 341

static int64_t chunk_most(void) { return (int64_t)CHUNK * CS_SC_LIST_KEYS; }

/* Room for `need` keys in chunk c's list (its first len kept); 0 when there is no memory, or past
 * chunk_most. */
static int grow(sc_lists *l, int32_t c, int64_t len, int64_t need)
{
    if (need <= l->cap[c]) return 1;
    const int64_t most = chunk_most();
    if (need > most) return 0;
    int64_t cap = need > 2 * l->cap[c] ? need : 2 * l->cap[c];
    cap = cap < most ? cap : most;
    int64_t *k = malloc(sizeof(int64_t) * (size_t)cap);
    if (!k) return 0;
    if (len) memcpy(k, l->chunk[c], sizeof(int64_t) * (size_t)len);
    free(l->chunk[c]);
    l->chunk[c] = k;
    l->cap[c] = cap;
    return 1;
}

static const int64_t *list_of(const sc_lists *l, int32_t v) { return l->chunk[v / CHUNK] + l->first[v]; }

/* Makes room for vertex v's list at len of its chunk and calls fill(keys, cap) until the list
 * fits (fill returns how many keys it has, past cap too). Returns the count, or -1 when there is
 * no memory (v then has an empty list). */
#define LIST_FILL(L, C, LEN, V, KEYS, CAP, FILL)                                                          \
    do {                                                                                                  \
        int32_t k_ = -1;                                                                                  \
        while (grow((L), (C), (LEN), (LEN) + 64)) {                                                       \
            const int64_t room_ = (L)->cap[C] - (LEN);                                                    \
            const int32_t CAP = room_ < INT32_MAX ? (int32_t)room_ : INT32_MAX;                           \
            int64_t *const KEYS = (L)->chunk[C] + (LEN);                                                  \
            k_ = (FILL);                                                                                  \
            if (k_ <= CAP) break;                                                                         \
            if (!grow((L), (C), (LEN), (LEN) + k_)) {                                                     \
                k_ = -1;                                                                                  \
                break;                                                                                    \
            }                                                                                             \
        }                                                                                                 \
        (L)->first[V] = (LEN);                                                                            \
        (L)->count[V] = k_ > 0 ? k_ : 0;                                                                  \
        (LEN) += (L)->count[V];                                                                           \
        lost_ += k_ < 0;                                                                                  \
    } while (0)

struct cs_sc_work {
    int32_t n;
    uint32_t mask;
    float *x0, *y0, *z0, *dx, *dy, *dz, *s, *s2, *px, *pv;
    float *xr, *dall;        /* the reference (3 n), the least distance of each vertex's pairs there */
    sc_lists rl;             /* each vertex's repelling pairs, sorted (cs_sc_pairs) */
    sc_lists bl;             /* each vertex's pairs within the bound's radius at the reference */
    sc_lists ol;             /* the pairs each vertex owns there (cs_sc_owned), handed out to bl */
    uint8_t *look;           /* vertices whose pairs the bound looks at this substep */
    int have_ref, lists_whole, bound_whole;
    int64_t pairs;           /* in all the lists */
    float ref_list, ref_bound, ref_thickness;
    uint32_t *key;
    int32_t *start, *ids, *cc;
};

void cs_sc_free(cs_sc_work *w)
{
    if (!w) return;
    lists_free(&w->rl, w->n);
    lists_free(&w->bl, w->n);
    lists_free(&w->ol, w->n);
    free(w->x0);
    free(w->xr);
    free(w->look);
    free(w->dall);
    free(w->dx);
    free(w->s);
    free(w->px);
    free(w->key);
    free(w->start);
    free(w->ids);
    free(w->cc);
    free(w);
}

/* The hash table's size for n vertices (a power of two, at least 2 n). */
static uint32_t table_size(int32_t n)
{
    uint32_t size = 1;
    while (size < 2u * (uint32_t)n) size <<= 1;
    return size;
}

uint64_t cs_sc_work_bytes(int32_t n)
{
    const uint64_t v = (uint64_t)n, c = (uint64_t)chunks(n) + 1, keys = sizeof(int64_t) * (uint64_t)chunk_most();
    /* three sets of lists, each chunk's full, and one chunk's growing into a new buffer */
    const uint64_t lists = 3 * (c * (sizeof(int64_t *) + sizeof(int64_t) + keys) +
                                (v + 1) * (sizeof(int64_t) + sizeof(int32_t))) + keys;
    return sizeof(cs_sc_work) + lists + sizeof(float) * 18 * v + v /* look */ + sizeof(uint32_t) * v +
           sizeof(int32_t) * ((uint64_t)table_size(n) + 1 + 4 * v);
}

static cs_status fit(cs_sc_work **wp, int32_t n)
{
    if (*wp && (*wp)->n == n) return CS_OK;
    cs_sc_free(*wp);
    *wp = NULL;
    cs_sc_work *w = calloc(1, sizeof *w);
    if (!w) return CS_E_NOMEM;
    const uint32_t size = table_size(n);
    w->n = n;
    w->mask = size - 1;
    w->x0 = malloc(sizeof(float) * 3 * (size_t)n);
    w->xr = malloc(sizeof(float) * 3 * (size_t)n);
    const int lists = lists_alloc(&w->rl, n) && lists_alloc(&w->bl, n) && lists_alloc(&w->ol, n);
    w->look = malloc((size_t)n);
    w->dall = malloc(sizeof(float) * (size_t)n);
    w->dx = malloc(sizeof(float) * 3 * (size_t)n);
    w->s = malloc(sizeof(float) * 2 * (size_t)n);
    w->px = malloc(sizeof(float) * 6 * (size_t)n);
    w->key = malloc(sizeof(uint32_t) * (size_t)n);
    w->start = malloc(sizeof(int32_t) * ((size_t)size + 1));
    w->ids = malloc(sizeof(int32_t) * (size_t)n);
    w->cc = malloc(sizeof(int32_t) * 3 * (size_t)n);
    if (!lists || !w->x0 || !w->xr || !w->look || !w->dall || !w->dx || !w->s || !w->px || !w->key || !w->start || !w->ids || !w->cc) {
        cs_sc_free(w);
        return CS_E_NOMEM;
    }
    w->y0 = w->x0 + n, w->z0 = w->y0 + n;
    w->dy = w->dx + n, w->dz = w->dy + n;
    w->s2 = w->s + n;
    w->pv = w->px + 3 * (size_t)n;
    *wp = w;
    return CS_OK;
}

void cs_sc_forget(cs_sc_work *w)
{
    if (w) w->have_ref = 0;
}

cs_status cs_sc_begin(cs_sc_work **wp, const cs_state *s)
{
    if (fit(wp, s->n) != CS_OK) return CS_E_NOMEM;
    cs_sc_work *w = *wp;
    const size_t b = sizeof(float) * (size_t)s->n;
    memcpy(w->x0, s->x, b);
    memcpy(w->y0, s->y, b);
    memcpy(w->z0, s->z, b);
    return CS_OK;
}

/* d = x - x0. Returns how far a vertex moves from the middle of all their displacements (the centre
 * of their box: two vertices move apart by at most twice it, whatever the cloth's motion as a
 * whole), into *C (when not NULL) the same of x0 from the reference, and into *far_most the
 * largest displacement itself (the bound's cuts scale displacements, so it is what bounds two
 * vertices' relative motion once some are cut). Maxima and minima: exact in any order. */
static float displacements(cs_sc_work *w, const cs_state *s, int threads, float *C, float *far_most)
{
    const int ref = C != NULL;
    const int32_t n = s->n;
    float lx = 3e38f, ly = 3e38f, lz = 3e38f, hx = -3e38f, hy = -3e38f, hz = -3e38f;
    float rlx = 3e38f, rly = 3e38f, rlz = 3e38f, rhx = -3e38f, rhy = -3e38f, rhz = -3e38f;
    CS_PARALLEL_FOR(threads, schedule(static) reduction(min : lx, ly, lz, rlx, rly, rlz) reduction(max : hx, hy, hz, rhx, rhy, rhz),
    for (int32_t v = 0; v < n; v++) {
        const float dx = s->x[v] - w->x0[v], dy = s->y[v] - w->y0[v], dz = s->z[v] - w->z0[v];
        w->dx[v] = dx, w->dy[v] = dy, w->dz[v] = dz;
        lx = dx < lx ? dx : lx, ly = dy < ly ? dy : ly, lz = dz < lz ? dz : lz;
        hx = dx > hx ? dx : hx, hy = dy > hy ? dy : hy, hz = dz > hz ? dz : hz;
        if (ref) {
            const float ex = w->x0[v] - w->xr[v], ey = w->y0[v] - w->xr[n + v], ez = w->z0[v] - w->xr[2 * n + v];
            rlx = ex < rlx ? ex : rlx, rly = ey < rly ? ey : rly, rlz = ez < rlz ? ez : rlz;
            rhx = ex > rhx ? ex : rhx, rhy = ey > rhy ? ey : rhy, rhz = ez > rhz ? ez : rhz;
        }
    });
    const float lo[3] = {lx, ly, lz}, hi[3] = {hx, hy, hz}, rlo[3] = {rlx, rly, rlz}, rhi[3] = {rhx, rhy, rhz};
    const cs_vec3 c = cs_sc_centre(lo, hi), cr = cs_sc_centre(rlo, rhi);
    float most = 0.0f, far = 0.0f, abs_most = 0.0f;
    CS_PARALLEL_FOR(threads, schedule(static) reduction(max : most, far, abs_most),
    for (int32_t v = 0; v < n; v++) {
        const cs_vec3 d = cs_v3(w->dx[v], w->dy[v], w->dz[v]);
        const float l = cs_len(cs_sub(d, c)), a = cs_len(d);
        most = l > most ? l : most;
        abs_most = a > abs_most ? a : abs_most;
        if (ref) {
            const cs_vec3 e = cs_v3(w->x0[v] - w->xr[v], w->y0[v] - w->xr[n + v], w->z0[v] - w->xr[2 * n + v]);
            const float f = cs_len(cs_sub(e, cr));
            far = f > far ? f : far;
        }
    });
    if (C) *C = far;
    *far_most = abs_most;
    return n > 0 ? most : 0.0f;
}

/* The longest intact render edge at positions x, y, z (each vertex's three own edges). */
static float longest_edge(const cs_phys *p, const float *x, const float *y, const float *z, const float *L0,
                          int threads)
{
    float most = 0.0f;
    const int32_t nx = p->nx, ny = p->ny;
    CS_PARALLEL_FOR(threads, schedule(static) reduction(max : most),
    for (int32_t v = 0; v < p->n; v++) {
        const int32_t i = v % nx, j = v / nx;
        for (int e = 0; e < 3; e++) {
            if ((e != 1 && i + 1 >= nx) || (e != 0 && j + 1 >= ny) || !cs_sc_edge_on(L0, nx, ny, i, j, e)) continue;
            const int32_t o = e == 0 ? v + 1 : e == 1 ? v + nx : v + nx + 1;
            const float l = cs_len(cs_sub(cs_sc_at(x, y, z, o), cs_sc_at(x, y, z, v)));
            most = l > most ? l : most;
        }
    });
    return most;
}

/* The hash grid of positions x, y, z. */
static cs_sc_grid build_grid(cs_sc_work *w, int32_t n, const float *x, const float *y, const float *z, float cell,
                             int threads)
{
    CS_PARALLEL_FOR(threads, schedule(static),
    for (int32_t v = 0; v < n; v++) w->key[v] = cs_sc_cell_of(cs_sc_at(x, y, z, v), cell, w->mask, w->cc + 3 * (size_t)v););
    cs_sc_sort(n, w->key, w->mask, w->start, w->ids);
    return (cs_sc_grid){w->start, w->ids, w->cc, w->mask, cell};
}

/* How much wider than the pairs that may meet this substep the bound looks when it takes a new
 * reference: more work then, and fewer passes after. */
static float ref_margin(const cs_phys *p)
{
    const float h = p->self_hx < p->self_hy ? p->self_hx : p->self_hy;
    return p->self_thickness > 0.5f * h ? p->self_thickness : 0.5f * h;
}

/* How far beyond the pairs that may touch in a substep the lists look when the bound takes a new
 * reference (they stay whole while the cloth moves less than half of it). */
static float list_margin(const cs_phys *p) { return 6.0f * p->self_thickness; }

static int key_order(const void *a, const void *b)
{
    const int64_t x = *(const int64_t *)a, y = *(const int64_t *)b;
    return (x > y) - (x < y);
}

/* Every vertex's list of the pairs within r at x0 (with repel the repelling ones, cs_sc_pairs',
 * each list sorted by key; else the bound's, cs_sc_limit's) into out: each pair found once, by
 * the vertex that owns it (cs_sc_owned, in parallel), then handed to each of its four vertices in
 * the owners' order (on one thread: a few keys a vertex). Returns 0, or n when there was no memory
 * for them (then every list is empty). */
static int32_t owned_lists(cs_sc_work *w, const cs_phys *p, const float *L0, const cs_sc_grid *G, float r,
                           float reach, int repel, sc_lists *out, int threads)
{
    const int32_t n = p->n;
    int32_t lost_ = 0, *count = out->count;
    CS_PARALLEL_FOR(threads, schedule(dynamic, 1) reduction(+ : lost_),
    for (int32_t c = 0; c < chunks(n); c++) {
        const int32_t end = (c + 1) * CHUNK < n ? (c + 1) * CHUNK : n;
        int64_t len = 0;
        for (int32_t v = c * CHUNK; v < end; v++)
            LIST_FILL(&w->ol, c, len, v, keys, cap,
                      cs_sc_owned(p, G, L0, w->x0, w->y0, w->z0, r, reach, v, repel, keys, cap));
    });
    for (int32_t v = 0; v < n; v++) count[v] = 0;
    if (lost_) return n;
    for (int pass = 0; pass < 2; pass++) { /* count, then (laid out) fill */
        for (int32_t v = 0; v < n; v++)
            for (int32_t k = 0; k < w->ol.count[v]; k++) {
                const int64_t key = list_of(&w->ol, v)[k];
                int32_t q[4], t[3], a[2], b[2];
                if (cs_sc_key_decode(p, key, &q[0], t, a, b))
                    q[0] = a[0], q[1] = a[1], q[2] = b[0], q[3] = b[1];
                else
                    q[1] = t[0], q[2] = t[1], q[3] = t[2];
                for (int e = 0; e < 4; e++) {
                    if (pass) out->chunk[q[e] / CHUNK][out->first[q[e]] + count[q[e]]] = key;
                    count[q[e]]++;
                }
            }
        if (pass) break;
        for (int32_t c = 0; c < chunks(n); c++) {
            const int32_t end = (c + 1) * CHUNK < n ? (c + 1) * CHUNK : n;
            int64_t len = 0;
            for (int32_t v = c * CHUNK; v < end; v++) out->first[v] = len, len += count[v], count[v] = 0;
            if (!grow(out, c, 0, len)) {
                for (int32_t v = 0; v < n; v++) count[v] = 0;
                return n;
            }
        }
    }
    if (repel) { /* each list by key, as cs_sc_pairs keeps it: the repulsion sums in that order */
        CS_PARALLEL_FOR(threads, schedule(dynamic, 64),
        for (int32_t v = 0; v < n; v++)
            if (count[v] > 1) qsort(out->chunk[v / CHUNK] + out->first[v], (size_t)count[v], sizeof(int64_t), key_order););
    }
    return 0;
}

/* Every vertex's list of repelling pairs within rad at x0 (cs_sc_pairs', by owned_lists); returns
 * the vertices left without one (no memory for them). */
static int32_t build_lists(cs_sc_work *w, const cs_phys *p, const float *L0, const cs_sc_grid *G, float reach,
                           float rad, int threads)
{
    const int32_t lost = owned_lists(w, p, L0, G, rad, reach, 1, &w->rl, threads);
    int64_t pairs = 0;
    for (int32_t v = 0; v < p->n; v++) pairs += w->rl.count[v];
    w->pairs = pairs;
    return lost;
}

cs_status cs_sc_end(cs_sc_work *w, const cs_phys *p, cs_state *s, int threads, cs_self_stats *st)
{
    const int32_t n = s->n;
    const float *L0 = s->L0;
    const int fresh = w->have_ref && w->ref_thickness == p->self_thickness;
    float C = 0.0f;
    float Ma; /* the largest displacement */
    float M = displacements(w, s, threads, fresh ? &C : NULL, &Ma);
    if (!(M < 3.0e38f) || !(C < 3.0e38f)) return CS_OK; /* not finite: the caller reports it */
    int32_t lost = 0;
    /* 3. repulsion, from the lists while they are whole and hold every repelling pair that can
     * touch at x1 (self_thickness + 2 (C + M) under the radius they were taken with); else new
     * lists at x0, within Rl (a pair within self_thickness at x1 was within self_thickness + 2 M
     * at x0), and the bound takes a new reference below. Either way the pairs that touch are the
     * same, and each vertex sums them in the same order (by key). */
    const int listed = fresh && w->lists_whole && p->self_thickness + 2.0f * (C + M) < 0.95f * w->ref_list;
    cs_sc_grid G = {0};
    float L = -1.0f, cell = 0.0f; /* the longest edge at x0 once known, the cells of G once built */
    if (!listed) {
        L = longest_edge(p, w->x0, w->y0, w->z0, L0, threads);
        const float Rl = p->self_thickness + 2.0f * M + list_margin(p);
        cell = Rl + 2.0f * L;
        G = build_grid(w, n, w->x0, w->y0, w->z0, cell, threads);
        lost = build_lists(w, p, L0, &G, cell, Rl, threads);
        w->lists_whole = lost == 0;
        w->ref_list = Rl;
    }
    int32_t touching = 0;
    /* look[v] (the bound's, free until then): whether a pair of v's touched, so that only those
     * vertices change (an x of -0 stays -0 elsewhere, whatever list a backend took the pairs from) */
    CS_PARALLEL_FOR(threads, schedule(dynamic, 32) reduction(+ : touching) if (w->pairs > 0),
    for (int32_t v = 0; v < n; v++) {
        w->look[v] = 0;
        if (!w->rl.count[v]) continue;
        cs_vec3 dx = cs_v3(0.0f, 0.0f, 0.0f), dv = dx;
        const int32_t t = cs_sc_repel(p, s->x, s->y, s->z, s->vx, s->vy, s->vz, s->w, w->x0, w->y0, w->z0,
                                      list_of(&w->rl, v), w->rl.count[v], v, &dx, &dv);
        touching += t;
        w->look[v] = t > 0;
        float *px = w->px + 3 * (size_t)v, *pv = w->pv + 3 * (size_t)v;
        px[0] = dx.x, px[1] = dx.y, px[2] = dx.z;
        pv[0] = dv.x, pv[1] = dv.y, pv[2] = dv.z;
    });
    if (touching > 0) {
        CS_PARALLEL_FOR(threads, schedule(static),
        for (int32_t v = 0; v < n; v++) {
            if (!w->look[v]) continue; /* no pair of its touched */
            const float *px = w->px + 3 * (size_t)v, *pv = w->pv + 3 * (size_t)v;
            s->x[v] += px[0], s->y[v] += px[1], s->z[v] += px[2];
            s->vx[v] += pv[0], s->vy[v] += pv[1], s->vz[v] += pv[2];
        });
        M = displacements(w, s, threads, NULL, &Ma);
    }
    /* 4. the bound. A pair is safe by the reference when one of its vertices v is (its least
     * distance there, less 2 C, leaves room for this substep's motion; margin 5 % for rounding):
     * only the other vertices look at their pairs, or all of them when the reference is taken
     * again (when the lists were not whole, or more than an eighth of the cloth would look) */
    const float r = p->self_thickness + 2.0f * Ma / CS_SC_GAMMA;
    int32_t cut = 0, looking = n;
    int full = !listed;
    if (!full) {
        looking = 0;
        CS_PARALLEL_FOR(threads, schedule(static) reduction(+ : looking),
        for (int32_t v = 0; v < n; v++) {
            w->look[v] = !(2.0f * Ma / CS_SC_GAMMA < 0.95f * (w->dall[v] - 2.0f * C));
            looking += w->look[v];
        });
        full = looking > n / 2;
    }
    if (full || looking > 0) {
        const float R = full ? r + ref_margin(p) : r, Rl = p->self_thickness + 2.0f * M + list_margin(p);
        const int new_lists = full && listed; /* the lists move to the new reference too */
        /* a partial pass takes each looking vertex's pairs from its list while the lists hold every
         * pair now within r: one beyond ref_bound at the reference is still beyond ref_bound - 2 C
         * (1 % and 1 um for rounding) */
        const int from_lists = !full && w->bound_whole && w->ref_bound - 2.0f * C >= 1.01f * r + 1e-6f;
        float reach = 0.0f;
        if (!from_lists) {
            if (L < 0.0f) L = longest_edge(p, w->x0, w->y0, w->z0, L0, threads);
            reach = R + 2.0f * L;
            /* cells as large as the farthest candidate either pass looks for (the grid of the
             * lists above serves when it is as large) */
            const float need = (new_lists && Rl > R ? Rl : R) + 2.0f * L;
            if (!(cell >= need)) G = build_grid(w, n, w->x0, w->y0, w->z0, cell = need, threads);
        }
        if (new_lists) {
            const int32_t none = build_lists(w, p, L0, &G, Rl + 2.0f * L, Rl, threads);
            w->lists_whole = none == 0;
            lost += none;
            w->ref_list = Rl;
        }
        for (int32_t v = 0; v < n; v++) w->s[v] = w->s2[v] = 1.0f;
        float *a = w->s, *b = w->s2;
        int changed = Ma > 0.0f || full;
        for (int sweep = 0; changed && sweep <= CS_SC_SWEEPS; sweep++) {
            const int outright = sweep == CS_SC_SWEEPS;
            changed = 0;
            if (full && sweep == 0) { /* every vertex, keeping its pairs within R for later */
                const int32_t lost_ = owned_lists(w, p, L0, &G, R, reach, 0, &w->bl, threads);
                CS_PARALLEL_FOR(threads, schedule(dynamic, 32) reduction(| : changed),
                for (int32_t v = 0; v < n; v++) {
                    if (lost_ == 0) {
                        b[v] = cs_sc_limit_listed(p, w->x0, w->y0, w->z0, w->dx, w->dy, w->dz, a, R, v, outright,
                                                  list_of(&w->bl, v), w->bl.count[v], &w->dall[v]);
                    } else {
                        int32_t nk;
                        b[v] = cs_sc_limit(p, &G, L0, w->x0, w->y0, w->z0, w->dx, w->dy, w->dz, a, R, reach, v,
                                           outright, &w->dall[v], NULL, 0, &nk);
                    }
                    changed |= b[v] != a[v];
                });
                w->bound_whole = lost_ == 0;
                w->ref_bound = R;
                lost += lost_;
            } else {
                const int listed_now = from_lists || (full && w->bound_whole);
                CS_PARALLEL_FOR(threads, schedule(dynamic, 32) reduction(| : changed),
                for (int32_t v = 0; v < n; v++) {
                    if (!full && !w->look[v]) continue;
                    if (listed_now) {
                        b[v] = cs_sc_limit_listed(p, w->x0, w->y0, w->z0, w->dx, w->dy, w->dz, a, R, v, outright,
                                                  list_of(&w->bl, v), w->bl.count[v], NULL);
                    } else {
                        float da;
                        int32_t nk;
                        b[v] = cs_sc_limit(p, &G, L0, w->x0, w->y0, w->z0, w->dx, w->dy, w->dz, a, R, reach, v,
                                           outright, &da, NULL, 0, &nk);
                    }
                    changed |= b[v] != a[v];
                });
            }
            float *t = a;
            a = b, b = t;
        }
        if (full) { /* the new reference */
            memcpy(w->xr, w->x0, sizeof(float) * 3 * (size_t)n);
            w->have_ref = 1;
            w->ref_thickness = p->self_thickness;
        }
        CS_PARALLEL_FOR(threads, schedule(static) reduction(+ : cut),
        for (int32_t v = 0; v < n; v++) {
            const float k = a[v];
            if (!(k < 1.0f)) continue;
            cut++;
            s->x[v] = w->x0[v] + k * w->dx[v];
            s->y[v] = w->y0[v] + k * w->dy[v];
            s->z[v] = w->z0[v] + k * w->dz[v];
            s->vx[v] *= k, s->vy[v] *= k, s->vz[v] *= k;
        });
    }
    if (st) {
        st->passes++;
        st->broad += full;
        st->pairs += full ? w->pairs : 0;
        st->contacts += touching;
        st->cut += cut;
        st->lost += lost;
    }
    return CS_OK;
}
