"""Pure-ASGI middleware: last-resort errors (500/503 on a usable connection), API key on the docs,
request body size limit (413) and request latency metrics."""

from __future__ import annotations

import hmac
import time

from starlette.exceptions import HTTPException
from starlette.types import ASGIApp, Message, Receive, Scope, Send

from gaintune_api.metrics import Metrics
from gaintune_api.problem_details import error_response, problem_response

__all__ = ["BodySizeLimit", "LatencyMetrics", "CatchAll", "DocsAuth"]


class _TrackedSend:
    """An ASGI ``send`` that records whether the response has started (after that no other response can be sent)."""

    def __init__(self, send: Send) -> None:
        self.send = send
        self.started = False

    async def __call__(self, msg: Message) -> None:
        if msg["type"] == "http.response.start":
            self.started = True
        await self.send(msg)


class CatchAll:
    """Answer any exception no handler took with a problem response, and swallow it.

    Starlette's own last-resort handler re-raises after answering, and uvicorn then closes
    the keep-alive connection without ``Connection: close``: the client's next request on
    it fails. Here the 500 (or the named 503/507 of a storage fault) completes normally, so
    the connection stays usable. If the response had already started, nothing valid can be
    sent: the exception is re-raised and uvicorn closes the connection (the client sees a
    truncated response, not a silent success).

    Parameters
    ----------
    app
        The ASGI app.
    retry_after
        Seconds for ``Retry-After`` on storage faults.
    """

    def __init__(self, app: ASGIApp, retry_after: int = 30) -> None:
        self.app = app
        self.retry_after = retry_after

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        if scope["type"] != "http":
            await self.app(scope, receive, send)
            return
        tracked = _TrackedSend(send)
        try:
            await self.app(scope, receive, tracked)
        except Exception as exc:  # noqa: BLE001 - the last resort
            if tracked.started:
                raise
            resp = error_response(exc, method=scope.get("method", "?"), path=scope.get("path", ""),
                                  retry_after=self.retry_after)
            await resp(scope, receive, send)


class DocsAuth:
    """Require a valid ``X-API-Key`` for the OpenAPI document and the docs pages (``Settings.docs_public`` off).

    Parameters
    ----------
    app
        The ASGI app.
    paths
        The documentation paths (``/openapi.json``, ``/docs``, ``/docs/oauth2-redirect``, ``/redoc``).
    keys
        Accepted keys (compared in constant time).
    """

    def __init__(self, app: ASGIApp, paths: set[str], keys: list[str]) -> None:
        self.app = app
        self.paths = paths
        self.keys = [k.encode() for k in keys]

    def _ok(self, scope: Scope) -> bool:
        for name, value in scope.get("headers", ()):
            if name == b"x-api-key":
                return any(hmac.compare_digest(k, value) for k in self.keys)
        return False

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        if scope["type"] == "http" and scope.get("path") in self.paths and not self._ok(scope):
            resp = problem_response(401, "Send a valid API key in the X-API-Key header (the docs are not public: "
                                    "GAINTUNE_DOCS_PUBLIC=false).", instance=scope.get("path", ""),
                                    headers={"WWW-Authenticate": "ApiKey"})
            await resp(scope, receive, send)
            return
        await self.app(scope, receive, send)


class _TooLarge(HTTPException):
    """Raised from ``receive`` when a streamed body passes the limit (an HTTPException: FastAPI passes it through)."""

    def __init__(self, max_bytes: int) -> None:
        super().__init__(413, f"Request bodies are limited to {max_bytes} bytes.")


class BodySizeLimit:
    """Reject bodies over ``max_bytes``: by Content-Length up front, or while a streamed body arrives."""

    def __init__(self, app: ASGIApp, max_bytes: int) -> None:
        self.app = app
        self.max_bytes = max_bytes

    async def _reject(self, scope: Scope, receive: Receive, send: Send) -> None:
        resp = problem_response(413, f"Request bodies are limited to {self.max_bytes} bytes.",
                                instance=scope.get("path", ""))
        await resp(scope, receive, send)

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        if scope["type"] != "http":
            await self.app(scope, receive, send)
            return
        for name, value in scope.get("headers", ()):
            if name == b"content-length":
                try:
                    n = int(value)
                except ValueError:
                    n = -1
                if n < 0 or n > self.max_bytes:
                    if n < 0:
                        resp = problem_response(400, "Invalid Content-Length header.", instance=scope.get("path", ""))
                        await resp(scope, receive, send)
                    else:
                        await self._reject(scope, receive, send)
                    return
        received = 0

        async def limited_receive() -> Message:
            nonlocal received
            msg = await receive()
            if msg["type"] == "http.request":
                received += len(msg.get("body", b""))
                if received > self.max_bytes:
                    raise _TooLarge(self.max_bytes)
            return msg

        tracked = _TrackedSend(send)
        try:
            await self.app(scope, limited_receive, tracked)
        except _TooLarge:
            if not tracked.started:
                await self._reject(scope, receive, send)


class LatencyMetrics:
    """Observe request latency per method, route template and status code."""

    def __init__(self, app: ASGIApp, metrics: Metrics) -> None:
        self.app = app
        self.metrics = metrics

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        if scope["type"] != "http":
            await self.app(scope, receive, send)
            return
        t0 = time.perf_counter()
        status = 500

        async def tracking_send(msg: Message) -> None:
            nonlocal status
            if msg["type"] == "http.response.start":
                status = msg["status"]
            await send(msg)

        try:
            await self.app(scope, receive, tracking_send)
        finally:
            route = scope.get("route")
            path = getattr(route, "path", None) or "unmatched"
            self.metrics.observe(scope.get("method", "GET"), path, status, time.perf_counter() - t0)
