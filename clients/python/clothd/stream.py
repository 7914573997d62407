"""clothd's WebSocket stream (PROTOCOL.md, "The stream"), through websocket-client (Debian's
python3-websocket), which is optional: without it, opening a stream raises MissingDependency.

A Stream finds the port (GET /v1/health), opens ``ws://host:port/stream`` with the client's
token in the subprotocol list, reads the hello (``stream.hello``), and subscribes. Iterating it
yields every message as it comes: dicts for text messages (events, ``subscribed``, ``error``)
and Frame objects for binary frames; ``frames()`` yields only the frames, ``events()`` only the
events. With ``reconnect=True`` a lost connection is opened again after 0.25 s, doubling to 8 s
(+-25%), back to 0.25 s after each hello, and the new hello is yielded; without it a lost
connection raises ConnectionFailed.

Frames are decoded by clothd.frames.FrameDecoder. A frame that does not decode, or a text
message that is not a JSON object of a known type, raises FrameError or ProtocolError, unless
``on_problem`` is given: then it is reported there and the stream goes on.
"""

from __future__ import annotations

import json
import random
import time
import urllib.parse
from typing import Any, Callable, Dict, Iterator, List, Optional, Sequence, Union

from .common import DEFAULT_SCENE as DEFAULT_SCENE, StreamClient, check_scene_id
from .errors import (ConnectionFailed, MissingDependency, NotFound, ProtocolError, StreamRefused, Timeout, Unavailable,
                     error_class)
from .frames import Buffer, Frame, FrameDecoder

_websocket: Any  # websocket-client, or None
try:
    import websocket as _websocket_module  # type: ignore[import]  # websocket-client ships no types
    _websocket = _websocket_module
except ImportError:  # optional: streams need it
    _websocket = None

#: What a stream yields: a text message as a dict (hello, event, subscribed, error), or a Frame.
Message = Union[Dict[str, Any], Frame]

PROTOCOL = "clothd.v1"
BACKOFF_MIN = 0.25
BACKOFF_MAX = 8.0
TEXT_TYPES = ("hello", "event", "subscribed", "error")
#: The close reason (with code 1001) of a stream whose scene was deleted.
SCENE_DELETED = "scene deleted"


def websocket_available() -> bool:
    """Whether websocket-client is importable (streams need it)."""
    return _websocket is not None


def stream_url(client: StreamClient, scene: str = DEFAULT_SCENE) -> str:
    """The URL of ``scene``'s stream, from GET /v1/health (503 unhealthy still tells it); NotFound
    where the server has no such scene."""
    if scene != DEFAULT_SCENE:
        client.scene(scene).sim()  # NotFound where the server has no such scene
    try:
        stream = client.health()["stream"]
    except Unavailable as e:
        stream = (e.body or {}).get("stream") if isinstance(e.body, dict) else None
        if not stream:
            raise
    if not stream:
        raise ProtocolError("this clothd has no stream (GET /v1/health: stream is null)")
    parts = urllib.parse.urlsplit(client.url)
    hostname = parts.hostname or ""
    host = "[%s]" % hostname if ":" in hostname else hostname
    scheme = "wss" if parts.scheme == "https" else "ws"
    query = "" if scene == DEFAULT_SCENE else "?scene=" + urllib.parse.quote(scene, safe="")
    return "%s://%s:%d%s%s" % (scheme, host, stream["port"], stream.get("path") or "/stream", query)


def parse_text(data: Union[str, Buffer]) -> Dict[str, Any]:
    """A text stream message: a JSON object of a known type (ProtocolError otherwise)."""
    try:
        m = json.loads(data)
    except ValueError as e:
        shown = data[:80] if isinstance(data, str) else bytes(data[:80])
        raise ProtocolError("a stream message is not JSON: %r" % (shown,)) from e
    if not isinstance(m, dict):
        raise ProtocolError("a stream message is not a JSON object: %r" % (m,))
    if m.get("type") not in TEXT_TYPES:
        raise ProtocolError("unknown stream message type %r" % (m.get("type"),))
    return m


