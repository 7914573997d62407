"""clothd.frames against frames built byte by byte from PROTOCOL.md's "Binary frames" table,
never by an encoder under test: a literal f32 frame, hand-quantized q16 values, a meshopt
payload made once by Debian's libmeshoptimizer (the encoder clothd uses), the scalar section's
padding, and malformed input (every truncation, random corruption: a FrameError, never another
exception). Run with and without numpy (--hide-numpy): arrays or lists, the same numbers.
"""

import random
import struct

import pytest

import clothd
from clothd import frames
from conftest import run_hidden

pytestmark = pytest.mark.both


def hexbytes(text):
    """'43 4c  # comment' lines -> bytes."""
    return bytes.fromhex("".join(line.split("#")[0] for line in text.splitlines()))


def rows(positions):
    """Positions as [[x, y, z], ...] of floats, from an array or a list."""
    return [[float(x) for x in p] for p in positions]


# A complete f32 frame, 2 vertices + 1 rock, written out byte by byte (132 bytes).
F32_FRAME = hexbytes("""
  43 4c 46 31                          # 0   magic "CLF1"
  48 00                                # 4   header size 72
  00 00                                # 6   flags: encoding 0 (f32), no scalar
  07 00 00 00 00 00 00 00              # 8   frame 7
  2c 01 00 00 00 00 00 00              # 16  step 300
  00 00 00 00 00 00 f8 3f              # 24  sim_time 1.5 (f64 0x3ff8000000000000)
  15 cd 85 3d fe 9c 97 17              # 32  wall ns 1700000000123456789 (0x17979cfe3d85cd15, > 2^53)
  02 00 00 00                          # 40  n_vertices 2
  01 00 00 00                          # 44  n_rocks 1
  00 00 80 bf 00 00 00 00 00 00 00 3f  # 48  bbox min (-1, 0, 0.5)
  00 00 80 3f 00 00 00 40 00 00 40 3f  # 60  bbox max (1, 2, 0.75)
  00 00 80 bf 00 00 00 00 00 00 40 3f  # 72  vertex 0 (-1, 0, 0.75)
  00 00 80 3e 00 00 00 40 00 00 00 3f  # 84  vertex 1 (0.25, 2, 0.5)
  09 00 00 00                          # 96  rock id 9
  00 00 00 00 00 00 00 bf 00 00 80 40  # 100 position (0, -0.5, 4)
  00 00 80 3e                          # 112 radius 0.25
  00 00 00 3f 00 00 00 bf 00 00 00 3f 00 00 00 3f  # 116 orientation (0.5, -0.5, 0.5, 0.5)
""")                                   # 132 end


def header(encoding, n, bmin, bmax, scalar=False, frame=1, step=2, sim_time=0.5, wall_ns=3, n_rocks=0):
    """The 72-byte header, field by field at the table's offsets."""
    out = bytearray(72)
    out[0:4] = b"CLF1"
    struct.pack_into("<H", out, 4, 72)
    struct.pack_into("<H", out, 6, encoding | (4 if scalar else 0))
    struct.pack_into("<Q", out, 8, frame)
    struct.pack_into("<Q", out, 16, step)
    struct.pack_into("<d", out, 24, sim_time)
    struct.pack_into("<Q", out, 32, wall_ns)
    struct.pack_into("<I", out, 40, n)
    struct.pack_into("<I", out, 44, n_rocks)
    struct.pack_into("<3f", out, 48, *bmin)
    struct.pack_into("<3f", out, 60, *bmax)
    return bytes(out)


def frame_of(*sections):
    """Sections in order, each zero-padded to a 4-byte boundary."""
    return b"".join(s + b"\0" * (-len(s) % 4) for s in sections)


def rock_bytes(rid, position, radius, orientation):
    return struct.pack("<I3ff4f", rid, *position, radius, *orientation)


