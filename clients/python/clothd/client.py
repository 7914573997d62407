"""clothd's HTTP API (proto/PROTOCOL.md, proto/openapi.yaml), with the standard library only.

One method per route; the server's JSON answers are returned as they are (dicts and lists),
binary ones as bytes; every refusal is raised as an exception of clothd.errors; every request
carries an X-Request-Id; the bearer token where one is given; a timeout on every call.

Scenes: the daemon of today runs one scene, ``default``, behind the routes without a prefix.
Every per-scene method lives in SceneRoutes: the client's own are those of ``default`` (the
unprefixed routes), and ``client.scene(id)`` gives a handle whose methods build
``/v1/scenes/{id}/...`` paths for any other id. A server without scenes answers those 404
(NotFound), as it answers scenes(), create_scene() and delete_scene(): the server decides, so a
server that has scenes needs no other client.
"""

from __future__ import annotations

import http.client
import itertools
import json
import os
import random
import re
import socket
import string
import urllib.parse
from typing import TYPE_CHECKING, Any, Dict, Iterable, Mapping, Optional, Sequence, Union, cast

from . import frames as _frames
from .aio import AsyncStream
from .common import DEFAULT_SCENE as DEFAULT_SCENE, SCENE_ID as SCENE_ID, check_scene_id as _check_scene_id
from .errors import ConnectionFailed, ProtocolError, Timeout, error_from_answer
from .stream import Stream

if TYPE_CHECKING:
    from .recording import Recording

#: A JSON object the server answers, as json.loads gives it (PROTOCOL.md describes each).
JsonObject = Dict[str, Any]

DEFAULT_URL = "http://127.0.0.1:8080"
DEFAULT_TIMEOUT = 30.0
#: X-Request-Id values the server echoes.
REQUEST_ID = re.compile(r"[A-Za-z0-9._:/+=-]{1,128}\Z")

_UNSET = object()


def _check_request_id(request_id: object) -> None:
    if not isinstance(request_id, str) or not REQUEST_ID.match(request_id):
        raise ValueError("X-Request-Id %r is not 1-128 characters of letters, digits and -_.:/+=" % (request_id,))


def _merge(changes: Optional[Mapping[str, Any]], kwargs: Mapping[str, Any]) -> JsonObject:
    body = dict(changes or {})
    body.update(kwargs)
    return body


class ClothState:
    """The cloth state's binary form: positions and velocities, n x 3 each, in vertex order
    (numpy float32 arrays of shape (n, 3) when numpy is there, else lists of [x, y, z])."""

    def __init__(self, positions: _frames.Positions, velocities: _frames.Positions) -> None:
        self.positions = positions
        self.velocities = velocities

    def __len__(self) -> int:
        return len(self.positions)

    def __repr__(self) -> str:
        return "ClothState(%d vertices)" % len(self)


