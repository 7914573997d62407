"""clothd.Client against the real clothd: every operation of proto/openapi.yaml is reached by a
method (counted by the daemon's own /metrics), answers hold what the protocol says (analytic
values; the binary cloth state against the JSON one; a restored snapshot against its hash), every
refusal is the exception of its status with slug, detail and param and changes nothing, tokens,
X-Request-Id, timeouts, an unreachable server, scene handles.
"""

import math
import re
import threading

import pytest

import clothd
from conftest import SOURCE, until, write_token


def spec_operations():
    """(METHOD, path) of every operation in proto/openapi.yaml (its paths are 2-space keys,
    their methods 4-space keys; a path that is a $ref to components/pathItems has the methods of
    that item, 6-space keys under its 4-space name; the paths that share an item - a scene's
    routes with and without the prefix /v1/scenes/{scene} - are one client method each, counted
    at the first)."""
    lines = (SOURCE / "proto" / "openapi.yaml").read_text().splitlines()
    items, item, section = {}, None, None
    for line in lines:
        if re.match(r"^  \S", line):
            section = line.strip()
        m = re.match(r"^    ([A-Za-z_]+):\s*$", line)
        if section == "pathItems:" and m:
            item = items.setdefault(m.group(1), [])
        m = re.match(r"^      (get|put|post|patch|delete):", line)
        if section == "pathItems:" and m and item is not None:
            item.append(m.group(1).upper())
    ops, path, shared = [], None, set()
    for line in lines:
        m = re.match(r"^  (/\S*):\s*$", line)
        if m:
            path = m.group(1)
        elif line and not line.startswith(" "):
            path = None
        m = re.match(r"^    (get|put|post|patch|delete):", line)
        if m and path:
            ops.append((m.group(1).upper(), path))
        m = re.match(r"^    \$ref: '#/components/pathItems/(\w+)'", line)
        if m and path and m.group(1) not in shared:
            shared.add(m.group(1))
            ops += [(method, path) for method in items[m.group(1)]]
    return ops


def answered(c):
    """2xx answers the daemon counted, by (METHOD, route pattern)."""
    seen = {}
    for route, method, status, count in re.findall(
            r'^clothd_http_requests_total\{route="([^"]+)",method="([A-Z]+)",status="(\d+)"\} (\d+)$', c.metrics(), re.M):
        if status.startswith("2"):
            seen[(method, route)] = seen.get((method, route), 0) + int(count)
    return seen


