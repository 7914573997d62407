/* test_selfcontact.c - the self-collision bound's test of a pair (cs_sc_safe in
 * clothsim/selfcontact.h) against geometry written here: whenever it calls a pair's motion safe,
 * the pair's vertex and triangle (or two edges), moved along their straight paths, never meet. */
#include "clothsim/selfcontact.h"
#include "testkit.h"
#include "tk_geom.h"

/* The distance between segments a0 a1 and b0 b1: where they cross in their common plane 0, else
 * the least of the four end-to-segment distances. */
static double segment_segment(d3 a0, d3 a1, d3 b0, d3 b1)
{
    const d3 u = sub3(a1, a0), v = sub3(b1, b0), w = sub3(b0, a0), n = cross3(u, v);
    const double nn = dot3(n, n);
    if (nn > 1e-30) { /* the closest points of the two lines, if both lie within the segments */
        const double s = dot3(cross3(w, v), n) / nn, t = dot3(cross3(w, u), n) / nn;
        if (s >= 0.0 && s <= 1.0 && t >= 0.0 && t <= 1.0) return len3(sub3(add3(a0, mul3(u, s)), add3(b0, mul3(v, t))));
    }
    const double e[4] = {point_segment(a0, b0, b1), point_segment(a1, b0, b1), point_segment(b0, a0, a1),
                         point_segment(b1, a0, a1)};
    double best = e[0];
    for (int k = 1; k < 4; k++) best = e[k] < best ? e[k] : best;
    return best;
}

/* A pair: its four vertices (a point and a triangle, na 1; or two edges, na 2) at x0, and their
 * displacements. */
typedef struct {
    int na;
    d3 x[4], d[4];
} pair;

static d3 at(const pair *P, int k, double t) { return add3(P->x[k], mul3(P->d[k], t)); }

static double distance(const pair *P, double t)
{
    if (P->na == 1) return point_triangle(at(P, 0, t), at(P, 1, t), at(P, 2, t), at(P, 3, t));
    return segment_segment(at(P, 0, t), at(P, 1, t), at(P, 2, t), at(P, 3, t));
}

/* Whether the pair meets on its way (the test's own account): sampled finely, its distance comes
 * within what its fastest relative motion covers in one sample, or the point passes through the
 * triangle's plane (the edges through each other's) between two samples where it is that near. */
static int meets(const pair *P)
{
    double fast = 0.0;
    for (int i = 0; i < P->na; i++)
        for (int k = P->na; k < 4; k++) {
            const double r = len3(sub3(P->d[i], P->d[k]));
            fast = r > fast ? r : fast;
        }
    const int N = 20000;
    const double near = 2.0 * fast / N + 1e-12;
    double f_last = 0.0;
    for (int s = 0; s <= N; s++) {
        const double t = (double)s / N;
        const d3 q0 = at(P, 0, t), q1 = at(P, 1, t), q2 = at(P, 2, t), q3 = at(P, 3, t);
        const double f = P->na == 1 ? dot3(sub3(q0, q1), cross3(sub3(q2, q1), sub3(q3, q1)))
                                    : dot3(sub3(q2, q0), cross3(sub3(q1, q0), sub3(q3, q2)));
        const double d = distance(P, t);
        if (d < near) return 1;
        if (s > 0 && (f < 0.0) != (f_last < 0.0) && d < 4.0 * near) return 1;
        f_last = f;
    }
    return 0;
}

/* cs_sc_safe on the pair (as floats) for the scales s; *lip set when the relative-motion test
 * alone would have called it safe. */
