"""clothd.Stream against the real clothd: frames of every encoding hold the positions GET
/v1/cloth/state gives (exactly for f32, within half a quantization step for q16 and meshopt);
events carry the X-Request-Id of their request; grab and release go through the stream into the
journal; a refused subscription; reconnection with waits of 0.25 s doubling to 8 s, and from
0.25 s again once back; a scene the server lacks; switching scenes and a deleted scene; a token; bad input; no websocket-client.
"""

import struct

import pytest

import clothd
from conftest import run_hidden, until, write_token


def worst(positions, expected):
    """The largest difference per axis between two n x 3 position lists or arrays."""
    out = [0.0, 0.0, 0.0]
    assert len(positions) == len(expected)
    for p, e in zip(positions, expected):
        for c in range(3):
            out[c] = max(out[c], abs(float(p[c]) - float(e[c])))
    return out


@pytest.mark.both
def test_frames_of_every_encoding_hold_the_cloth_state(client):
    # A rock on the cloth and a few frames: a surface that is not flat on any axis.
    client.add_rock([0.2, 0.1, 1.3], 0.2, density=2000)
    client.step(frames=20)
    expected = client.cloth_state_binary().positions
    encodings = (["f32", "q16"] + (["meshopt"] if clothd.meshopt_available() else [])
                 + (["delta"] if clothd.frames.zstd_available() else []))
    with client.stream() as s:
        assert s.hello["protocol"] == "clothd.v1" and s.hello["state"] == "paused"
        assert s.hello["scene"]["nx"] == 64
        for encoding in encodings:
            scalar = "speed" if encoding == "q16" else "none"
            assert s.subscribe(encoding=encoding, scalar=scalar)["encoding"] == encoding
            # (A frame the sim made without the scalar may come first, then that frame with it.)
            f = s.wait_for(lambda m: isinstance(m, clothd.Frame) and m.encoding == encoding
                           and (m.scalar is None) == (scalar == "none"))
            assert (f.n_vertices, f.n_rocks) == (64 * 64, 1)
            err = worst(f.positions, expected)
            if encoding == "f32":
                assert err == [0, 0, 0]
            elif encoding == "delta":  # the grid's half step, and float32's rounding of the result
                assert f.delta.quantum == struct.unpack("<f", struct.pack("<f", 0.0001))[0]
                assert all(e <= f.delta.quantum / 2 + 2 ** -24 * 4 for e in err), err
                assert any(e > 0 for e in err)
            else:
                half = [(f.bbox_max[c] - f.bbox_min[c]) / 65535 / 2 + 1e-6 for c in range(3)]
                assert all(err[c] <= half[c] for c in range(3)), (encoding, err, half)
                assert any(e > 0 for e in err)  # quantized, not exact
            if scalar != "none":
                assert len(f.scalar) == 64 * 64
            if clothd.numpy_available():
                assert f.positions.shape == (64 * 64, 3)
            else:
                assert isinstance(f.positions, list)
    client.clear_rocks()


@pytest.mark.skipif(not clothd.frames.zstd_available(), reason="zstd's C library is not loadable")
def test_delta_keyframes_on_request(client):
    with client.stream() as s:
        assert s.subscribe(encoding="delta", quantum=0.001)["quantum"] == 0.001
        first = s.wait_for(lambda m: isinstance(m, clothd.Frame) and m.encoding == "delta")
        assert first.delta.keyframe  # a subscriber starts with a keyframe
        s.keyframe()  # while paused it comes with the next change: step until it does
        seen = []

        def new_keyframe():
            client.step(frames=1)
            f = s.wait_for(lambda m: isinstance(m, clothd.Frame) and m.encoding == "delta")
            seen.append(f)
            return f.delta.keyframe and f.delta.key_id > first.delta.key_id
        until("a keyframe after the ask", new_keyframe)
        assert all(f.delta.key_id == first.delta.key_id for f in seen[:-1])  # deltas until then
        # Asked for, not the once-a-second one: 0.25 s or more after the first, well before 1 s.
        assert 0.25e9 <= seen[-1].wall_ns - first.wall_ns < 0.9e9, seen[-1].wall_ns - first.wall_ns


def test_events_grab_release_and_a_refused_subscription(client):
    with client.stream() as s:
        tagged = client.with_options(request_id="py-stream-test.1")
        added = tagged.add_rock([0, 0, 2], 0.1)
        ev = s.wait_for(lambda m: isinstance(m, dict) and m.get("event") == "rock_add")
        assert ev["request_id"] == "py-stream-test.1" and ev["result"]["id"] == added["id"]
        client.remove_rock(added["id"])
        ev = s.wait_for(lambda m: isinstance(m, dict) and m.get("event") == "rock_remove")
        assert client.is_own_request(ev["request_id"])

        s.grab(1234, [0.1, 0.2, 1.4])
        grab = until("the grab in the journal", lambda: next(
            (e for e in client.journal()["entries"] if e["command"]["op"] == "grab" and e["command"]["vertex"] == 1234), None))
        assert grab["command"]["target"] == [0.1, 0.2, 1.4]
        s.release()
        until("the release", lambda: client.journal()["entries"][-1]["command"]["op"] == "release")

        with pytest.raises(clothd.StreamRefused) as e:
            s.subscribe(encoding="jpeg")
        assert e.value.param == "encoding" and e.value.about == "subscribe" and e.value.status in (400, 422)
        # on_event sees each event as it is read.
        events = []
        s2 = client.stream(on_event=events.append)
        client.add_rock([0, 0, 2], 0.1)
        s2.wait_for(lambda m: isinstance(m, dict) and m.get("event") == "rock_add")
        assert [e["event"] for e in events] == ["rock_add"]
        s2.close()
    client.clear_rocks()