def test_every_operation_is_a_method_and_the_answers_hold_what_the_protocol_says(client):
    c = client
    assert c.health()["stream"]["protocol"] == "clothd.v1"
    assert c.livez() == {"status": "live"}
    ready = c.readyz()
    assert ready["status"] == "ready" and 1 <= ready["scenes"] <= ready["max_scenes"]
    assert re.fullmatch(r"[0-9a-f]{16}", c.sim(hash=True)["state_hash"])
    s0 = c.pause()
    stepped = c.step(frames=2)
    assert stepped["frame"] == s0["frame"] + 2 and stepped["step"] == s0["step"] + 2 * s0["substeps"]
    assert c.step(substeps=5)["step"] == stepped["step"] + 5
    assert c.cancel_step() == {"cancelled": False, "step": stepped["step"] + 5, "frame": stepped["frame"]}
    assert c.resume()["state"] == "running"
    c.pause()
    c.reset()
    assert c.sim()["step"] == 0

    assert c.set_params(k_bend=31.5)["params"]["k_bend"] == 31.5
    assert c.set_params({"wind": [1, 0, 0]}, drag=0.25)["params"]["wind"] == [1, 0, 0]
    assert c.params()["drag"] == 0.25
    assert any(p["name"] == "k_bend" and p["kind"] == "live" for p in c.params_schema()["params"])
    assert c.set_scene(nx=24, ny=20)["nx"] == 24
    assert c.get_scene()["ny"] == 20 and c.sim()["n_vertices"] == 480

    added = c.add_rock((0, 0, 2), 0.1, density=300)
    assert added["rock"]["mass"] == pytest.approx(300 * 4 / 3 * math.pi * 0.1 ** 3, rel=1e-6)
    assert [r["id"] for r in c.rocks()["rocks"]] == [added["id"]]
    assert c.rock(added["id"])["position"] == [0, 0, 2]
    assert c.set_rock(added["id"], position=[0.5, 0, 2])["rock"]["position"] == [0.5, 0, 2]
    assert c.remove_rock(added["id"])["id"] == added["id"]
    c.add_rock([0, 0, 2], 0.1)
    c.add_rock([0.3, 0, 2], 0.1)
    assert c.clear_rocks()["removed"] == 2

    assert c.set_pins(preset="corners")["pinned"] == 4
    assert c.set_pins(vertices=[10, 11], pinned=True)["pinned"] == 6
    assert c.grab(100, (0, 0, 1.5))["vertex"] == 100
    c.release()
    assert [e["command"]["op"] for e in c.journal()["entries"]][-2:] == ["grab", "release"]

    state = c.cloth_state()
    assert len(state["positions"]) == 480

    snap = c.snapshot()
    h = c.sim()["state_hash"]
    c.step(frames=3)
    assert c.sim()["state_hash"] != h
    assert c.restore_snapshot(snap)["state_hash"] == h
    assert c.journal_bundle()[:8] == snap[:8]  # the bundle starts with its base snapshot

    assert [e["id"] for e in c.scenes()["scenes"]] == ["default"]  # the daemon's scenes: list, create, delete
    assert c.create_scene(id="made", scene={"nx": 4, "ny": 4})["n_vertices"] == 16
    assert c.delete_scene("made") == {"id": "made", "deleted": True}
    # Recordings, of the default scene and of another (both paused: each holds its first frame
    # and waits), listed, downloaded, parsed, deleted.
    assert c.record(1, encoding="f32", id="ops")["state"] == "recording"
    c.create_scene(id="rec", scene={"nx": 4, "ny": 4})
    assert c.scene("rec").record(1, id="ops2")["scene"] == "rec"
    assert sorted(r["id"] for r in c.recordings.list()["recordings"]) == ["ops", "ops2"]
    # The sim thread writes the hello and the first frame at its next pose, after the answer.
    until("the recording's first frame written",
          lambda: [r["frames"] >= 1 for r in c.recordings.list()["recordings"] if r["id"] == "ops"] == [True])
    rec = c.recordings.read("ops")
    assert rec.hello["recording"]["id"] == "ops" and rec.decode(0).n_vertices == 480
    assert c.recordings.get("ops")[:4] == b"CLR1"
    assert c.recordings.delete("ops") == {"id": "ops", "deleted": True}
    c.delete_scene("rec")
    # Its scene went: the sim thread stops the recording when it drops the scene, just after the
    # DELETE's answer.
    until("the deleted scene's recording stopped", lambda: c.recordings.list()["recordings"][0]["state"] == "stopped")
    assert c.recordings.list()["recordings"][0]["reason"] == "scene deleted"
    c.recordings.delete("ops2")
    c.cloth_state_binary()
    c.metrics()
    seen = answered(c)
    assert [op for op in spec_operations() if not seen.get(op)] == []
    assert len(spec_operations()) >= 25


@pytest.mark.both
def test_the_binary_cloth_state_holds_the_json_numbers_as_float32(client):
    import struct
    client.add_rock([0.1, 0, 1.3], 0.2, density=2000)
    client.step(frames=10)
    js = client.cloth_state()
    binary = client.cloth_state_binary()
    f32 = lambda x: struct.unpack("<f", struct.pack("<f", x))[0]  # noqa: E731
    assert len(binary) == len(js["positions"])
    assert [[float(x) for x in p] for p in binary.positions] == [[f32(x) for x in p] for p in js["positions"]]
    assert [[float(x) for x in p] for p in binary.velocities] == [[f32(x) for x in p] for p in js["velocities"]]
    if clothd.numpy_available():
        assert binary.positions.shape == (len(js["positions"]), 3)
    else:
        assert isinstance(binary.positions, list)
    client.clear_rocks()