static int safe_scaled(const pair *P, const float s[4], int *lip)
{
    float x[3][4], dd[3][4];
    for (int k = 0; k < 4; k++) {
        x[0][k] = (float)P->x[k].x, x[1][k] = (float)P->x[k].y, x[2][k] = (float)P->x[k].z;
        dd[0][k] = (float)P->d[k].x, dd[1][k] = (float)P->d[k].y, dd[2][k] = (float)P->d[k].z;
    }
    const cs_vec3 v[4] = {cs_v3(x[0][0], x[1][0], x[2][0]), cs_v3(x[0][1], x[1][1], x[2][1]),
                          cs_v3(x[0][2], x[1][2], x[2][2]), cs_v3(x[0][3], x[1][3], x[2][3])};
    const int32_t q[4] = {0, 1, 2, 3};
    float dist;
    cs_vec3 dir;
    if (P->na == 1) {
        float bw[3];
        dist = cs_sc_point_tri(v[0], v[1], v[2], v[3], bw);
        dir = cs_sub(v[0], cs_add(cs_add(cs_scale(v[1], bw[0]), cs_scale(v[2], bw[1])), cs_scale(v[3], bw[2])));
    } else {
        float ps, pt;
        dist = cs_sc_seg_seg_st(v[0], v[1], v[2], v[3], &ps, &pt);
        dir = cs_sub(cs_add(v[0], cs_scale(cs_sub(v[1], v[0]), ps)), cs_add(v[2], cs_scale(cs_sub(v[3], v[2]), pt)));
    }
    const float m = cs_sc_round_margin(q, x[0], x[1], x[2], dd[0], dd[1], dd[2], s, 0.005f);
    *lip = cs_sc_relative(q, P->na, q + P->na, 4 - P->na, dd[0], dd[1], dd[2], s) < CS_SC_GAMMA * dist - m;
    return cs_sc_safe(q, P->na, dist, m, dir, x[0], x[1], x[2], dd[0], dd[1], dd[2], s);
}

/* The same, every scale 1. */
static int safe(const pair *P, int *lip)
{
    const float s[4] = {1.0f, 1.0f, 1.0f, 1.0f};
    return safe_scaled(P, s, lip);
}

/* Layers pressed together: a point a micrometre over a triangle, far nearer than the relative
 * motion allows, is safe while it slides and lifts away (one corner even dropping), not while it
 * goes through. The same for two parallel edges half a millimetre apart. */
static void test_written_cases(void **unused)
{
    (void)unused;
    int lip;
    const d3 o = {0.5, 0.25, 0.01};
    pair up = {1, {add3(o, (d3){0.003, 0.003, 1e-6}), o, add3(o, (d3){0.01, 0, 0}), add3(o, (d3){0, 0.01, 0})},
               {{8e-3, 0, 2e-3}, {0, 0, 0}, {0, 0, -3e-3}, {0, 0, 0}}};
    assert_true(safe(&up, &lip));
    assert_false(lip);
    assert_false(meets(&up));
    pair down = up;
    down.d[0] = (d3){1e-3, 0, -2e-3};
    assert_false(safe(&down, &lip));
    assert_true(meets(&down));
    pair edges = {2, {{0.5, 0.2, 0.0105}, {0.51, 0.2, 0.0105}, {0.5, 0.2, 0.01}, {0.51, 0.2, 0.01}},
                  {{0.01, 0, 1e-3}, {0.01, 0, 1e-3}, {0, 0, 0}, {0, 0, 0}}};
    assert_true(safe(&edges, &lip));
    assert_false(lip);
    assert_false(meets(&edges));
    pair through = edges; /* the upper edge turned across the lower and pushed through it */
    through.x[0] = (d3){0.505, 0.195, 0.0105}, through.x[1] = (d3){0.505, 0.205, 0.0105};
    through.d[0] = through.d[1] = (d3){0, 0, -1e-3};
    assert_false(safe(&through, &lip));
    assert_true(meets(&through));
}

/* splitmix64 */
static uint64_t next_u64(uint64_t *s)
{
    uint64_t z = (*s += 0x9e3779b97f4a7c15ull);
    z = (z ^ (z >> 30)) * 0xbf58476d1ce4e5b9ull;
    z = (z ^ (z >> 27)) * 0x94d049bb133111ebull;
    return z ^ (z >> 31);
}

static double uniform(uint64_t *s) { return (double)(next_u64(s) >> 11) / 9007199254740992.0; }

/* Random pairs near a point of a cloth 1 m from the origin: a 1 cm triangle (or edge) and a
 * point (or edge) over it at 1 um to 5 mm, each vertex moving up to 10 mm, half the time the
 * upper side pushed down. No pair called safe meets; many that meet are found (so the draw does
 * test something), and many pairs that the relative motion alone would have cut are called safe. */