def test_f32_literal_frame_decodes_field_by_field():
    assert len(F32_FRAME) == 132
    for data in (F32_FRAME, bytearray(F32_FRAME), memoryview(b"xxx" + F32_FRAME)[3:]):
        f = clothd.decode_frame(data)
        assert (f.frame, f.step, f.sim_time, f.wall_ns) == (7, 300, 1.5, 1700000000123456789)
        assert (f.encoding, f.n_vertices, f.n_rocks, f.nbytes) == ("f32", 2, 1, 132)
        assert f.bbox_min == (-1, 0, 0.5) and f.bbox_max == (1, 2, 0.75)
        assert rows(f.positions) == [[-1, 0, 0.75], [0.25, 2, 0.5]]
        assert f.scalar is None
        assert f.rocks == [clothd.Rock(9, (0, -0.5, 4), 0.25, (0.5, -0.5, 0.5, 0.5))]
    # The helpers above follow the table too: they build the same bytes.
    built = frame_of(header(0, 2, (-1, 0, 0.5), (1, 2, 0.75), frame=7, step=300, sim_time=1.5,
                            wall_ns=1700000000123456789, n_rocks=1),
                     struct.pack("<6f", -1, 0, 0.75, 0.25, 2, 0.5),
                     rock_bytes(9, (0, -0.5, 4), 0.25, (0.5, -0.5, 0.5, 0.5)))
    assert built == F32_FRAME


def test_arrays_with_numpy_lists_without():
    f = clothd.decode_frame(F32_FRAME)
    if clothd.numpy_available():
        import numpy
        assert isinstance(f.positions, numpy.ndarray)
        assert f.positions.shape == (2, 3) and f.positions.dtype == numpy.float32
    else:
        assert isinstance(f.positions, list) and f.positions[1] == [0.25, 2.0, 0.5]
    assert isinstance(clothd.decode_frame(F32_FRAME, numpy=False).positions, list)


def test_q16_hand_quantized_a_flat_axis_and_the_half_step_bound():
    # x in 0..10, y in -1..1, z flat at 2: (2.5, 0.3, 2) and (10, -1, 2).
    # x: 2.5/10*65535 = 16383.75 -> 16384; y: 1.3/2*65535 = 42597.75 -> 42598; z: flat -> 0.
    bmin, bmax = (0, -1, 2), (10, 1, 2)
    q = [16384, 42598, 0, 65535, 0, 0]
    f = clothd.decode_frame(frame_of(header(1, 2, bmin, bmax), struct.pack("<6H", *q)))
    assert f.encoding == "q16" and f.nbytes == 72 + 12
    got = rows(f.positions)
    want = [[bmin[c] + q[3 * v + c] * (bmax[c] - bmin[c]) / 65535 for c in range(3)] for v in range(2)]
    for g, w in zip(got, want):
        assert g == pytest.approx(w, abs=1e-6)
    for g, w in zip(got, [[2.5, 0.3, 2], [10, -1, 2]]):
        assert g == pytest.approx(w, abs=10 / 65535 / 2 + 1e-6)
    assert got[0][2] == 2  # a flat axis: exactly min
    # An extent below 1e-9 m (but not 0) is flat too.
    tiny = clothd.decode_frame(frame_of(header(1, 1, (0, 0, 0), (5e-10, 1, 1)), struct.pack("<3H", 0, 0, 65535)))
    assert rows(tiny.positions) == [[0, 0, 1]]

    # Property: random positions in a bbox, quantized by the spec's formula, decode to within
    # half a step.
    rng = random.Random(12345)
    f32 = lambda x: struct.unpack("<f", struct.pack("<f", x))[0]  # noqa: E731
    lo, hi = [f32(x) for x in (-3.2, 0.1, -0.7)], [f32(x) for x in (4.9, 2.6, 0.3)]
    n = 1000
    xs = [[f32(lo[c] + rng.random() * (hi[c] - lo[c])) for c in range(3)] for _ in range(n)]
    qs = [round((x[c] - lo[c]) / (hi[c] - lo[c]) * 65535) for x in xs for c in range(3)]
    g = rows(clothd.decode_frame(frame_of(header(1, n, lo, hi), struct.pack("<%dH" % (3 * n), *qs))).positions)
    for v in range(n):
        for c in range(3):
            assert abs(g[v][c] - xs[v][c]) <= (hi[c] - lo[c]) / 65535 / 2 + 1e-6