def refusal(call):
    with pytest.raises(clothd.ClothdError) as e:
        call()
    return e.value


def test_a_refusal_is_the_exception_of_its_status_and_changes_nothing(client):
    c = client
    h = c.sim()["state_hash"]
    cases = [
        (lambda: c.set_params(k_bend=-1), clothd.Unprocessable, 422, "out-of-range", "k_bend"),
        (lambda: c.set_params(no_such=1), clothd.BadRequest, 400, "unknown-field", "no_such"),
        (lambda: c.set_params(k_bend="stiff"), clothd.Unprocessable, 422, "wrong-type", "k_bend"),
        (lambda: c.rock(999), clothd.NotFound, 404, "not-found", "id"),
        (lambda: c.remove_rock(999), clothd.NotFound, 404, "not-found", "id"),
        (lambda: c.step(frames=0), clothd.Unprocessable, 422, "out-of-range", "frames"),
        (lambda: c.restore_snapshot(b"\1\2\3"), clothd.BadRequest, 400, "bad-snapshot", None),
        (lambda: c.request("POST", "/v1/health"), clothd.MethodNotAllowed, 405, "method-not-allowed", None),
        (lambda: c.request("GET", "/v1/no-such-route"), clothd.NotFound, 404, "not-found", None),
    ]
    for call, cls, status, slug, param in cases:
        e = refusal(call)
        assert type(e) is cls and isinstance(e, clothd.ClientError)
        assert (e.status, e.slug, e.param, e.type) == (status, slug, param, "urn:clothd:problem:" + slug)
        assert e.detail and str(e) == e.detail
        assert re.fullmatch(r"py-[a-z0-9]{6}-\d+", e.request_id)
    assert "GET" in refusal(lambda: c.request("POST", "/v1/health")).allow
    assert c.sim()["state_hash"] == h  # nothing changed
    # NaN and infinities (not JSON, but what Python writes): the server's 422 naming the field.
    for bad in (float("nan"), float("inf")):
        e = refusal(lambda: c.set_params(solver_tolerance=bad))
        assert type(e) is clothd.Unprocessable and (e.slug, e.param) == ("out-of-range", "solver_tolerance")
    assert c.sim()["state_hash"] == h
    with pytest.raises(ValueError):
        c.set_pins()
    c.resume()
    e = refusal(lambda: c.step(frames=1))
    assert type(e) is clothd.Conflict and e.slug == "wrong-state"
    c.pause()


def test_413_429_and_the_answers_no_request_here_can_provoke(start_daemon):
    d = start_daemon("--auto-drop-interval", "0", "--paused", "--max-body", "1024", "--rate-limit", "1", "--rate-burst", "2")
    c = clothd.Client(d.url)
    e = refusal(lambda: c.set_params(k_bend=1, pad="x" * 2000))
    assert type(e) is clothd.PayloadTooLarge and (e.status, e.slug) == (413, "too-large")
    limited = None
    for _ in range(10):
        try:
            c.pause()
        except clothd.RateLimited as x:
            limited = x
            break
    assert limited is not None and limited.slug == "rate-limited"
    assert isinstance(limited.retry_after, int) and limited.retry_after >= 1
    # 503 busy needs a full command queue, which no test can hold still: the mapping alone,
    # from PROTOCOL.md's table; and libmicrohttpd's own HTML answers.
    busy = clothd.error_from_answer(503, "application/problem+json",
                                    b'{"type":"urn:clothd:problem:busy","title":"Busy","status":503,"detail":"full"}',
                                    method="POST", path="/v1/rocks", retry_after="1")
    assert type(busy) is clothd.Busy and (busy.slug, busy.retry_after, busy.detail) == ("busy", 1, "full")
    gone = clothd.error_from_answer(503, "application/problem+json",
                                    b'{"type":"urn:clothd:problem:unavailable","title":"U","status":503,"detail":"x"}',
                                    method="GET", path="/v1/snapshot")
    assert type(gone) is clothd.Unavailable and isinstance(gone, clothd.ServerError)
    html = clothd.error_from_answer(431, "text/html", b"<html>Request header too large</html>", method="GET", path="/")
    assert type(html) is clothd.ClientError and html.problem is None and "too large" in str(html)


