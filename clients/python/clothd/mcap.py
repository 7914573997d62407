"""A clothd recording as MCAP (Foxglove, Lichtblick): ``Recording.to_mcap(path)``.

The same file as the JavaScript client's exporter (clients/js/src/recording-export.js
``exportMcap``; DESIGN section 10): one channel ``/clothd/<scene>`` of ``foxglove.SceneUpdate``
messages, JSON-encoded (message encoding ``json``, schema encoding ``jsonschema``, the schema of
@foxglove/schemas, kept beside this file as foxglove.SceneUpdate.json), one per frame at log and
publish time ``started_ns`` + the frame's time code in seconds: entity ``cloth`` (a
TriangleListPrimitive of the intact triangles, indexed) and ``rock-<id>`` per rock (a
SpherePrimitive, size = diameter) in frame ``clothd``; a rock that goes is deleted. Each message's
JSON is the JavaScript exporter's, byte for byte (numbers as JavaScript writes them). The file
is chunked (1 MiB, zstd level 3 where zstd's C library loads, else uncompressed) with message
indexes, and ends with the summary (schema, channel, statistics, chunk indexes), summary offsets
and CRCs, written as it goes: a long recording never sits in memory. The format is MCAP's
specification (mcap.dev/spec); the tests read these files with @mcap/core's reader.
"""

from __future__ import annotations

import json
import math
import re
import struct
import zlib
from decimal import Decimal
from pathlib import Path
from typing import Any, BinaryIO, Dict, List, Optional, Tuple

from .frames import zstd_available, zstd_compress
from .timeline import RecordingSource, Topology, Walk, frames_of, outcome, require_frames, time_codes, triangles

MAGIC = b"\x89MCAP0\r\n"
_HEADER, _FOOTER, _SCHEMA, _CHANNEL, _MESSAGE, _CHUNK = 0x01, 0x02, 0x03, 0x04, 0x05, 0x06
_MESSAGE_INDEX, _CHUNK_INDEX, _STATISTICS, _SUMMARY_OFFSET, _DATA_END = 0x07, 0x08, 0x0B, 0x0E, 0x0F
CHUNK_SIZE = 1 << 20
_SCHEMA_FILE = Path(__file__).with_name("foxglove.SceneUpdate.json")
_CHANNEL_ID, _SCHEMA_ID = 0, 1


def _str(s: str) -> bytes:
    b = s.encode("utf-8")
    return struct.pack("<I", len(b)) + b


def _record(op: int, content: bytes) -> bytes:
    return struct.pack("<BQ", op, len(content)) + content


def js_number(x: float) -> str:
    """x as JavaScript's JSON.stringify writes it (ECMAScript Number::toString: the shortest digits
    that read back, decimal from 1e-7 to 1e21, an exponent outside; -0 as 0, NaN and infinities as
    null)."""
    if isinstance(x, int) and not isinstance(x, bool):
        x = float(x)
    r = repr(x)
    if "e" not in r and r[-2:] != ".0" and r[0] != "n" and r[-1] != "f":  # as Python writes it
        return r
    if not math.isfinite(x):
        return "null"
    if x == 0:
        return "0"
    sign = "-" if x < 0 else ""
    t = Decimal(repr(abs(x))).normalize().as_tuple()  # repr: the shortest round-trip digits
    digits = "".join(map(str, t.digits))
    k = len(digits)
    n = int(t.exponent) + k  # x = 0.digits * 10^n
    if k <= n <= 21:
        return sign + digits + "0" * (n - k)
    if 0 < n <= 21:
        return sign + digits[:n] + "." + digits[n:]
    if -6 < n <= 0:
        return sign + "0." + "0" * -n + digits
    e = n - 1
    return sign + digits[0] + ("." + digits[1:] if k > 1 else "") + "e" + ("+" if e >= 0 else "-") + str(abs(e))


_ESCAPE = re.compile(r'[\x00-\x1f"\\\u2028\u2029]')


class _Raw(str):
    """JSON text already written (a long array of numbers)."""


def _js_json(v: Any) -> str:
    """JSON.stringify of v (dicts keep their order; no spaces; _Raw as it is)."""
    if isinstance(v, _Raw):
        return v
    if isinstance(v, dict):
        return "{" + ",".join(json.dumps(str(k), ensure_ascii=False) + ":" + _js_json(x) for k, x in v.items()) + "}"
    if isinstance(v, (list, tuple)):
        return "[" + ",".join(_js_json(x) for x in v) + "]"
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, (int, float)):
        return js_number(v)
    if v is None:
        return "null"
    return json.dumps(str(v), ensure_ascii=False).replace("\u2028", "\\u2028").replace("\u2029", "\\u2029")


