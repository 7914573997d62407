/* tk_geom.h - geometry in double that the self-collision tests write for themselves (never the
 * product's contact code): vectors, and the distances from a point to a segment and a triangle.
 * Tests only. */
#ifndef CLOTHD_TK_GEOM_H
#define CLOTHD_TK_GEOM_H

#include <math.h>

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

#endif