class Stream:
    """One connection to the stream of a scene (client.stream() makes one, connected).

    subscription: {encoding, max_fps, scalar, quantum, max_kbps} sent on every connection. reconnect: open a lost
    connection again with backoff. numpy: as clothd.frames.decode_frame's. timeout: seconds to
    connect and to wait for the hello (None: for ever). on_event(event), on_status(state,
    detail) and on_problem(text): called as they happen (on_status: "open", "closed").
    """

    def __init__(self, client: StreamClient, scene: str = DEFAULT_SCENE, subscription: Optional[Dict[str, Any]] = None, *,
                 reconnect: bool = False, numpy: Optional[bool] = None, timeout: Optional[float] = 30.0,
                 on_event: Optional[Callable[[Dict[str, Any]], None]] = None,
                 on_status: Optional[Callable[[str, str], None]] = None,
                 on_problem: Optional[Callable[[str], None]] = None) -> None:
        if _websocket is None:
            raise MissingDependency("the stream needs websocket-client (Debian: apt install python3-websocket)")
        self.client = client
        self.scene = scene
        self.subscription: Dict[str, Any] = dict(subscription or {})
        self.reconnect = reconnect
        self.timeout = timeout
        self.decoder = FrameDecoder(numpy=numpy)
        self.on_event, self.on_status, self.on_problem = on_event, on_status, on_problem
        self.hello: Optional[Dict[str, Any]] = None
        self.subscribed: Optional[Dict[str, Any]] = None
        self.ws: Any = None  # websocket.WebSocket
        self.backoff = BACKOFF_MIN
        #: The waits chosen before each reconnection (s), newest last.
        self.retry_waits: List[float] = []
        self.closed = False
        self._waiting: List[Message] = []  # messages read while waiting for another, yielded first
        self.connect()

    # ---- connection ----
    def url(self) -> str:
        """The stream's URL, from GET /v1/health (503 unhealthy still tells it)."""
        return stream_url(self.client, self.scene)

    def connect(self) -> Dict[str, Any]:
        """Opens the connection and reads the hello; raises what stops it."""
        url = self.url()
        protocols = [PROTOCOL] + (["bearer." + self.client.token] if self.client.token else [])
        try:
            # No Origin: websocket-client would send one naming the stream's port, which the
            # server refuses as another origin (a browser's page must come from the HTTP port).
            self.ws = _websocket.create_connection(url, subprotocols=protocols, timeout=self.timeout,
                                                   suppress_origin=True, enable_multithread=True)
        except _websocket.WebSocketBadStatusException as e:
            # Refused before the upgrade, with an HTTP status (401 without the token, 403 ...).
            status = getattr(e, "status_code", None)
            cls = error_class(status) if isinstance(status, int) and status >= 400 else ConnectionFailed
            raise cls("the stream at %s refused the connection: %s" % (url, e), status=status) from e
        except (OSError, _websocket.WebSocketException) as e:
            raise ConnectionFailed("cannot open the stream at %s: %s" % (url, e)) from e
        self.decoder = FrameDecoder(numpy=self.decoder.numpy)  # a new connection sends its own keyframe
        hello = self._receive(self.timeout)
        if not isinstance(hello, dict) or hello.get("type") != "hello":
            self._close_socket()
            raise ProtocolError("the stream's first message is not a hello: %r" % (hello,))
        if hello.get("protocol") != PROTOCOL:
            self._close_socket()
            raise ProtocolError("clothd speaks %r, this client %s" % (hello.get("protocol"), PROTOCOL))
        self.hello = hello
        self.backoff = BACKOFF_MIN
        self.ws.settimeout(None)
        if self.subscription:
            self.send(dict(self.subscription, type="subscribe"))
        if self.on_status:
            self.on_status("open", url)
        return hello

    def _close_socket(self) -> None:
        if self.ws is not None:
            try:
                self.ws.close()
            except Exception:  # noqa: BLE001 - closing a broken socket
                pass
        self.ws = None

    def close(self) -> None:
        """Closes the stream; iteration ends."""
        self.closed = True
        self._close_socket()

    def __enter__(self) -> Stream:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def next_wait(self) -> float:
        """The wait before the next reconnection (s): the backoff +-25% (so that clients part
        ways); the backoff doubles, up to 8 s."""
        wait = self.backoff * (0.75 + 0.5 * random.random())
        self.backoff = min(self.backoff * 2, BACKOFF_MAX)
        return wait

    def _reconnect(self, why: str) -> Optional[Dict[str, Any]]:
        """Opens the connection again with backoff, until it holds; returns the new hello."""
        self._close_socket()
        while not self.closed:
            wait = self.next_wait()
            self.retry_waits.append(wait)
            if self.on_status:
                self.on_status("closed", "%s; reconnecting in %.1f s" % (why, wait))
            time.sleep(wait)
            if self.closed:
                break
            try:
                return self.connect()
            except NotFound:
                raise
            except (ConnectionFailed, Unavailable, Timeout, ProtocolError) as e:
                why = str(e)
        return None

    # ---- reading ----
    def _receive(self, timeout: Optional[float] = None) -> Optional[Message]:
        """One message: a dict (text) or a Frame; None when the connection closed."""
        deadline = None if timeout is None else time.monotonic() + timeout
        while True:
            left = None if deadline is None else max(0.0, deadline - time.monotonic())
            try:
                self.ws.settimeout(left)
                opcode, data = self.ws.recv_data()
            except _websocket.WebSocketTimeoutException as e:
                raise Timeout("no stream message within %s s" % timeout) from e
            except (OSError, _websocket.WebSocketConnectionClosedException) as e:
                if self.closed:
                    return None
                raise ConnectionFailed("the stream closed: %s" % e) from e
            if opcode == _websocket.ABNF.OPCODE_CLOSE:
                if self.closed:
                    return None
                code = int.from_bytes(data[:2], "big") if len(data) >= 2 else None
                if code == 1001 and bytes(data[2:]).decode("utf-8", "replace") == SCENE_DELETED:
                    self._close_socket()
                    raise NotFound("scene %r was deleted (the stream closed: 1001, %s)" % (self.scene, SCENE_DELETED),
                                   status=404)
                raise ConnectionFailed("the stream closed (the server sent a close%s)" % (
                    "" if code is None else ": %d" % code))
            if opcode not in (_websocket.ABNF.OPCODE_BINARY, _websocket.ABNF.OPCODE_TEXT):
                continue  # ping, pong: not messages
            m = self._message(data, opcode == _websocket.ABNF.OPCODE_BINARY)
            if m is not None:
                return m

    def _message(self, data: Buffer, binary: bool) -> Optional[Message]:
        """A Frame or a dict; with on_problem, None for what does not fit the protocol (reported)."""
        try:
            return self.decoder.decode(data) if binary else self._text(data)
        except ProtocolError as e:
            if not self.on_problem:
                raise
            self.on_problem(str(e))  # reported; the stream goes on
            return None

    def inject(self, data: Union[str, bytes]) -> Optional[Message]:
        """Handles one message as if the server had sent it (str: text, bytes: a frame): the
        Frame or dict, or None when on_problem took it. A test's way to send what no server does."""
        return self._message(data.encode("utf-8") if isinstance(data, str) else data, not isinstance(data, str))

    def _text(self, data: Buffer) -> Dict[str, Any]:
        m = parse_text(data)
        if m["type"] == "subscribed":
            self.subscribed = m
        elif m["type"] == "event" and self.on_event:
            self.on_event(m)
        return m

    def receive(self, timeout: Optional[float] = None) -> Message:
        """The next message (a dict or a Frame), waiting at most ``timeout`` s (Timeout past it).
        With reconnect, a lost connection is opened again and the new hello is returned."""
        if self._waiting:
            return self._waiting.pop(0)
        while not self.closed:
            try:
                m = self._receive(timeout)
            except ConnectionFailed as e:
                if not self.reconnect or self.closed:
                    raise
                m = self._reconnect(str(e))
            if m is not None:
                return m
        raise ConnectionFailed("the stream is closed")

    def __iter__(self) -> Iterator[Message]:
        """Every message as it comes, until close()."""
        while not self.closed:
            try:
                yield self.receive()
            except ConnectionFailed:
                if self.closed:
                    return
                raise

    def frames(self) -> Iterator[Frame]:
        """The frames as they come (the other messages are kept in hello, subscribed, on_event)."""
        for m in self:
            if isinstance(m, Frame):
                yield m

    def events(self) -> Iterator[Dict[str, Any]]:
        """The events as they come."""
        for m in self:
            if isinstance(m, dict) and m.get("type") == "event":
                yield m

    def wait_for(self, match: Callable[[Message], bool], timeout: float = 15.0) -> Message:
        """The next message for which match(message) is true, waiting at most ``timeout`` s in
        all (Timeout past it); the messages read meanwhile are yielded afterwards, in order."""
        deadline = time.monotonic() + timeout
        skipped: List[Message] = []
        try:
            while True:
                left = deadline - time.monotonic()
                if left <= 0:
                    raise Timeout("no matching stream message within %s s" % timeout)
                m = self.receive(left)
                if match(m):
                    return m
                skipped.append(m)
        finally:
            self._waiting[:0] = skipped

    def next_frame(self, timeout: float = 15.0) -> Frame:
        """The next frame (Timeout after ``timeout`` s)."""
        m = self.wait_for(lambda m: isinstance(m, Frame), timeout)
        assert isinstance(m, Frame)
        return m

    # ---- sending ----
    def send(self, message: Dict[str, Any]) -> None:
        """Sends a client message (a dict, as JSON)."""
        if self.ws is None:
            raise ConnectionFailed("the stream is not connected")
        try:
            self.ws.send(json.dumps(message, allow_nan=False))
        except (OSError, _websocket.WebSocketException) as e:
            raise ConnectionFailed("the stream closed: %s" % e) from e

    def subscribe(self, encoding: Optional[str] = None, max_fps: Optional[float] = None, scalar: Optional[str] = None,
                  quantum: Optional[float] = None, max_kbps: Optional[float] = None, wait: bool = True,
                  timeout: float = 15.0) -> Optional[Dict[str, Any]]:
        """Changes the subscription (kept across reconnections): encoding (f32, q16, meshopt,
        delta), max_fps, scalar, quantum (delta's grid, m), max_kbps (a byte budget; 0 lifts it).
        wait: return the server's ``subscribed`` answer, or raise StreamRefused with its ``error``."""
        change: Dict[str, Any] = {k: v for k, v in (("encoding", encoding), ("max_fps", max_fps), ("scalar", scalar),
                                    ("quantum", quantum), ("max_kbps", max_kbps)) if v is not None}
        if change.get("max_kbps") == 0:
            change["max_kbps"] = None  # null: no budget
        self.subscription.update(change)
        self.send(dict(change, type="subscribe"))
        if not wait:
            return None
        m = self.wait_for(lambda m: isinstance(m, dict) and (
            m.get("type") == "subscribed" or (m.get("type") == "error" and m.get("about") == "subscribe")), timeout)
        assert isinstance(m, dict)
        if m["type"] == "error":
            raise StreamRefused("the stream refused the subscription: %s" % m.get("detail"), m)
        return m

    def switch_scene(self, scene_id: str, timeout: float = 15.0) -> Dict[str, Any]:
        """Streams another scene on this connection (``{"type": "subscribe", "scene": id}``),
        keeping the subscription; reconnections open that scene. Returns the server's
        ``subscribed`` answer; the new scene's hello is then ``stream.hello``, and what the scene
        before sent until then is dropped. A scene the server lacks (or an id it refuses) raises
        StreamRefused with the server's ``error``, and the stream stays on its scene."""
        check_scene_id(scene_id)
        self.send({"type": "subscribe", "scene": scene_id})
        deadline = time.monotonic() + timeout
        before: List[Message] = []
        after: List[Message] = []
        hello: Optional[Dict[str, Any]] = None
        while True:
            left = deadline - time.monotonic()
            if left <= 0:
                self._waiting[:0] = before + after
                raise Timeout("no answer to the switch to scene %r within %s s" % (scene_id, timeout))
            m = self.receive(left)
            if not isinstance(m, dict):
                (before if hello is None else after).append(m)
                continue
            kind = m.get("type")
            if kind == "error" and m.get("about") == "subscribe" and hello is None:
                self._waiting[:0] = before
                raise StreamRefused("the stream refused scene %r: %s" % (scene_id, m.get("detail")), m)
            if kind == "hello" and m.get("scene_id") == scene_id:
                hello = m
            elif kind == "subscribed" and hello is not None:
                self.hello, self.scene = hello, scene_id
                self._waiting[:0] = after
                return m
            elif hello is None:
                before.append(m)
            else:
                after.append(m)

    def keyframe(self) -> None:
        """Asks for a delta keyframe (the server sends at most four a second)."""
        self.send({"type": "keyframe"})

    def grab(self, vertex: int, target: Sequence[float]) -> None:
        """Pulls ``vertex`` toward ``target`` [x, y, z], as PUT /v1/grab without a round trip."""
        self.send({"type": "grab", "vertex": vertex, "target": list(target)})

    def release(self) -> None:
        """Releases the grabbed vertex, as DELETE /v1/grab."""
        self.send({"type": "release"})
