/* tk_geom.h - geometry in double that the self-collision tests write for themselves (never the
 * product's contact code): vectors, and the distances from a point to a segment and a triangle.
 * Tests only. */
#ifndef CLOTHD_TK_GEOM_H
#define CLOTHD_TK_GEOM_H

#include <math.h>
#include <stdlib.h>

typedef struct {
    double x, y, z;
} d3;

static inline d3 sub3(d3 a, d3 b) { return (d3){a.x - b.x, a.y - b.y, a.z - b.z}; }
static inline d3 add3(d3 a, d3 b) { return (d3){a.x + b.x, a.y + b.y, a.z + b.z}; }
static inline d3 mul3(d3 a, double k) { return (d3){a.x * k, a.y * k, a.z * k}; }
static inline d3 cross3(d3 a, d3 b) { return (d3){a.y * b.z - a.z * b.y, a.z * b.x - a.x * b.z, a.x * b.y - a.y * b.x}; }
static inline double dot3(d3 a, d3 b) { return a.x * b.x + a.y * b.y + a.z * b.z; }
static inline double len3(d3 a) { return sqrt(dot3(a, a)); }

/* The distance from p to segment a b. */
static inline double point_segment(d3 p, d3 a, d3 b)
{
    const d3 e = sub3(b, a);
    double s = dot3(sub3(p, a), e) / dot3(e, e);
    s = s < 0.0 ? 0.0 : s > 1.0 ? 1.0 : s;
    return len3(sub3(p, add3(a, mul3(e, s))));
}

/* The distance from p to triangle a b c: the plane's where the foot falls inside, else the
 * least of the edges'. */
static inline double point_triangle(d3 p, d3 a, d3 b, d3 c)
{
    const d3 n = cross3(sub3(b, a), sub3(c, a));
    const double nn = dot3(n, n);
    double best = 1e300;
    if (nn > 0.0) {
        const double t = dot3(sub3(p, a), n) / nn;
        const d3 f = sub3(p, mul3(n, t));
        if (dot3(cross3(sub3(b, a), sub3(f, a)), n) >= 0.0 && dot3(cross3(sub3(c, b), sub3(f, b)), n) >= 0.0 &&
            dot3(cross3(sub3(a, c), sub3(f, c)), n) >= 0.0)
            best = fabs(t) * sqrt(nn);
    }
    const double e[3] = {point_segment(p, a, b), point_segment(p, b, c), point_segment(p, c, a)};
    for (int k = 0; k < 3; k++) best = e[k] < best ? e[k] : best;
    return best;
}

/* Whether segment p q passes through triangle a b c (Moller-Trumbore). */
static inline int segment_through(d3 p, d3 q, d3 a, d3 b, d3 c)
{
    const d3 dir = sub3(q, p), e1 = sub3(b, a), e2 = sub3(c, a), h = cross3(dir, e2);
    const double det = dot3(e1, h);
    if (fabs(det) < 1e-18) return 0;
    const d3 s = sub3(p, a), qq = cross3(s, e1);
    const double u = dot3(s, h) / det, v = dot3(dir, qq) / det, t = dot3(e2, qq) / det;
    return u >= 0.0 && v >= 0.0 && u + v <= 1.0 && t >= 0.0 && t <= 1.0;
}

/* Pairs of an nx x ny grid's triangles (each quad split on its +x+y diagonal, positions xyz: 3
 * floats a vertex) that share no vertex and cross: an edge of one passes through the other. Pairs
 * whose boxes lie apart are skipped (they cannot cross). -1 without memory. */
static inline long crossings(const float *xyz, int nx, int ny)
{
    const int nt = 2 * (nx - 1) * (ny - 1);
    int(*t)[3] = malloc(sizeof *t * (size_t)nt);
    d3(*tri)[3] = malloc(sizeof *tri * (size_t)nt);
    double(*box)[6] = malloc(sizeof *box * (size_t)nt);
    if (!t || !tri || !box) {
        free(t), free(tri), free(box);
        return -1;
    }
    for (int j = 0, k = 0; j < ny - 1; j++)
        for (int i = 0; i < nx - 1; i++) {
            const int v = j * nx + i;
            t[k][0] = v, t[k][1] = v + 1, t[k][2] = v + nx + 1, k++;
            t[k][0] = v, t[k][1] = v + nx + 1, t[k][2] = v + nx, k++;
        }
    for (int k = 0; k < nt; k++) {
        for (int q = 0; q < 3; q++) tri[k][q] = (d3){xyz[3 * t[k][q]], xyz[3 * t[k][q] + 1], xyz[3 * t[k][q] + 2]};
        for (int c = 0; c < 3; c++) {
            const double a = c == 0 ? tri[k][0].x : c == 1 ? tri[k][0].y : tri[k][0].z;
            box[k][c] = box[k][3 + c] = a;
            for (int q = 1; q < 3; q++) {
                const double x = c == 0 ? tri[k][q].x : c == 1 ? tri[k][q].y : tri[k][q].z;
                box[k][c] = x < box[k][c] ? x : box[k][c];
                box[k][3 + c] = x > box[k][3 + c] ? x : box[k][3 + c];
            }
        }
    }
    long n = 0;
    for (int k = 0; k < nt; k++)
        for (int l = k + 1; l < nt; l++) {
            int apart = 0, share = 0;
            for (int c = 0; c < 3; c++) apart |= box[k][c] > box[l][3 + c] || box[l][c] > box[k][3 + c];
            if (apart) continue;
            for (int a = 0; a < 3; a++)
                for (int b = 0; b < 3; b++) share |= t[k][a] == t[l][b];
            if (share) continue;
            const d3 *P = tri[k], *Q = tri[l];
            int hit = 0;
            for (int e = 0; e < 3; e++)
                hit |= segment_through(P[e], P[(e + 1) % 3], Q[0], Q[1], Q[2]) |
                       segment_through(Q[e], Q[(e + 1) % 3], P[0], P[1], P[2]);
            n += hit;
        }
    free(t), free(tri), free(box);
    return n;
}

#endif
