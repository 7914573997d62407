"""The binary frames of clothd's stream, decoded from PROTOCOL.md's "Binary frames" table.

Little-endian; a 72-byte header, then positions, the scalar (when flagged) and the rocks, each
section starting on a 4-byte boundary::

    offset size field
         0    4 magic "CLF1"
         4    2 header size (72)
         6    2 flags: bits 0-1 encoding (0 f32, 1 q16, 2 meshopt, 3 delta), bit 2 scalar present
         8    8 frame (u64)          16  8 step (u64)
        24    8 sim_time (f64, s)    32  8 wall clock at publish (u64, ns since the epoch)
        40    4 n_vertices (u32)     44  4 n_rocks (u32)
        48   12 bbox min (3 f32)     60 12 bbox max (3 f32)
        72      positions: f32: 3 f32 per vertex; q16: 3 u16 per vertex over the bbox;
                meshopt: u32 byte count, then the q16 positions padded to 4 u16 per vertex and
                compressed with meshoptimizer's vertex codec (vertex size 8);
                delta: a 44-byte head (kind u32 2 keyframe 3 delta, keyframe id u32, keyframe
                frame u64, quantum f64, grid origin 3 i32, row u32, byte count u32), then per
                axis a block (basis u8, 3 zero, escapes u32, byte count u32) and a zstd frame of
                the int8 residuals (int32 escapes) of the grid values' parallelogram prediction;
                kinds 0 and 1 (the first layout): zstd frames of byte planes of zigzagged residuals
                (PROTOCOL.md)
                scalar (flag bit 2): one u8 per vertex
                rocks: n_rocks x {id u32, position 3 f32, radius f32, orientation 4 f32 (x, y, z, w)}

Positions come as a numpy array of shape (n, 3), float32, when numpy is importable (and
``numpy`` is not False), else as a list of [x, y, z] lists; the scalar likewise as a uint8 array
or a list of ints.

meshopt frames are decoded by meshoptimizer's own C library (``meshopt_decodeVertexBuffer``,
Debian's libmeshoptimizer2d) through ctypes; where it is missing they raise MissingDependency.
Set ``CLOTHD_MESHOPTIMIZER_LIB`` to the library's path where it is installed elsewhere.

delta frames are decompressed by zstd's own C library (``ZSTD_decompress``, Debian's libzstd1)
through ctypes (``CLOTHD_ZSTD_LIB`` names it where it is elsewhere), and refer to the newest
keyframe: FrameDecoder, which decodes a stream's frames in order, keeps it; decode_frame, which
keeps nothing, refuses them.

The encodings are dispatched in one table, ``POSITION_DECODERS`` (flags bits 0-1 to a
function).
"""

from __future__ import annotations

import array
import ctypes
import ctypes.util
import os
import struct
import sys
from dataclasses import dataclass, field
from typing import Any, Callable, Dict, List, Optional, Sequence, Tuple, Union

from .errors import FrameError, MissingDependency

_numpy: Any  # numpy, or None
try:
    import numpy as _numpy_module
    _numpy = _numpy_module
except ImportError:  # optional: lists instead
    _numpy = None

#: An (n, 3) float32 numpy array, or a list of n [x, y, z] lists (numpy=False, or no numpy).
Positions = Any
#: A uint8 numpy array of n, or a list of n ints.
Scalars = Any
#: What frames are decoded from.
Buffer = Union[bytes, bytearray, memoryview]
Vec3 = Tuple[float, float, float]

MAGIC = b"CLF1"
HEADER_SIZE = 72
ROCK_SIZE = 36
MESHOPT_STRIDE = 8
FLAG_SCALAR = 4
ENCODING_MASK = 3
#: flag bits 3-15: 0 in every frame (bit 3 is kept for the encoding's third bit, later)
FLAG_RESERVED = 0xFFF8
#: The most vertices a frame may claim: clothd's largest cloth, 4096 x 4096.
MAX_VERTICES = 4096 * 4096
#: Below this extent (m) a q16 axis is flat: all 0, decoding to bbox min.
Q16_EXTENT_MIN = 1e-9

