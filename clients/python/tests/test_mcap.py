"""Recording.to_mcap (clothd.mcap) on a recording of the real clothd, read back by this test's own
reading of the MCAP specification (mcap.dev/spec: records, chunks, message indexes, the summary,
the CRCs computed here with zlib): every message a foxglove.SceneUpdate whose cloth points equal
the frames as clothd.recording decodes them, the triangles of the grid less the torn springs, the
rock's sphere; the numbers written as JavaScript writes them. Bad input: a cut file, no frames,
an unknown compression. (tests/clients/js_export.test.mjs reads this client's MCAP with
@mcap/core's reader and holds its messages equal, byte for byte, to the JavaScript exporter's.)
"""

import json
import struct
import warnings
import zlib

import pytest

import clothd
from clothd.mcap import js_number
from clothd.recording import RecordingError, read_recording
from clothd.usd import triangles

from test_usd import NX, NY, as_f32, flat, recording  # noqa: F401 (the module's recording fixture)

pytestmark = pytest.mark.both
MAGIC = b"\x89MCAP0\r\n"


def records(buf, at, end):
    """(opcode, content, offset) of the records in buf[at:end]."""
    while at < end:
        op, n = struct.unpack_from("<BQ", buf, at)
        yield op, buf[at + 9:at + 9 + n], at
        at += 9 + n


def string(b, at):
    n = struct.unpack_from("<I", b, at)[0]
    return b[at + 4:at + 4 + n].decode(), at + 4 + n


def read_mcap(buf):
    """The file as this test reads the specification: header, schema, channel, messages (from the
    chunks), the summary's statistics and chunk indexes; every CRC checked."""
    assert buf[:8] == MAGIC and buf[-8:] == MAGIC
    op, n = struct.unpack_from("<BQ", buf, len(buf) - 8 - 29)
    assert (op, n) == (0x02, 20)
    summary_start, offsets_start, summary_crc = struct.unpack_from("<QQI", buf, len(buf) - 8 - 20)
    assert zlib.crc32(buf[summary_start:len(buf) - 8 - 4]) == summary_crc
    out = {"messages": [], "chunks": 0}
    data_end = None
    for op, c, at in records(buf, 8, summary_start):
        if op == 0x01:
            out["header"] = (string(c, 0)[0], string(c, string(c, 0)[1])[0])
        elif op == 0x03:
            sid = struct.unpack_from("<H", c)[0]
            name, p = string(c, 2)
            enc, p = string(c, p)
            out["schema"] = (sid, name, enc, c[p + 4:p + 4 + struct.unpack_from("<I", c, p)[0]])
        elif op == 0x04:
            cid, sid = struct.unpack_from("<HH", c)
            topic, p = string(c, 4)
            enc, p = string(c, p)
            out["channel"] = (cid, sid, topic, enc)
        elif op == 0x06:
            t0, t1, size, crc = struct.unpack_from("<QQQI", c)
            comp, p = string(c, 28)
            body = c[p + 8:p + 8 + struct.unpack_from("<Q", c, p)[0]]
            raw = clothd.frames.zstd_decompress(body, size) if comp == "zstd" else body
            assert comp in ("", "zstd") and len(raw) == size and zlib.crc32(raw) == crc
            out["chunks"] += 1
            for mop, m, _ in records(raw, 0, len(raw)):
                assert mop == 0x05
                ch, seq, log, pub = struct.unpack_from("<HIQQ", m)
                assert t0 <= log <= t1 and pub == log and ch == out["channel"][0]
                out["messages"].append((seq, log, json.loads(m[22:])))
        elif op == 0x0F:
            data_end = at
            assert struct.unpack_from("<I", c)[0] == zlib.crc32(buf[:at])
    assert data_end is not None
    for op, c, at in records(buf, summary_start, offsets_start):
        if op == 0x0B:
            out["statistics"] = struct.unpack_from("<QHIIIIQQ", c)
        elif op == 0x08:
            start, length = struct.unpack_from("<QQ", c, 16)
            assert buf[start] == 0x06 and 9 + struct.unpack_from("<Q", buf, start + 1)[0] == length
    return out