static void test_random_pairs(void **unused)
{
    (void)unused;
    uint64_t seed = 2026;
    const int cases = SANITIZED ? 300 : 3000;
    int met = 0, kept = 0, by_direction = 0;
    for (int c = 0; c < cases; c++) {
        pair P;
        P.na = 1 + (c & 1);
        const d3 o = {0.6 + 0.4 * uniform(&seed), 0.3 + 0.4 * uniform(&seed), 0.01};
        const double h = pow(10.0, -6.0 + 3.7 * uniform(&seed)), L = 0.01;
        if (P.na == 1) {
            P.x[1] = o;
            P.x[2] = add3(o, (d3){L, 0.002 * uniform(&seed), 0});
            P.x[3] = add3(o, (d3){0.003 * uniform(&seed), L, 0});
            P.x[0] = add3(o, (d3){L * 0.3 * uniform(&seed), L * 0.3 * uniform(&seed), h});
        } else {
            const double a = 3.14159 * uniform(&seed);
            P.x[2] = o, P.x[3] = add3(o, (d3){L, 0, 0});
            P.x[0] = add3(o, (d3){L * 0.5 - 0.5 * L * cos(a), -0.5 * L * sin(a), h});
            P.x[1] = add3(o, (d3){L * 0.5 + 0.5 * L * cos(a), 0.5 * L * sin(a), h});
        }
        const int push = next_u64(&seed) & 1;
        for (int k = 0; k < 4; k++) {
            P.d[k] = (d3){0.01 * (uniform(&seed) - 0.5), 0.01 * (uniform(&seed) - 0.5), 0.004 * (uniform(&seed) - 0.5)};
            if (push && k < P.na) P.d[k].z -= h + 0.003 * uniform(&seed);
        }
        int lip;
        const int s = safe(&P, &lip), m = meets(&P);
        met += m;
        kept += s;
        by_direction += s && !lip;
        if (s && m) fail_msg("case %d (na %d, height %.3g m): called safe, and it meets", c, P.na, h);
    }
    print_message("%d random pairs: %d meet, %d called safe (%d of them by a direction, not by the relative motion)\n",
                  cases, met, kept, by_direction);
    assert_true(met > cases / 10);
    assert_true(by_direction > cases / 10);
}

/* Pairs a few ulps apart, as the product moves them: x0 in float, each vertex ending at
 * fl(x0 + d) (every scale 1). The test's own account of whether they meet runs on those float
 * ends, not on x0 + d exact: a point 0.01 to 3 um from a tilted triangle (or an edge from an
 * edge) 1 m from the origin, every vertex moving by up to the distance in any direction (the
 * relative motion under 0.9 of the distance half the time). No pair called safe meets; with no
 * room for rounding in the first test, some did (a point a quarter of a micrometre over a face
 * went through, its relative motion 0.86 of the distance). */
