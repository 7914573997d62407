"""clothd recordings (CLR1, PROTOCOL.md "Recordings"): one scene's stream written down.

A recording is the scene's ``hello`` (text), then its events (text records) and every frame it
published (binary CLF1 frames, as clothd.frames decodes them), in order. A finished one ends
with an index of its frames and texts and a 16-byte tail that points at it, so frame k is found
at once; a file without a valid tail (still being recorded, or cut by a crash) is read by
scanning its records up to the last complete one (``complete`` is then False).

    rec = clothd.read_recording(open("run.clr", "rb").read())
    rec.hello["scene"]["nx"], len(rec), rec.duration
    frame = rec.decode(rec.seek(2.5))        # the frame 2.5 s in (its keyframe decoded first)
    for frame in rec: ...                    # every frame in order
    rec.to_usd("run.usda")                   # USD text for Blender or Houdini (clothd.usd)
"""

from __future__ import annotations

import json
import math
import os
import struct
import warnings
from typing import Any, Callable, Dict, Iterator, List, NoReturn, Optional, Tuple, Union

from .errors import RecordingError as RecordingError  # raised here; clothd.recording.RecordingError stays
from .frames import DELTA_KEY_KINDS, POSITION_DECODERS, Buffer, Frame, FrameDecoder
from .mcap import write_mcap
from .timeline import require_frames
from .usd import write_usd

#: A text record's place: (offset, payload length).
TextEntry = Tuple[int, int]

REC_MAGIC = b"CLR1"
TAIL_MAGIC = b"CLRX"
REC_VERSION = 1
FILE_HEADER = 16
RECORD_HEAD = 8
TAIL_SIZE = 16
INDEX_FRAME_SIZE = 24
INDEX_TEXT_SIZE = 8
TEXT, FRAME, INDEX = 1, 2, 3
MAX_RECORDS = 1 << 24

_CLF_HEADER = 72
_CLF_DELTA = 3
_CLF_MAX_VERTICES = 4096 * 4096
_ENCODINGS = tuple(POSITION_DECODERS[k][0] for k in sorted(POSITION_DECODERS))  # the wire's order
_RELAYOUT = ("scene", "snapshot_restored")


def _align4(n: int) -> int:
    return (n + 3) & ~3


class FrameEntry:
    """Where frame k is: its record's ``offset``, payload ``length``, ``sim_time``, ``key`` (the
    ordinal of the keyframe it needs; itself unless a delta) and ``texts_before``."""
    __slots__ = ("offset", "length", "sim_time", "key", "texts_before")

    def __init__(self, offset: int, length: int, sim_time: float, key: int, texts_before: int) -> None:
        self.offset, self.length, self.sim_time, self.key, self.texts_before = offset, length, sim_time, key, texts_before

    def __repr__(self) -> str:
        return "FrameEntry(offset=%d, length=%d, sim_time=%r, key=%d, texts_before=%d)" % (
            self.offset, self.length, self.sim_time, self.key, self.texts_before)