_HEADER = struct.Struct("<4sHHQQdQII3f3f")
_DELTA_HEAD = struct.Struct("<IIQd3iII")
DELTA_HEAD = 44
DELTA_KEY_KINDS = (2, 0)  # a delta section's kinds that are keyframes: 2, or 0 (the first, byte-plane layout)
_ROCK = struct.Struct("<I3ff4f")
assert _HEADER.size == HEADER_SIZE and _ROCK.size == ROCK_SIZE and _DELTA_HEAD.size == DELTA_HEAD


def _align4(n: int) -> int:
    return (n + 3) & ~3


@dataclass
class Rock:
    """A rock as a frame carries it."""
    id: int
    position: Vec3
    radius: float
    orientation: Tuple[float, float, float, float]  # quaternion x, y, z, w


@dataclass
class Frame:
    """One decoded frame. ``nbytes`` is the size of the message it came from."""
    frame: int
    step: int
    sim_time: float
    wall_ns: int
    encoding: str
    n_vertices: int
    n_rocks: int
    bbox_min: Vec3
    bbox_max: Vec3
    positions: Positions
    scalar: Optional[Scalars]
    rocks: List[Rock] = field(default_factory=list)
    nbytes: int = 0
    delta: Optional[Delta] = None  # a Delta for delta frames


def numpy_available() -> bool:
    """Whether numpy is importable (frames and cloth states decode to numpy arrays then)."""
    return _numpy is not None


def _use_numpy(numpy: Optional[bool]) -> bool:
    """numpy: None (when importable), True (required) or False (lists)."""
    if numpy is None:
        return _numpy is not None
    if numpy and _numpy is None:
        raise MissingDependency("numpy=True, but numpy is not importable (Debian: apt install python3-numpy)")
    return bool(numpy)


def float32_rows(data: Buffer, offset: int, n: int, numpy: Optional[bool] = None) -> Positions:
    """n x 3 little-endian float32 from data[offset:]: an (n, 3) float32 array, or [x, y, z] lists."""
    if _use_numpy(numpy):
        return _numpy.frombuffer(data, dtype="<f4", count=3 * n, offset=offset).reshape(n, 3).astype(_numpy.float32)
    a = array.array("f")
    a.frombytes(bytes(data[offset:offset + 12 * n]))
    if sys.byteorder == "big":
        a.byteswap()
    return [list(a[3 * v:3 * v + 3]) for v in range(n)]


def _dequantize(q: Any, stride: int, n: int, bmin: Vec3, bmax: Vec3, numpy: bool) -> Positions:
    """q16 values (stride u16 per vertex, the first 3 used) mapped back over the bbox."""
    step = [(bmax[c] - bmin[c]) / 65535.0 if bmax[c] - bmin[c] >= Q16_EXTENT_MIN else 0.0 for c in range(3)]
    if numpy:
        qa = _numpy.asarray(q).reshape(n, stride)[:, :3].astype(_numpy.float64)
        return (_numpy.asarray(bmin, dtype=_numpy.float64) + qa * _numpy.asarray(step)).astype(_numpy.float32)
    return [[bmin[c] + q[stride * v + c] * step[c] for c in range(3)] for v in range(n)]


def _u16s(data: Buffer, offset: int, count: int, numpy: bool) -> Any:
    if numpy:
        return _numpy.frombuffer(data, dtype="<u2", count=count, offset=offset)
    a = array.array("H")
    a.frombytes(bytes(data[offset:offset + 2 * count]))
    if sys.byteorder == "big":
        a.byteswap()
    return a


def _positions_f32(data: Buffer, at: int, n: int, bmin: Vec3, bmax: Vec3, numpy: bool,
                   state: Optional[FrameDecoder] = None) -> Tuple[Positions, int]:
    _need(data, at, 12 * n, "positions")
    return float32_rows(data, at, n, numpy), at + 12 * n