# MESHOPT_Q (5 vertices, x, y, z, 0 as uint16_t q[5][4]) encoded once by a small C program
# against Debian's libmeshoptimizer 0.18 (meshopt_encodeVertexVersion(0);
# meshopt_encodeVertexBuffer(out, 256, q, 5, 8)), which gave these 82 bytes.
MESHOPT_Q = [0, 0, 65535, 0, 65535, 32768, 0, 0, 1000, 65535, 300, 0, 12345, 54321, 40000, 0, 65535, 0, 7, 0]
MESHOPT_BYTES = bytes.fromhex(
    "a0011fc000002da273011fc00000085a610107c000006461013fc00000fffe5558012fc00000582871012bc00000c9c8"
    "000000000000000000000000000000000000000000000000000000000000ffff0000")
MESHOPT_MIN, MESHOPT_MAX = (-2, 0, 1), (2, 3, 1.5)


def meshopt_frame():
    return frame_of(header(2, 5, MESHOPT_MIN, MESHOPT_MAX, n_rocks=1),
                    frame_of(struct.pack("<I", len(MESHOPT_BYTES)), MESHOPT_BYTES),
                    rock_bytes(1, (1, 2, 3), 0.5, (0, 0, 0, 1)))


@pytest.mark.skipif(not clothd.meshopt_available(), reason="libmeshoptimizer is not installed")
def test_meshopt_libmeshoptimizer_bytes_decode_to_the_dequantized_q16_values():
    assert len(MESHOPT_BYTES) == 82
    data = meshopt_frame()
    assert len(data) == 72 + 88 + 36  # 4 + 82 bytes, padded to 88
    f = clothd.decode_frame(data)
    assert (f.encoding, f.n_vertices) == ("meshopt", 5)
    want = [[MESHOPT_MIN[c] + MESHOPT_Q[4 * v + c] * (MESHOPT_MAX[c] - MESHOPT_MIN[c]) / 65535 for c in range(3)]
            for v in range(5)]
    for g, w in zip(rows(f.positions), want):
        assert g == pytest.approx(w, abs=1e-6)
    assert f.rocks == [clothd.Rock(1, (1, 2, 3), 0.5, (0, 0, 0, 1))]
    # A payload the codec refuses (its bytes cut short inside): a FrameError.
    broken = frame_of(header(2, 5, MESHOPT_MIN, MESHOPT_MAX), frame_of(struct.pack("<I", 40), MESHOPT_BYTES[:40]))
    with pytest.raises(clothd.FrameError, match="meshopt payload"):
        clothd.decode_frame(broken)


def test_meshopt_without_its_library_says_what_is_missing():
    p = run_hidden([], "import clothd\n"
                   "try:\n"
                   "    clothd.decode_frame(bytes.fromhex(%r))\n"
                   "except clothd.MissingDependency as e:\n"
                   "    print('missing:', e)\n" % meshopt_frame().hex(),
                   env={"CLOTHD_MESHOPTIMIZER_LIB": "/nonexistent/libmeshoptimizer.so"})
    assert p.returncode == 0, p.stderr
    assert "missing: meshopt frames need meshoptimizer's C library" in p.stdout
    assert "libmeshoptimizer2d" in p.stdout and "/nonexistent/libmeshoptimizer.so" in p.stdout