class Recording:
    """A parsed recording (``read_recording``): ``hello``, ``info`` (the hello's ``recording``),
    ``frames`` (FrameEntry each), ``texts`` ((offset, length) each), ``complete``, ``duration``,
    ``problem`` (read with ``salvage``: what was wrong past the hello, None when nothing)."""

    def __init__(self, data: memoryview, frames: List[FrameEntry], texts: List[TextEntry], complete: bool,
                 numpy: Optional[bool] = None, problem: Optional[str] = None) -> None:
        self._data = data
        self.problem = problem
        self.frames = frames
        self.texts = texts
        self.complete = complete
        self.numpy = numpy
        self.hello = self.text(0)
        if self.hello.get("type") != "hello" or not isinstance(self.hello.get("scene"), dict):
            raise RecordingError("the first record is not a hello with its scene", FILE_HEADER)
        self.info: Dict[str, Any] = self.hello.get("recording") or {}
        self._t0 = frames[0].sim_time if frames else 0.0
        self.duration = frames[-1].sim_time - self._t0 if frames else 0.0
        self._decoder: Optional[FrameDecoder] = None
        self._decoded_key: Optional[int] = None

    def __len__(self) -> int:
        return len(self.frames)

    def __repr__(self) -> str:
        return "Recording(%r, %d frames, %.3f s%s)" % (self.info.get("id"), len(self.frames), self.duration,
                                                        "" if self.complete else ", cut")

    def frame_bytes(self, k: int) -> bytes:
        """The CLF1 message of frame k (bytes)."""
        f = self.frames[k]
        return bytes(self._data[f.offset + RECORD_HEAD:f.offset + RECORD_HEAD + f.length])

    def text(self, k: int) -> Dict[str, Any]:
        """Text record k, parsed (0 is the hello)."""
        offset, length = self.texts[k]
        raw = bytes(self._data[offset + RECORD_HEAD:offset + RECORD_HEAD + length])
        try:
            value = json.loads(raw.decode("utf-8"))
        except (UnicodeDecodeError, ValueError) as e:
            raise RecordingError("text record %d is not JSON: %s" % (k, e), offset) from None
        if not isinstance(value, dict):
            raise RecordingError("text record %d is not a JSON object" % k, offset)
        return value

    def events(self, until: Optional[int] = None) -> List[Dict[str, Any]]:
        """The events (text records after the hello) before frame ``until`` (all when None)."""
        end = len(self.texts) if until is None else self.frames[until].texts_before
        return [self.text(k) for k in range(1, end)]

    def seek(self, t: float) -> int:
        """The ordinal of the last frame at or before t seconds past the first (-1 when none)."""
        lo, hi = 0, len(self.frames) - 1
        if hi < 0:
            return -1
        while lo < hi:
            mid = (lo + hi + 1) >> 1
            if self.frames[mid].sim_time - self._t0 <= t + 1e-9:
                lo = mid
            else:
                hi = mid - 1
        return lo

    def decode(self, k: int) -> Frame:
        """Frame k decoded (clothd.frames.Frame); a delta frame's keyframe is decoded first
        when the last one decoded was another."""
        f = self.frames[k]
        if self._decoder is None:
            self._decoder = FrameDecoder(numpy=self.numpy)
        if f.key != k and self._decoded_key != f.key:
            self._decoder.decode(self.frame_bytes(f.key))
            self._decoded_key = f.key
        frame = self._decoder.decode(self.frame_bytes(k))
        if f.key == k:
            self._decoded_key = k
        return frame

    def __iter__(self) -> Iterator[Frame]:
        for k in range(len(self.frames)):
            yield self.decode(k)

    def to_usd(self, path: Union[str, os.PathLike[str]]) -> Dict[str, Any]:
        """Writes the recording as USD text (.usda) to ``path``, one frame at a time (clothd.usd).
        Answers ``{frames, written, cut, problem, time_codes}``; a cut or corrupt recording exports
        up to its last whole frame, with a warning (RuntimeWarning) that says where it stopped. A
        recording without frames is a RecordingError and writes nothing."""
        require_frames(self)  # no frames: no file is made
        return self._export(path, lambda out: write_usd(self, out), text=True)

    def to_mcap(self, path: Union[str, os.PathLike[str]], compression: Optional[str] = None) -> Dict[str, Any]:
        """Writes the recording as MCAP (Foxglove, Lichtblick) to ``path``, one frame at a time
        (clothd.mcap): one channel of foxglove.SceneUpdate, chunks compressed with zstd where its C
        library loads (``compression``: ``zstd``, ``none``, or None for that choice). Answers
        ``{frames, written, cut, problem, time_codes, compression}``; cut, corrupt and empty
        recordings as ``to_usd``."""
        require_frames(self)
        return self._export(path, lambda out: write_mcap(self, out, compression), text=False)

    def _export(self, path: Union[str, os.PathLike[str]], write: Callable[[Any], Dict[str, Any]], text: bool) -> Dict[str, Any]:
        """write(stream) into path + ".part", renamed to path once whole (removed on an error)."""
        part = os.fspath(path) + ".part"
        try:
            with (open(part, "w", encoding="utf-8", newline="\n") if text else open(part, "wb")) as out:
                result = write(out)
            os.replace(part, path)
        except BaseException:
            if os.path.exists(part):
                os.remove(part)
            raise
        if result["cut"]:
            warnings.warn("clothd recording export: " + result["problem"], RuntimeWarning, stacklevel=3)
        return result


