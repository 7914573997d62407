"""What the exporters (clothd.usd, clothd.mcap) share: a recording read as a timeline.

The rules of the JavaScript client's exporters (clients/js/src/recording-export.js, ``timeCodes``
and ``framesOf``): a frame's time code is its sim time past the first, in frames (one frame on
where the sim time goes back: a reset, a scene or a snapshot restored), rounded to 1e-6; a frame
followed by one at the same time code (a command between two frames) gives way to it; the
cloth's grid and torn springs follow the hello and the events before each frame; a frame that
does not decode ends the export with the frames before it, and says so.
"""

from __future__ import annotations

from typing import AbstractSet, Any, Dict, Iterator, List, Optional, Protocol, Sequence, Tuple, Union

from .errors import RecordingError
from .frames import Frame


class FrameEntry(Protocol):
    """What an exporter reads of an index entry (clothd.recording.FrameEntry)."""
    @property
    def sim_time(self) -> float: ...

    @property
    def texts_before(self) -> int: ...


class RecordingSource(Protocol):
    """What an exporter reads of a recording (clothd.recording.Recording has it): the exporters do
    not import recording.py, which calls them."""
    @property
    def frames(self) -> Sequence[FrameEntry]: ...

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


class Topology:
    """The cloth's grid and torn springs, from the hello and the events after it; ``version`` counts
    the changes."""

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


def require_frames(rec: RecordingSource) -> None:
    """A recording without frames is a RecordingError: nothing to export."""
    if not rec.frames:
        raise RecordingError("the recording has no frames%s: nothing to export"
                             % (" (%s)" % rec.problem if rec.problem else "" if rec.complete else " (it is cut after its hello)"),
                             16)


def time_codes(rec: RecordingSource) -> Tuple[Union[int, float], List[float]]:
    """The frame rate (an int where it is whole) and each frame's time code."""
    rate: Union[int, float] = rec.info.get("frame_rate") or (rec.hello.get("params") or {}).get("frame_rate") or 60
    rate = float(rate) if float(rate) > 0 else 60.0
    if rate == int(rate):
        rate = int(rate)
    frames = rec.frames
    tcs, total = [0.0], 0.0
    for a, b in zip(frames, frames[1:]):
        d = (b.sim_time - a.sim_time) * rate
        total += d if d >= 0 else 1
        tcs.append(round(total * 1e6) / 1e6)
    return rate, tcs


class Walk:
    """What a walk over the frames met: ``decoded`` (frames decoded) and ``problem`` (the frame
    that did not decode, or None)."""

    def __init__(self) -> None:
        self.decoded = 0
        self.problem: Optional[str] = None


def frames_of(rec: RecordingSource, tcs: Sequence[float], walk: Walk, topo: Topology) -> Iterator[Tuple[Frame, float]]:
    """Each frame that is exported, decoded, with its time code; ``topo`` follows the events before
    it. Stops at a frame that does not decode (``walk.problem`` says which)."""
    frames = rec.frames
    texts = 1
    for k in range(len(frames)):
        try:
            while texts < frames[k].texts_before:
                topo.apply(rec.text(texts))
                texts += 1
            frame = rec.decode(k)
        except Exception as e:  # a bad record: the frames before it are the export
            walk.problem = "frame %d does not decode (%s): exported the %d frames before it" % (k, e, k)
            return
        walk.decoded = k + 1
        if k + 1 < len(frames) and tcs[k + 1] == tcs[k]:
            continue
        yield frame, tcs[k]


def outcome(rec: RecordingSource, walk: Walk, written: int, first: Optional[float],
            last: Optional[float]) -> Dict[str, Any]:
    """An exporter's answer: ``{frames, written, cut, problem, time_codes}``."""
    problems = [p for p in (rec.problem, None if rec.complete or rec.problem else
                            "the recording is cut (no index): exported the %d whole frames it has" % len(rec.frames),
                            walk.problem) if p]
    return {"frames": walk.decoded, "written": written, "cut": bool(problems), "problem": "; ".join(problems) or None,
            "time_codes": (first, last)}