def _positions_q16(data: Buffer, at: int, n: int, bmin: Vec3, bmax: Vec3, numpy: bool,
                   state: Optional[FrameDecoder] = None) -> Tuple[Positions, int]:
    _need(data, at, 6 * n, "positions")
    return _dequantize(_u16s(data, at, 3 * n, numpy), 3, n, bmin, bmax, numpy), at + 6 * n


def _positions_meshopt(data: Buffer, at: int, n: int, bmin: Vec3, bmax: Vec3, numpy: bool,
                       state: Optional[FrameDecoder] = None) -> Tuple[Positions, int]:
    _need(data, at, 4, "positions")
    (length,) = struct.unpack_from("<I", data, at)
    _need(data, at + 4, length, "positions")
    decoded = meshopt_decode_vertex_buffer(bytes(data[at + 4:at + 4 + length]), n, MESHOPT_STRIDE)
    return _dequantize(_u16s(decoded, 0, 4 * n, numpy), 4, n, bmin, bmax, numpy), at + 4 + length


@dataclass
class Keyframe:
    """The newest keyframe of a delta stream, as FrameDecoder holds it."""
    id: int
    frame: int
    n: int
    quantum: float
    g: Any  # 3 n int32 grid values: a numpy int32 array or a list


def _planes_residuals(z: bytes, n: int, numpy: bool) -> Any:
    """Kinds 0 and 1 (the first layout): the residuals (3 axes of n, mod 2^32) from the byte planes z of
    their zigzags."""
    if numpy:
        planes = _numpy.frombuffer(z, dtype=_numpy.uint8).reshape(3, 4, n).astype(_numpy.uint32)
        u = planes[:, 0] | (planes[:, 1] << 8) | (planes[:, 2] << 16) | (planes[:, 3] << 24)
        return (u >> 1) ^ (_numpy.uint32(0) - (u & 1))  # (3, n)
    m = 0xFFFFFFFF
    out = []
    for c in range(3):
        base = 4 * c * n
        u = [z[base + v] | z[base + n + v] << 8 | z[base + 2 * n + v] << 16 | z[base + 3 * n + v] << 24 for v in range(n)]
        out.append([(x >> 1) ^ (-(x & 1) & m) for x in u])
    return out


def _axis_residuals(raw: bytes, n: int, escapes: int, numpy: bool) -> Any:
    """One axis block's values (kinds 2 and 3): n int8 residuals, -128 taking the next of the
    escapes int32 that follow; mod 2^32."""
    if numpy:
        r = _numpy.frombuffer(raw, dtype=_numpy.int8, count=n).astype(_numpy.int32)
        at = _numpy.flatnonzero(r == -128)
        if len(at) != escapes:
            raise FrameError("delta axis has %d escapes, its head says %d" % (len(at), escapes))
        r[at] = _numpy.frombuffer(raw, dtype="<i4", count=escapes, offset=n)
        return r.view(_numpy.uint32)
    out: List[int] = []
    e = 0
    for v in range(n):
        x = raw[v] - 256 if raw[v] >= 128 else raw[v]
        if x == -128:
            if e >= escapes:
                raise FrameError("delta axis has more escapes than its head's %d" % escapes)
            x = struct.unpack_from("<i", raw, n + 4 * e)[0]
            e += 1
        out.append(x & 0xFFFFFFFF)
    if e != escapes:
        raise FrameError("delta axis has %d escapes, its head says %d" % (e, escapes))
    return out