def read_recording(data: Buffer, numpy: Optional[bool] = None, salvage: bool = False) -> Recording:
    """A Recording from a whole .clr file (or as much as there is of one); RecordingError when
    it is not one or is corrupt. numpy: as clothd.frames (None: numpy when installed). salvage:
    for an export, a bad index is ignored (the records are scanned) and a bad record after the
    hello ends the frames before it; ``problem`` says what was wrong."""
    view = memoryview(bytes(data))
    if len(view) < FILE_HEADER:
        raise RecordingError("a recording is at least %d bytes, this is %d" % (FILE_HEADER, len(view)), 0)
    if bytes(view[0:4]) != REC_MAGIC:
        raise RecordingError("not a clothd recording (magic %r)" % bytes(view[0:4]), 0)
    version, flags = struct.unpack_from("<II", view, 4)
    if version != REC_VERSION:
        raise RecordingError("recording version %d, this reader knows %d" % (version, REC_VERSION), 4)
    if flags:
        raise RecordingError("recording flags this reader does not know", 8)
    problem: List[str] = []
    found: Optional[Tuple[List[FrameEntry], List[TextEntry]]]
    try:
        found = _read_index(view)
    except RecordingError as e:
        if not salvage:
            raise
        problem.append("%s; its records were scanned instead" % e)
        found = None
    frames, texts = found if found else _scan(view, problem if salvage else None)
    if not texts or texts[0][0] != FILE_HEADER:
        raise RecordingError("the first record of a recording is its hello (text)", FILE_HEADER)
    rec = Recording(view, frames, texts, complete=found is not None, numpy=numpy)
    try:
        _check_frames(view, rec)
    except RecordingError as e:
        if not salvage or e.frame is None:
            raise
        del frames[e.frame:]
        problem.append("%s: the %d frames before it are kept" % (e, e.frame))
    rec.problem = "; ".join(problem) or None
    return rec


def _u32(data: memoryview, at: int) -> int:
    value: int = struct.unpack_from("<I", data, at)[0]
    return value


def _read_index(data: memoryview) -> Optional[Tuple[List[FrameEntry], List[TextEntry]]]:
    size = len(data)
    if size < FILE_HEADER + RECORD_HEAD + 8 + TAIL_SIZE:
        return None
    tail = size - TAIL_SIZE
    if bytes(data[tail:tail + 4]) != TAIL_MAGIC or _u32(data, tail + 4) != 0:
        return None
    at: int = struct.unpack_from("<Q", data, tail + 8)[0]

    def bad(what: str, where: int = tail + 8) -> NoReturn:
        raise RecordingError("the recording's index: " + what, where)

    if at < FILE_HEADER or at % 4 or at + RECORD_HEAD + 8 > tail:
        bad("its offset %d is not inside the file" % at)
    if _u32(data, at) != INDEX:
        bad("the tail points at a record that is not the index", at)
    length = _u32(data, at + 4)
    if at + RECORD_HEAD + _align4(length) != tail:
        bad("a payload of %d bytes does not end at the tail" % length, at + 4)
    nf, nt = struct.unpack_from("<II", data, at + 8)
    if nf + nt > MAX_RECORDS:
        bad("%d records, more than %d" % (nf + nt, MAX_RECORDS), at + 8)
    if length != 8 + INDEX_FRAME_SIZE * nf + INDEX_TEXT_SIZE * nt:
        bad("%d frames and %d texts do not take %d bytes" % (nf, nt, length), at + 8)

    def record(offset: int, kind: int, k: int, what: str) -> int:
        if offset < FILE_HEADER or offset % 4 or offset + RECORD_HEAD > at or _u32(data, offset) != kind:
            bad("%s %d does not point at a %s record" % (what, k, "text" if kind == TEXT else "frame"), offset)
        n = _u32(data, offset + 4)
        if offset + RECORD_HEAD + n > at:
            bad("%s %d runs past the index" % (what, k), offset)
        return n

    frames: List[FrameEntry] = []
    texts: List[TextEntry] = []
    p = at + 16
    for k in range(nf):
        offset, sim_time, key, before = struct.unpack_from("<QdII", data, p)
        entry = FrameEntry(offset, record(offset, FRAME, k, "frame"), sim_time, key, before)
        if k and offset <= frames[-1].offset:
            bad("frame %d is not after frame %d" % (k, k - 1), p)
        if key > k or before > nt:
            bad("frame %d's keyframe or text count is out of range" % k, p + 16)
        frames.append(entry)
        p += INDEX_FRAME_SIZE
    for k in range(nt):
        offset = struct.unpack_from("<Q", data, p)[0]
        texts.append((offset, record(offset, TEXT, k, "text")))
        if k and offset <= texts[-2][0]:
            bad("text %d is not after text %d" % (k, k - 1), p)
        p += INDEX_TEXT_SIZE
    t = 0
    for k, f in enumerate(frames):
        while t < nt and texts[t][0] < f.offset:
            t += 1
        if f.texts_before != t:
            bad("frame %d says %d texts come before it, there are %d" % (k, f.texts_before, t),
                at + 16 + INDEX_FRAME_SIZE * k + 20)
    return frames, texts


