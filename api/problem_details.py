"""RFC 7807 problem responses and the exception handlers that produce them.

Every error body is ``application/problem+json``::

    {"type": "...", "title": "...", "status": 422, "detail": "...", "instance": "/v1/tune",
     "errors": [{"loc": "loops.0.type", "msg": "Input should be 'p', 'pi', ..."}]}

No handler ever returns a stack trace. Storage faults (a read-only or full job
database or data directory, see :mod:`gaintune_api.storage_faults`) are answered with 503, or
507 when full, with ``Retry-After`` and a ``cause`` member naming the fault
(e.g. ``"database-read-only"``), and logged as a warning without a traceback.
Unexpected exceptions are logged and answered with a generic 500 problem by
:class:`gaintune_api.middleware.CatchAll`, which keeps the keep-alive connection usable.
"""

from __future__ import annotations

import json
import logging
import math
import sqlite3
from typing import Any

from fastapi import FastAPI, Request
from fastapi.exceptions import RequestValidationError
from fastapi.responses import JSONResponse
from starlette.exceptions import HTTPException as StarletteHTTPException

from gaintune.errors import GaintuneError, problem_details
from gaintune_api.storage_faults import StorageFault, classify

__all__ = ["ApiError", "problem_response", "install_handlers", "SafeJSONResponse", "json_safe", "PROBLEM_TYPES",
           "storage_problem", "error_response"]

log = logging.getLogger("gaintune.api")

PROBLEM_BASE = "https://gaintune.dev/problems/"
PROBLEM_TYPES = {
    400: "malformed-request",
    401: "unauthorized",
    404: "not-found",
    405: "method-not-allowed",
    409: "conflict",
    410: "gone",
    413: "payload-too-large",
    415: "unsupported-media-type",
    422: "validation-error",
    429: "too-many-requests",
    500: "internal-error",
    501: "not-implemented",
    503: "unavailable",
    507: "insufficient-storage",
}
TITLES = {
    400: "Malformed request",
    401: "Missing or invalid API key",
    404: "Not found",
    405: "Method not allowed",
    409: "Conflict",
    410: "Gone",
    413: "Request body too large",
    415: "Unsupported media type",
    422: "Invalid input",
    429: "Too many requests",
    500: "Internal server error",
    501: "Not implemented",
    503: "Service unavailable",
    507: "Insufficient storage",
}