static void test_rounded_ends(void **unused)
{
    (void)unused;
    uint64_t seed = 77;
    const int cases = SANITIZED ? 1000 : 8000;
    int met = 0, kept = 0;
    for (int c = 0; c < cases; c++) {
        pair P;
        P.na = 1 + (c & 1);
        const d3 o = {0.9 + 0.2 * uniform(&seed), 0.9 + 0.2 * uniform(&seed), 0.9 + 0.2 * uniform(&seed)};
        /* a tilted frame: e1, e2 in the face, nn its normal */
        const d3 a = {uniform(&seed) - 0.5, uniform(&seed) - 0.5, uniform(&seed) - 0.5};
        const d3 b = {uniform(&seed) - 0.5, uniform(&seed) - 0.5, uniform(&seed) - 0.5};
        const d3 nn = mul3(cross3(a, b), 1.0 / len3(cross3(a, b)));
        const d3 e1 = mul3(a, 1.0 / len3(a)), e2 = cross3(nn, e1);
        const double h = pow(10.0, -8.0 + 3.0 * uniform(&seed)), L = 0.01;
        if (P.na == 1) {
            P.x[1] = o, P.x[2] = add3(o, mul3(e1, L)), P.x[3] = add3(o, mul3(e2, L));
            P.x[0] = add3(add3(o, add3(mul3(e1, 0.3 * L * uniform(&seed)), mul3(e2, 0.3 * L * uniform(&seed)))),
                          mul3(nn, h));
        } else {
            const double t = 3.14159 * uniform(&seed);
            const d3 m = add3(o, mul3(e1, 0.5 * L)), u = add3(mul3(e1, 0.5 * L * cos(t)), mul3(e2, 0.5 * L * sin(t)));
            P.x[2] = o, P.x[3] = add3(o, mul3(e1, L));
            P.x[0] = add3(sub3(m, u), mul3(nn, h)), P.x[1] = add3(add3(m, u), mul3(nn, h));
        }
        /* what the product sees (x0 and d in float, a scale from a cut half the time) and where
         * its vertices end: x0 + fl(s d), rounded */
        float s[4];
        pair R = P;
        for (int k = 0; k < 4; k++) {
            const d3 d = {h * (uniform(&seed) - 0.5), h * (uniform(&seed) - 0.5), h * (uniform(&seed) - 0.5)};
            const double sign = k < P.na ? -1.0 : 1.0;
            P.d[k] = add3(d, mul3(nn, sign * 0.45 * h * uniform(&seed)));
            s[k] = (next_u64(&seed) & 1) ? 1.0f : (float)(0.2 + 0.8 * uniform(&seed));
            const float x0[3] = {(float)P.x[k].x, (float)P.x[k].y, (float)P.x[k].z};
            const float d0[3] = {(float)P.d[k].x, (float)P.d[k].y, (float)P.d[k].z};
            float end[3];
            for (int q = 0; q < 3; q++) {
                const float sd = s[k] * d0[q];
                end[q] = x0[q] + sd;
            }
            R.x[k] = (d3){x0[0], x0[1], x0[2]};
            R.d[k] = (d3){d0[0], d0[1], d0[2]};
            P.x[k] = R.x[k];
            P.d[k] = sub3((d3){end[0], end[1], end[2]}, R.x[k]); /* the path the vertex takes */
        }
        int lip;
        const int sf = safe_scaled(&R, s, &lip);
        R = P;
        const int m = meets(&R);
        met += m, kept += sf;
        if (sf && m) fail_msg("case %d (na %d, %.3g m apart): called safe, and its float ends meet", c, P.na, h);
    }
    print_message("%d pairs a few ulps apart: %d meet, %d called safe\n", cases, met, kept);
    assert_true(met > cases / 40);
    assert_true(kept > cases / 20);
}

/* The repulsion of one vertex-triangle pair (cs_sc_pair_push), all four vertices of one mass: a
 * point 1 mm over a triangle pushed to self_thickness, and one the step took 1 mm through it
 * pushed back to its side at x0 - self_thickness above, not below. The point moves 1 / den of
 * the separation missing (den = 1 + sum of its barycentric weights squared), the triangle's
 * closest point the rest. */
static void test_push_back_to_the_side_at_x0(void **unused)
{
    (void)unused;
    cs_phys ph;
    memset(&ph, 0, sizeof ph);
    ph.self_thickness = 0.005f;
    const int32_t t[3] = {1, 2, 3};
    float w[4] = {1.0f, 1.0f, 1.0f, 1.0f}, zero[4] = {0};
    /* the triangle in z = 0, the point over its centroid: at x0 1 mm above */
    float x[4] = {0.01f / 3.0f, 0.0f, 0.01f, 0.0f}, y[4] = {0.01f / 3.0f, 0.0f, 0.0f, 0.01f};
    float z0[4] = {0.001f, 0.0f, 0.0f, 0.0f};
    for (int through = 0; through < 2; through++) {
        float z1[4] = {through ? -0.001f : 0.001f, 0.0f, 0.0f, 0.0f};
        cs_vec3 dx = cs_v3(0.0f, 0.0f, 0.0f), dv = dx;
        float wsum = 0.0f;
        assert_int_equal(cs_sc_pair_push(&ph, x, y, z1, zero, zero, zero, w, x, y, z0, 0, t, 0, &dx, &dv, &wsum), 1);
        const double den = 1.0 + 3.0 / 9.0, missing = through ? 0.006 : 0.004;
        tk_assert_near(dx.z, missing / den, 1e-7);
        tk_assert_near(fabs((double)dx.x) + fabs((double)dx.y), 0.0, 1e-7); /* along the normal */
        tk_assert_near(wsum, 1.0, 0.0);
    }
}

