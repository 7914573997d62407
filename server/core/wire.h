/* wire.h - the stream's binary message: a pose encoded as proto/clothd_frame.h lays it out (the
 * layout PROTOCOL.md calls a binary frame), in one of its encodings (f32, q16, meshopt, delta), with or
 * without a scalar. Pure: the stream encodes each pose once per encoding in use. */
#ifndef CLOTHD_WIRE_H
#define CLOTHD_WIRE_H

#include <stddef.h>

#include "core/pose.h"

/* Bytes an encoding of the pose may take at most. */
size_t wire_bound(const pose *p, int encoding, int scalar);
/* Writes the encoding (with the scalar when scalar != SCALAR_NONE and the pose has it) into out
 * (wire_bound bytes); returns the bytes written (0 for CLF_DELTA: wire_encode_delta). */
size_t wire_encode(const pose *p, int encoding, int scalar, unsigned char *out);
/* The delta encoding's message, around its positions section (delta_encode's, len bytes). */
size_t wire_encode_delta(const pose *p, int scalar, const unsigned char *section, size_t len, unsigned char *out);

#endif