class SceneRoutes:
    """The routes of one scene. ``id`` is its id, ``prefix`` where its routes are."""

    def __init__(self, client: Client, scene_id: str) -> None:
        _check_scene_id(scene_id)
        self._client = client
        self.id = scene_id
        self.prefix = "/v1" if scene_id == DEFAULT_SCENE else "/v1/scenes/" + scene_id

    def _call(self, method: str, route: str, body: Any = None, **options: Any) -> Any:
        return self._client.request(method, self.prefix + route, body, **options)

    def _obj(self, method: str, route: str, body: Any = None, **options: Any) -> JsonObject:
        """A route whose answer is a JSON object."""
        return cast(JsonObject, self._call(method, route, body, **options))

    def _bytes(self, route: str) -> bytes:
        """GET of a route's binary form."""
        return cast(bytes, self._call("GET", route, accept="application/octet-stream", as_="bytes"))

    # ---- the simulation ----
    def sim(self, hash: bool = False) -> JsonObject:
        """GET /sim: state, step, frame, time, energy, real-time factor. ``hash=True`` computes
        the state hash now (it is null while running otherwise)."""
        return self._obj("GET", "/sim?hash=1" if hash else "/sim")

    def pause(self) -> JsonObject:
        """POST /sim/pause; answers as sim(), with the state hash."""
        return self._obj("POST", "/sim/pause")

    def resume(self) -> JsonObject:
        """POST /sim/resume."""
        return self._obj("POST", "/sim/resume")

    def step(self, frames: Optional[int] = None, substeps: Optional[int] = None) -> JsonObject:
        """POST /sim/step while paused (Conflict while running): ``frames`` or ``substeps``
        (default one frame). Answers once they ran, or once something ended the step
        (``interrupted``: True). No timeout unless the client has a step_timeout: a long step
        answers when it is done (cancel_step() from another thread ends it)."""
        if frames is not None and substeps is not None:
            raise ValueError("step() takes frames or substeps, not both")
        body = {"substeps": substeps} if substeps is not None else {"frames": 1 if frames is None else frames}
        return self._obj("POST", "/sim/step", body, timeout=self._client._options["step_timeout"])

    def cancel_step(self) -> JsonObject:
        """DELETE /sim/step: ends the step in progress; ``{cancelled, step, frame}``."""
        return self._obj("DELETE", "/sim/step")

    def reset(self) -> JsonObject:
        """POST /sim/reset: rebuilds the scene, no rocks, step 0 (parameters are kept)."""
        return self._obj("POST", "/sim/reset")

    # ---- parameters and the scene ----
    def params(self) -> JsonObject:
        """GET /params: every live parameter, as one dict."""
        return self._obj("GET", "/params")

    def set_params(self, changes: Optional[Mapping[str, Any]] = None, **params: Any) -> JsonObject:
        """PATCH /params: all of them or none (``set_params(k_bend=30, wind=[2, 0, 0])``);
        ``{applied_step, params}``."""
        return self._obj("PATCH", "/params", _merge(changes, params))

    def params_schema(self) -> JsonObject:
        """GET /params/schema: ``{params: [{name, type, unit, default, min, max, choices, kind, help}]}``."""
        return self._obj("GET", "/params/schema")

    def get_scene(self) -> JsonObject:
        """GET /scene: the scene fields (nx, ny, size_x, size_y, height, orientation, pins, areal_density)."""
        return self._obj("GET", "/scene")

    def set_scene(self, fields: Optional[Mapping[str, Any]] = None, **scene: Any) -> JsonObject:
        """PUT /scene: any subset of the fields; rebuilds the cloth, clears the rocks, step 0."""
        return self._obj("PUT", "/scene", _merge(fields, scene))

    # ---- rocks, pins, grab ----
    def rocks(self) -> JsonObject:
        """GET /rocks: ``{rocks: [{id, kinematic, position, velocity, angular_velocity, orientation, radius, density, mass}]}``."""
        return self._obj("GET", "/rocks")

    def add_rock(self, position: Sequence[float], radius: float, **fields: Any) -> JsonObject:
        """POST /rocks: a rock at ``position`` (m) of ``radius`` (m); optional velocity,
        angular_velocity, orientation, density (kg/m^3, default 300), kinematic.
        ``{id, rock, applied_step}``."""
        return self._obj("POST", "/rocks", dict(fields, position=list(position), radius=radius))

    def clear_rocks(self) -> JsonObject:
        """DELETE /rocks: ``{applied_step, removed}``."""
        return self._obj("DELETE", "/rocks")

    def rock(self, rock_id: Union[int, str]) -> JsonObject:
        """GET /rocks/{id}."""
        return self._obj("GET", "/rocks/%s" % urllib.parse.quote(str(rock_id), safe=""))

    def set_rock(self, rock_id: Union[int, str], changes: Optional[Mapping[str, Any]] = None,
                 **fields: Any) -> JsonObject:
        """PATCH /rocks/{id}: any fields of add_rock's (a teleport keeps the velocity unless given)."""
        return self._obj("PATCH", "/rocks/%s" % urllib.parse.quote(str(rock_id), safe=""), _merge(changes, fields))

    def remove_rock(self, rock_id: Union[int, str]) -> JsonObject:
        """DELETE /rocks/{id}: ``{applied_step, id}``."""
        return self._obj("DELETE", "/rocks/%s" % urllib.parse.quote(str(rock_id), safe=""))

    def set_pins(self, preset: Optional[str] = None, vertices: Optional[Iterable[int]] = None,
                 pinned: bool = True) -> JsonObject:
        """PUT /pins: a ``preset`` (replaces every pin), or ``vertices`` pinned (or, with
        pinned=False, freed); ``{pinned, applied_step}``, pinned being how many are now."""
        if (preset is None) == (vertices is None):
            raise ValueError("set_pins() takes a preset or vertices")
        body: JsonObject = ({"preset": preset} if preset is not None
                            else {"vertices": list(vertices or ()), "pinned": pinned})
        return self._obj("PUT", "/pins", body)

    def grab(self, vertex: int, target: Sequence[float]) -> JsonObject:
        """PUT /grab: pulls ``vertex`` toward ``target`` [x, y, z] (the stream's grab() does it
        without a round trip)."""
        return self._obj("PUT", "/grab", {"vertex": vertex, "target": list(target)})

    def release(self) -> JsonObject:
        """DELETE /grab."""
        return self._obj("DELETE", "/grab")

    # ---- state ----
    def cloth_state(self) -> JsonObject:
        """GET /cloth/state as JSON: ``{step, nx, ny, positions: [[x, y, z], ...], velocities}``."""
        return self._obj("GET", "/cloth/state")

    def cloth_state_binary(self, numpy: Optional[bool] = None) -> ClothState:
        """GET /cloth/state in its binary form (little-endian float32): a ClothState, whose
        positions and velocities are (n, 3) numpy arrays, or lists where numpy is not there
        (numpy=False asks for lists)."""
        data = self._bytes("/cloth/state")
        if len(data) % 24:
            raise ProtocolError("the binary cloth state has %d bytes, not 24 per vertex" % len(data),
                                method="GET", path=self.prefix + "/cloth/state")
        n = len(data) // 24
        return ClothState(_frames.float32_rows(data, 0, n, numpy), _frames.float32_rows(data, 12 * n, n, numpy))

    def snapshot(self) -> bytes:
        """GET /snapshot: the whole state as the server's versioned, checksummed binary (bytes)."""
        return self._bytes("/snapshot")

    def restore_snapshot(self, data: Union[bytes, bytearray, memoryview]) -> JsonObject:
        """PUT /snapshot: restores one (bytes), or changes nothing; ``{applied_step, step, state_hash}``."""
        return self._obj("PUT", "/snapshot", bytes(data))

    def journal(self) -> JsonObject:
        """GET /journal: ``{base_step, entries: [{step, command}]}``."""
        return self._obj("GET", "/journal")

    def journal_bundle(self) -> bytes:
        """GET /journal as a replay bundle (bytes) for ``clothd replay``."""
        return self._bytes("/journal")

    # ---- recordings and the stream ----
    def record(self, seconds: float, encoding: Optional[str] = None, id: Optional[str] = None) -> JsonObject:
        """Starts a recording of this scene for ``seconds`` of simulated time: POST
        /v1/scenes/{id}/recordings (/v1/recordings for ``default``) ``{seconds, encoding?, id?}``
        (encoding: f32, q16, meshopt or
        delta, the server's default delta; id: the recording's, generated when None). Returns
        ``{id, scene, state, ...}``; ``client.recordings.read(rid)`` reads the file once done."""
        body: JsonObject = {"seconds": seconds}
        if encoding is not None:
            body["encoding"] = encoding
        if id is not None:
            _check_scene_id(id, "recording id")
            body["id"] = id
        return self._obj("POST", "/recordings", body)

    def stream(self, encoding: Optional[str] = None, max_fps: Optional[float] = None, scalar: Optional[str] = None,
               **options: Any) -> Stream:
        """The stream of this scene, connected (clothd.stream.Stream; a context manager).
        encoding, max_fps, scalar: the subscription; options: Stream's (reconnect, numpy,
        timeout, on_event, on_status, on_problem)."""
        sub = {k: v for k, v in (("encoding", encoding), ("max_fps", max_fps), ("scalar", scalar)) if v is not None}
        return Stream(self._client, scene=self.id, subscription=sub, **options)

    def astream(self, encoding: Optional[str] = None, max_fps: Optional[float] = None, scalar: Optional[str] = None,
                **options: Any) -> AsyncStream:
        """The stream of this scene in asyncio (clothd.aio.AsyncStream), not yet connected: ``async
        with client.astream(...) as s`` connects it. options: AsyncStream's (numpy, timeout, on_event)."""
        sub = {k: v for k, v in (("encoding", encoding), ("max_fps", max_fps), ("scalar", scalar)) if v is not None}
        return AsyncStream(self._client, scene=self.id, subscription=sub, **options)