/* The ring bound (cs_sc_ring_spread) against every pair of owners on a 12 x 12 grid: the farthest
 * any corner of one owner's quad moves relative to any of the other's (computed here, in double)
 * never passes it. The displacements are a swing (smooth, large) with a rough patch of noise; the
 * neighbour differences and their windows' maxima are computed here from the displacements. Some
 * pair comes within 3/4 of its bound, so a bound that counted one ring fewer would fail. */
static void test_ring_bound(void **unused)
{
    (void)unused;
    enum { NX = 12, NY = 12, N = NX * NY };
    uint64_t seed = 7;
    float dx[N], dy[N], dz[N], gh[CS_SC_WINDOWS * N];
    double g[N];
    for (int v = 0; v < N; v++) {
        const double i = v % NX, j = v / NX, rough = (i >= 3 && i < 6 && j >= 4 && j < 8) ? 0.004 : 0.0;
        dx[v] = (float)(0.02 * j / NY + rough * (uniform(&seed) - 0.5));
        dy[v] = (float)(-0.02 * i / NX + rough * (uniform(&seed) - 0.5));
        dz[v] = (float)(0.03 * sin(0.5 * i) * cos(0.3 * j) + rough * (uniform(&seed) - 0.5));
    }
    for (int v = 0; v < N; v++) {
        g[v] = 0.0;
        for (int q = 0; q < N; q++) {
            const int di = q % NX - v % NX, dj = q / NX - v / NX;
            if (q == v || di < -1 || di > 1 || dj < -1 || dj > 1) continue;
            const d3 a = {dx[v], dy[v], dz[v]}, b = {dx[q], dy[q], dz[q]};
            g[v] = fmax(g[v], len3(sub3(a, b)));
        }
    }
    for (int k = 0; k < CS_SC_WINDOWS; k++)
        for (int v = 0; v < N; v++) {
            double m = 0.0;
            for (int q = 0; q < N; q++)
                if (abs(q % NX - v % NX) <= cs_sc_window(k) && abs(q / NX - v / NX) <= cs_sc_window(k)) m = fmax(m, g[q]);
            gh[k * N + v] = (float)m;
        }
    int bounded = 0;
    double closest = 0.0;
    for (int v = 0; v < N; v++)
        for (int u = 0; u < N; u++) {
            if (u == v) continue;
            const int vi = v % NX, vj = v / NX, ui = u % NX, uj = u / NX;
            const float b = cs_sc_ring_spread(gh, 0.0f, N, v, vi, vj, u, ui, uj, 1e30f);
            if (b >= 1e30f) continue; /* beyond every window */
            double most = 0.0;
            for (int p = 0; p < 4; p++)
                for (int q = 0; q < 4; q++) {
                    const int ai = vi + (p & 1), aj = vj + (p >> 1), bi = ui + (q & 1), bj = uj + (q >> 1);
                    if (ai >= NX || aj >= NY || bi >= NX || bj >= NY) continue;
                    const int a = aj * NX + ai, c = bj * NX + bi;
                    most = fmax(most, len3(sub3((d3){dx[a], dy[a], dz[a]}, (d3){dx[c], dy[c], dz[c]})));
                }
            if (most > (double)b * (1.0 + 1e-6))
                fail_msg("owners %d and %d: their corners move %.6g m apart, the ring bound says %.6g", v, u, most, (double)b);
            bounded++;
            closest = fmax(closest, most / (double)b);
        }
    print_message("%d pairs of owners within a window; the closest came to %.2f of its bound\n", bounded, closest);
    assert_true(bounded > N * 20);
    assert_true(closest > 0.75);
}

int main(void)
{
    const struct CMUnitTest tests[] = {
        cmocka_unit_test(test_written_cases),
        cmocka_unit_test(test_random_pairs),
        cmocka_unit_test(test_rounded_ends),
        cmocka_unit_test(test_push_back_to_the_side_at_x0),
        cmocka_unit_test(test_ring_bound),
    };
    return cmocka_run_group_tests(tests, NULL, NULL);
}
