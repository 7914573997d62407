"""clothd.recording against a recording written out byte by byte from PROTOCOL.md's
"Recordings" tables (never by a writer under test): read through its index, cut at every length
(scanned up to its last complete record), seek, and corrupt files refused with a
RecordingError that names the byte, never another exception.
"""

import json
import random
import struct

import pytest

import clothd
from clothd.recording import RecordingError, read_recording

pytestmark = pytest.mark.both


def f32_frame(frame, sim_time, xyz):
    """An f32 frame of a 2 x 1 cloth, no rocks: the 72-byte header, then 6 f32."""
    head = b"CLF1" + struct.pack("<HHQQdQII", 72, 0, frame, 10 * frame, sim_time, 0, 2, 0) + b"\0" * 24
    return head + struct.pack("<6f", *xyz)


def record(kind, payload):
    return struct.pack("<II", kind, len(payload)) + payload + b"\0" * (-len(payload) % 4)


HELLO = {"type": "hello", "scene_id": "default", "scene": {"nx": 2, "ny": 1}, "torn": [],
         "recording": {"id": "r", "scene": "default", "encoding": "f32", "seconds": 1, "started_ns": 0,
                       "frame_rate": 60}}
HELLO_TEXT = json.dumps(HELLO).encode()
EVENT_TEXT = b'{"type":"event","event":"torn","springs":[0]}'
FRAMES = [f32_frame(7, 0.5, [0, 0, 1, 1, 0, 1]), f32_frame(8, 0.5 + 1 / 60, [0, 0, 0.9, 1, 0, 0.8])]
AT_HELLO = 16
AT_F0 = AT_HELLO + len(record(1, HELLO_TEXT))
AT_EV = AT_F0 + len(record(2, FRAMES[0]))
AT_F1 = AT_EV + len(record(1, EVENT_TEXT))
AT_INDEX = AT_F1 + len(record(2, FRAMES[1]))
INDEX = (struct.pack("<II", 2, 2) + struct.pack("<QdII", AT_F0, 0.5, 0, 1) + struct.pack("<QdII", AT_F1, 0.5 + 1 / 60, 1, 2)
         + struct.pack("<QQ", AT_HELLO, AT_EV))
FILE = (b"CLR1" + struct.pack("<III", 1, 0, 0) + record(1, HELLO_TEXT) + record(2, FRAMES[0]) + record(1, EVENT_TEXT)
        + record(2, FRAMES[1]) + record(3, INDEX) + b"CLRX" + struct.pack("<IQ", 0, AT_INDEX))


def rows(positions):
    return [[round(float(x), 6) for x in p] for p in positions]


def test_a_finished_recording_reads_through_its_index():
    rec = read_recording(FILE)
    assert rec.complete
    assert rec.hello == HELLO
    assert rec.info["frame_rate"] == 60
    assert [(f.offset, f.length, f.key, f.texts_before) for f in rec.frames] == [(AT_F0, 96, 0, 1), (AT_F1, 96, 1, 2)]
    assert [t[0] for t in rec.texts] == [AT_HELLO, AT_EV]
    assert rec.events() == [{"type": "event", "event": "torn", "springs": [0]}]
    assert rec.events(until=0) == []
    assert rows(rec.decode(1).positions) == [[0, 0, 0.9], [1, 0, 0.8]]
    assert [f.frame for f in rec] == [7, 8]
    assert abs(rec.duration - 1 / 60) < 1e-12
    assert (rec.seek(0), rec.seek(0.01), rec.seek(1 / 60), rec.seek(99)) == (0, 0, 1, 1)
    assert clothd.read_recording is read_recording


def test_a_file_cut_anywhere_reads_up_to_its_last_complete_record():
    for n in range(16, len(FILE)):
        cut = FILE[:n]
        if n < AT_HELLO + 8 + len(HELLO_TEXT):  # no whole hello (its padding may be cut)
            with pytest.raises(RecordingError):
                read_recording(cut)
            continue
        rec = read_recording(cut)
        assert not rec.complete, n
        want = 2 if n >= AT_F1 + 8 + 96 else 1 if n >= AT_F0 + 8 + 96 else 0
        assert len(rec) == want, n
        assert len(rec.texts) == (2 if n >= AT_EV + 8 + len(EVENT_TEXT) else 1), n