def json_safe(obj: Any) -> Any:
    """Replace non-finite floats by the strings "Infinity", "-Infinity", "NaN" (JSON has no such numbers)."""
    if isinstance(obj, float):
        if math.isfinite(obj):
            return obj
        return "NaN" if math.isnan(obj) else ("Infinity" if obj > 0 else "-Infinity")
    if isinstance(obj, dict):
        return {k: json_safe(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [json_safe(v) for v in obj]
    return obj


class SafeJSONResponse(JSONResponse):
    """JSONResponse that never fails on inf/NaN (encoded as strings, like the verification report)."""

    def render(self, content: Any) -> bytes:
        """``content`` as compact JSON, non-finite floats as strings."""
        try:
            return json.dumps(content, ensure_ascii=False, allow_nan=False, separators=(",", ":")).encode()
        except ValueError:
            return json.dumps(json_safe(content), ensure_ascii=False, allow_nan=False, separators=(",", ":")).encode()


class ApiError(Exception):
    """An error with a status, a detail and optional per-field errors."""

    def __init__(self, status: int, detail: str, errors: list[dict[str, Any]] | None = None,
                 headers: dict[str, str] | None = None, title: str | None = None,
                 extra: dict[str, Any] | None = None) -> None:
        super().__init__(detail)
        self.status = status
        self.detail = detail
        self.errors = errors
        self.headers = headers
        self.title = title
        self.extra = extra


def problem_response(status: int, detail: str, *, instance: str = "", errors: list[dict[str, Any]] | None = None,
                     headers: dict[str, str] | None = None, title: str | None = None,
                     extra: dict[str, Any] | None = None, type_: str | None = None) -> JSONResponse:
    """An ``application/problem+json`` response (``extra``: extension members such as ``cause``)."""
    body: dict[str, Any] = {
        "type": PROBLEM_BASE + (type_ or PROBLEM_TYPES.get(status, "error")),
        "title": title or TITLES.get(status, "Error"),
        "status": status,
        "detail": detail,
    }
    if instance:
        body["instance"] = instance
    if errors is not None:
        body["errors"] = errors
    if extra:
        body.update(extra)
    return SafeJSONResponse(body, status_code=status, headers=headers, media_type="application/problem+json")


def storage_problem(fault: StorageFault, *, instance: str = "", retry_after: int = 30) -> JSONResponse:
    """503 (507 when full) naming the store and the cause, with Retry-After: "try later", not "bug"."""
    log.warning("storage fault on %s: %s", instance or "?", fault)
    return problem_response(
        fault.status, f"{fault.detail} Retry later; an operator must free or remount the storage.", instance=instance,
        headers={"Retry-After": str(retry_after)}, title="Storage unavailable", type_="storage-fault",
        extra={"cause": fault.cause},
    )


def error_response(exc: BaseException, *, method: str, path: str, retry_after: int = 30) -> JSONResponse:
    """The problem for an exception no route handled: a named storage fault, else a logged generic 500."""
    fault = classify(exc)
    if fault is not None:
        return storage_problem(fault, instance=path, retry_after=retry_after)
    log.error("unhandled error on %s %s", method, path, exc_info=exc)
    return problem_response(500, "An internal error occurred; it has been logged.", instance=path)


def _retry_after(request: Request) -> int:
    settings = getattr(request.app.state, "settings", None)
    return int(getattr(settings, "retry_after", 30))


def _loc(parts: tuple | list) -> str:
    parts = list(parts)
    if parts and parts[0] in ("body", "query", "path", "header"):
        kind = parts.pop(0)
        if kind != "body":
            parts.insert(0, kind)
    return ".".join(str(p) for p in parts)


def validation_errors(exc: RequestValidationError) -> list[dict[str, Any]]:
    """``[{loc, msg}]``; errors in a spec (the body, or its ``spec`` member) name the fix (gaintune.spec.hints)."""
    from gaintune.spec.hints import explain

    groups: dict[tuple, list[dict[str, Any]]] = {}
    out = []
    for err in exc.errors():
        loc = tuple(err.get("loc", ()))
        if loc[:1] != ("body",):
            out.append({"loc": _loc(loc), "msg": str(err.get("msg", "invalid"))[:1000]})
            continue
        prefix = ("spec",) if loc[1:2] == ("spec",) else ()
        groups.setdefault(prefix, []).append({**err, "loc": loc[1 + len(prefix):]})
    for prefix, errs in groups.items():
        for e in explain(errs):
            dotted = ".".join([*prefix, e["loc"]] if e["loc"] else prefix)
            out.append({"loc": dotted, "msg": e["msg"][:1000]})
    return out


def install_handlers(app: FastAPI) -> None:
    """Answer every error of ``app`` as problem details: invalid requests, ApiError, GaintuneError, HTTP errors
    and storage faults (named, 503/507; anything else a logged 500)."""

    @app.exception_handler(RequestValidationError)
    async def _validation(request: Request, exc: RequestValidationError):
        errors = validation_errors(exc)
        if any(e["msg"].startswith("JSON decode error") for e in errors):
            return problem_response(400, "The request body is not valid JSON.", instance=request.url.path,
                                    errors=errors)
        return problem_response(422, f"{len(errors)} invalid field(s)", instance=request.url.path, errors=errors)

    @app.exception_handler(ApiError)
    async def _api_error(request: Request, exc: ApiError):
        return problem_response(exc.status, exc.detail, instance=request.url.path, errors=exc.errors,
                                headers=exc.headers, title=exc.title, extra=exc.extra)

    @app.exception_handler(GaintuneError)
    async def _gaintune(request: Request, exc: GaintuneError):
        return problem_response(422, "The spec or gains are invalid.", instance=request.url.path,
                                errors=problem_details(exc))

    @app.exception_handler(StarletteHTTPException)
    async def _http(request: Request, exc: StarletteHTTPException):
        detail = exc.detail if isinstance(exc.detail, str) else TITLES.get(exc.status_code, "Error")
        return problem_response(exc.status_code, detail, instance=request.url.path,
                                headers=getattr(exc, "headers", None))

    # Storage errors may surface from any route as the raw exception; classify names them (or logs a 500).
    @app.exception_handler(StorageFault)
    @app.exception_handler(sqlite3.Error)
    @app.exception_handler(OSError)
    async def _storage(request: Request, exc: Exception):
        return error_response(exc, method=request.method, path=request.url.path, retry_after=_retry_after(request))

    # No ``Exception`` handler here: Starlette re-raises after calling it, and uvicorn then drops the
    # keep-alive connection without ``Connection: close``. gaintune_api.middleware.CatchAll answers those instead.
