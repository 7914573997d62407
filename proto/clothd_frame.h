/* clothd_frame.h - the binary frame of the clothd stream (PROTOCOL.md, Binary frames), little-endian.
 *
 *   offset  size  field
 *        0     4  magic "CLF1"
 *        4     2  header size (72)
 *        6     2  flags: bits 0-1 encoding (0 f32, 1 q16, 2 meshopt, 3 delta), bit 2 scalar present,
 *                 bits 3-15 reserved (0: a reader refuses a frame with any set; bit 3 is kept for
 *                 the encoding, the field's third bit, when a fifth encoding comes)
 *        8     8  frame (u64)
 *       16     8  step (u64)
 *       24     8  sim_time (f64, s)
 *       32     8  wall clock at publish (u64, ns since the Unix epoch)
 *       40     4  n_vertices (u32)
 *       44     4  n_rocks (u32)
 *       48    12  bbox min (3 f32, m)
 *       60    12  bbox max (3 f32, m)
 *       72        positions:
 *                   f32:     n_vertices x 3 f32 (x, y, z)
 *                   q16:     n_vertices x 3 u16, each axis mapped from bbox min..max to 0..65535
 *                            (an axis whose extent is below 1e-9 m is all 0)
 *                   meshopt: u32 byte count, then the q16 positions padded to 4 u16 per vertex
 *                            (x, y, z, 0: an 8-byte stride) compressed with meshoptimizer's
 *                            vertex codec (meshopt_encodeVertexBuffer, vertex size 8)
 *                   delta:   a 44-byte head, then three axis blocks (offsets from the
 *                            section's start):
 *                             0  4  kind (u32): 2 keyframe, 3 delta (0 and 1: the same in the
 *                                   first, byte-plane layout, below; still decoded)
 *                             4  4  keyframe id (u32): the keyframe's sequence number, from 1;
 *                                   a keyframe carries its own, a delta its keyframe's
 *                             8  8  keyframe frame (u64): the `frame` of that keyframe
 *                            16  8  quantum (f64, m): the grid's spacing
 *                            24 12  grid origin (3 i32): the keyframe's per-axis minimum of g
 *                            36  4  row (u32): vertices per grid row (the cloth's nx)
 *                            40  4  byte count (u32) of what follows (the three axis blocks)
 *                            44     axis blocks x, y, z, each a multiple of 4 bytes:
 *                                    0  1  basis (u8): 0 a = g - origin, 1 a = g - g of the
 *                                          keyframe (a delta only; the encoder takes per axis
 *                                          whichever compresses smaller)
 *                                    1  3  zero
 *                                    4  4  escapes E (u32, at most n)
 *                                    8  4  byte count L (u32) of the zstd frame that follows
 *                                   12  L  one zstd frame of n + 4 E bytes: n int8 residuals r
 *                                          (-127..127; -128 is an escape: the residual is the
 *                                          next of the E int32 that follow), then E int32
 *                                          then zero padding to 4 bytes
 *                            g = round(x / quantum) clamped to int32 (round half away from 0);
 *                            r = a - (a[i-1,j] + a[i,j-1] - a[i-1,j-1]), a neighbour missing
 *                            on the first row or column counts as 0 (i = v mod row, j = v div
 *                            row), all mod 2^32. x decodes as (origin + a) quantum (basis 0) or
 *                            (g of the keyframe + a) quantum (basis 1), within quantum/2.
 *                            Kinds 0 and 1 (the first layout): after the head, zstd frames of 12 n bytes
 *                            together: byte b (0 low .. 3) of zigzag(r) = (r << 1) ^ (r >> 31)
 *                            of axis c of vertex v is byte (4 c + b) n + v; basis 0 for a
 *                            keyframe, 1 for a delta.
 *                 scalar (when flagged): n_vertices u8, 0 = slow or unstrained .. 255
 *                 rocks: n_rocks x 36 bytes {id u32, position 3 f32, radius f32,
 *                        orientation 4 f32 (quaternion x, y, z, w)}
 * Every section starts on a 4-byte boundary (zero padding after the one before). */
#ifndef CLOTHD_FRAME_H
#define CLOTHD_FRAME_H

#define CLF_MAGIC "CLF1"
#define CLF_HEADER_SIZE 72

#define CLF_OFF_MAGIC 0
#define CLF_OFF_HEADER_SIZE 4
#define CLF_OFF_FLAGS 6
#define CLF_OFF_FRAME 8
#define CLF_OFF_STEP 16
#define CLF_OFF_SIM_TIME 24
#define CLF_OFF_WALL_NS 32
#define CLF_OFF_N_VERTICES 40
#define CLF_OFF_N_ROCKS 44
#define CLF_OFF_BBOX_MIN 48
#define CLF_OFF_BBOX_MAX 60

/* The encodings, one list (X(symbol, name)): the enum below, the server's names
 * (stream_encoding_names), and in the same order clients/js/src/frame.mjs's ENCODINGS and the
 * Python client's POSITION_DECODERS; each encoding's value is its position here, its wire code. */
#define CLF_ENCODINGS(X) X(CLF_F32, "f32") X(CLF_Q16, "q16") X(CLF_MESHOPT, "meshopt") X(CLF_DELTA, "delta")
#define CLF_ENCODING_ENUM_(sym, name) sym,
enum clf_encoding { CLF_ENCODINGS(CLF_ENCODING_ENUM_) CLF_ENCODING_COUNT };
#undef CLF_ENCODING_ENUM_
#define CLF_FLAG_ENCODING_MASK 0x3u
#define CLF_FLAG_SCALAR 0x4u
#define CLF_FLAG_RESERVED 0xFFF8u /* bits 3-15: 0 (bit 3: the encoding's third bit, later) */

#define CLF_ROCK_SIZE 36
#define CLF_MESHOPT_STRIDE 8 /* bytes per vertex given to the meshopt codec */
#define CLF_Q16_EXTENT_MIN 1e-9f

/* The delta positions section: offsets from its start. */
enum clf_delta_kind { CLF_DELTA_KEY_PLANES = 0, CLF_DELTA_DELTA_PLANES = 1, CLF_DELTA_KEY = 2, CLF_DELTA_DELTA = 3 };
#define CLF_DELTA_KIND_IS_KEY(k) ((k) == CLF_DELTA_KEY || (k) == CLF_DELTA_KEY_PLANES)
#define CLF_DELTA_OFF_KIND 0
#define CLF_DELTA_OFF_KEY_ID 4
#define CLF_DELTA_OFF_KEY_FRAME 8
#define CLF_DELTA_OFF_QUANTUM 16
#define CLF_DELTA_OFF_ORIGIN 24
#define CLF_DELTA_OFF_ROW 36
#define CLF_DELTA_OFF_LENGTH 40
#define CLF_DELTA_HEAD 44
/* An axis block of kinds 2 and 3. */
enum clf_delta_basis { CLF_DELTA_BASIS_ORIGIN = 0, CLF_DELTA_BASIS_KEY = 1 };
#define CLF_DELTA_AXIS_OFF_BASIS 0
#define CLF_DELTA_AXIS_OFF_ESCAPES 4
#define CLF_DELTA_AXIS_OFF_LENGTH 8
#define CLF_DELTA_AXIS_HEAD 12
#define CLF_DELTA_ESCAPE (-128)

/* Section sizes rounded up to 4 bytes. */
#define CLF_ALIGN4(n) (((n) + 3u) & ~(size_t)3u)

#endif
