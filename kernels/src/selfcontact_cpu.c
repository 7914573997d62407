/* selfcontact_cpu.c - self_collision on the CPU backend: the functions of clothsim/selfcontact.h
 * looped over the cloth with OpenMP (kernels/MODEL.md, "Self-collision"). After a substep (a part
 * under implicit_euler) that began at x0 (cs_sc_begin):
 *   1. d = x - x0, a centre c of it (centre_of), each vertex's spread e = |s d - c| (every
 *      scale s 1) and its largest difference g of s d to a grid neighbour (nbr_spread):
 *      a pair's vertices move relative to one another by at most the sum of its two sides'
 *      largest e, and where its owners lie within a few rings of each other by at most the ring
 *      bound (cs_sc_ring_spread, from the largest g about them: windows), so it can touch, or fail
 *      the bound's test, only within its own reach (cs_sc_pair_reach) - small where the cloth
 *      barely moves or moves as one sheet, large only where layers move against each other;
 *   2. the lists: each pair within its reach at x0 found once, by the one of its two owners that
 *      moves more (cs_sc_found: a vertex looks as far as its own spread says, among the quads'
 *      boxes), and handed to its four vertices (find_lists; the repelling ones also into lists
 *      sorted by key). They are kept while they provably still hold every such pair: each
 *      vertex's spread and neighbour difference within those they were found for (plus a slack),
 *      x0 within a drift of where they were found (drift_of), the same thickness, and no spring
 *      torn or state set from outside since (cs_sc_forget);
 *   3. repulsion (cs_sc_repel) per vertex into scratch, then added;
 *   4. the bound (cs_sc_limit_listed) over each vertex's list, in Jacobi sweeps of the scales until
 *      none changes (at most CS_SC_SWEEPS, then one sweep that cuts every pair within the cloth's
 *      largest reach outright, from the grid as the CUDA backend); a cut that spreads a vertex
 *      past its lists has them found again; x = x0 + s d, v = s v. A vertex whose pairs all lay
 *      beyond their reach where the lists were found, less the drift since, is skipped (dminb,
 *      dminr, ehp).
 * Every maximum is exact in any order and every vertex writes only its own entries, so the result
 * does not depend on the thread count. A pair beyond its reach is safe and never touches, so the
 * CUDA backend, which gathers every pair within the cloth's largest reach afresh each pass
 * (cs_sc_pairs, cs_sc_limit), gets the same bits. When there is no memory or room for the lists,
 * the pass gathers as the CUDA backend does (its repulsion on one thread).
 *
 * Under implicit_euler the parts of a substep come from the repelling pairs that may touch in it
 * (cs_sc_part_rate: cs_sc_near_speed over the lists; where they do not hold every such pair, the
 * pairs of the few vertices they no longer serve gathered afresh as well (strays), or with more of
 * those the lists found again at the positions now). */
#include <math.h>
#include <stdatomic.h>
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
    float **dist;      /* where kept (the finders' lists), each key's distance at x0 beside it */
    int64_t *cap;      /* the room in each */
    int64_t *first;    /* where each vertex's list starts in its chunk's */
    int32_t *count;    /* and how many pairs it has */
    int32_t nchunks;
    _Atomic int64_t used; /* the room the chunks hold, all together */
    int64_t budget;       /* the most they may (CS_SC_LIST_KEYS a vertex) */
} sc_lists;

static int32_t chunks(int32_t n) { return (n + CHUNK - 1) / CHUNK; }

static void lists_free(sc_lists *l, int32_t n)
{
    if (l->chunk)
        for (int32_t c = 0; c < chunks(n); c++) free(l->chunk[c]);
    if (l->dist)
        for (int32_t c = 0; c < chunks(n); c++) free(l->dist[c]);
    free(l->chunk);
    free(l->dist);
    free(l->cap);
    free(l->first);
    free(l->count);
}

/* The most keys a set of lists may hold: CS_SC_LIST_KEYS a vertex on average (and at least
 * CS_SC_LIST_FLOOR, list_budget), wherever they lie
 * (where the cloth moves fast, its chunks hold many more; the chunks' buffers grow in parallel
 * against one integer budget, so which chunk passes it first may vary, but past it every list is
 * given up and the pass's bits do not depend on the lists). A cloth finer than its thickness
 * finds thousands of pairs a vertex within a list's radius (a flat 512 x 512 cloth of the
 * default size asked for more than 20 GB and was killed for it); past this the lists are given up
 * as when memory runs out - the bound finds the vertices' pairs in the grid instead, reported as
 * lost - so that what a step holds stays bounded, and cs_scene_memory counts it
 * (cs_sc_work_bytes). */
#define CS_SC_LIST_KEYS 341
/* A cloth of up to 128 x 128 may hold as many as one of that size: the daemon's default 64 x 64
 * scene, a stone landing on it every three seconds, passed 341 keys a vertex as each landed (the
 * stone's cloth swinging by up to 67 mm a substep about the median, a quarter of it by more than
 * 2 cm), and the passes without lists ran it at 0.03 of real time; with four times the keys at
 * 0.32-0.38 (build machine, 2026-12-07). */
#define CS_SC_LIST_FLOOR ((int64_t)128 * 128 * CS_SC_LIST_KEYS)

static int64_t chunk_most(void) { return (int64_t)CHUNK * CS_SC_LIST_KEYS; }

static int64_t list_budget(int32_t n)
{
    const int64_t per = (int64_t)chunks(n) * chunk_most();
    return per > CS_SC_LIST_FLOOR ? per : CS_SC_LIST_FLOOR;
}