def test_tokens(start_daemon, tmp_path):
    control, view = "control-token-0123456789", "view-token-0123456789ab"
    d = start_daemon("--auto-drop-interval", "0", "--token-file", write_token(tmp_path, "t", control),
                     "--view-token-file", write_token(tmp_path, "v", view))
    none = clothd.Client(d.url)
    assert none.health()["status"] == "ok"  # an open route
    e = refusal(none.sim)
    assert type(e) is clothd.Unauthorized and e.slug == "unauthorized"
    viewer = clothd.Client(d.url, token=view)
    assert isinstance(viewer.params()["k_bend"], float)
    e = refusal(viewer.pause)
    assert type(e) is clothd.Forbidden and e.slug == "forbidden"
    controller = clothd.Client(d.url, token_file=write_token(tmp_path, "mine", "  " + control + "  "))
    assert controller.pause()["state"] == "paused"


def test_timeouts_an_unreachable_server_and_request_ids(client):
    c = client
    # 100000 frames take minutes here: a 0.2 s step timeout gives up; the step goes on until cancelled.
    e = refusal(lambda: c.with_options(step_timeout=0.2).step(frames=100000))
    assert type(e) is clothd.Timeout and isinstance(e, TimeoutError) and e.status is None
    assert c.cancel_step()["cancelled"] is True
    e = refusal(clothd.Client("http://127.0.0.1:9", timeout=2).health)
    assert type(e) is clothd.ConnectionFailed and isinstance(e, ConnectionError)
    assert "cannot reach clothd at http://127.0.0.1:9" in str(e)
    with pytest.raises(ValueError):
        c.with_options(request_id="has space")
    with pytest.raises(ValueError):
        clothd.Client(c.url, request_id_prefix="x" * 130)
    with pytest.raises(ValueError):
        clothd.Client("ftp://127.0.0.1:8080")
    tagged = c.with_options(request_id="tagged-request.1")
    assert refusal(lambda: tagged.rock(12345)).request_id == "tagged-request.1"
    assert c.is_own_request(c.next_request_id()) and not c.is_own_request("viewer-abc-1")


def test_a_step_answers_interrupted_when_cancelled_from_another_thread(client):
    answer = {}
    t = threading.Thread(target=lambda: answer.update(client.step(frames=100000)))
    t.start()
    # The step shows its progress in GET /v1/sim; once it runs, cancel it.
    start = client.sim()["step"]
    until("the step to run", lambda: client.sim()["step"] > start)
    assert client.cancel_step()["cancelled"] is True
    t.join(60)
    assert answer["interrupted"] is True and answer["interrupted_by"] == "cancel"


def test_scenes(client):
    c = client
    default = c.scene("default")
    assert default.prefix == "/v1" and default.sim()["step"] == c.sim()["step"]
    for bad in ("Not A Scene", "", "-x", "x" * 64):
        with pytest.raises(ValueError):
            c.scene(bad)
    # A scene of its own size and parameters, made and listed by the server.
    made = c.create_scene(id="other", scene={"nx": 7, "ny": 5}, params={"k_bend": 0.02})
    assert (made["id"], made["n_vertices"]) == ("other", 35)
    other = c.scene("other")
    assert other.prefix == "/v1/scenes/other"
    assert sorted(s["id"] for s in c.scenes()["scenes"]) == ["default", "other"]
    assert other.params()["k_bend"] == 0.02
    other.add_rock([0, 0, 1.5], 0.1)
    assert len(other.rocks()["rocks"]) == 1
    assert c.rocks()["rocks"] == []  # nothing reached the default scene
    assert type(refusal(lambda: c.create_scene(id="other"))) is clothd.Conflict
    c.delete_scene("other")
    for call in (other.sim, lambda: c.delete_scene("other"), lambda: other.record(1)):
        assert type(refusal(call)) is clothd.NotFound
    assert [s["id"] for s in c.scenes()["scenes"]] == ["default"]