class Scene(SceneRoutes):
    """A handle on one scene of the daemon (``client.scene(id)``)."""

    def __repr__(self) -> str:
        return "Scene(%r)" % self.id


class Recordings:
    """The daemon's recordings (a server without them answers NotFound)."""

    def __init__(self, client: Client) -> None:
        self._client = client

    def list(self) -> JsonObject:
        """GET /v1/recordings: ``{recordings: [{id, scene, state, frames, seconds, bytes}]}``."""
        return cast(JsonObject, self._client.request("GET", "/v1/recordings"))

    def get(self, rid: str) -> bytes:
        """GET /v1/recordings/{rid}: the file (bytes)."""
        return cast(bytes, self._client.request("GET", "/v1/recordings/%s" % urllib.parse.quote(str(rid), safe=""),
                                                accept="application/octet-stream", as_="bytes"))

    def read(self, rid: str, numpy: Optional[bool] = None) -> Recording:
        """The recording ``rid`` downloaded and parsed (clothd.recording.Recording): frames
        decoded on demand, ``seek(t)``, events. A recording still running reads as far as it got
        (``complete`` False)."""
        from .recording import read_recording
        return read_recording(self.get(rid), numpy=numpy)

    def delete(self, rid: str) -> JsonObject:
        """DELETE /v1/recordings/{rid} (a running one stops first)."""
        return cast(JsonObject, self._client.request("DELETE", "/v1/recordings/%s" % urllib.parse.quote(str(rid), safe="")))


