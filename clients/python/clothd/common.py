"""What the HTTP client (clothd.client) and the streams (clothd.stream, clothd.aio) share, so that
the streams need nothing of clothd.client: a scene's id (DEFAULT_SCENE, SCENE_ID and its check),
and StreamClient, what a stream asks of the client it is given (clothd.client.Client is one).
"""

from __future__ import annotations

import re
from typing import Any, Dict, Optional, Protocol

DEFAULT_SCENE = "default"
#: Scene ids the server takes (checked here, before any request).
SCENE_ID = re.compile(r"[a-z0-9][a-z0-9_-]{0,62}\Z")


def check_scene_id(scene_id: object, what: str = "scene id") -> None:
    """Scene and recording ids are the same slug."""
    if not isinstance(scene_id, str) or not SCENE_ID.match(scene_id):
        raise ValueError("%s %r is not one clothd takes ([a-z0-9][a-z0-9_-]{0,62})" % (what, scene_id))


class SceneReads(Protocol):
    """The routes of a scene a stream reads (clothd.client.SceneRoutes)."""

    def sim(self) -> Dict[str, Any]:
        """GET /v1/sim of the scene."""
        ...


class StreamClient(Protocol):
    """What a stream asks of its client (clothd.client.Client): where the server is, its token,
    GET /v1/health, and a scene's routes."""

    @property
    def url(self) -> str:
        """The server's URL."""
        ...

    @property
    def token(self) -> Optional[str]:
        """The token requests carry, or None."""
        ...

    def health(self) -> Dict[str, Any]:
        """GET /v1/health."""
        ...

    def scene(self, scene_id: str) -> SceneReads:
        """The routes of the scene scene_id."""
        ...
