"""A clothd recording as USD text (.usda): ``Recording.to_usd(path)``.

The same layer as the JavaScript client's exporter (clients/js/src/recording-export.js; DESIGN
section 10): ``upAxis = "Z"``, ``metersPerUnit = 1``, ``timeCodesPerSecond`` the recording's
frame rate, start/endTimeCode; ``/clothd/cloth`` a Mesh with time-sampled ``points`` (each frame
written to the file as it is decoded, then dropped), ``extent``, and ``faceVertexCounts`` /
``faceVertexIndices`` at the first frame and where tears change the topology; each rock an Xform
``/clothd/rock_<id>`` with time-sampled ``xformOp:translate`` and ``xformOp:orient`` (quatf, real
first) over a Sphere of its radius. Numbers are written so that they read back to the same
float32. A time code is the frame's sim time past the first in frames (one frame on where the sim
time goes back: a reset); a frame followed by one at the same time (a command between two frames)
gives way to it.
"""

from __future__ import annotations

import math
import re
import struct
from typing import Any, Dict, List, Optional, Set, TextIO, Tuple

from .timeline import RecordingSource, Topology, Walk, frames_of, outcome, require_frames, time_codes
from .timeline import triangles as triangles  # the rule of the drawn triangles, for the exporters' callers


_F32 = struct.Struct("<f")


def f32(x: float) -> str:
    """A float32 value as the first of %.7g, %.8g, %.9g that reads back to the same float32. A
    float64 (positions decoded without numpy) is rounded to float32 first: its own %.9g could read
    back to the float32 next to it."""
    x = float(x)
    try:
        x = _F32.unpack(_F32.pack(x))[0]
    except OverflowError:  # past float32's range
        x = math.copysign(math.inf, x)
    if x == 0:
        return "-0" if math.copysign(1.0, x) < 0 else "0"
    if not math.isfinite(x):
        return "nan" if x != x else ("inf" if x > 0 else "-inf")
    for p in (7, 8):
        s = "%.*g" % (p, x)
        if _F32.unpack(_F32.pack(float(s)))[0] == x:
            return s
    return "%.9g" % x


def _f32_all(values: Any) -> List[str]:
    """f32 of each of a flat float32 numpy array, the same strings: all formatted at once with %.7g
    (one format string), read back at once, those that differ again with %.8g, then %.9g."""
    import numpy as np
    out = np.empty(len(values), dtype=object)
    todo = np.arange(len(values))
    wide = values.astype(np.float64)
    for p in (7, 8, 9):
        sub = wide[todo].tolist()
        strs = np.array((("%%.%dg\n" % p) * len(sub) % tuple(sub)).split("\n")[:-1], dtype=object)
        if p == 9:
            out[todo] = strs
            break
        same = np.array(strs.tolist(), dtype=np.float64).astype(np.float32) == values[todo]
        out[todo[same]] = strs[same]
        todo = todo[~same]
        if not len(todo):
            break
    strings: List[str] = out.tolist()
    return strings


def _time(tc: float) -> str:
    return str(int(tc)) if tc == int(tc) else repr(tc)


_ESCAPES = {"\\": "\\\\", '"': '\\"', "\n": "\\n", "\t": "\\t", "\r": "\\r"}


def _escape(m: re.Match[str]) -> str:
    return _ESCAPES.get(m.group(0), "\ufffd")


def _string(s: object) -> str:
    """A USD string literal: double-quoted, UTF-8, with \\ \" \\n \\t \\r escaped; other control
    characters (and a lone surrogate) become U+FFFD, as the JavaScript exporter writes them."""
    text = str(s).encode("utf-16", "surrogatepass").decode("utf-16", "replace")
    return '"%s"' % re.sub(r'[\\"\x00-\x1f\x7f]', _escape, text)


def _flat(positions: Any) -> List[float]:
    if hasattr(positions, "reshape"):
        flat: List[float] = positions.reshape(-1).tolist()
        return flat
    return [c for p in positions for c in p]


