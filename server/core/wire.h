/* wire.h - the stream's binary message: a pose encoded as proto/clothd_frame.h lays it out (the
 * layout PROTOCOL.md calls a binary frame), in one of its encodings (f32, q16, meshopt), with or
 * without a scalar. Pure: the stream encodes each pose once per encoding in use. */
#ifndef CLOTHD_WIRE_H
#define CLOTHD_WIRE_H

#include <stddef.h>

#include "core/pose.h"

/* Bytes an encoding of the pose may take at most. */
size_t wire_bound(const pose *p, int encoding, int scalar);
/* Writes the encoding (with the scalar when scalar != SCALAR_NONE and the pose has it) into out
 * (wire_bound bytes); returns the bytes written. */
size_t wire_encode(const pose *p, int encoding, int scalar, unsigned char *out);

#endif