def test_scalar_section_is_padded_and_the_rocks_follow():
    rock = (42, (0.5, 1, -1), 2, (0, 1, 0, 0))
    # f32: positions 72..108, scalar 108..111, 1 pad byte, rock at 112.
    # q16: positions 72..90, 2 pad bytes, scalar 92..95, 1 pad byte, rock at 96.
    for encoding, positions, rock_at in ((0, struct.pack("<9f", 0, 0, 0, 1, 1, 1, 0.5, 0.25, 0), 112),
                                         (1, struct.pack("<9H", 0, 0, 0, 65535, 65535, 65535, 0, 0, 0), 96)):
        data = frame_of(header(encoding, 3, (0, 0, 0), (1, 1, 1), scalar=True, n_rocks=1), positions,
                        bytes([0, 128, 255]), rock_bytes(*rock))
        assert len(data) == rock_at + 36 and struct.unpack_from("<I", data, rock_at)[0] == 42
        f = clothd.decode_frame(data)
        assert [int(s) for s in f.scalar] == [0, 128, 255]
        assert f.rocks == [clothd.Rock(*rock)]
        assert rows(f.positions)[1] == [1, 1, 1]


def test_bad_input_is_a_frame_error_that_says_why():
    cases = [
        (F32_FRAME[:71], "shorter than its header"),
        (b"", "shorter than its header"),
        (F32_FRAME[:3] + b"2" + F32_FRAME[4:], "magic"),
        (F32_FRAME[:6] + b"\x03\x00" + F32_FRAME[8:], "delta frame"),
        (F32_FRAME + b"\0\0\0\0", "136 bytes"),
        (F32_FRAME[:4] + b"\x10\x00" + F32_FRAME[6:], "header size 16"),
        (F32_FRAME[:40] + b"\xff\xff\xff\xff" + F32_FRAME[44:], "more than"),
        # reserved flag bits (bit 3: a fifth encoding's, later; bit 15): refused, not misread as f32
        (F32_FRAME[:6] + b"\x08\x00" + F32_FRAME[8:], "flags 0x8 set bits"),
        (F32_FRAME[:6] + b"\x00\x80" + F32_FRAME[8:], "flags 0x8000 set bits"),
    ]
    for cut in (1, 36, 60):
        cases.append((F32_FRAME[:132 - cut], "truncated"))
    for data, why in cases:
        with pytest.raises(clothd.FrameError, match=why):
            clothd.decode_frame(data)
    # A FrameError is a ProtocolError and a ValueError.
    assert issubclass(clothd.FrameError, clothd.ProtocolError) and issubclass(clothd.FrameError, ValueError)


def test_every_truncation_and_random_corruption_is_a_frame_or_a_frame_error():
    samples = [F32_FRAME, frame_of(header(1, 3, (0, 0, 0), (1, 1, 1), scalar=True), struct.pack("<9H", *range(9)),
                                   bytes(3))]
    if clothd.meshopt_available():
        samples.append(meshopt_frame())
    rng = random.Random(7)
    for data in samples:
        truncate_and_corrupt(data, clothd.decode_frame, rng)


def truncate_and_corrupt(data, decode, rng):
    """Every truncation of data is a FrameError; 300 random corruptions decode or are one."""
    for cut in range(len(data)):
        with pytest.raises(clothd.FrameError):
            decode(data[:cut])
    for _ in range(300):
        b = bytearray(data)
        for _ in range(rng.randint(1, 4)):
            b[rng.randrange(len(b))] = rng.randrange(256)
        try:
            decode(bytes(b))
        except clothd.FrameError:
            pass


def test_frame_decoder_is_the_stateful_form_of_decode_frame():
    d = clothd.FrameDecoder(numpy=False)
    assert d.decode(F32_FRAME) == clothd.decode_frame(F32_FRAME, numpy=False)
    assert frames.POSITION_DECODERS[1][0] == "q16"


# delta: a 2 x 2 cloth on a 0.5 m grid worked out by hand from the layout (PROTOCOL.md), the same
# case as tests/web/frame.test.mjs: keyframe g = (2,4,0) (4,4,0) (2,6,1) (5,6,-2), origin (2,4,-2);
# the delta moves vertex 0 by +1 on x and vertex 3 by -2 on z. The zstd frames of their byte
# planes were made once with the zstd command line (zstd -1 --no-check) and pasted here.
KEY_ZSTD = bytes.fromhex("28b52ffd2030ad00006000040002000400040002050003100086e6f0a105")
DELTA_ZSTD = bytes.fromhex("28b52ffd20307d000038020101020003000200c0c022d002")


