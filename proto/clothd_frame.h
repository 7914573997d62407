/* clothd_frame.h - the binary frame of the clothd stream (PROTOCOL.md, Binary frames), little-endian.
 *
 *   offset  size  field
 *        0     4  magic "CLF1"
 *        4     2  header size (72)
 *        6     2  flags: bits 0-1 encoding (0 f32, 1 q16, 2 meshopt), bit 2 scalar present
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

enum clf_encoding { CLF_F32 = 0, CLF_Q16 = 1, CLF_MESHOPT = 2 };
#define CLF_FLAG_ENCODING_MASK 0x3u
#define CLF_FLAG_SCALAR 0x4u

#define CLF_ROCK_SIZE 36
#define CLF_MESHOPT_STRIDE 8 /* bytes per vertex given to the meshopt codec */
#define CLF_Q16_EXTENT_MIN 1e-9f

/* Section sizes rounded up to 4 bytes. */
#define CLF_ALIGN4(n) (((n) + 3u) & ~(size_t)3u)

#endif