def test_js_number_writes_as_javascript_does():
    # JSON.stringify's output for each (ECMAScript Number::toString), written out here.
    cases = {1e-7: "1e-7", 1.5e-6: "0.0000015", 123.0: "123", 1e21: "1e+21", 1e20: "100000000000000000000",
             0.1 + 0.2: "0.30000000000000004", -0.0: "0", 5e-324: "5e-324", -2.5e-8: "-2.5e-8",
             1.7976931348623157e308: "1.7976931348623157e+308", 0.78: "0.78", 1733430000: "1733430000",
             as_f32(0.1): "0.10000000149011612", float("nan"): "null", 123456.789: "123456.789"}
    for x, want in cases.items():
        assert js_number(x) == want, (x, js_number(x), want)


@pytest.mark.parametrize("compression", ["none", None])
def test_to_mcap_of_a_real_recording(recording, tmp_path, compression):
    data, rate, n_torn = recording
    if compression is None and not clothd.frames.zstd_available():
        pytest.skip("no libzstd")
    rec = read_recording(data)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        r = rec.to_mcap(tmp_path / "r.mcap", compression=compression)
    f = read_mcap((tmp_path / "r.mcap").read_bytes())
    assert r["compression"] == ("none" if compression == "none" else "zstd") and not r["cut"]
    assert f["header"] == ("", "clothd")
    sid, name, enc, schema = f["schema"]
    assert (name, enc) == ("foxglove.SceneUpdate", "jsonschema")
    assert json.loads(schema)["title"] == "foxglove.SceneUpdate"
    assert f["channel"][1:] == (sid, "/clothd/default", "json")
    times = [fr.sim_time for fr in rec.frames]
    keep = [k for k in range(len(times)) if k + 1 == len(times) or times[k + 1] != times[k]]
    msgs = f["messages"]
    assert len(msgs) == len(keep) == r["written"] and f["statistics"][0] == len(msgs) and f["statistics"][5] == f["chunks"]
    assert [s for s, _, _ in msgs] == list(range(len(msgs)))
    base = int(float(rec.info["started_ns"]))
    for i, (seq, log, msg) in enumerate(msgs):
        k = keep[i]
        assert abs(log - base - round((times[k] - times[0]) * 1e9)) <= 1000, (i, log)
        cloth = msg["entities"][0]
        assert cloth["id"] == "cloth" and cloth["frame_id"] == "clothd"
        tri = cloth["triangles"][0]
        assert [c for p in tri["points"] for c in (p["x"], p["y"], p["z"])] == flat(rec.decode(k).positions)
        rock = msg["entities"][1]["spheres"][0]
        r0 = rec.decode(k).rocks[0]
        assert [rock["pose"]["position"][a] for a in "xyz"] == list(r0.position)
        assert rock["size"]["x"] == 2 * r0.radius
    first, last = msgs[0][2]["entities"][0]["triangles"][0]["indices"], msgs[-1][2]["entities"][0]["triangles"][0]["indices"]
    assert first == triangles(NX, NY, set())
    assert n_torn > 0 and len(last) < len(first)


def test_bad_input(recording, tmp_path):
    data, _, _ = recording
    rec = read_recording(data)
    cut = read_recording(data[:rec.frames[6].offset + 30])
    with pytest.warns(RuntimeWarning, match="cut"):
        r = cut.to_mcap(tmp_path / "cut.mcap", compression="none")
    assert r["frames"] == 6 and r["cut"] and len(read_mcap((tmp_path / "cut.mcap").read_bytes())["messages"]) == 6
    hello_only = read_recording(data[:rec.frames[0].offset])
    with pytest.raises(RecordingError, match="no frames"):
        hello_only.to_mcap(tmp_path / "none.mcap")
    with pytest.raises(ValueError, match="compression"):
        rec.to_mcap(tmp_path / "x.mcap", compression="lz4")
    assert not list(tmp_path.glob("none.mcap*")) and not list(tmp_path.glob("x.mcap*"))