def _undo_prediction(r: Any, n: int, row: int, numpy: bool) -> Any:
    """The grid differences a (3 n interleaved, int32, mod 2^32) from the residuals r (3 axes)."""
    row = max(1, min(row, n))  # a row longer than the cloth is its one row
    if numpy:
        rows = -(-n // row)
        grid = _numpy.zeros((3, rows * row), dtype=_numpy.uint32)
        grid[:, :n] = _numpy.asarray(r, dtype=_numpy.uint32).reshape(3, n)
        # The parallelogram prediction's inverse is the 2D running sum, mod 2^32.
        grid = grid.reshape(3, rows, row).cumsum(axis=2, dtype=_numpy.uint32).cumsum(axis=1, dtype=_numpy.uint32)
        return grid.reshape(3, rows * row)[:, :n].T.reshape(3 * n).view(_numpy.int32)
    m = 0xFFFFFFFF
    a = [0] * (3 * n)
    for c in range(3):
        rc = r[c]
        for v in range(n):
            i, k = v % row, 3 * v + c
            if i and v >= row:
                p = a[k - 3] + a[k - 3 * row] - a[k - 3 - 3 * row]
            elif i:
                p = a[k - 3]
            elif v >= row:
                p = a[k - 3 * row]
            else:
                p = 0
            a[k] = (rc[v] + p) & m
    return [x - (1 << 32) if x >= 1 << 31 else x for x in a]


def _axis_blocks(data: Buffer, at: int, length: int, n: int, is_key: bool, numpy: bool) -> Tuple[Any, List[int]]:
    """Kinds 2 and 3: the three axis blocks at data[at:at + length]: (residuals, bases)."""
    end, p = at + length, at
    r: List[Any] = []
    bases: List[int] = []
    for c in range(3):
        if p + 12 > end:
            raise FrameError("delta axis %d block at byte %d runs past the positions (%d)" % (c, p, end))
        basis = data[p]
        escapes, zlen = struct.unpack_from("<II", data, p + 4)
        if basis > 1 or (basis == 1 and is_key):
            raise FrameError("delta axis %d of basis %d in a %s" % (c, basis, "keyframe" if is_key else "delta"))
        if escapes > n:
            raise FrameError("delta axis %d claims %d escapes for %d vertices" % (c, escapes, n))
        if p + 12 + zlen > end:
            raise FrameError("delta axis %d zstd frame of %d bytes runs past the positions" % (c, zlen))
        raw = zstd_decompress(bytes(data[p + 12:p + 12 + zlen]), n + 4 * escapes)
        r.append(_axis_residuals(raw, n, escapes, numpy))
        bases.append(basis)
        p += (12 + zlen + 3) & ~3
    if p != (end + 3) & ~3:
        raise FrameError("delta axis blocks end at byte %d, the positions at %d" % (p, (end + 3) & ~3))
    return (_numpy.stack(r) if numpy else r), bases


def _positions_delta(data: Buffer, at: int, n: int, bmin: Vec3, bmax: Vec3, numpy: bool,
                     state: Optional[FrameDecoder] = None) -> Tuple[Positions, int]:
    if state is None:
        raise FrameError("a delta frame (encoding 3) needs a FrameDecoder, which keeps its keyframe")
    _need(data, at, DELTA_HEAD, "positions")
    kind, key_id, key_frame, quantum, ox, oy, oz, row, length = _DELTA_HEAD.unpack_from(data, at)
    if kind > 3:
        raise FrameError("unknown delta kind %d" % kind)
    is_key = kind in DELTA_KEY_KINDS
    if not 0 < quantum < float("inf"):
        raise FrameError("delta quantum %r is not a positive number" % quantum)
    if row < 1:
        raise FrameError("delta row of 0 vertices")
    _need(data, at + DELTA_HEAD, length, "positions")
    key = state.keyframe
    if not is_key and not (key and key.id == key_id and key.n == n and key.quantum == quantum):
        raise FrameError("delta of keyframe %d (frame %d), and this decoder holds %s"
                         % (key_id, key_frame, "keyframe %d" % key.id if key else "no keyframe"))
    if kind >= 2:
        r, bases = _axis_blocks(data, at + DELTA_HEAD, length, n, is_key, numpy)
    else:  # the first layout's byte planes: a keyframe on the origin, a delta on the keyframe
        r = _planes_residuals(zstd_decompress(bytes(data[at + DELTA_HEAD:at + DELTA_HEAD + length]), 12 * n), n, numpy)
        bases = [0 if is_key else 1] * 3
    a = _undo_prediction(r, n, row, numpy)
    origin = (ox, oy, oz)
    key_g: Any = key.g if key is not None else None  # a delta's keyframe, checked above
    if numpy:
        base = _numpy.tile(_numpy.asarray(origin, dtype=_numpy.int32), n)
        if not is_key:
            pick = _numpy.tile(_numpy.asarray(bases) == 1, n)
            base = _numpy.where(pick, key_g, base).astype(_numpy.int32)
        g = (base.view(_numpy.uint32) + a.view(_numpy.uint32)).view(_numpy.int32)
        with _numpy.errstate(over="ignore"):  # past float32: inf, as float32 arithmetic (and frame.mjs) gives
            positions = (g.astype(_numpy.float64) * quantum).astype(_numpy.float32).reshape(n, 3)
    else:
        base = [key_g[k] if bases[k % 3] == 1 else origin[k % 3] for k in range(3 * n)]
        g = [((b + d + (1 << 31)) & 0xFFFFFFFF) - (1 << 31) for b, d in zip(base, a)]
        positions = [[float(array.array("f", [g[3 * v + c] * quantum])[0]) for c in range(3)] for v in range(n)]
    state.pending = Keyframe(key_id, key_frame, n, quantum, g) if is_key else None
    state.last_delta = Delta(is_key, key_id, key_frame, quantum)
    return positions, at + DELTA_HEAD + length


@dataclass
class Delta:
    """What a delta frame says of itself: a keyframe or not, its keyframe's id and frame, the quantum."""
    keyframe: bool
    key_id: int
    key_frame: int
    quantum: float


#: flags bits 0-1 -> (name, decoder of the positions section).
PositionDecoder = Callable[[Buffer, int, int, Vec3, Vec3, bool, Optional["FrameDecoder"]], Tuple[Positions, int]]
POSITION_DECODERS: Dict[int, Tuple[str, PositionDecoder]] = {
    0: ("f32", _positions_f32),
    1: ("q16", _positions_q16),
    2: ("meshopt", _positions_meshopt),
    3: ("delta", _positions_delta),
}
DELTA = 3


def _need(data: Buffer, at: int, count: int, what: str) -> None:
    if at + count > len(data):
        raise FrameError("frame of %d bytes is truncated: its %s need %d" % (len(data), what, at + count))


def decode_frame(data: Buffer, numpy: Optional[bool] = None, _state: Optional[FrameDecoder] = None) -> Frame:
    """Decodes one binary stream message (bytes-like) into a Frame; FrameError when it is not one.

    numpy: None to use numpy when it is importable, True to require it, False for lists. A delta
    frame needs FrameDecoder.
    """
    use_np = _use_numpy(numpy)
    data = memoryview(data).cast("B") if not isinstance(data, (bytes, bytearray)) else data
    if len(data) < HEADER_SIZE:
        raise FrameError("frame of %d bytes is shorter than its header" % len(data))
    (magic, header_size, flags, frame, step, sim_time, wall_ns, n, n_rocks,
     x0, y0, z0, x1, y1, z1) = _HEADER.unpack_from(data, 0)
    if magic != MAGIC:
        raise FrameError("not a clothd frame (magic %r)" % bytes(magic))
    if header_size < HEADER_SIZE:
        raise FrameError("frame header size %d is below %d" % (header_size, HEADER_SIZE))
    if flags & FLAG_RESERVED:
        raise FrameError("frame flags 0x%x set bits this reader does not know" % flags)
    code = flags & ENCODING_MASK
    if n > MAX_VERTICES:
        raise FrameError("frame claims %d vertices, more than %d" % (n, MAX_VERTICES))
    encoding, decode_positions = POSITION_DECODERS[code]
    bmin, bmax = (x0, y0, z0), (x1, y1, z1)
    positions, at = decode_positions(data, header_size, n, bmin, bmax, use_np, _state)
    at = _align4(at)
    scalar = None
    if flags & FLAG_SCALAR:
        _need(data, at, n, "scalars")
        scalar = (_numpy.frombuffer(data, dtype=_numpy.uint8, count=n, offset=at).copy() if use_np
                  else list(bytes(data[at:at + n])))
        at = _align4(at + n)
    _need(data, at, ROCK_SIZE * n_rocks, "rocks")
    rocks: List[Rock] = []
    for _ in range(n_rocks):
        rid, px, py, pz, radius, qx, qy, qz, qw = _ROCK.unpack_from(data, at)
        rocks.append(Rock(rid, (px, py, pz), radius, (qx, qy, qz, qw)))
        at += ROCK_SIZE
    if at != len(data):
        raise FrameError("frame has %d bytes, its sections %d" % (len(data), at))
    out = Frame(frame, step, sim_time, wall_ns, encoding, n, n_rocks, bmin, bmax, positions, scalar,
                rocks, len(data))
    if code == DELTA and _state is not None:
        out.delta = _state.last_delta
        if _state.pending is not None:  # only a frame that decoded whole replaces the keyframe
            _state.keyframe, _state.pending = _state.pending, None
    return out


class FrameDecoder:
    """Decodes one stream's frames in the order they came.

    f32, q16 and meshopt frames stand alone; delta frames refer to the newest keyframe, which
    this object keeps (``keyframe``). A delta of a keyframe it has not seen is a FrameError and
    changes nothing (the server sends each client the keyframe first; the stream's
    ``{"type": "keyframe"}`` asks for a new one).
    """

    def __init__(self, numpy: Optional[bool] = None) -> None:
        self.numpy = numpy
        self.keyframe: Optional[Keyframe] = None
        self.pending: Optional[Keyframe] = None
        self.last_delta: Optional[Delta] = None

    def decode(self, data: Buffer) -> Frame:
        """The Frame of one binary message (FrameError when it does not decode)."""
        self.pending = None
        return decode_frame(data, numpy=self.numpy, _state=self)


# ---- C libraries through ctypes: meshoptimizer's vertex codec, zstd ----

class _CLibrary:
    """A C library loaded at first use: the first of its names (or the path in the environment
    variable ``env``) that loads and has every function, each set to (restype, argtypes). ``get()``
    gives the functions in that order, or None with the reason in ``why``."""

    def __init__(self, env: str, names: Tuple[str, ...], functions: Dict[str, Tuple[Any, List[Any]]]) -> None:
        self.env, self.names, self.functions = env, names, functions
        self.fns: Optional[List[Any]] = None
        self.why: Optional[str] = None

    def get(self) -> Optional[List[Any]]:
        if self.fns is not None or self.why is not None:
            return self.fns
        given = os.environ.get(self.env)
        names = [given] if given else [n for n in (ctypes.util.find_library(self.names[0]),) + self.names[1:] if n]
        tried = []
        for name in names:
            try:
                lib = ctypes.CDLL(name)
                fns = [getattr(lib, f) for f in self.functions]
            except (OSError, AttributeError) as e:
                tried.append("%s (%s)" % (name, e))
                continue
            for fn, (restype, argtypes) in zip(fns, self.functions.values()):
                fn.restype, fn.argtypes = restype, argtypes
            self.fns = fns
            return fns
        self.why = "; ".join(tried) or "no library found"
        return None


_meshopt = _CLibrary("CLOTHD_MESHOPTIMIZER_LIB", ("meshoptimizer", "libmeshoptimizer.so.2d", "libmeshoptimizer.so",
                                                  "libmeshoptimizer.dylib", "meshoptimizer.dll"),
                     {"meshopt_decodeVertexBuffer": (ctypes.c_int, [ctypes.c_void_p, ctypes.c_size_t, ctypes.c_size_t,
                                                                     ctypes.c_char_p, ctypes.c_size_t])})
_zstd = _CLibrary("CLOTHD_ZSTD_LIB", ("zstd", "libzstd.so.1", "libzstd.dylib", "zstd.dll"),
                  {"ZSTD_decompress": (ctypes.c_size_t, [ctypes.c_void_p, ctypes.c_size_t, ctypes.c_char_p, ctypes.c_size_t]),
                   "ZSTD_isError": (ctypes.c_uint, [ctypes.c_size_t]),
                   "ZSTD_findDecompressedSize": (ctypes.c_ulonglong, [ctypes.c_char_p, ctypes.c_size_t]),
                   "ZSTD_compress": (ctypes.c_size_t, [ctypes.c_void_p, ctypes.c_size_t, ctypes.c_char_p, ctypes.c_size_t,
                                                       ctypes.c_int]),
                   "ZSTD_compressBound": (ctypes.c_size_t, [ctypes.c_size_t])})


def meshopt_available() -> bool:
    """Whether meshopt frames can be decoded here (meshoptimizer's C library is loadable)."""
    return _meshopt.get() is not None


def meshopt_decode_vertex_buffer(encoded: bytes, count: int, size: int) -> bytes:
    """meshopt_decodeVertexBuffer: ``count`` vertices of ``size`` bytes from ``encoded`` (bytes)."""
    fns = _meshopt.get()
    if fns is None:
        raise MissingDependency(
            "meshopt frames need meshoptimizer's C library (libmeshoptimizer; Debian: apt install "
            "libmeshoptimizer2d, or set CLOTHD_MESHOPTIMIZER_LIB to its path), which could not be "
            "loaded: %s; subscribe to q16 or f32 instead" % _meshopt.why)
    (fn,) = fns
    out = ctypes.create_string_buffer(count * size)
    rc = fn(out, count, size, encoded, len(encoded))
    if rc != 0:
        raise FrameError("the meshopt payload of %d bytes does not decode to %d vertices (meshoptimizer error %d)"
                         % (len(encoded), count, rc))
    return out.raw


def zstd_available() -> bool:
    """Whether delta frames can be decoded here (zstd's C library is loadable)."""
    return _zstd.get() is not None


def zstd_decompress(compressed: bytes, size: int) -> bytes:
    """ZSTD_decompress: exactly ``size`` bytes from the zstd frames ``compressed`` (one or more,
    concatenated; FrameError otherwise)."""
    lib = _zstd.get()
    if lib is None:
        raise MissingDependency(
            "delta frames need zstd's C library (libzstd; Debian: apt install libzstd1, or set "
            "CLOTHD_ZSTD_LIB to its path), which could not be loaded: %s; subscribe to q16 or f32 "
            "instead" % _zstd.why)
    fn, is_error, content_size = lib[:3]
    if content_size(compressed, len(compressed)) != size:  # before allocating what the frames claim
        raise FrameError("the delta payload of %d bytes does not hold %d bytes" % (len(compressed), size))
    out = ctypes.create_string_buffer(size + 1)
    got = fn(out, size + 1, compressed, len(compressed))
    if is_error(got) or got != size:
        raise FrameError("the delta payload of %d bytes does not decompress to %d bytes" % (len(compressed), size))
    return out.raw[:size]


def zstd_compress(data: bytes, level: int = 3) -> bytes:
    """ZSTD_compress: one zstd frame of ``data`` at ``level`` (the MCAP exporter's chunks)."""
    lib = _zstd.get()
    if lib is None:
        raise MissingDependency("zstd compression needs zstd's C library (libzstd; Debian: apt install libzstd1, or "
                                "set CLOTHD_ZSTD_LIB to its path), which could not be loaded: %s" % _zstd.why)
    is_error, compress, bound = lib[1], lib[3], lib[4]
    out = ctypes.create_string_buffer(bound(len(data)))
    got = compress(out, len(out), data, len(data), level)
    if is_error(got):
        raise RuntimeError("ZSTD_compress failed on %d bytes" % len(data))
    return out.raw[:got]