def write_usd(rec: RecordingSource, out: TextIO) -> Dict[str, Any]:
    """Writes recording ``rec`` (clothd.recording.Recording) as USD text to the text stream ``out``;
    answers ``{frames, written, cut, problem, time_codes}`` (frames decoded, time samples written,
    whether it stopped early and why). A recording without frames is a RecordingError."""
    require_frames(rec)
    frames = rec.frames
    info = rec.info
    rate, tcs = time_codes(rec)

    def tc(k: int) -> float:
        return tcs[k]

    scene = str(info.get("scene") or rec.hello.get("scene_id") or "")
    out.write('#usda 1.0\n(\n    defaultPrim = "clothd"\n    doc = %s\n    endTimeCode = %s\n    metersPerUnit = 1\n'
              '    startTimeCode = 0\n    timeCodesPerSecond = %s\n    upAxis = "Z"\n)\n\n'
              % (_string("clothd recording %s of scene %s" % (info.get("id") or "", scene)), _time(tc(len(frames) - 1)), rate))
    out.write('def Xform "clothd" (\n    customData = {\n        string encoding = %s\n        string recording = %s\n'
              '        string scene = %s\n    }\n)\n{\n    def Mesh "cloth"\n    {\n        uniform bool doubleSided = 1\n'
              '        uniform token subdivisionScheme = "none"\n        point3f[] points.timeSamples = {\n'
              % (_string(info.get("encoding") or ""), _string(info.get("id") or ""), _string(scene)))
    topo = Topology(rec.hello)
    # (tc, nx, ny, full torn list or None, added)
    changes: List[Tuple[float, int, int, Optional[List[int]], List[int]]] = []
    last: Optional[Tuple[int, Tuple[int, int], Set[int]]] = None
    extents: List[Tuple[float, Any, Any]] = []
    rocks: Dict[int, Dict[str, Any]] = {}
    present: Set[int] = set()
    written = 0
    first: Optional[float] = None
    last_tc: Optional[float] = None
    walk = Walk()
    for frame, t in frames_of(rec, tcs, walk, topo):
        if first is None:
            first = t
        last_tc = t
        if hasattr(frame.positions, "reshape"):  # numpy
            p = frame.positions.reshape(-1, 3)
            lo, hi = (p.min(axis=0).tolist(), p.max(axis=0).tolist()) if len(p) else ((0, 0, 0), (0, 0, 0))
            text = _f32_all(p.reshape(-1))
        else:
            flat = _flat(frame.positions)
            xs, ys, zs = flat[0::3], flat[1::3], flat[2::3]
            lo, hi = ((min(xs), min(ys), min(zs)), (max(xs), max(ys), max(zs))) if flat else ((0, 0, 0), (0, 0, 0))
            text = [f32(x) for x in flat]
        extents.append((t, lo, hi))
        out.write("            %s: [%s],\n" % (_time(t), ("(%s, %s, %s), " * (len(text) // 3) % tuple(text))[:-2]))
        written += 1
        if last is None or last[0] != topo.version or last[1] != (topo.nx, topo.ny):
            if last is None or last[1] != (topo.nx, topo.ny) or not last[2] <= topo.torn:
                changes.append((t, topo.nx, topo.ny, sorted(topo.torn), []))
            elif topo.torn != last[2]:
                changes.append((t, topo.nx, topo.ny, None, sorted(topo.torn - last[2])))
            last = (topo.version, (topo.nx, topo.ny), set(topo.torn))
        now: Set[int] = set()
        for r in frame.rocks:
            now.add(r.id)
            rock = rocks.get(r.id)
            if rock is None:
                rock = rocks[r.id] = {"radius": r.radius, "poses": [], "vis": [] if t == first else [(first, False)]}
            if r.id not in present and rock["vis"]:
                rock["vis"].append((t, True))
            x, y, z = r.position
            qx, qy, qz, qw = r.orientation
            rock["poses"].append((t, (x, y, z), (qw, qx, qy, qz)))
        for rid in present - now:
            rocks[rid]["vis"].append((t, False))
        present = now
    out.write("        }\n        float3[] extent.timeSamples = {\n")
    for t, lo, hi in extents:
        out.write("            %s: [(%s), (%s)],\n" % (_time(t), ", ".join(map(f32, lo)), ", ".join(map(f32, hi))))
    out.write("        }\n")
    for which in ("faceVertexCounts", "faceVertexIndices"):
        out.write("        int[] %s.timeSamples = {\n" % which)
        torn: Set[int] = set()
        for t, nx, ny, full, added in changes:
            if full is not None:
                torn = set(full)
            torn.update(added)
            tri = triangles(nx, ny, torn)
            values = ["3"] * (len(tri) // 3) if which == "faceVertexCounts" else [str(v) for v in tri]
            out.write("            %s: [%s],\n" % (_time(t), ", ".join(values)))
        out.write("        }\n")
    out.write("    }\n")
    for rid in sorted(rocks):
        rock = rocks[rid]
        rad = f32(rock["radius"])
        out.write('\n    def Xform "rock_%d"\n    {\n        float3 xformOp:translate.timeSamples = {\n' % (rid & 0xFFFFFFFF))
        for t, p, _ in rock["poses"]:
            out.write("            %s: (%s),\n" % (_time(t), ", ".join(map(f32, p))))
        out.write("        }\n        quatf xformOp:orient.timeSamples = {\n")
        for t, _, q in rock["poses"]:
            out.write("            %s: (%s),\n" % (_time(t), ", ".join(map(f32, q))))
        out.write('        }\n        uniform token[] xformOpOrder = ["xformOp:translate", "xformOp:orient"]\n')
        if rock["vis"]:
            out.write("        token visibility.timeSamples = {\n%s        }\n" % "".join(
                '            %s: "%s",\n' % (_time(t), "inherited" if v else "invisible") for t, v in rock["vis"]))
        out.write('\n        def Sphere "sphere"\n        {\n            float3[] extent = [(-%s, -%s, -%s), (%s, %s, %s)]\n'
                  '            double radius = %s\n        }\n    }\n' % ((rad,) * 7))
    out.write("}\n")
    return outcome(rec, walk, written, first, last_tc)