class Client(SceneRoutes):
    """A clothd server: its daemon-wide routes, and those of the ``default`` scene.

    url: the server (default http://127.0.0.1:8080). token or token_file: the control or view
    token, sent as ``Authorization: Bearer``. timeout: seconds for each blocking socket
    operation of a request (connect, send, each read; default 30; None waits for ever).
    step_timeout: the same for step() (default None: a long step answers when it is done).
    request_id_prefix: requests carry ``X-Request-Id: <prefix>-<n>`` (default ``py-<6 random
    characters>``).
    """

    def __init__(self, url: str = DEFAULT_URL, *, token: Optional[str] = None,
                 token_file: Optional[Union[str, os.PathLike[str]]] = None, timeout: Optional[float] = DEFAULT_TIMEOUT,
                 step_timeout: Optional[float] = None, request_id_prefix: Optional[str] = None) -> None:
        super().__init__(self, DEFAULT_SCENE)
        parts = urllib.parse.urlsplit(url)
        if parts.scheme not in ("http", "https") or not parts.hostname:
            raise ValueError("url %r is not http://host[:port] or https://host[:port]" % (url,))
        self.url = url.rstrip("/")
        self._scheme, self._host, self._port = parts.scheme, parts.hostname, parts.port
        self._base_path = parts.path.rstrip("/")
        if token_file is not None:
            with open(token_file, encoding="utf-8") as f:
                token = f.read().strip()
        if request_id_prefix is None:
            request_id_prefix = "py-" + "".join(random.choice(string.ascii_lowercase + string.digits) for _ in range(6))
        _check_request_id(request_id_prefix + "-1")
        # Shared with every client with_options() makes.
        self._shared: Dict[str, Any] = {"token": token, "prefix": request_id_prefix, "seq": itertools.count(1), "last": None}
        self._options: Dict[str, Any] = {"timeout": timeout, "step_timeout": step_timeout, "request_id": None}
        #: The recordings' routes.
        self.recordings = Recordings(self)

    @classmethod
    def from_env(cls, **options: Any) -> Client:
        """A client for CLOTHD_URL (default http://127.0.0.1:$CLOTHD_PORT, port 8080) with the
        token of CLOTHD_TOKEN_FILE, where set: as scripts/clothctl finds them."""
        url = os.environ.get("CLOTHD_URL") or "http://127.0.0.1:%s" % os.environ.get("CLOTHD_PORT", "8080")
        if os.environ.get("CLOTHD_TOKEN_FILE"):
            options.setdefault("token_file", os.environ["CLOTHD_TOKEN_FILE"])
        return cls(url, **options)

    def __repr__(self) -> str:
        return "Client(%r)" % self.url

    @property
    def token(self) -> Optional[str]:
        """The token requests carry, or None."""
        token: Optional[str] = self._shared["token"]
        return token

    @token.setter
    def token(self, value: Optional[str]) -> None:
        self._shared["token"] = value

    @property
    def last_request_id(self) -> Optional[str]:
        """The X-Request-Id of the last request sent."""
        last: Optional[str] = self._shared["last"]
        return last

    def with_options(self, **changes: Any) -> Client:
        """The same client with other settings: timeout, step_timeout, request_id (one
        X-Request-Id for every request the new client makes)."""
        unknown = set(changes) - set(self._options)
        if unknown:
            raise TypeError("with_options() takes timeout, step_timeout, request_id, not %s" % ", ".join(sorted(unknown)))
        if changes.get("request_id") is not None:
            _check_request_id(changes["request_id"])
        c = object.__new__(Client)
        c.__dict__.update(self.__dict__)
        c._options = dict(self._options, **changes)
        c._client = c
        c.recordings = Recordings(c)
        return c

    def next_request_id(self) -> str:
        """The X-Request-Id of the next request: events that carry it answer this client's own."""
        return "%s-%d" % (self._shared["prefix"], next(self._shared["seq"]))

    def is_own_request(self, request_id: object) -> bool:
        """Whether a request id (an event's ``request_id``) is one of this client's."""
        return isinstance(request_id, str) and request_id.startswith(self._shared["prefix"] + "-")

    # ---- daemon-wide routes ----
    def health(self) -> JsonObject:
        """GET /v1/health: ``{status, backend, device, version, stream: {port, path, protocol}}``
        (Unavailable, with this body in ``body``, when the backend has failed)."""
        return cast(JsonObject, self.request("GET", "/v1/health"))

    def livez(self) -> JsonObject:
        """GET /livez: ``{status: "live"}`` while the sim thread turns (Unavailable when it has
        stalled past ``liveness_timeout``)."""
        return cast(JsonObject, self.request("GET", "/livez"))

    def readyz(self) -> JsonObject:
        """GET /readyz: ``{status: "ready", scenes, max_scenes}`` (Unavailable while starting or
        stopping, or with no room for another scene)."""
        return cast(JsonObject, self.request("GET", "/readyz"))

    def metrics(self) -> str:
        """GET /metrics: the Prometheus text."""
        return cast(str, self.request("GET", "/metrics", as_="text"))

    def scene(self, scene_id: str) -> Scene:
        """A handle on scene ``scene_id``; ``default`` is the client's own routes."""
        return Scene(self, scene_id)

    def scenes(self) -> JsonObject:
        """GET /v1/scenes."""
        return cast(JsonObject, self.request("GET", "/v1/scenes"))

    def create_scene(self, id: Optional[str] = None, scene: Optional[Mapping[str, Any]] = None,
                     params: Optional[Mapping[str, Any]] = None) -> JsonObject:
        """POST /v1/scenes ``{id?, scene?, params?}``."""
        body: JsonObject = {}
        if id is not None:
            _check_scene_id(id)
            body["id"] = id
        if scene is not None:
            body["scene"] = scene
        if params is not None:
            body["params"] = params
        return cast(JsonObject, self.request("POST", "/v1/scenes", body))

    def delete_scene(self, scene_id: str) -> JsonObject:
        """DELETE /v1/scenes/{id}."""
        _check_scene_id(scene_id)
        return cast(JsonObject, self.request("DELETE", "/v1/scenes/" + scene_id))

    # ---- one request ----
    def request(self, method: str, path: str, body: Any = None, *, accept: Optional[str] = None, as_: str = "json",
                timeout: Any = _UNSET, request_id: Optional[str] = None,
                headers: Optional[Mapping[str, str]] = None) -> Any:
        """One request to ``path`` (e.g. /v1/sim). body: a dict or list (sent as JSON) or bytes.
        as_: "json" (the parsed answer, None when empty), "bytes" or "text". Raises a
        ClothdError for every refusal, a Timeout, a ConnectionFailed, or a ProtocolError for a
        success that is not JSON."""
        timeout = self._options["timeout"] if timeout is _UNSET else timeout
        request_id = request_id or self._options["request_id"] or self.next_request_id()
        _check_request_id(request_id)
        self._shared["last"] = request_id
        sent = {"X-Request-Id": request_id}
        if self.token:
            sent["Authorization"] = "Bearer " + self.token
        if accept:
            sent["Accept"] = accept
        payload: Optional[bytes] = None
        if isinstance(body, (bytes, bytearray, memoryview)):
            payload = bytes(body)
            sent["Content-Type"] = "application/octet-stream"
        elif body is not None:
            # NaN and infinities, which JSON lacks, go as Python writes them (NaN, Infinity): the
            # server answers 422 naming their field, as for any value out of range.
            payload = json.dumps(body).encode("utf-8")
            sent["Content-Type"] = "application/json"
        sent.update(headers or {})
        conn: http.client.HTTPConnection
        if self._scheme == "https":
            conn = http.client.HTTPSConnection(self._host, self._port, timeout=timeout)
        else:
            conn = http.client.HTTPConnection(self._host, self._port, timeout=timeout)
        where: Dict[str, Any] = dict(method=method, path=path, request_id=request_id)
        try:
            conn.request(method, self._base_path + path, body=payload, headers=sent)
            res = conn.getresponse()
            data = res.read()
        except (TimeoutError, socket.timeout) as e:  # one class from Python 3.10 on
            raise Timeout("%s %s: no answer within %s s" % (method, path, timeout), **where) from e
        except (OSError, http.client.HTTPException) as e:
            raise ConnectionFailed("%s %s: cannot reach clothd at %s (%s)" % (method, path, self.url, e), **where) from e
        finally:
            conn.close()
        if res.status >= 400:
            raise error_from_answer(res.status, res.getheader("Content-Type", ""), data,
                                    retry_after=res.getheader("Retry-After"), allow=res.getheader("Allow"), **where)
        if as_ == "bytes":
            return data
        if as_ == "text":
            return data.decode("utf-8")
        if not data:
            return None
        try:
            return json.loads(data)
        except ValueError as e:
            raise ProtocolError("%s %s: the answer (%d) is not JSON: %r" % (method, path, res.status, data[:80]),
                                status=res.status, body=data, **where) from e
