/* pose.h - the cloth and its rocks at one moment, as the sim side hands them to the stream: the
 * raw float positions, their bounding box, the per-vertex scalars the viewers asked for, and the
 * rocks. (A "frame" in clothd is a period of simulated time, 1 / frame_rate; the stream's binary
 * message, which encodes a pose, is a wire message: wire.h.) */
#ifndef CLOTHD_POSE_H
#define CLOTHD_POSE_H

#include <stddef.h>
#include <stdint.h>

/* Per-vertex scalars a pose may carry, one byte per vertex (0 slow or unstrained .. 255). */
enum { SCALAR_NONE = 0, SCALAR_SPEED = 1, SCALAR_STRAIN = 2, SCALAR_KINDS = 3 };
/* Full scale of the scalars: 255 at this speed (m/s) or strain. */
#define SCALAR_SPEED_FULL 2.0f
#define SCALAR_STRAIN_FULL 0.25f

typedef struct pose_rock {
    uint32_t id;
    float position[3], radius, orientation[4];
} pose_rock;

typedef struct pose {
    uint64_t frame, step, wall_ns;  /* the frame count and step it was taken at; the wall clock then */
    double sim_time;
    int32_t n, n_rocks;
    int32_t nx;                     /* vertices per grid row (the cloth's nx) */
    size_t cap_n, cap_rocks;
    float *xyz;                     /* 3 n */
    float bbox[6];                  /* min x, y, z, max x, y, z */
    uint8_t *scalar[SCALAR_KINDS];  /* [SCALAR_SPEED], [SCALAR_STRAIN]: n each, when has[k] */
    int has[SCALAR_KINDS];
    pose_rock *rocks;
} pose;

/* Makes room for n vertices and r rocks; 0 or -1 (out of memory). */
int pose_reserve(pose *p, int32_t n, int32_t r);
void pose_free(pose *p);
/* The bounding box of the positions. */
void pose_bbox(pose *p);

#endif
