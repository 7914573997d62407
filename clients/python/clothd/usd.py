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
from typing import AbstractSet, Any, Dict, List, Optional, Protocol, Sequence, Set, TextIO, Tuple

from .errors import RecordingError
from .frames import Frame


class _FrameEntry(Protocol):
    """What the writer reads of an index entry (clothd.recording.FrameEntry)."""
    @property
    def sim_time(self) -> float: ...

    @property
    def texts_before(self) -> int: ...


class RecordingSource(Protocol):
    """What the writer reads of a recording (clothd.recording.Recording has it): this module does
    not import recording.py, which calls it."""
    @property
    def frames(self) -> Sequence[_FrameEntry]: ...

    @property
    def problem(self) -> Optional[str]: ...

    @property
    def complete(self) -> bool: ...

    @property
    def hello(self) -> Dict[str, Any]: ...

    @property
    def info(self) -> Dict[str, Any]: ...

    def text(self, k: int) -> Dict[str, Any]: ...

    def decode(self, k: int) -> Frame: ...

_F32 = struct.Struct("<f")


def f32(x: float) -> str:
    """A float32 value as the first of %.7g, %.8g, %.9g that reads back to the same float32."""
    x = float(x)
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


def triangles(nx: int, ny: int, torn: AbstractSet[int]) -> List[int]:
    """The drawn triangles of an nx x ny cloth less the torn springs (PROTOCOL.md "hello": each
    grid quad split on its +x+y diagonal, a triangle drawn while its three springs are intact);
    the rule web/src/topology.js triangleIndices draws."""
    n = nx * ny
    out: List[int] = []
    for j in range(ny - 1):
        for i in range(nx - 1):
            v00 = j * nx + i
            v10, v01 = v00 + 1, v00 + nx
            v11 = v01 + 1
            diagonal = (2 * n + v00) not in torn
            if diagonal and v00 not in torn and (n + v10) not in torn:
                out += (v00, v10, v11)
            if diagonal and v01 not in torn and (n + v00) not in torn:
                out += (v00, v11, v01)
    return out


class _Topology:
    """The cloth's grid and torn springs, from the hello and the events after it."""

    def __init__(self, hello: Dict[str, Any]) -> None:
        scene = hello.get("scene") or {}
        self.nx, self.ny = int(scene.get("nx") or 0), int(scene.get("ny") or 0)
        self.torn = set(hello.get("torn") or [])
        self.version = 0

    def apply(self, ev: Dict[str, Any]) -> None:
        if ev.get("type") != "event":
            return
        kind = ev.get("event")
        if kind in ("scene", "reset", "snapshot_restored"):
            scene = ev.get("result") if kind == "scene" else ev.get("scene") if kind == "snapshot_restored" else None
            if isinstance(scene, dict):
                self.nx = int(scene.get("nx") or self.nx)
                self.ny = int(scene.get("ny") or self.ny)
            self.torn = set(ev.get("torn") or []) if kind == "snapshot_restored" else set()
            self.version += 1
        elif kind == "torn":
            before = len(self.torn)
            self.torn.update(ev.get("springs") or [])
            if len(self.torn) != before:
                self.version += 1


def _flat(positions: Any) -> List[float]:
    if hasattr(positions, "reshape"):
        flat: List[float] = positions.reshape(-1).tolist()
        return flat
    return [c for p in positions for c in p]


def write_usd(rec: RecordingSource, out: TextIO) -> Dict[str, Any]:
    """Writes recording ``rec`` (clothd.recording.Recording) as USD text to the text stream ``out``;
    answers ``{frames, written, cut, problem, time_codes}`` (frames decoded, time samples written,
    whether it stopped early and why). A recording without frames is a RecordingError."""
    frames = rec.frames
    if not frames:
        raise RecordingError("the recording has no frames%s: nothing to export"
                             % (" (%s)" % rec.problem if rec.problem else "" if rec.complete else " (it is cut after its hello)"),
                             16)
    info = rec.info
    rate = info.get("frame_rate") or (rec.hello.get("params") or {}).get("frame_rate") or 60
    rate = float(rate) if float(rate) > 0 else 60.0
    if rate == int(rate):
        rate = int(rate)
    # A frame's time code: its sim time past the first, in frames; going on by one frame where
    # the sim time goes back (a reset, a scene or a snapshot restored), so that it never decreases.
    tcs, total = [0.0], 0.0
    for a, b in zip(frames, frames[1:]):
        d = (b.sim_time - a.sim_time) * rate
        total += d if d >= 0 else 1
        tcs.append(round(total * 1e6) / 1e6)

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
    topo = _Topology(rec.hello)
    # (tc, nx, ny, full torn list or None, added)
    changes: List[Tuple[float, int, int, Optional[List[int]], List[int]]] = []
    last: Optional[Tuple[int, Tuple[int, int], Set[int]]] = None
    extents: List[Tuple[float, Any, Any]] = []
    rocks: Dict[int, Dict[str, Any]] = {}
    present: Set[int] = set()
    texts, written, decoded = 1, 0, 0
    first: Optional[float] = None
    last_tc: Optional[float] = None
    problem: Optional[str] = None
    for k in range(len(frames)):
        try:
            while texts < frames[k].texts_before:
                topo.apply(rec.text(texts))
                texts += 1
            frame = rec.decode(k)
        except Exception as e:  # a bad record: the frames before it are the export
            problem = "frame %d does not decode (%s): exported the %d frames before it" % (k, e, k)
            break
        decoded = k + 1
        t = tc(k)
        if k + 1 < len(frames) and tc(k + 1) == t:
            continue
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
    problems = [p for p in (rec.problem, None if rec.complete or rec.problem else
                            "the recording is cut (no index): exported the %d whole frames it has" % len(frames), problem) if p]
    return {"frames": decoded, "written": written, "cut": bool(problems), "problem": "; ".join(problems) or None,
            "time_codes": (first, last_tc)}
