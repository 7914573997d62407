"""clothd's WebSocket stream in asyncio, through the websockets package (Debian's
python3-websockets), which is optional: without it, connecting raises MissingDependency.

    async with client.astream(encoding="q16") as s:     # hello read, q16 subscribed
        async for frame in s.frames():                   # decoded as the synchronous stream's
            ...

The messages are those of clothd.stream.Stream (dicts for text, Frames for binary frames,
decoded by clothd.frames.FrameDecoder), with the same methods as coroutines; a lost connection
raises ConnectionFailed (no reconnection here), a deleted scene NotFound. The HTTP call that finds
the stream's port runs in a thread (asyncio.to_thread), so the loop is never blocked.
"""

from __future__ import annotations

import asyncio
import importlib
import json
from typing import Any, AsyncIterator, Callable, Dict, List, Optional, Sequence

from .common import DEFAULT_SCENE, StreamClient
from .errors import ConnectionFailed, MissingDependency, NotFound, ProtocolError, StreamRefused, Timeout, error_class
from .frames import Frame, FrameDecoder
from .stream import PROTOCOL, SCENE_DELETED, Message, parse_text, stream_url

_ws: Any  # websockets.client, or None (imported by name: mypy checks this module with or without it)
_ws_exceptions: Any
try:
    _ws = importlib.import_module("websockets.client")
    _ws_exceptions = importlib.import_module("websockets.exceptions")
except ImportError:  # optional: the asyncio stream needs it
    _ws = _ws_exceptions = None


def websockets_available() -> bool:
    """Whether the websockets package is importable (the asyncio stream needs it)."""
    return _ws is not None