def delta_frame(kind, key_id, key_frame, quantum, origin, row, payload, frame=1, n=4):
    head = struct.pack("<IIQd3iII", kind, key_id, key_frame, quantum, *origin, row, len(payload))
    return frame_of(header(3, n, (0, 0, 0), (1, 1, 1), frame=frame), head, payload)


KEY = delta_frame(0, 1, 77, 0.5, (2, 4, -2), 2, KEY_ZSTD, frame=77)
DELTA_1 = delta_frame(1, 1, 77, 0.5, (2, 4, -2), 2, DELTA_ZSTD, frame=78)
needs_zstd = pytest.mark.skipif(not clothd.frames.zstd_available(), reason="zstd's C library is not loadable")


@needs_zstd
def test_delta_keyframe_and_delta_worked_out_by_hand():
    for numpy in ([False, True] if clothd.frames.numpy_available() else [False]):
        d = clothd.FrameDecoder(numpy=numpy)
        with pytest.raises(clothd.FrameError, match="holds no keyframe"):
            d.decode(DELTA_1)
        k = d.decode(KEY)
        assert k.encoding == "delta" and k.delta == frames.Delta(True, 1, 77, 0.5)
        assert rows(k.positions) == [[1, 2, 0], [2, 2, 0], [1, 3, 0.5], [2.5, 3, -1]]
        assert k.nbytes == 72 + 44 + 32
        for _ in range(2):  # any number of deltas decode with the keyframe alone
            f = d.decode(DELTA_1)
            assert f.delta == frames.Delta(False, 1, 77, 0.5) and f.frame == 78
            assert rows(f.positions) == [[1.5, 2, 0], [2, 2, 0], [1, 3, 0.5], [2.5, 3, -2]]
        # Another keyframe's delta, a broken frame: errors that leave the keyframe held.
        with pytest.raises(clothd.FrameError, match=r"keyframe 2 \(frame 90\).*holds keyframe 1"):
            d.decode(delta_frame(1, 2, 90, 0.5, (2, 4, -2), 2, DELTA_ZSTD))
        with pytest.raises(clothd.FrameError, match="bytes"):
            d.decode(delta_frame(0, 5, 99, 0.5, (0, 0, 0), 2, KEY_ZSTD) + bytes(4))
        with pytest.raises(clothd.FrameError, match="does not hold"):
            d.decode(delta_frame(0, 6, 99, 0.5, (0, 0, 0), 2, KEY_ZSTD, n=3))
        assert d.keyframe.id == 1
        assert rows(d.decode(DELTA_1).positions)[0] == [1.5, 2, 0]


# The same cloth in the layout of kinds 2 and 3 (PROTOCOL.md): an axis block per axis (basis u8,
# 3 zero, escapes u32, byte count u32, one zstd frame of n int8 residuals and the int32 escapes).
# Keyframe residuals: x 0 2 0 1, y 0 0 2 0, z 2 0 1 -3. The delta: x on the keyframe (basis 1),
# residuals 1 -1 -1 1 (vertex 0 +1); y on the origin (basis 0), a = g - 4 = 0 0 2 2, residuals
# 0 0 2 0; z on the keyframe, vertex 3 -200 (g -202), residual -200 an escape (byte -128, then
# the int32). zstd frames made once with the zstd command line (zstd -1 --no-check).
def axis_block(basis, escapes, zframe):
    body = struct.pack("<B3xII", basis, escapes, len(zframe)) + zframe
    return body + bytes(-len(body) % 4)


KEY2 = delta_frame(2, 1, 77, 0.5, (2, 4, -2), 2, b"".join([
    axis_block(0, 0, bytes.fromhex("28b52ffd200421000000020001")),
    axis_block(0, 0, bytes.fromhex("28b52ffd200421000000000200")),
    axis_block(0, 0, bytes.fromhex("28b52ffd2004210000020001fd"))]), frame=77)