static int lists_alloc(sc_lists *l, int32_t n, int dists)
{
    l->chunk = calloc((size_t)chunks(n) + 1, sizeof(int64_t *));
    if (dists && !(l->dist = calloc((size_t)chunks(n) + 1, sizeof(float *)))) return 0;
    l->cap = calloc((size_t)chunks(n) + 1, sizeof(int64_t));
    l->first = malloc(sizeof(int64_t) * ((size_t)n + 1));
    l->count = malloc(sizeof(int32_t) * ((size_t)n + 1));
    l->nchunks = chunks(n);
    atomic_init(&l->used, 0);
    l->budget = list_budget(n);
    return l->chunk && l->cap && l->first && l->count;
}

/* Gives back the room of every chunk when the chunks hold more than a quarter of the budget: a
 * chunk keeps the most it ever needed, so after the cloth moved fast in one place and then in
 * another the budget would run out with most of it idle. Before the chunks fill again. */
static void lists_trim(sc_lists *l)
{
    if (atomic_load(&l->used) <= l->budget / 4) return;
    for (int32_t c = 0; c < l->nchunks; c++) {
        free(l->chunk[c]);
        l->chunk[c] = NULL;
        if (l->dist) free(l->dist[c]), l->dist[c] = NULL;
        l->cap[c] = 0;
    }
    atomic_store(&l->used, 0);
}

/* Takes more keys of room from the lists' budget; 0 (nothing taken) past it. */
static int take_room(sc_lists *l, int64_t more)
{
    if (atomic_fetch_add(&l->used, more) + more <= l->budget) return 1;
    atomic_fetch_sub(&l->used, more);
    return 0;
}

/* Room for `need` keys in chunk c's list (its first len kept); 0 when there is no memory, or past
 * the budget. */