class AsyncStream:
    """One connection to the stream of a scene, in asyncio (``client.astream()`` makes one;
    ``async with`` or ``await s.connect()`` opens it).

    subscription: {encoding, max_fps, scalar, quantum, max_kbps}, sent once connected. numpy: as
    clothd.frames.decode_frame's. timeout: seconds to connect and to wait for the hello.
    on_event(event): called with each event as it is read.
    """

    def __init__(self, client: StreamClient, scene: str = DEFAULT_SCENE, subscription: Optional[Dict[str, Any]] = None, *,
                 numpy: Optional[bool] = None, timeout: Optional[float] = 30.0,
                 on_event: Optional[Callable[[Dict[str, Any]], None]] = None) -> None:
        self.client = client
        self.scene = scene
        self.subscription: Dict[str, Any] = dict(subscription or {})
        self.timeout = timeout
        self.decoder = FrameDecoder(numpy=numpy)
        self.on_event = on_event
        self.hello: Optional[Dict[str, Any]] = None
        self.subscribed: Optional[Dict[str, Any]] = None
        self.ws: Any = None  # websockets' WebSocketClientProtocol
        self.closed = False
        self._waiting: List[Message] = []  # messages read while waiting for another, returned first

    async def connect(self) -> Dict[str, Any]:
        """Opens the connection, reads the hello and subscribes; returns the hello."""
        if _ws is None:
            raise MissingDependency("the asyncio stream needs websockets (Debian: apt install python3-websockets)")
        url = await asyncio.to_thread(stream_url, self.client, self.scene)
        protocols = [PROTOCOL] + (["bearer." + self.client.token] if self.client.token else [])
        try:
            # No Origin (websockets sends none unless told): a page's would have to be the HTTP port's.
            self.ws = await _ws.connect(url, subprotocols=protocols, open_timeout=self.timeout, max_size=None,
                                        ping_interval=None)
        except _ws_exceptions.InvalidStatusCode as e:
            status = e.status_code
            cls = error_class(status) if status >= 400 else ConnectionFailed
            raise cls("the stream at %s refused the connection: %s" % (url, e), status=status) from e
        except (OSError, asyncio.TimeoutError, _ws_exceptions.WebSocketException) as e:
            raise ConnectionFailed("cannot open the stream at %s: %s" % (url, e)) from e
        self.closed = False
        hello = await self._receive(self.timeout)
        if not isinstance(hello, dict) or hello.get("type") != "hello":
            await self.close()
            raise ProtocolError("the stream's first message is not a hello: %r" % (hello,))
        if hello.get("protocol") != PROTOCOL:
            await self.close()
            raise ProtocolError("clothd speaks %r, this client %s" % (hello.get("protocol"), PROTOCOL))
        self.hello = hello
        if self.subscription:
            await self.send(dict(self.subscription, type="subscribe"))
        return hello

    async def close(self) -> None:
        """Closes the stream; iteration ends."""
        self.closed = True
        if self.ws is not None:
            await self.ws.close()
            self.ws = None

    async def __aenter__(self) -> AsyncStream:
        await self.connect()
        return self

    async def __aexit__(self, *exc: object) -> None:
        await self.close()

    # ---- reading ----
    async def _receive(self, timeout: Optional[float] = None) -> Message:
        if self.ws is None:
            raise ConnectionFailed("the stream is not connected")
        try:
            data = await asyncio.wait_for(self.ws.recv(), timeout)
        except asyncio.TimeoutError as e:
            raise Timeout("no stream message within %s s" % timeout) from e
        except _ws_exceptions.ConnectionClosed as e:
            close = e.rcvd
            if close is not None and close.code == 1001 and close.reason == SCENE_DELETED:
                raise NotFound("scene %r was deleted (the stream closed: 1001, %s)" % (self.scene, SCENE_DELETED),
                               status=404) from e
            raise ConnectionFailed("the stream closed: %s" % e) from e
        if isinstance(data, str):
            m = parse_text(data)
            if m["type"] == "subscribed":
                self.subscribed = m
            elif m["type"] == "event" and self.on_event:
                self.on_event(m)
            return m
        return self.decoder.decode(data)

    async def receive(self, timeout: Optional[float] = None) -> Message:
        """The next message (a dict or a Frame), waiting at most ``timeout`` s (Timeout past it)."""
        if self._waiting:
            return self._waiting.pop(0)
        return await self._receive(timeout)

    def __aiter__(self) -> AsyncIterator[Message]:
        return self._messages()

    async def _messages(self) -> AsyncIterator[Message]:
        while not self.closed:
            try:
                yield await self.receive()
            except ConnectionFailed:
                if self.closed:
                    return
                raise

    async def frames(self) -> AsyncIterator[Frame]:
        """The frames as they come."""
        async for m in self:
            if isinstance(m, Frame):
                yield m

    async def events(self) -> AsyncIterator[Dict[str, Any]]:
        """The events as they come."""
        async for m in self:
            if isinstance(m, dict) and m.get("type") == "event":
                yield m

    async def wait_for(self, match: Callable[[Message], bool], timeout: float = 15.0) -> Message:
        """The next message for which match(message) is true, within ``timeout`` s in all
        (Timeout past it); the messages read meanwhile are returned afterwards, in order."""
        loop = asyncio.get_running_loop()
        deadline = loop.time() + timeout
        skipped: List[Message] = []
        try:
            while True:
                left = deadline - loop.time()
                if left <= 0:
                    raise Timeout("no matching stream message within %s s" % timeout)
                m = await self.receive(left)
                if match(m):
                    return m
                skipped.append(m)
        finally:
            self._waiting[:0] = skipped

    async def next_frame(self, timeout: float = 15.0) -> Frame:
        """The next frame (Timeout after ``timeout`` s)."""
        m = await self.wait_for(lambda m: isinstance(m, Frame), timeout)
        assert isinstance(m, Frame)
        return m

    # ---- sending ----
    async def send(self, message: Dict[str, Any]) -> None:
        """Sends a client message (a dict, as JSON)."""
        if self.ws is None:
            raise ConnectionFailed("the stream is not connected")
        try:
            await self.ws.send(json.dumps(message, allow_nan=False))
        except _ws_exceptions.ConnectionClosed as e:
            raise ConnectionFailed("the stream closed: %s" % e) from e

    async def subscribe(self, encoding: Optional[str] = None, max_fps: Optional[float] = None,
                        scalar: Optional[str] = None, quantum: Optional[float] = None,
                        max_kbps: Optional[float] = None, timeout: float = 15.0) -> Dict[str, Any]:
        """Changes the subscription, as Stream.subscribe: the server's ``subscribed`` answer, or
        StreamRefused with its ``error``."""
        change: Dict[str, Any] = {k: v for k, v in (("encoding", encoding), ("max_fps", max_fps), ("scalar", scalar),
                                                    ("quantum", quantum), ("max_kbps", max_kbps)) if v is not None}
        if change.get("max_kbps") == 0:
            change["max_kbps"] = None  # null: no budget
        self.subscription.update(change)
        await self.send(dict(change, type="subscribe"))
        m = await self.wait_for(lambda m: isinstance(m, dict) and (
            m.get("type") == "subscribed" or (m.get("type") == "error" and m.get("about") == "subscribe")), timeout)
        assert isinstance(m, dict)
        if m["type"] == "error":
            raise StreamRefused("the stream refused the subscription: %s" % m.get("detail"), m)
        return m

    async def keyframe(self) -> None:
        """Asks for a delta keyframe."""
        await self.send({"type": "keyframe"})

    async def grab(self, vertex: int, target: Sequence[float]) -> None:
        """Pulls ``vertex`` toward ``target`` [x, y, z], as PUT /v1/grab without a round trip."""
        await self.send({"type": "grab", "vertex": vertex, "target": list(target)})

    async def release(self) -> None:
        """Releases the grabbed vertex."""
        await self.send({"type": "release"})
