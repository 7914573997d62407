"""Recording.to_usd (clothd.usd) on a recording of the real clothd: the USD text's stage metadata,
its points at chosen time codes equal to the frames as clothd.recording decodes them (float32 for
float32, read by this test's own reading of the USD grammar), the topology (the whole grid first,
the torn springs' triangles gone after, matching the daemon's count of torn springs), the rock's
Xform; each frame written before the next is decoded; bad input: a cut file, a corrupt frame, no
frames, one frame. (The JavaScript test tests/clients/js_export.test.mjs also reads this client's
USD with TinyUSDZ, a real USD parser.)
"""

import random
import re
import struct
import warnings

import pytest

import clothd
from clothd.recording import RecordingError, read_recording
from clothd.usd import f32, triangles

pytestmark = pytest.mark.both
F = struct.Struct("<f")
NX, NY = 9, 7


def as_f32(x):
    return F.unpack(F.pack(float(x)))[0]


def usd_attr(text, head):
    """{time: [numbers]} of the timeSamples block that starts with ``head`` (this test's reading)."""
    at = text.index(head + ".timeSamples = {")
    body = text[text.index("{", at) + 1:text.index("\n        }", at)]
    out = {}
    for line in body.strip().splitlines():
        t, value = line.strip().split(":", 1)
        out[float(t)] = [float(x) for x in re.findall(r"-?(?:\d+\.?\d*|\.\d+)(?:e[-+]?\d+)?|nan|-?inf", value)]
    return out


def flat(positions):
    return [as_f32(c) for p in positions for c in p]


@pytest.fixture(scope="module")
def recording(tmp_path_factory):
    from conftest import Daemon, until
    d = Daemon(["--nx", str(NX), "--ny", str(NY), "--paused", "--auto-drop-interval", "0"])
    try:
        c = clothd.Client(d.url)
        c.set_params(tear_strain=0.3)
        c.add_rock([0.1, 0, 1.4], 0.12)
        rate = c.params()["frame_rate"]
        c.record(0.25, encoding="q16", id="py-usd")
        c.step(frames=5)
        c.grab(0, [-3, -3, 3])
        c.step(frames=10)
        until("the recording done", lambda: c.recordings.list()["recordings"][0]["state"] == "done")
        data = c.recordings.get("py-usd")
        n_torn = c.sim()["n_torn"]
    finally:
        d.stop()
    return data, rate, n_torn


def test_f32_reads_back_exactly():
    rnd = random.Random(7)
    for _ in range(20000):
        x = F.unpack(struct.pack("<I", rnd.getrandbits(32)))[0]
        if x == x and abs(x) != float("inf"):
            assert as_f32(float(f32(x))) == x, (x, f32(x))
    assert f32(0.5) == "0.5" and f32(as_f32(0.1)) == "0.1" and f32(-0.0) == "-0"