static int grow(sc_lists *l, int32_t c, int64_t len, int64_t need)
{
    if (need <= l->cap[c]) return 1;
    int64_t cap = need > 2 * l->cap[c] ? need : 2 * l->cap[c];
    if (!take_room(l, cap - l->cap[c])) {
        cap = need;
        if (!take_room(l, cap - l->cap[c])) return 0;
    }
    int64_t *k = malloc(sizeof(int64_t) * (size_t)cap);
    if (!k) {
        atomic_fetch_sub(&l->used, cap - l->cap[c]);
        return 0;
    }
    if (l->dist) {
        float *d = malloc(sizeof(float) * (size_t)cap);
        if (!d) {
            free(k);
            atomic_fetch_sub(&l->used, cap - l->cap[c]);
            return 0;
        }
        if (len) memcpy(d, l->dist[c], sizeof(float) * (size_t)len);
        free(l->dist[c]);
        l->dist[c] = d;
    }
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
#define LIST_FILL(L, C, LEN, V, KEYS, DISTS, CAP, FILL)                                                   \
    do {                                                                                                  \
        int32_t k_ = -1;                                                                                  \
        while (grow((L), (C), (LEN), (LEN) + 64)) {                                                       \
            const int64_t room_ = (L)->cap[C] - (LEN);                                                    \
            const int32_t CAP = room_ < INT32_MAX ? (int32_t)room_ : INT32_MAX;                           \
            int64_t *const KEYS = (L)->chunk[C] + (LEN);                                                  \
            float *const DISTS = (L)->dist ? (L)->dist[C] + (LEN) : NULL;                                 \
            (void)DISTS;                                                                                  \
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
    float *e;                /* each vertex's spread now: |s d - c| (cs_sc_pair_reach's spreads) */
    float *eu;               /* the spread the lists were found for (at least e while they serve) */
    float *eh;               /* the largest eu of each vertex and the far ends of its own edges */
    float *dminb, *dminr;    /* the least distance where they were found of each vertex's pairs in bl, rl */
    float *ehp;              /* the largest eu of a vertex of any of each vertex's pairs */
    float *ell;              /* the longest of each vertex's own edges at x0 (cs_sc_own_reach) */
    float *g;                /* each vertex's largest difference of s d to a grid neighbour now */
    float *gu;               /* the g the lists were found for (at least g while they serve) */
    float *gh;               /* the largest gu within each window of rings (CS_SC_WINDOWS n) */
    float ga;                /* what the lists' ring bounds add (cs_sc_ring_spread) */
    float *qb;               /* each vertex's cs_sc_quad_box at x0 (6 n) */
    float *qc;               /* their centres (x, y, z, each n) and the radii about them (n) */
    float *xr;               /* x0 where the lists were found (3 n) */
    int have_ref;            /* whether xr and the lists belong to the state now */
    float ref_thickness;     /* the self_thickness they were found for */
    int64_t bpairs, rpairs;  /* the keys in all of bl and all of rl */
    int32_t rate_finds;      /* the lists cs_sc_part_rate found since the last pass, and their */
    int64_t rate_pairs;      /* repelling pairs (its statistics, which the pass reports) */
    sc_lists rl;             /* each vertex's repelling pairs, sorted by key (the repulsion's order) */
    sc_lists bl;             /* each vertex's pairs, all of them (the bound's) */
    sc_lists ol;             /* the pairs each vertex finds (cs_sc_found), handed out to rl and bl */
    uint8_t *look;           /* vertices one of whose pairs touched */
    uint8_t *intact;         /* cs_sc_intact of each vertex, for cs_sc_found */
    int64_t *fb;             /* the repulsion's keys when there are no lists (one vertex's, growing) */
    int32_t fbcap;
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
    free(w->e);
    free(w->xr);
    free(w->qb);
    free(w->look);
    free(w->fb);
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
    const uint64_t v = (uint64_t)n, c = (uint64_t)chunks(n) + 1, keys = sizeof(int64_t) * (uint64_t)chunk_most(),
                   full = sizeof(int64_t) * (uint64_t)list_budget(n);
    /* three sets of lists, their budget full, and one chunk's growing into a new buffer */
    const uint64_t lists = 3 * (c * (sizeof(int64_t *) + sizeof(int64_t)) + full + keys +
                                (v + 1) * (sizeof(int64_t) + sizeof(int32_t))) + keys +
                           c * sizeof(float *) + (full + keys) / 2 /* the finders' distances */;
    return sizeof(cs_sc_work) + lists + sizeof(float) * (36 + CS_SC_WINDOWS) * v + 2 * v /* look, intact */ + sizeof(uint32_t) * v +
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
    w->e = malloc(sizeof(float) * (9 + CS_SC_WINDOWS) * (size_t)n);
    w->xr = malloc(sizeof(float) * 3 * (size_t)n);
    w->qb = malloc(sizeof(float) * 10 * (size_t)n);
    const int lists = lists_alloc(&w->rl, n, 0) && lists_alloc(&w->bl, n, 0) && lists_alloc(&w->ol, n, 1);
    w->look = malloc(2 * (size_t)n);
    w->dx = malloc(sizeof(float) * 3 * (size_t)n);
    w->s = malloc(sizeof(float) * 2 * (size_t)n);
    w->px = malloc(sizeof(float) * 6 * (size_t)n);
    w->key = malloc(sizeof(uint32_t) * (size_t)n);
    w->start = malloc(sizeof(int32_t) * ((size_t)size + 1));
    w->ids = malloc(sizeof(int32_t) * (size_t)n);
    w->cc = malloc(sizeof(int32_t) * 3 * (size_t)n);
    if (!lists || !w->x0 || !w->e || !w->xr || !w->qb || !w->look || !w->dx || !w->s || !w->px || !w->key || !w->start || !w->ids || !w->cc) {
        cs_sc_free(w);
        return CS_E_NOMEM;
    }
    w->y0 = w->x0 + n, w->z0 = w->y0 + n;
    w->qc = w->qb + 6 * (size_t)n;
    w->eu = w->e + n, w->eh = w->eu + n, w->dminb = w->eh + n, w->dminr = w->dminb + n, w->ehp = w->dminr + n;
    w->ell = w->ehp + n;
    w->g = w->ell + n, w->gu = w->g + n, w->gh = w->gu + n;
    w->intact = w->look + n;
    memset(w->e, 0, sizeof(float) * (9 + CS_SC_WINDOWS) * (size_t)n);
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

static int float_order(const void *a, const void *b)
{
    const float x = *(const float *)a, y = *(const float *)b;
    return (x > y) - (x < y);
}

/* A centre of the vectors (a[.][v] - b[.][v]) (b may be NULL), v in 0 .. n: each axis's median over
 * at most 64 of them, every n / 64-th (a point most of the cloth moves about, which a fast corner
 * does not pull as it pulls the box's centre; the bounds hold about any point, so a sample does). 0
 * where one is not finite. */
static cs_vec3 centre_of(const float *const a[3], const float *const b[3], int32_t n)
{
    float buf[3][64];
    const int32_t step = n / 64 + 1;
    int32_t k = 0;
    for (int32_t v = 0; v < n && k < 64; v += step, k++)
        for (int q = 0; q < 3; q++) {
            const float x = a[q][v] - (b ? b[q][v] : 0.0f);
            if (!(x - x == 0.0f)) return cs_v3(0.0f, 0.0f, 0.0f);
            buf[q][k] = x;
        }
    if (k == 0) return cs_v3(0.0f, 0.0f, 0.0f);
    for (int q = 0; q < 3; q++) qsort(buf[q], (size_t)k, sizeof(float), float_order);
    return cs_v3(buf[0][k / 2], buf[1][k / 2], buf[2][k / 2]);
}

/* Vertex v's spread |s d - c| for its scale s. */
static float spread_of(const cs_sc_work *w, int32_t v, float s, cs_vec3 c)
{
    return cs_len(cs_sub(cs_scale(cs_sc_at(w->dx, w->dy, w->dz, v), s), c));
}

/* Vertex v's largest difference of s a (s NULL: every scale 1) to one of its eight grid neighbours,
 * times k: what bounds its pairs' relative motion along the grid (cs_sc_ring_spread). */
static float nbr_spread(const cs_phys *p, const float *ax, const float *ay, const float *az, const float *s, float k,
                        int32_t v)
{
    const int32_t nx = p->nx, ny = p->ny, i = v % nx, j = v / nx;
    const cs_vec3 a = cs_scale(cs_sc_at(ax, ay, az, v), s ? s[v] : 1.0f);
    float m = 0.0f;
    for (int32_t dj = -1; dj <= 1; dj++)
        for (int32_t di = -1; di <= 1; di++) {
            if ((!di && !dj) || i + di < 0 || i + di >= nx || j + dj < 0 || j + dj >= ny) continue;
            const int32_t u = v + dj * nx + di;
            m = cs_sc_max(m, cs_len(cs_sub(a, cs_scale(cs_sc_at(ax, ay, az, u), s ? s[u] : 1.0f))));
        }
    return k * m;
}

/* The largest of src within r vertices of each along the rows (cols 0) or the columns (1), into
 * dst. */
static void axis_max(const cs_phys *p, const float *src, float *dst, int32_t r, int cols, int threads)
{
    const int32_t nx = p->nx, ny = p->ny, len = cols ? ny : nx, step = cols ? nx : 1;
    CS_PARALLEL_FOR(threads, schedule(static),
    for (int32_t j = 0; j < ny; j++)
        for (int32_t i = 0; i < nx; i++) {
            const int32_t at = cols ? j : i, v = j * nx + i;
            float m = 0.0f;
            for (int32_t q = at - r < 0 ? 0 : at - r; q <= at + r && q < len; q++) m = cs_sc_max(m, src[v + (q - at) * step]);
            dst[v] = m;
        });
}

/* The largest of src within r rings of each vertex (a square's window: by rows, then columns),
 * into dst (tmp: room for n). */
static void window_max(const cs_phys *p, const float *src, float *tmp, float *dst, int32_t r, int threads)
{
    axis_max(p, src, tmp, r, 0, threads);
    axis_max(p, tmp, dst, r, 1, threads);
}

/* gh from gu: each window's from the one before it (g is scratch here; every check computes it
 * afresh). */
static void windows(cs_sc_work *w, const cs_phys *p, int threads)
{
    for (int k = 0; k < CS_SC_WINDOWS; k++)
        window_max(p, k ? w->gh + (size_t)(k - 1) * (size_t)p->n : w->gu, w->g, w->gh + (size_t)k * (size_t)p->n,
                   k ? cs_sc_window(k) - cs_sc_window(k - 1) : cs_sc_window(0), threads);
}

/* How far vertex v's x0 has drifted from where the lists were found, about a centre c of all the
 * drifts. */
static float drift_of(const cs_sc_work *w, int32_t n, int32_t v, cs_vec3 c)
{
    const float *xr = w->xr;
    return cs_len(cs_sub(cs_v3(w->x0[v] - xr[v], w->y0[v] - xr[n + v], w->z0[v] - xr[2 * n + v]), c));
}

/* d = x - x0. Returns the farthest a vertex moves from a centre (centre_of: two vertices move apart
 * by at most twice it, whatever the cloth's motion as a whole), and into *far_most the largest
 * displacement itself (the bound's cuts scale displacements, so it is what bounds two vertices'
 * relative motion once some are cut). Also each vertex's spread e = |d - centre| (every scale 1,
 * as spreads()) and neighbour difference g, into *over whether one passes the eu (or gu) the
 * lists were found for, and with have_ref
 * into *drifted the farthest any vertex's x0 has drifted from where the lists were found (drift_of,
 * about a centre of every drift; else 3e38). Maxima: exact in any order. */
static float displacements(cs_sc_work *w, const cs_phys *p, const cs_state *s, int threads, cs_vec3 *centre,
                           float *far_most, int *over, float *drifted)
{
    const int32_t n = s->n, ref = w->have_ref;
    CS_PARALLEL_FOR(threads, schedule(static),
    for (int32_t v = 0; v < n; v++) {
        w->dx[v] = s->x[v] - w->x0[v], w->dy[v] = s->y[v] - w->y0[v], w->dz[v] = s->z[v] - w->z0[v];
    });
    const float *xr = w->xr, *const d3[3] = {w->dx, w->dy, w->dz}, *const x3[3] = {w->x0, w->y0, w->z0},
                *const r3[3] = {xr, xr + n, xr + 2 * (size_t)n};
    const cs_vec3 c = centre_of(d3, NULL, n), cr = ref ? centre_of(x3, r3, n) : c;
    float most = 0.0f, abs_most = 0.0f, far = 0.0f;
    int past = 0;
    CS_PARALLEL_FOR(threads, schedule(static) reduction(max : most, abs_most, far) reduction(| : past),
    for (int32_t v = 0; v < n; v++) {
        const float a = cs_len(cs_sc_at(w->dx, w->dy, w->dz, v));
        w->e[v] = spread_of(w, v, 1.0f, c);
        w->g[v] = nbr_spread(p, w->dx, w->dy, w->dz, NULL, 1.0f, v);
        most = w->e[v] > most ? w->e[v] : most;
        abs_most = a > abs_most ? a : abs_most;
        past |= !(w->e[v] <= w->eu[v]) || !(w->g[v] <= w->gu[v]);
        if (ref) {
            const float f = drift_of(w, n, v, cr);
            far = f > far ? f : far;
        }
    });
    *centre = c;
    *far_most = abs_most;
    *over = past;
    *drifted = ref ? far : 3e38f;
    return n > 0 ? most : 0.0f;
}

/* Each vertex's spread e = |s d - centre| and neighbour difference g for the scales s; returns
 * whether the lists still serve: every e and g within the eu and gu they were found for. */
static int spreads(cs_sc_work *w, const cs_phys *p, const float *s, cs_vec3 centre, int32_t n, int threads)
{
    int over = 0;
    CS_PARALLEL_FOR(threads, schedule(static) reduction(| : over),
    for (int32_t v = 0; v < n; v++) {
        w->e[v] = spread_of(w, v, s[v], centre);
        w->g[v] = nbr_spread(p, w->dx, w->dy, w->dz, s, 1.0f, v);
        over |= !(w->e[v] <= w->eu[v]) || !(w->g[v] <= w->gu[v]);
    });
    return !over;
}

/* The longest intact render edge at positions x, y, z (each vertex's three own edges,
 * cs_sc_own_reach). */
static float longest_edge(const cs_phys *p, const float *x, const float *y, const float *z, const float *L0,
                          int threads)
{
    float most = 0.0f;
    CS_PARALLEL_FOR(threads, schedule(static) reduction(max : most),
    for (int32_t v = 0; v < p->n; v++) {
        const float l = cs_sc_own_reach(p, L0, x, y, z, v);
        most = l > most ? l : most;
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

static int key_order(const void *a, const void *b)
{
    const int64_t x = *(const int64_t *)a, y = *(const int64_t *)b;
    return (x > y) - (x < y);
}

/* How far beyond its spread now each vertex's lists look: the room the repulsion's pushes and the
 * centre's shift take before the lists must be found again. */
static float slack(const cs_phys *p) { return 0.25f * p->self_thickness; }

/* The neighbour difference g the lists are found for: half again as much as now, and the slack (a
 * cloth that swings changes its differences from one substep to the next: on the bench's 64 x 64
 * cloth with 8 rocks the lists were found 1.53 times a pass with this, 1.79 with g + slack; build
 * machine, 2026-12-07). g_was is its inverse. */
static float g_budget(const cs_phys *p, float g) { return 1.5f * g + slack(p); }
static float g_was(const cs_phys *p, float gu) { return (gu - slack(p)) / 1.5f; }

/* How far x0 may drift (drift_of) before the lists are found again: every reach is twice this
 * wider, as a pair's distance changes by at most the drift of its two sides. More room means
 * fewer finds, but a pass skips a vertex only while its nearest pair lies beyond the thickness
 * and twice the drift: on a flat grid the nearest pairs that share no vertex lie about 0.7 of the
 * spacing apart, so the room keeps the thickness and twice it under that (from a quarter of the
 * thickness to the thickness). */
static float room(const cs_phys *p)
{
    const float h = p->self_hx < p->self_hy ? p->self_hx : p->self_hy, th = p->self_thickness;
    const float q = 0.4f * (0.7f * h - th);
    return q < 0.25f * th ? 0.25f * th : q > th ? th : q;
}

/* Every vertex's lists for spreads up to eu = e + slack and neighbour differences up to
 * g_budget(g) (e, g from spreads()): the pairs each vertex finds (cs_sc_found, in parallel, over a
 * grid of its quads' boxes at x0), handed on one thread, in the finders' order,
 * to each of their four vertices - into bl all of them, into rl those that repel, each rl then
 * sorted by key. Returns the vertices left without lists (n when there
 * was no memory or room for them: then every list is empty and the lists do not serve). */
static int32_t find_lists(cs_sc_work *w, const cs_phys *p, const float *L0, int threads)
{
    const int32_t n = p->n, nx = p->nx, ny = p->ny;
    const float more = slack(p), extra = 2.0f * room(p);
    double sum = 0.0; /* (the cells' size only: what is found does not depend on it) */
    for (int32_t v = 0; v < n; v++) w->eu[v] = w->e[v] + more, w->gu[v] = g_budget(p, w->g[v]), sum += w->eu[v];
    windows(w, p, threads);
    CS_PARALLEL_FOR(threads, schedule(static),
    for (int32_t v = 0; v < n; v++) {
        const int32_t i = v % nx, j = v / nx;
        w->intact[v] = cs_sc_intact(L0, nx, ny, v);
        float m = w->eu[v];
        if (i + 1 < nx) m = cs_sc_max(m, w->eu[v + 1]);
        if (j + 1 < ny) m = cs_sc_max(m, w->eu[v + nx]);
        if (i + 1 < nx && j + 1 < ny) m = cs_sc_max(m, w->eu[v + nx + 1]);
        w->eh[v] = m;
        w->ell[v] = cs_sc_own_reach(p, NULL, w->x0, w->y0, w->z0, v);
        float *b = w->qb + 6 * (size_t)v;
        cs_sc_quad_box(p, w->x0, w->y0, w->z0, v, b);
        const cs_vec3 lo = cs_v3(b[0], b[1], b[2]), hi = cs_v3(b[3], b[4], b[5]);
        const cs_vec3 mid = cs_scale(cs_add(lo, hi), 0.5f);
        w->qc[v] = mid.x, w->qc[n + v] = mid.y, w->qc[2 * (size_t)n + v] = mid.z;
        w->qc[3 * (size_t)n + v] = cs_sc_max(cs_len(cs_sub(hi, mid)), cs_len(cs_sub(mid, lo)));
    });
    float Qm = 0.0f, qsum = 0.0f; /* the largest radius of a quad's box, and the mean (the cells' size only) */
    for (int32_t v = 0; v < n; v++) Qm = cs_sc_max(Qm, w->qc[3 * (size_t)n + v]), qsum += w->qc[3 * (size_t)n + v];
    const float mean = n > 0 ? (float)(sum / n) : 0.0f;
    const float qmean = n > 0 ? qsum / (float)n : 0.0f;
    const cs_sc_grid G = build_grid(w, n, w->qc, w->qc + n, w->qc + 2 * (size_t)n,
                                    cs_sc_pair_reach(p->self_thickness, 2.0f * mean) + extra + Qm + qmean, threads);
    memcpy(w->xr, w->x0, sizeof(float) * 3 * (size_t)n);
    w->ref_thickness = p->self_thickness;
    w->have_ref = 0; /* until they are whole */
    int32_t lost_ = 0;
    lists_trim(&w->ol);
    lists_trim(&w->bl);
    lists_trim(&w->rl);
    CS_PARALLEL_FOR(threads, schedule(dynamic, 1) reduction(+ : lost_),
    for (int32_t c = 0; c < chunks(n); c++) {
        const int32_t end = (c + 1) * CHUNK < n ? (c + 1) * CHUNK : n;
        int64_t len = 0;
        for (int32_t v = c * CHUNK; v < end; v++)
            LIST_FILL(&w->ol, c, len, v, keys, dists, cap,
                      cs_sc_found(p, &G, L0, w->x0, w->y0, w->z0, w->intact, w->eh, w->ell, w->qb, w->qc, Qm, w->gh,
                                  w->ga, extra, v, keys, dists, cap));
    });
    sc_lists *out[2] = {&w->bl, &w->rl};
    for (int l = 0; l < 2; l++)
        for (int32_t v = 0; v < n; v++) out[l]->count[v] = 0;
    if (lost_) return n;
    for (int32_t v = 0; v < n; v++) w->dminb[v] = w->dminr[v] = 3e38f, w->ehp[v] = 0.0f;
    for (int pass = 0; pass < 2; pass++) { /* count (and the least distances), then (laid out) fill */
        for (int32_t v = 0; v < n; v++)
            for (int32_t k = 0; k < w->ol.count[v]; k++) {
                const int64_t key = list_of(&w->ol, v)[k];
                const float d = w->ol.dist[v / CHUNK][w->ol.first[v] + k];
                int32_t q[4], t[3], ea[2], eb[2];
                int repels;
                if (cs_sc_key_decode(p, key, &q[0], t, ea, eb)) {
                    q[0] = ea[0], q[1] = ea[1], q[2] = eb[0], q[3] = eb[1];
                    repels = cs_sc_ee_repels(p, ea, eb);
                } else {
                    q[1] = t[0], q[2] = t[1], q[3] = t[2];
                    repels = cs_sc_repels(p, q[0], t);
                }
                float eq = 0.0f;
                for (int e = 0; e < 4 && !pass; e++) eq = cs_sc_max(eq, w->eu[q[e]]);
                for (int e = 0; e < 4 && !pass; e++) w->ehp[q[e]] = cs_sc_max(w->ehp[q[e]], eq);
                for (int l = 0; l < 1 + repels; l++)
                    for (int e = 0; e < 4; e++) {
                        sc_lists *o = out[l];
                        if (pass) o->chunk[q[e] / CHUNK][o->first[q[e]] + o->count[q[e]]] = key;
                        o->count[q[e]]++;
                        float *m = l ? w->dminr : w->dminb;
                        m[q[e]] = d < m[q[e]] ? d : m[q[e]];
                    }
            }
        if (pass) break;
        for (int l = 0; l < 2; l++)
            for (int32_t c = 0; c < chunks(n); c++) {
                const int32_t end = (c + 1) * CHUNK < n ? (c + 1) * CHUNK : n;
                int64_t len = 0;
                for (int32_t v = c * CHUNK; v < end; v++) out[l]->first[v] = len, len += out[l]->count[v], out[l]->count[v] = 0;
                if (!grow(out[l], c, 0, len)) {
                    for (int m = 0; m < 2; m++)
                        for (int32_t v = 0; v < n; v++) out[m]->count[v] = 0;
                    return n;
                }
            }
    }
    int32_t *count = w->rl.count;
    w->bpairs = w->rpairs = 0;
    for (int32_t v = 0; v < n; v++) w->bpairs += w->bl.count[v], w->rpairs += count[v];
    CS_PARALLEL_FOR(threads, schedule(dynamic, 64),
    for (int32_t v = 0; v < n; v++)
        if (count[v] > 1) qsort(w->rl.chunk[v / CHUNK] + w->rl.first[v], (size_t)count[v], sizeof(int64_t), key_order););
    w->have_ref = 1;
    return 0;
}

/* Vertex v's repelling pairs found afresh (cs_sc_pairs, sorted) into w->fb, for a pass without
 * lists; returns how many, or -1 when there is no memory for them. */
static int32_t repel_keys(cs_sc_work *w, const cs_phys *p, const float *L0, const cs_sc_grid *G, float rad,
                          int32_t v)
{
    for (;;) {
        const int32_t k = cs_sc_pairs(p, G, L0, w->x0, w->y0, w->z0, G->cell, rad, v, w->fb, w->fbcap);
        if (k <= w->fbcap) return k;
        int64_t *b = realloc(w->fb, sizeof(int64_t) * (size_t)k);
        if (!b) return -1;
        w->fb = b, w->fbcap = k;
    }
}

/* Vertex v's repulsion from its pairs keys[0..k) (cs_sc_repel) into the scratch px, pv, and look[v]
 * whether one touched; returns the pairs that touch. */
static int32_t repel(cs_sc_work *w, const cs_phys *p, const cs_state *s, int32_t v, const int64_t *keys, int32_t k)
{
    cs_vec3 dx = cs_v3(0.0f, 0.0f, 0.0f), dv = dx;
    const int32_t t = cs_sc_repel(p, s->x, s->y, s->z, s->vx, s->vy, s->vz, s->w, w->x0, w->y0, w->z0, keys, k, v,
                                  &dx, &dv);
    w->look[v] = t > 0;
    float *px = w->px + 3 * (size_t)v, *pv = w->pv + 3 * (size_t)v;
    px[0] = dx.x, px[1] = dx.y, px[2] = dx.z;
    pv[0] = dv.x, pv[1] = dv.y, pv[2] = dv.z;
    return t;
}

/* The vertices the lists no longer serve for cs_sc_part_rate: a spread e past the eu they were found
 * for, or a drift past the room (drift_of, about a centre of every drift). Marks them 1 in w->s
 * (0 elsewhere; the pass sets its scales afresh) and returns how many there are. A pair whose four
 * vertices are all served lies in the lists (each of its sides spreads within its eh and drifts
 * within the room), so only the pairs of these can be missing. */
static int32_t strays(cs_sc_work *w, const cs_phys *p, int32_t n, int threads)
{
    const float *xr = w->xr, *const x3[3] = {w->x0, w->y0, w->z0}, *const r3[3] = {xr, xr + n, xr + 2 * (size_t)n};
    const cs_vec3 c = centre_of(x3, r3, n);
    const float rm = room(p);
    int32_t count = 0;
    CS_PARALLEL_FOR(threads, schedule(static) reduction(+ : count),
    for (int32_t v = 0; v < n; v++) {
        const int bad = !(w->e[v] <= w->eu[v]) || !(drift_of(w, n, v, c) <= rm);
        w->s[v] = bad ? 1.0f : 0.0f;
        count += bad;
    });
    return count;
}

/* At most this many vertices (of n) the lists no longer serve have their pairs gathered afresh for
 * cs_sc_part_rate, rather than the lists found again: a stone's landing spreads the whole cloth
 * past them, but under a resting stone a few vertices gain speed every substep (kernels/MODEL.md,
 * "Self-collision"). */
static int32_t few(int32_t n) { return n / 16; }

cs_status cs_sc_part_rate(cs_sc_work **wp, const cs_phys *p, const cs_state *s, float h, int threads, float *rate)
{
    if (cs_sc_begin(wp, s) != CS_OK) return CS_E_NOMEM; /* x0: the positions now */
    cs_sc_work *w = *wp;
    const int32_t n = s->n;
    const float th = p->self_thickness;
    const float *const v3[3] = {s->vx, s->vy, s->vz};
    const cs_vec3 cv = centre_of(v3, NULL, n);
    /* the lists hold every repelling pair that may touch within h while each vertex's reach in h
     * lies within the spread they were found for (as for a pass: cs_sc_end); else the pairs of the
     * few vertices past it (strays) are gathered afresh beside them, or with more the lists are
     * found again for it here */
    float Vm = 0.0f;
    int gover = 0; /* a neighbour difference past the one the lists were found for */
    CS_PARALLEL_FOR(threads, schedule(static) reduction(max : Vm) reduction(| : gover),
    for (int32_t v = 0; v < n; v++) {
        const float V = cs_sc_speed(p, s->vx, s->vy, s->vz, v, cv, h);
        w->e[v] = h * V;
        w->g[v] = nbr_spread(p, s->vx, s->vy, s->vz, NULL, h, v);
        gover |= !(w->g[v] <= w->gu[v]);
        Vm = V > Vm ? V : Vm;
    });
    const float ga = cs_len(p->gravity) * h * h; /* (cs_sc_speed's gravity, on the ring bound) */
    *rate = 0.0f;
    if (!(Vm < 3.0e38f)) return CS_OK; /* not finite: the step reports it */
    const float *L0 = s->L0;
    /* (a neighbour difference past the lists' widens the ring bound of every pair about it: they are
     * found again) */
    const int kept = w->have_ref && w->ref_thickness == th && !gover && ga <= w->ga;
    int32_t stray = kept ? strays(w, p, n, threads) : 0; /* vertices the lists do not serve */
    int listed = kept && stray <= few(n);
    if (!listed) {
        stray = 0;
        w->ga = ga;
        listed = find_lists(w, p, L0, threads) == 0;
        w->rate_finds++, w->rate_pairs += listed ? w->rpairs : 0;
    }
    float most = 0.0f;
    if (listed) {
        CS_PARALLEL_FOR(threads, schedule(dynamic, 64) reduction(max : most),
        for (int32_t v = 0; v < n; v++) {
            if (!w->rl.count[v]) continue;
            const float q = cs_sc_near_speed(p, s->x, s->y, s->z, s->vx, s->vy, s->vz, h, list_of(&w->rl, v),
                                             w->rl.count[v]);
            most = q > most ? q : most;
        });
    }
    if (!listed || stray) { /* one thread, as the passes without lists: every repelling pair (with lists,
                              * the strays') within the reach of the fastest */
        const float rad = cs_sc_near_reach(th, h, Vm);
        const float L = longest_edge(p, w->x0, w->y0, w->z0, L0, threads);
        const cs_sc_grid G = build_grid(w, n, w->x0, w->y0, w->z0, rad + 2.0f * L, threads);
        for (int32_t v = 0; v < n; v++) {
            if (listed && w->s[v] == 0.0f) continue;
            const int32_t k = repel_keys(w, p, L0, &G, rad, v);
            const float q = k > 0 ? cs_sc_near_speed(p, s->x, s->y, s->z, s->vx, s->vy, s->vz, h, w->fb, k)
                                  : k < 0 ? Vm : 0.0f; /* (no memory: as fast as the fastest) */
            most = q > most ? q : most;
        }
    }
    *rate = most / (CS_SC_PART * th);
    return CS_OK;
}

cs_status cs_sc_end(cs_sc_work *w, const cs_phys *p, cs_state *s, int threads, cs_self_stats *st)
{
    const int32_t n = s->n;
    const float *L0 = s->L0, th = p->self_thickness;
    cs_vec3 c;
    float Ma, drifted; /* the largest displacement; the farthest drift (displacements) */
    int over;
    float M = displacements(w, p, s, threads, &c, &Ma, &over, &drifted);
    if (!(M < 3.0e38f)) return CS_OK; /* not finite: the caller reports it */
    float L = -1.0f; /* the longest edge at x0, once needed */
#define LONGEST() (L < 0.0f ? (L = longest_edge(p, w->x0, w->y0, w->z0, L0, threads)) : L)
    /* 1. the lists, found again unless they serve: the spreads now (every scale 1) within theirs, x0
     * within their room of where they were found, the same thickness, and the same state (the
     * backend forgets them when the state is set from outside or a spring tore: a torn triangle
     * or edge leaves the pairs) */
    int32_t lost = 0, finds = 0;
    int listed = !over && w->have_ref && w->ref_thickness == th && drifted <= room(p);
    if (!listed) {
        lost = find_lists(w, p, L0, threads), finds = 1;
        listed = lost == 0;
        drifted = 0.0f; /* (found at x0) */
    }
    int32_t touching = 0, cut = 0;
    float *a = w->s;
    if (listed && w->bpairs == 0) goto done; /* no pair within its reach: nothing touches or is cut */
    for (int32_t v = 0; v < n; v++) w->s[v] = w->s2[v] = 1.0f;
    /* 2. repulsion: a pair that touches at x1 was within self_thickness + its spread at x0, so the
     * lists hold it (or, without them, cs_sc_pairs within self_thickness + 2 M finds it); each vertex
     * sums its pairs in the order of their keys. A vertex whose pairs all lay further than
     * self_thickness and twice the largest spread of a vertex of theirs (ehp) where the lists were
     * found, less twice the drift since, has none that touches. */
    if (listed && w->rpairs > 0) {
        CS_PARALLEL_FOR(threads, schedule(dynamic, 32) reduction(+ : touching),
        for (int32_t v = 0; v < n; v++) {
            w->look[v] = 0;
            if (!w->rl.count[v] || !(w->dminr[v] - 2.0f * drifted < th + 2.02f * w->ehp[v] + 1e-6f)) continue;
            touching += repel(w, p, s, v, list_of(&w->rl, v), w->rl.count[v]);
        });
    } else if (!listed) { /* one thread: a rare path (no memory, or lists past their cap) */
        const float Rl = th + 2.0f * M;
        const cs_sc_grid G = build_grid(w, n, w->x0, w->y0, w->z0, Rl + 2.0f * LONGEST(), threads);
        for (int32_t v = 0; v < n; v++) {
            w->look[v] = 0;
            const int32_t k = repel_keys(w, p, L0, &G, Rl, v);
            if (k < 0) {
                lost++;
                continue;
            }
            touching += repel(w, p, s, v, w->fb, k);
        }
    }
    if (touching > 0) {
        /* (look[v]: only the vertices a touching pair moved change - an x of -0 stays -0 elsewhere,
         * whatever list a backend took the pairs from) */
        CS_PARALLEL_FOR(threads, schedule(static),
        for (int32_t v = 0; v < n; v++) {
            if (!w->look[v]) continue;
            const float *px = w->px + 3 * (size_t)v, *pv = w->pv + 3 * (size_t)v;
            s->x[v] += px[0], s->y[v] += px[1], s->z[v] += px[2];
            s->vx[v] += pv[0], s->vy[v] += pv[1], s->vz[v] += pv[2];
        });
        M = displacements(w, p, s, threads, &c, &Ma, &over, &drifted);
        if (listed && over) {
            lost += find_lists(w, p, L0, threads), finds++;
            listed = lost == 0;
            drifted = 0.0f;
        }
    }
    /* 3. the bound: Jacobi sweeps of each vertex's pairs within r and their own reach at x0, from
     * its lists while they serve the sweep's scales (found again when a cut spreads a vertex past
     * them), else from the grid within r */
    const float r = th + 2.0f * Ma / CS_SC_GAMMA;
    cs_sc_grid G = {0};
    if (!listed) G = build_grid(w, n, w->x0, w->y0, w->z0, r + 2.0f * LONGEST(), threads);
    float *b = w->s2;
    int changed = Ma > 0.0f;
    for (int sweep = 0; changed && sweep <= CS_SC_SWEEPS; sweep++) {
        /* the sweep that cuts outright cuts every pair within r: from the grid, as the CUDA backend */
        const int outright = sweep == CS_SC_SWEEPS;
        if (outright && listed) {
            listed = 0;
            G = build_grid(w, n, w->x0, w->y0, w->z0, r + 2.0f * LONGEST(), threads);
        }
        changed = 0;
        /* a vertex whose pairs all lay beyond the reach of twice the largest spread of a vertex of
         * theirs (ehp) where the lists were found, less twice the drift since, has none that can
         * be unsafe: nothing cuts it */
        CS_PARALLEL_FOR(threads, schedule(dynamic, 32) reduction(| : changed),
        for (int32_t v = 0; v < n; v++) {
            if (listed && !(w->dminb[v] - 2.0f * drifted < cs_sc_pair_reach(th, 2.0f * w->ehp[v]) + 1e-6f)) {
                b[v] = a[v];
            } else if (listed) {
                b[v] = cs_sc_limit_listed(p, w->x0, w->y0, w->z0, w->dx, w->dy, w->dz, a, r, v, outright,
                                          list_of(&w->bl, v), w->bl.count[v], NULL);
            } else {
                float da;
                int32_t nk;
                b[v] = cs_sc_limit(p, &G, L0, w->x0, w->y0, w->z0, w->dx, w->dy, w->dz, a, r, r + 2.0f * L, v,
                                   outright, &da, NULL, 0, &nk);
            }
            changed |= b[v] != a[v];
        });
        float *t = a;
        a = b, b = t;
        if (changed && listed && !spreads(w, p, a, c, n, threads)) {
            for (int32_t v = 0; v < n; v++)
                w->e[v] = cs_sc_max(w->e[v], w->eu[v] - slack(p)), w->g[v] = cs_sc_max(w->g[v], g_was(p, w->gu[v]));
            lost += find_lists(w, p, L0, threads), finds++;
            listed = lost == 0;
            drifted = 0.0f;
            if (!listed) G = build_grid(w, n, w->x0, w->y0, w->z0, r + 2.0f * LONGEST(), threads);
        }
    }
#undef LONGEST
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
done:
    if (st) {
        st->passes++;
        st->broad += finds + w->rate_finds; /* (cs_sc_part_rate's too) */
        st->pairs += (finds && listed ? w->rpairs : 0) + w->rate_pairs;
        st->contacts += touching;
        st->cut += cut;
        st->lost += lost;
    }
    w->rate_finds = 0, w->rate_pairs = 0;
    return CS_OK;
}
