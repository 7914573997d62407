"""clothd: a Python client of the clothd simulation service.

    import clothd
    c = clothd.Client("http://127.0.0.1:8080")
    c.pause()
    c.add_rock([0, 0, 2], 0.1, density=300)
    c.step(frames=120)
    sag = c.cloth_state_binary().positions[:, 2].min()

The HTTP API through the standard library (clothd.client), the stream through websocket-client
where it is installed (clothd.stream; in asyncio through websockets, clothd.aio), the binary frames (clothd.frames; numpy arrays where
numpy is there, lists otherwise), recordings (clothd.recording), and the exceptions every refusal becomes (clothd.errors).
See clients/python/README.md.
"""

from .client import DEFAULT_URL, Client, ClothState, Recordings, Scene, SceneRoutes
from .common import DEFAULT_SCENE, SCENE_ID
from .errors import (BadRequest, Busy, ClientError, ClothdError, Conflict, ConnectionFailed, Forbidden,
                     FrameError, MethodNotAllowed, MissingDependency, NotFound, PayloadTooLarge, ProtocolError, RecordingError,
                     RateLimited, ServerError, StreamRefused, Timeout, Unauthorized, Unavailable, Unprocessable,
                     UriTooLong, error_class, error_from_answer)
from .frames import Frame, FrameDecoder, Rock, decode_frame, meshopt_available, numpy_available
from .recording import Recording, read_recording
from .stream import Stream, websocket_available
from .aio import AsyncStream, websockets_available

__version__ = "0.1.0"

__all__ = [
    "Client", "Scene", "SceneRoutes", "Recordings", "ClothState", "Stream", "AsyncStream", "websockets_available", "Frame", "FrameDecoder", "Rock",
    "decode_frame", "read_recording", "Recording", "RecordingError", "numpy_available", "meshopt_available", "websocket_available", "error_class",
    "error_from_answer", "DEFAULT_URL", "DEFAULT_SCENE", "SCENE_ID",
    "ClothdError", "ClientError", "BadRequest", "Unauthorized", "Forbidden", "NotFound", "MethodNotAllowed",
    "Conflict", "PayloadTooLarge", "UriTooLong", "Unprocessable", "RateLimited", "ServerError", "Unavailable",
    "Busy", "Timeout", "ConnectionFailed", "ProtocolError", "FrameError", "StreamRefused", "MissingDependency",
]