def _scan(data: memoryview, problem: Optional[List[str]] = None) -> Tuple[List[FrameEntry], List[TextEntry]]:
    frames: List[FrameEntry] = []
    texts: List[TextEntry] = []
    key = -1
    at, size = FILE_HEADER, len(data)
    while at + RECORD_HEAD <= size:
        if len(frames) + len(texts) >= MAX_RECORDS:
            raise RecordingError("more than %d records" % MAX_RECORDS, at)
        kind, length = struct.unpack_from("<II", data, at)
        if kind < TEXT or kind > INDEX:
            if problem is None:
                raise RecordingError("record of unknown type %d" % kind, at)
            problem.append("record of unknown type %d at byte %d: the records before it are kept" % (kind, at))
            break
        if at + RECORD_HEAD + length > size:
            break  # cut mid-record: what came before counts
        if kind == TEXT:
            texts.append((at, length))
        elif kind == FRAME:
            p = at + RECORD_HEAD
            is_key = (length < _CLF_HEADER + 4 or (struct.unpack_from("<H", data, p + 6)[0] & 3) != _CLF_DELTA
                      or _u32(data, p + _CLF_HEADER) in DELTA_KEY_KINDS)
            if is_key:
                key = len(frames)
            sim_time = struct.unpack_from("<d", data, p + 24)[0] if length >= _CLF_HEADER else math.nan
            frames.append(FrameEntry(at, length, sim_time, max(key, 0), len(texts)))
        else:
            break  # an index without a valid tail: the recording ended here
        at += RECORD_HEAD + _align4(length)
    return frames, texts


def _check_frames(data: memoryview, rec: Recording) -> None:
    """Every frame record holds a CLF1 frame of the recording's encoding, with as many vertices
    as the one before (the hello's nx x ny first; any after a scene or snapshot_restored event),
    its index's sim time, and for a delta the keyframe its entry names, the last before it."""
    encoding = rec.info.get("encoding")
    scene = rec.hello["scene"]
    n = int(scene.get("nx") or 0) * int(scene.get("ny") or 0)
    seen, key_id = 1, -1
    for k, f in enumerate(rec.frames):
        p = f.offset + RECORD_HEAD

        def bad(what: str) -> NoReturn:
            err = RecordingError("frame %d: %s" % (k, what), f.offset)
            err.frame = k
            raise err

        if f.length < _CLF_HEADER or bytes(data[p:p + 4]) != b"CLF1" or struct.unpack_from("<H", data, p + 4)[0] != _CLF_HEADER:
            bad("not a clothd frame (CLF1)")
        e = struct.unpack_from("<H", data, p + 6)[0] & 3
        nv = _u32(data, p + 40)
        if encoding is not None and _ENCODINGS[e] != encoding:
            bad("a %s frame in a %s recording" % (_ENCODINGS[e], encoding))
        while seen < f.texts_before:
            try:
                if rec.text(seen).get("event") in _RELAYOUT:
                    n = -1
            except RecordingError as err:
                err.frame = k
                raise
            seen += 1
        if nv > _CLF_MAX_VERTICES or (n >= 0 and nv != n):
            bad("%d vertices, the cloth has %d" % (nv, n))
        n = nv
        own = struct.unpack_from("<d", data, p + 24)[0]
        if not math.isfinite(f.sim_time) or f.sim_time != own:
            bad("its sim time is not the frame's")
        if e == _CLF_DELTA:
            if f.length < _CLF_HEADER + 44:
                bad("a delta frame shorter than its head")
            kind, ident = struct.unpack_from("<II", data, p + _CLF_HEADER)
            if kind in DELTA_KEY_KINDS:
                if f.key != k:
                    bad("a keyframe whose index names frame %d as its keyframe" % f.key)
                key_id = ident
            elif (kind not in (1, 3) or ident != key_id or f.key >= k
                  or _u32(data, rec.frames[f.key].offset + RECORD_HEAD + _CLF_HEADER + 4) != ident):
                bad("a delta of keyframe %d that the recording does not hold before it" % ident)
        elif f.key != k:
            bad("a frame that needs no keyframe names another")
