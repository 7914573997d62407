"""What the clothd client raises.

Every answer that is not a success becomes one of these: an HTTP status of 400 or more (its
``application/problem+json`` body, RFC 9457, read into the exception), no answer in time, no
connection, or an answer that breaks the protocol. A server error is never returned as a value.

::

    ClothdError
    +- ClientError (4xx): BadRequest 400, Unauthorized 401, Forbidden 403, NotFound 404,
    |    MethodNotAllowed 405, Conflict 409, PayloadTooLarge 413, UriTooLong 414,
    |    Unprocessable 422, RateLimited 429
    +- ServerError (5xx): Unavailable 503, Busy 503 ``busy``
    +- Timeout (also a TimeoutError), ConnectionFailed (also a ConnectionError)
    +- ProtocolError: an answer or a stream message that breaks the protocol
    |    +- FrameError (also a ValueError): a binary frame that does not decode
    |    +- RecordingError (also a ValueError): a file that is not a recording, or a corrupt one
    |    +- StreamRefused: the stream answered a client message with an ``error`` message
    +- MissingDependency (also an ImportError): an optional package or library is not there
"""

from __future__ import annotations

import json
from typing import Any, Dict, List, Optional, Type

PROBLEM_PREFIX = "urn:clothd:problem:"


class ClothdError(Exception):
    """The base of every error the client raises.

    Attributes (None where they do not apply):
      status: the HTTP status; type: the problem's type URI; slug: its last part
      (``out-of-range``, ``unstable``, ``busy``, ... as in PROTOCOL.md); title; detail: the
      server's explanation (also ``str(error)``); param: the parameter or field to blame;
      problem: the problem+json body; body: a refused answer's body when it is not a problem (a
      503 health answer, libmicrohttpd's HTML); request_id: the request's X-Request-Id;
      retry_after: seconds to wait (Retry-After, for 429 and 503); allow: the path's methods
      (405); method and path: the request.
    """

    def __init__(self, message: str, *, status: Optional[int] = None, problem: Optional[Dict[str, Any]] = None,
                 body: Any = None, request_id: Optional[str] = None, retry_after: Optional[int] = None,
                 allow: Optional[List[str]] = None, method: Optional[str] = None, path: Optional[str] = None) -> None:
        super().__init__(message)
        self.status = status
        self.problem = problem
        self.body = body
        p = problem if isinstance(problem, dict) else {}
        t = p.get("type")
        self.type: Optional[str] = t if isinstance(t, str) else None
        self.slug: Optional[str] = (self.type[len(PROBLEM_PREFIX):]
                                    if self.type and self.type.startswith(PROBLEM_PREFIX) else None)
        self.title: Optional[str] = p.get("title") if isinstance(p.get("title"), str) else None
        self.detail: Optional[str] = p.get("detail") if isinstance(p.get("detail"), str) else None
        self.param: Optional[str] = p.get("param") if isinstance(p.get("param"), str) else None
        self.request_id = request_id
        self.retry_after = retry_after
        self.allow = allow
        self.method = method
        self.path = path

    def __repr__(self) -> str:
        return "%s(status=%r, slug=%r, param=%r, detail=%r)" % (
            type(self).__name__, self.status, self.slug, self.param, str(self))


class ClientError(ClothdError):
    """A 4xx answer: the request is at fault."""


class BadRequest(ClientError):
    """400: malformed JSON, a wrong type (but a parameter's), an unknown field, a refused snapshot."""


class Unauthorized(ClientError):
    """401: a token is needed, or the one given is not this server's."""


class Forbidden(ClientError):
    """403: the view token on a change, a Host not allowed, a cross-site request."""


class NotFound(ClientError):
    """404: an unknown route, rock or scene."""


class MethodNotAllowed(ClientError):
    """405: the path has other methods (``allow``)."""


class Conflict(ClientError):
    """409: the wrong state (a step while running)."""


class PayloadTooLarge(ClientError):
    """413: a body larger than ``max_body``."""


class UriTooLong(ClientError):
    """414: a request target of 2048 bytes or more."""


