/* frame.h - a frame of the stream as the sim thread publishes it (raw floats), and its
 * encodings on the wire (proto/clothd_frame.h). */
#ifndef CLOTHD_STREAM_FRAME_H
#define CLOTHD_STREAM_FRAME_H

#include <stddef.h>
#include <stdint.h>

enum { SCALAR_NONE = 0, SCALAR_SPEED = 1, SCALAR_STRAIN = 2, SCALAR_KINDS = 3 };
/* Full scale of the scalars: 255 at this speed (m/s) or strain. */
#define SCALAR_SPEED_FULL 2.0f
#define SCALAR_STRAIN_FULL 0.25f

typedef struct frame_rock {
    uint32_t id;
    float position[3], radius, orientation[4];
} frame_rock;

typedef struct raw_frame {
    uint64_t frame, step, wall_ns;
    double sim_time;
    int32_t n, n_rocks;
    size_t cap_n, cap_rocks;
    float *xyz;                  /* 3 n */
    float bbox[6];               /* min x, y, z, max x, y, z */
    uint8_t *scalar[SCALAR_KINDS]; /* [SCALAR_SPEED], [SCALAR_STRAIN]: n each, when has[k] */
    int has[SCALAR_KINDS];
    frame_rock *rocks;
} raw_frame;

/* Makes room for n vertices and r rocks; 0 or -1 (out of memory). */
int raw_frame_reserve(raw_frame *f, int32_t n, int32_t r);
void raw_frame_free(raw_frame *f);
/* The bounding box of the positions. */
void raw_frame_bbox(raw_frame *f);

/* Bytes an encoding of the frame may take at most. */
size_t frame_bound(const raw_frame *f, int encoding, int scalar);
/* Writes the encoding (with the scalar when scalar != SCALAR_NONE and the frame has it) into out
 * (frame_bound bytes); returns the bytes written. */
size_t frame_encode(const raw_frame *f, int encoding, int scalar, unsigned char *out);

#endif
