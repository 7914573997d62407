"""clothd.aio.AsyncStream against the real clothd: the hello and the subscription, frames that
hold the cloth GET /v1/cloth/state gives, two streams read at once on one event loop, a grab
sent on the stream reaching the scene, and a deleted scene's close raised as NotFound."""

import asyncio

import pytest

import clothd

pytestmark = pytest.mark.skipif(not clothd.websockets_available(),
                                reason="the asyncio stream needs websockets (apt install python3-websockets)")


def run(coro, timeout=20):
    return asyncio.run(asyncio.wait_for(coro, timeout))


def test_frames_hold_the_cloth_state_and_two_streams_share_a_loop(client):
    client.set_scene(nx=8, ny=6)

    async def main():
        async with client.astream(encoding="f32") as a, client.astream(encoding="q16") as b:
            assert a.hello["protocol"] == "clothd.v1" and a.hello["scene"]["nx"] == 8
            assert a.subscription == {"encoding": "f32"}
            # A paused scene publishes after each command: the step's last frame comes on both.
            stepped = await asyncio.to_thread(client.step, frames=3)
            fa, fb = await asyncio.gather(
                a.wait_for(lambda m: isinstance(m, clothd.Frame) and m.step == stepped["step"]),
                b.wait_for(lambda m: isinstance(m, clothd.Frame) and m.step == stepped["step"]))
            state = await asyncio.to_thread(client.cloth_state_binary, numpy=False)
            return fa, fb, state, a.subscribed

    fa, fb, state, subscribed = run(main())
    assert subscribed["encoding"] == "f32"
    assert (fa.encoding, fb.encoding, fa.n_vertices) == ("f32", "q16", 48)
    assert [list(map(float, p)) for p in fa.positions] == state.positions  # f32: the float32 values themselves
    extent = max(hi - lo for lo, hi in zip(fb.bbox_min, fb.bbox_max))
    for p, q in zip(fb.positions, state.positions):  # q16: within one step of the grid over the bbox
        assert all(abs(float(x) - y) <= extent / 65535 + 1e-6 for x, y in zip(p, q))


def test_subscribe_refused_grab_and_a_deleted_scene(client):
    client.create_scene(id="aio", scene={"nx": 6, "ny": 4})

    async def main():
        async with client.scene("aio").astream() as s:
            assert s.hello["scene_id"] == "aio"
            with pytest.raises(clothd.StreamRefused):
                await s.subscribe(encoding="nonsense")
            assert (await s.subscribe(encoding="q16"))["encoding"] == "q16"
            await s.grab(5, [0.1, 0.2, 1.4])
            journal = client.scene("aio").journal
            while not any(e["command"]["op"] == "grab" and e["command"]["vertex"] == 5
                          and e["command"]["target"] == [0.1, 0.2, 1.4] for e in (await asyncio.to_thread(journal))["entries"]):
                await asyncio.sleep(0.02)  # polled until the grab is journaled (run() bounds the wait)
            await asyncio.to_thread(client.delete_scene, "aio")
            with pytest.raises(clothd.NotFound, match="was deleted"):
                while True:
                    await s.receive(timeout=15)

    try:
        run(main())
    finally:
        if any(x["id"] == "aio" for x in client.scenes()["scenes"]):
            client.delete_scene("aio")