def test_frames_iterate_while_running(client):
    client.resume()
    with client.stream(encoding="q16") as s:
        steps = []
        for f in s.frames():
            if f.encoding == "q16":
                steps.append(f.step)
            if len(steps) == 3:
                break
    client.pause()
    assert steps[0] < steps[1] < steps[2]


def test_reconnects_with_backoff_and_starts_again_from_a_quarter_second(start_daemon):
    d = start_daemon("--auto-drop-interval", "0", "--paused")
    c = clothd.Client(d.url)
    stream_port = c.health()["stream"]["port"]
    state = {"phase": 1}

    def on_status(kind, detail):
        if kind != "closed":
            return
        if state["phase"] == 1 and len(s.retry_waits) == 4:
            # After four waits the daemon comes back, on the same ports.
            state["d"] = start_daemon("--auto-drop-interval", "0", "--paused", "--port", str(d.port),
                                      "--stream-port", str(stream_port), "--nx", "40")
        elif state["phase"] == 2:
            s.close()  # the first wait after the second loss is all this test needs

    s = c.stream(reconnect=True, on_status=on_status)
    d.stop()
    hello = s.wait_for(lambda m: isinstance(m, dict) and m.get("type") == "hello", timeout=60)
    assert hello["scene"]["nx"] == 40  # the new daemon's
    for k, w in enumerate(s.retry_waits):
        assert 0.75 * 0.25 * 2 ** k <= w <= 1.25 * 0.25 * 2 ** k, (k, w)
    assert len(s.retry_waits) >= 4
    assert s.backoff == 0.25  # the hello starts it again
    n = len(s.retry_waits)
    state["phase"] = 2
    state["d"].stop()
    for _ in s:  # what was on its way, then the loss, one wait, and the close of on_status
        pass
    assert len(s.retry_waits) == n + 1 and 0.1875 <= s.retry_waits[-1] <= 0.3125
    # The cap: from 4 s the backoff doubles to 8 s and stays there.
    s.backoff = 4.0
    waits = [s.next_wait() for _ in range(4)]
    assert 3 <= waits[0] <= 5 and all(6 <= w <= 10 for w in waits[1:]) and s.backoff == 8.0


def test_without_reconnect_a_lost_stream_raises(start_daemon):
    d = start_daemon("--auto-drop-interval", "0", "--paused")
    s = clothd.Client(d.url).stream()
    d.stop()
    with pytest.raises(clothd.ConnectionFailed):
        for _ in s:
            pass


def test_a_scene_this_clothd_does_not_have(client):
    with pytest.raises(clothd.NotFound):
        client.scene("elsewhere").stream()


def test_switch_scene_and_a_deleted_scene(client):
    client.create_scene(id="two", scene={"nx": 6, "ny": 4})
    try:
        with client.stream() as s:
            own = client.sim()["n_vertices"]
            assert s.next_frame().n_vertices == own
            ack = s.switch_scene("two")
            assert ack["scene"] == "two" and s.scene == "two"
            assert s.hello["scene_id"] == "two" and s.hello["scene"]["nx"] == 6
            assert s.next_frame().n_vertices == 24  # two's own, none of default's after the switch
            with pytest.raises(clothd.StreamRefused):
                s.switch_scene("nowhere")
            assert s.scene == "two"
            with pytest.raises(ValueError):
                s.switch_scene("Two")
            # Deleting two closes the stream with 1001 "scene deleted": NotFound, no reconnection.
            client.delete_scene("two")
            with pytest.raises(clothd.NotFound, match="was deleted"):
                while True:
                    s.receive(timeout=15)  # Timeout, not a hang, if the close never came
    finally:
        if any(x["id"] == "two" for x in client.scenes()["scenes"]):
            client.delete_scene("two")


def test_a_token_and_bad_input(start_daemon, tmp_path):
    d = start_daemon("--auto-drop-interval", "0", "--token-file", write_token(tmp_path, "t", "stream-token-0123456789"))
    with pytest.raises(clothd.Unauthorized):
        clothd.Client(d.url).stream()  # GET /v1/health is open; the stream itself refuses
    problems = []
    with clothd.Client(d.url, token="stream-token-0123456789").stream(on_problem=problems.append) as s:
        assert isinstance(s.next_frame(), clothd.Frame)
        assert s.inject(b"CLF1\x48\0\0\0") is None
        assert s.inject('{"type":"no-such-message"}') is None
        assert s.inject("[1, 2]") is None
        assert s.inject("not json") is None
        assert len(problems) == 4
        assert "shorter than its header" in problems[0]
        assert "unknown stream message type 'no-such-message'" in problems[1]
        assert "not a JSON object" in problems[2] and "not JSON" in problems[3]
        assert isinstance(s.next_frame(), clothd.Frame)  # it goes on
    with clothd.Client(d.url, token="stream-token-0123456789").stream() as s:
        with pytest.raises(clothd.FrameError):
            s.inject(b"XXXX" + bytes(68))


def test_without_websocket_client_the_stream_says_what_is_missing():
    p = run_hidden(["websocket"], "import clothd\n"
                                  "print(clothd.websocket_available())\n"
                                  "try:\n"
                                  "    clothd.Client('http://127.0.0.1:9').stream()\n"
                                  "except clothd.MissingDependency as e:\n"
                                  "    print('missing:', e)\n")
    assert p.returncode == 0, p.stderr
    assert p.stdout.splitlines() == ["False", "missing: the stream needs websocket-client (Debian: apt install python3-websocket)"]