def broken(edit):
    b = bytearray(FILE)
    edit(b)
    return bytes(b)


@pytest.mark.parametrize("edit, message", [
    (lambda b: b.__setitem__(0, 0x58), "not a clothd recording"),
    (lambda b: struct.pack_into("<I", b, 4, 2), "version 2"),
    (lambda b: struct.pack_into("<I", b, 8, 1), "flags"),
    (lambda b: struct.pack_into("<Q", b, len(b) - 8, len(b)), "offset"),
    (lambda b: struct.pack_into("<Q", b, AT_INDEX + 16, AT_HELLO), "frame 0 does not point at a frame record"),
    (lambda b: struct.pack_into("<I", b, AT_INDEX + 16 + 24 + 20, 1), "frame 1 says 1 texts"),
    (lambda b: struct.pack_into("<I", b, AT_F0 + 8 + 40, 3), "frame 0: 3 vertices, the cloth has 2"),
    (lambda b: b.__setitem__(AT_F1 + 8, 0x41), "frame 1: not a clothd frame"),
    (lambda b: (struct.pack_into("<I", b, AT_EV, 9), struct.pack_into("<I", b, len(b) - 16, 0)), "unknown type 9"),
    (lambda b: b.__setitem__(slice(AT_EV + 8, AT_EV + 10), b"{{"), "text record 1 is not JSON"),
    (lambda b: (struct.pack_into("<I", b, AT_HELLO, 2), struct.pack_into("<I", b, len(b) - 16, 0)), "first record"),
])
def test_corrupt_files_are_refused_with_the_place_named(edit, message):
    with pytest.raises(RecordingError, match=message) as e:
        read_recording(broken(edit))
    assert e.value.offset is not None


def test_random_corruption_is_a_recording_error_or_a_recording():
    rng = random.Random(7)
    for _ in range(400):
        b = bytearray(FILE)
        for _ in range(rng.randint(1, 4)):
            b[rng.randrange(len(b))] = rng.randrange(256)
        try:
            rec = read_recording(bytes(b))
            for k in range(len(rec)):
                try:
                    rec.decode(k)
                except clothd.FrameError:
                    pass
        except RecordingError:
            pass


def test_a_recording_of_the_real_daemon_reads_back(start_daemon):
    """A delta recording of a real clothd: its first frame (the scene paused) is the cloth state
    within quantum / 2, and once running, the recording of 0.5 s of sim time has one frame a
    frame period apart from its first to the one that reaches 0.5 s."""
    from conftest import until
    d = start_daemon("--nx", "12", "--ny", "10", "--paused", "--auto-drop-interval", "0")
    c = clothd.Client(d.url)
    c.add_rock([0, 0, 1.5], 0.1)
    rate = c.params()["frame_rate"]
    state = c.cloth_state_binary(numpy=False)
    made = c.record(0.5, id="py-rec")
    assert (made["id"], made["scene"], made["state"], made["encoding"]) == ("py-rec", "default", "recording", "delta")
    first = until("the first frame", lambda: c.recordings.list()["recordings"][0]["frames"] >= 1)
    assert first
    c.resume()
    until("the recording done", lambda: c.recordings.list()["recordings"][0]["state"] == "done")
    c.pause()
    rec = c.recordings.read("py-rec")
    assert rec.complete and rec.info["encoding"] == "delta"
    assert rec.hello["scene"]["nx"] == 12 and len(rec.hello["rocks"]) == 1
    assert len(rec) == round(0.5 * rate) + 1
    times = [f.sim_time for f in rec.frames]
    assert all(abs(b - a - 1 / rate) < 1e-9 for a, b in zip(times, times[1:]))
    assert rec.duration == pytest.approx(0.5, abs=1e-9)
    f0 = rec.decode(0)
    for got, want in zip(rows(f0.positions), rows(state.positions)):
        assert all(abs(g - w) <= 0.5e-4 + 1e-6 for g, w in zip(got, want)), (got, want)
    assert [r.id for r in rec.decode(len(rec) - 1).rocks] == [r["id"] for r in c.rocks()["rocks"]]
    assert rec.seek(0.25) == round(0.25 * rate)
    with pytest.raises(clothd.NotFound):
        c.recordings.read("nope")