def test_to_usd_of_a_real_recording(recording, tmp_path):
    data, rate, n_torn = recording
    rec = read_recording(data)
    path = tmp_path / "run.usda"
    result = rec.to_usd(path)
    assert result["cut"] is False and result["problem"] is None
    text = path.read_text()
    assert text.startswith("#usda 1.0\n")
    head = text[:text.index(")")]
    meta = dict(re.findall(r"(\w+) = (\S+)", head))
    last = round((rec.frames[-1].sim_time - rec.frames[0].sim_time) * rate)
    assert (meta["upAxis"], meta["metersPerUnit"], float(meta["timeCodesPerSecond"]), meta["startTimeCode"],
            float(meta["endTimeCode"])) == ('"Z"', "1", rate, "0", last)
    assert last == round(0.25 * rate)

    points = usd_attr(text, "point3f[] points")
    by_time = {}
    for k, f in enumerate(rec.frames):
        by_time[round((f.sim_time - rec.frames[0].sim_time) * rate)] = k
    assert sorted(points) == sorted(by_time) and result["written"] == len(by_time)
    for t in (0, 3, 9, last):
        want = flat(rec.decode(by_time[t]).positions)
        assert [as_f32(x) for x in points[t]] == want, t  # the decimals read back to the float32s

    indices = usd_attr(text, "int[] faceVertexIndices")
    counts = usd_attr(text, "int[] faceVertexCounts")
    assert sorted(indices) == sorted(counts) and len(indices) >= 2
    assert len(indices[0]) == 6 * (NX - 1) * (NY - 1) and counts[0] == [3] * (2 * (NX - 1) * (NY - 1))
    torn = set()
    for ev in rec.events():
        torn.update(ev.get("springs") or [])
    assert len(torn) == n_torn > 0
    assert indices[max(indices)] == triangles(NX, NY, torn)

    rock = text[text.index('def Xform "rock_'):]
    assert 'uniform token[] xformOpOrder = ["xformOp:translate", "xformOp:orient"]' in rock
    assert re.search(r'def Sphere "sphere"\s*\{[^}]*double radius = 0\.12\b', rock)
    translate, orient = usd_attr(rock, "float3 xformOp:translate"), usd_attr(rock, "quatf xformOp:orient")
    end = rec.decode(len(rec) - 1).rocks[0]
    assert [as_f32(x) for x in translate[last]] == [as_f32(c) for c in end.position]
    assert [as_f32(x) for x in orient[last]] == [as_f32(c) for c in (end.orientation[3], *end.orientation[:3])]


def test_each_frame_is_written_before_the_next_is_decoded(recording):
    data, _, _ = recording
    rec = read_recording(data)
    lines = []

    class Out:
        def write(self, s):
            lines.append(s)

    decode, seen = rec.decode, []

    def spy(k):
        seen.append((k, sum(s.count("\n") for s in lines)))
        return decode(k)

    rec.decode = spy
    from clothd.usd import write_usd
    write_usd(rec, Out())
    grown = [b - a for (_, a), (_, b) in zip(seen, seen[1:])]
    # One line of points per frame, written before the next is decoded; none for a frame that the
    # next one replaces (the same sim time: the grab between two frames).
    same = [rec.frames[k].sim_time == rec.frames[k + 1].sim_time for k in range(len(rec) - 1)]
    assert [k for k, _ in seen] == list(range(len(rec))) and any(same)
    assert grown == [0 if s else 1 for s in same]


def test_bad_input(recording, tmp_path):
    data, rate, _ = recording
    rec = read_recording(data)
    # Cut inside frame 6's record: frames 0..5 export, with a warning.
    cut = read_recording(data[:rec.frames[6].offset + 30])
    with pytest.warns(RuntimeWarning, match="cut"):
        r = cut.to_usd(tmp_path / "cut.usda")
    assert r["frames"] == 6 and r["cut"]
    assert len(usd_attr((tmp_path / "cut.usda").read_text(), "point3f[] points")) == 6
    # A corrupt frame (its magic): refused plainly, read with salvage the frames before it.
    bad = bytearray(data)
    bad[rec.frames[4].offset + 8] ^= 0xFF
    with pytest.raises(RecordingError):
        read_recording(bytes(bad))
    salvaged = read_recording(bytes(bad), salvage=True)
    assert len(salvaged) == 4 and "frame 4" in salvaged.problem
    with pytest.warns(RuntimeWarning, match="frame 4"):
        assert salvaged.to_usd(tmp_path / "bad.usda")["frames"] == 4
    # The hello alone: an error, no file.
    hello_only = read_recording(data[:rec.frames[0].offset])
    with pytest.raises(RecordingError, match="no frames"):
        hello_only.to_usd(tmp_path / "none.usda")
    assert not list(tmp_path.glob("none.usda*"))
    # One frame: exports, start and end at 0.
    one = read_recording(data[:rec.frames[1].offset])
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        r = one.to_usd(tmp_path / "one.usda")
    text = (tmp_path / "one.usda").read_text()
    assert r["written"] == 1 and "endTimeCode = 0\n" in text
    assert [as_f32(x) for x in usd_attr(text, "point3f[] points")[0]] == flat(rec.decode(0).positions)