class Unprocessable(ClientError):
    """422: a value out of range, a parameter's of a wrong type, a change the stability guard refuses, a limit reached."""


class RateLimited(ClientError):
    """429: too many changing requests; ``retry_after`` says how long to wait."""


class ServerError(ClothdError):
    """A 5xx answer."""


class Unavailable(ServerError):
    """503: the backend failed or the daemon is shutting down."""


class Busy(ServerError):
    """503 ``busy``: the command queue is full; ``retry_after`` (1 s) says when to ask again."""


class Timeout(ClothdError, TimeoutError):
    """No answer within the timeout."""


class ConnectionFailed(ClothdError, ConnectionError):
    """No connection to clothd (refused, reset, a name that does not resolve)."""


class ProtocolError(ClothdError):
    """An answer or a stream message that does not fit the protocol."""


class FrameError(ProtocolError, ValueError):
    """A binary frame that does not decode."""


class RecordingError(ProtocolError, ValueError):
    """A file that is not a recording, or a corrupt one; ``offset`` is where it went wrong."""

    def __init__(self, text: str, offset: Optional[int] = None) -> None:
        super().__init__(text if offset is None else "%s (at byte %d)" % (text, offset))
        self.offset = offset
        #: The frame it was found in (a salvaging read keeps the frames before it), or None.
        self.frame: Optional[int] = None


class StreamRefused(ProtocolError):
    """The stream answered a client message with an ``error`` message (kept in ``message``)."""

    def __init__(self, text: str, message: Dict[str, Any]) -> None:
        super().__init__(text, status=message.get("status"), body=message)
        self.message = message
        self.about = message.get("about")
        self.param = message.get("param")
        self.detail = message.get("detail")


class MissingDependency(ClothdError, ImportError):
    """An optional package or library is not there (the message names it and how to get it)."""


#: The class of each status; any other falls back to ClientError or ServerError.
STATUS_ERRORS: Dict[int, Type[ClothdError]] = {
    400: BadRequest, 401: Unauthorized, 403: Forbidden, 404: NotFound, 405: MethodNotAllowed,
    409: Conflict, 413: PayloadTooLarge, 414: UriTooLong, 422: Unprocessable, 429: RateLimited,
    503: Unavailable,
}


def error_class(status: int, slug: Optional[str] = None) -> Type[ClothdError]:
    """The exception class for an HTTP status and problem type slug (503 ``busy`` is Busy)."""
    if status == 503 and slug == "busy":
        return Busy
    return STATUS_ERRORS.get(status, ServerError if status >= 500 else ClientError)


def error_from_answer(status: int, content_type: Optional[str], data: Any, *, method: str, path: str,
                      request_id: Optional[str] = None, retry_after: Optional[str] = None,
                      allow: Optional[str] = None) -> ClothdError:
    """The exception for a refused answer (status >= 400) and its raw body."""
    text = data.decode("utf-8", "replace") if isinstance(data, (bytes, bytearray)) else (data or "")
    try:
        parsed = json.loads(text)
    except ValueError:
        parsed = None
    is_problem = "problem+json" in (content_type or "") and isinstance(parsed, dict)
    problem = parsed if is_problem else None
    body = None if is_problem else (parsed if parsed is not None else (text or None))
    t = problem.get("type") if problem else None
    slug = t[len(PROBLEM_PREFIX):] if isinstance(t, str) and t.startswith(PROBLEM_PREFIX) else None
    cls = error_class(status, slug)
    why = None
    if problem:
        why = problem.get("detail") or problem.get("title")
    if not isinstance(why, str) or not why:
        why = text[:200] if isinstance(body, str) and text.strip() else "%s %s: HTTP %d" % (method, path, status)
    seconds = None
    if retry_after is not None and retry_after.strip().isdigit():
        seconds = int(retry_after.strip())
    methods = [m.strip() for m in allow.split(",") if m.strip()] if allow else None
    return cls(why, status=status, problem=problem, body=body, request_id=request_id,
               retry_after=seconds, allow=methods, method=method, path=path)
