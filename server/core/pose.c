/* pose.c - the buffers of a pose (see pose.h). */
#include <math.h>
#include <stdlib.h>
#include <string.h>

#include "core/pose.h"

int pose_reserve(pose *f, int32_t n, int32_t r)
{
    if ((size_t)n > f->cap_n) {
        float *xyz = realloc(f->xyz, sizeof(float) * 3 * (size_t)n);
        if (!xyz) return -1;
        f->xyz = xyz;
        for (int k = 1; k < SCALAR_KINDS; k++) {
            uint8_t *s = realloc(f->scalar[k], (size_t)n);
            if (!s) return -1;
            f->scalar[k] = s;
        }
        f->cap_n = (size_t)n;
    }
    if ((size_t)r > f->cap_rocks) {
        pose_rock *rk = realloc(f->rocks, sizeof *rk * (size_t)r);
        if (!rk) return -1;
        f->rocks = rk;
        f->cap_rocks = (size_t)r;
    }
    return 0;
}

void pose_free(pose *f)
{
    free(f->xyz);
    for (int k = 0; k < SCALAR_KINDS; k++) free(f->scalar[k]);
    free(f->rocks);
    memset(f, 0, sizeof *f);
}

void pose_bbox(pose *f)
{
    float lo[3] = {INFINITY, INFINITY, INFINITY}, hi[3] = {-INFINITY, -INFINITY, -INFINITY};
    for (int32_t v = 0; v < f->n; v++) {
        for (int c = 0; c < 3; c++) {
            const float x = f->xyz[3 * v + c];
            lo[c] = x < lo[c] ? x : lo[c];
            hi[c] = x > hi[c] ? x : hi[c];
        }
    }
    for (int c = 0; c < 3; c++) {
        f->bbox[c] = f->n ? lo[c] : 0.0f;
        f->bbox[3 + c] = f->n ? hi[c] : 0.0f;
    }
}