class _Writer:
    """MCAP records to ``out`` as they come: the data section (its CRC kept), chunks of messages
    with their message indexes, then the summary and the footer."""

    def __init__(self, out: BinaryIO, compression: str) -> None:
        self.out, self.compression = out, compression
        self.pos, self.crc = 0, 0
        self.chunk = bytearray()
        self.index: List[Tuple[int, int]] = []  # (log time, offset in the chunk)
        self.chunk_times: Optional[Tuple[int, int]] = None
        self.chunk_indexes: List[bytes] = []
        self.count, self.chunks = 0, 0
        self.times: Optional[Tuple[int, int]] = None

    def put(self, b: bytes, data: bool = True) -> None:
        self.out.write(b)
        self.pos += len(b)
        if data:
            self.crc = zlib.crc32(b, self.crc)

    def message(self, channel: int, seq: int, ns: int, data: bytes) -> None:
        self.index.append((ns, len(self.chunk)))
        self.chunk += _record(_MESSAGE, struct.pack("<HIQQ", channel, seq, ns, ns) + data)
        self.chunk_times = (ns, ns) if self.chunk_times is None else (min(self.chunk_times[0], ns), max(self.chunk_times[1], ns))
        self.times = (ns, ns) if self.times is None else (min(self.times[0], ns), max(self.times[1], ns))
        self.count += 1
        if len(self.chunk) > CHUNK_SIZE:
            self.flush()

    def flush(self) -> None:
        if not self.index or self.chunk_times is None:
            return
        raw = bytes(self.chunk)
        body = zstd_compress(raw, 3) if self.compression == "zstd" else raw
        start = self.pos
        self.put(_record(_CHUNK, struct.pack("<QQQI", self.chunk_times[0], self.chunk_times[1], len(raw),
                                             zlib.crc32(raw)) + _str(self.compression) + struct.pack("<Q", len(body)) + body))
        chunk_length = self.pos - start
        index_at = self.pos
        entries = b"".join(struct.pack("<QQ", t, o) for t, o in self.index)
        self.put(_record(_MESSAGE_INDEX, struct.pack("<HI", _CHANNEL_ID, len(entries)) + entries))
        offsets = struct.pack("<HQ", _CHANNEL_ID, index_at)
        self.chunk_indexes.append(_record(_CHUNK_INDEX, struct.pack("<QQQQ", self.chunk_times[0], self.chunk_times[1], start,
                                                                    chunk_length)
                                          + struct.pack("<I", len(offsets)) + offsets
                                          + struct.pack("<Q", self.pos - index_at) + _str(self.compression)
                                          + struct.pack("<QQ", len(body), len(raw))))
        self.chunks += 1
        self.chunk, self.index, self.chunk_times = bytearray(), [], None

    def end(self, schema: bytes, channel: bytes) -> None:
        self.flush()
        self.put(_record(_DATA_END, struct.pack("<I", self.crc)), data=False)
        summary_start, scrc = self.pos, 0
        groups: List[Tuple[int, int, int]] = []

        def group(op: int, records: List[bytes]) -> None:
            nonlocal scrc
            at = self.pos
            for r in records:
                self.put(r, data=False)
                scrc = zlib.crc32(r, scrc)
            if self.pos > at:
                groups.append((op, at, self.pos - at))

        t0, t1 = self.times or (0, 0)
        counts = struct.pack("<HQ", _CHANNEL_ID, self.count)
        stats = _record(_STATISTICS, struct.pack("<QHIIIIQQ", self.count, 1, 1, 0, 0, self.chunks, t0, t1)
                        + struct.pack("<I", len(counts)) + counts)
        group(_SCHEMA, [schema])
        group(_CHANNEL, [channel])
        group(_STATISTICS, [stats])
        group(_CHUNK_INDEX, self.chunk_indexes)
        offsets_start = self.pos
        group(0, [_record(_SUMMARY_OFFSET, struct.pack("<BQQ", op, at, length)) for op, at, length in groups])
        head = struct.pack("<BQQQ", _FOOTER, 20, summary_start, offsets_start)
        scrc = zlib.crc32(head, scrc)
        self.put(head + struct.pack("<I", scrc) + MAGIC, data=False)