DELTA2 = delta_frame(3, 1, 77, 0.5, (2, 4, -2), 2, b"".join([
    axis_block(1, 0, bytes.fromhex("28b52ffd200421000001ffff01")),
    axis_block(0, 0, bytes.fromhex("28b52ffd200421000000000200")),
    axis_block(1, 1, bytes.fromhex("28b52ffd20084100000000008038ffffff"))]), frame=78)


@needs_zstd
def test_delta_axis_blocks_worked_out_by_hand():
    for numpy in ([False, True] if clothd.frames.numpy_available() else [False]):
        d = clothd.FrameDecoder(numpy=numpy)
        k = d.decode(KEY2)
        assert k.delta == frames.Delta(True, 1, 77, 0.5)
        assert rows(k.positions) == [[1, 2, 0], [2, 2, 0], [1, 3, 0.5], [2.5, 3, -1]]
        for _ in range(2):
            f = d.decode(DELTA2)
            assert f.delta == frames.Delta(False, 1, 77, 0.5)
            assert rows(f.positions) == [[1.5, 2, 0], [2, 2, 0], [1, 3, 0.5], [2.5, 3, -101]]
        # A keyframe of the first layout's byte planes is held alike: the new layout's deltas decode on it.
        d.decode(KEY)
        assert rows(d.decode(DELTA2).positions)[3] == [2.5, 3, -101]
        # Bad blocks: a basis 1 in a keyframe, escapes the head does not count, too many.
        bad = bytearray(KEY2)
        bad[72 + 44] = 1
        with pytest.raises(clothd.FrameError, match="basis 1 in a keyframe"):
            d.decode(bytes(bad))
        bad = bytearray(DELTA2)
        struct.pack_into("<I", bad, 72 + 44 + 2 * 28 + 4, 0)  # z's block (after two of 28 bytes)
        with pytest.raises(clothd.FrameError):
            d.decode(bytes(bad))
        bad = bytearray(DELTA2)
        struct.pack_into("<I", bad, 72 + 44 + 4, 5)
        with pytest.raises(clothd.FrameError, match="5 escapes for 4 vertices"):
            d.decode(bytes(bad))
        assert d.keyframe.id == 1 and rows(d.decode(DELTA2).positions)[0] == [1.5, 2, 0]


@needs_zstd
def test_delta_grid_values_past_float32_decode_to_inf_without_a_warning():
    # A quantum of 1e300 m (finite, positive: a frame may say it) puts g = 2 at 2e300, past
    # float32's 3.4e38: inf, with numpy as without, and no RuntimeWarning of numpy's cast.
    import warnings
    huge = bytearray(KEY2)
    struct.pack_into("<d", huge, 72 + 16, 1e300)
    for numpy in ([False, True] if clothd.frames.numpy_available() else [False]):
        with warnings.catch_warnings():
            warnings.simplefilter("error")
            p = rows(clothd.FrameDecoder(numpy=numpy).decode(bytes(huge)).positions)
        assert p[0] == [float("inf"), float("inf"), 0] and p[3] == [float("inf"), float("inf"), -float("inf")]


@needs_zstd
def test_delta_axis_blocks_truncations_and_corruption_are_frame_errors():
    def decode(data):
        d = clothd.FrameDecoder()
        d.decode(KEY2)
        return d.decode(data)
    for data in (KEY2, DELTA2):
        truncate_and_corrupt(data, decode, random.Random(12))


def test_delta_needs_the_stateful_decoder():
    with pytest.raises(clothd.FrameError, match="FrameDecoder"):
        clothd.decode_frame(KEY)


@needs_zstd
def test_delta_truncations_and_corruption_are_frame_errors():
    def decode(data):  # a decoder holding KEY, as a stream's would
        d = clothd.FrameDecoder()
        d.decode(KEY)
        return d.decode(data)
    for data in (KEY, DELTA_1):
        truncate_and_corrupt(data, decode, random.Random(11))