def write_mcap(rec: RecordingSource, out: BinaryIO, compression: Optional[str] = None) -> Dict[str, Any]:
    """Writes recording ``rec`` (clothd.recording.Recording) as MCAP to the binary stream ``out``;
    answers ``{frames, written, cut, problem, time_codes, compression}``. ``compression``: ``zstd``,
    ``none``, or None for zstd where zstd's C library loads. A recording without frames is a
    RecordingError."""
    require_frames(rec)
    if compression not in (None, "zstd", "none"):
        raise ValueError("compression is zstd, none or None, not %r" % (compression,))
    comp = "zstd" if compression == "zstd" or (compression is None and zstd_available()) else ""
    rate, tcs = time_codes(rec)
    info = rec.info
    scene = str(info.get("scene") or rec.hello.get("scene_id") or "default")
    schema = _record(_SCHEMA, struct.pack("<H", _SCHEMA_ID) + _str("foxglove.SceneUpdate") + _str("jsonschema")
                     + (lambda d: struct.pack("<I", len(d)) + d)(_SCHEMA_FILE.read_bytes().strip()))
    meta = _str("recording") + _str(str(info.get("id") or "")) + _str("scene") + _str(scene)
    channel = _record(_CHANNEL, struct.pack("<HH", _CHANNEL_ID, _SCHEMA_ID)
                      + _str("/clothd/" + (re.sub(r"[^A-Za-z0-9_-]", "_", scene) or "scene")) + _str("json")
                      + struct.pack("<I", len(meta)) + meta)
    w = _Writer(out, comp)
    w.put(MAGIC + _record(_HEADER, _str("") + _str("clothd")) + schema + channel)
    try:
        started = float(info.get("started_ns") or 0)  # a JSON number to JavaScript: the double nearest
    except (TypeError, ValueError):
        started = 0.0
    base = int(started) if math.isfinite(started) and started > 0 else 0
    walk, topo = Walk(), Topology(rec.hello)
    tri = _Raw("[]")
    shape: Optional[Tuple[int, int, int]] = None
    present: List[int] = []
    written, seq = 0, 0
    first: Optional[float] = None
    last: Optional[float] = None
    identity = {"position": {"x": 0, "y": 0, "z": 0}, "orientation": {"x": 0, "y": 0, "z": 0, "w": 1}}
    for frame, tc in frames_of(rec, tcs, walk, topo):
        ns = base + math.floor(tc / rate * 1e9 + 0.5)  # Math.round
        stamp = {"sec": ns // 1000000000, "nsec": ns % 1000000000}
        if shape != (topo.version, topo.nx, topo.ny):
            tri = _Raw("[" + ",".join(map(str, triangles(topo.nx, topo.ny, topo.torn))) + "]")
            shape = (topo.version, topo.nx, topo.ny)
        if hasattr(frame.positions, "reshape"):  # numpy: float32 already
            flat = frame.positions.reshape(-1).tolist()
        else:  # as float32, what the frame holds and JavaScript's Float32Array gives
            flat = [c for p in frame.positions for c in p]
            flat = list(struct.unpack("<%df" % len(flat), struct.pack("<%df" % len(flat), *flat)))
        nums = [js_number(c) for c in flat]
        points = _Raw("[" + ",".join('{"x":%s,"y":%s,"z":%s}' % (nums[3 * v], nums[3 * v + 1], nums[3 * v + 2])
                                     for v in range(len(nums) // 3)) + "]")

        def entity(eid: str, **extra: Any) -> Dict[str, Any]:
            e: Dict[str, Any] = {"timestamp": stamp, "frame_id": "clothd", "id": eid, "lifetime": {"sec": 0, "nsec": 0},
                                 "frame_locked": False, "metadata": [], "arrows": [], "cubes": [], "spheres": [],
                                 "cylinders": [], "lines": [], "triangles": [], "texts": [], "models": []}
            e.update(extra)
            return e

        entities = [entity("cloth", triangles=[{"pose": identity, "points": points,
                                                "color": {"r": 0.78, "g": 0.33, "b": 0.24, "a": 1}, "colors": [],
                                                "indices": tri}])]
        now: List[int] = []
        for r in frame.rocks:
            now.append(r.id)
            x, y, z = r.position
            qx, qy, qz, qw = r.orientation
            d = 2 * r.radius
            entities.append(entity("rock-%d" % (r.id & 0xFFFFFFFF), spheres=[{
                "pose": {"position": {"x": x, "y": y, "z": z}, "orientation": {"x": qx, "y": qy, "z": qz, "w": qw}},
                "size": {"x": d, "y": d, "z": d}, "color": {"r": 0.85, "g": 0.64, "b": 0.25, "a": 1}}]))
        gone = [{"timestamp": stamp, "type": 0, "id": "rock-%d" % (rid & 0xFFFFFFFF)} for rid in present if rid not in now]
        present = list(dict.fromkeys(now))
        w.message(_CHANNEL_ID, seq, ns, _js_json({"deletions": gone, "entities": entities}).encode("utf-8"))
        seq += 1
        written += 1
        if first is None:
            first = (ns - base) / 1e9
        last = (ns - base) / 1e9
    w.end(schema, channel)
    result = outcome(rec, walk, written, first, last)
    result["compression"] = comp or "none"
    return result
