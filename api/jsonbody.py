"""Strict JSON request bodies: no NaN/Infinity literals, no overflowing numbers, bounded depth and array length.

Python's ``json`` accepts ``NaN``, ``Infinity`` and ``1e999`` (-> inf); JSON
does not. :class:`StrictJSONRoute` parses the body once with hooks that
reject them (400) and checks nesting depth and array length (422 with the
path), before FastAPI validates it against the pydantic model.
"""

from __future__ import annotations

import json
import math
from collections.abc import Callable
from typing import Any

from fastapi import Request, Response
from fastapi.routing import APIRoute

from gaintune_api.problem_details import ApiError

__all__ = ["StrictJSONRoute", "parse_strict", "parse_yaml", "body_kind", "check_shape"]


def _reject_constant(name: str) -> Any:
    raise ValueError(f"{name} is not valid JSON; numbers must be finite")


def _float(text: str) -> float:
    v = float(text)
    if not math.isfinite(v):
        raise ValueError(f"number {text[:40]} overflows a 64-bit float")
    return v


def parse_strict(body: bytes) -> Any:
    """Parse JSON, raising ApiError(400) for invalid or non-finite input."""
    try:
        return json.loads(body, parse_constant=_reject_constant, parse_float=_float)
    except RecursionError:
        raise ApiError(400, "The request body is nested too deeply.") from None
    except UnicodeDecodeError:
        raise ApiError(400, "The request body is not valid UTF-8.") from None
    except json.JSONDecodeError as exc:
        raise ApiError(400, f"The request body is not valid JSON: {exc.msg} at line {exc.lineno} "
                            f"column {exc.colno}.") from None
    except ValueError as exc:
        raise ApiError(400, f"The request body is not valid JSON: {str(exc)[:200]}.") from None


def check_shape(data: Any, max_depth: int, max_items: int) -> None:
    """Iteratively check nesting depth and array length; ApiError(422) naming the path."""
    stack: list[tuple[Any, tuple, int]] = [(data, (), 1)]
    while stack:
        node, path, depth = stack.pop()
        if isinstance(node, (dict, list)):
            if depth > max_depth:
                raise ApiError(422, f"JSON nested deeper than {max_depth} levels.",
                               errors=[{"loc": ".".join(map(str, path)), "msg": f"nesting exceeds {max_depth} levels"}])
            if isinstance(node, list):
                if len(node) > max_items:
                    raise ApiError(422, f"JSON array longer than {max_items} items.",
                                   errors=[{"loc": ".".join(map(str, path)),
                                            "msg": f"array has {len(node)} items; at most {max_items}"}])
                stack.extend((v, (*path, i), depth + 1) for i, v in enumerate(node) if isinstance(v, (dict, list)))
            else:
                stack.extend((v, (*path, k), depth + 1) for k, v in node.items() if isinstance(v, (dict, list)))


YAML_TYPES = ("application/yaml", "application/x-yaml", "text/yaml", "text/x-yaml")


def body_kind(content_type: str) -> str | None:
    """``"json"``, ``"yaml"`` or None (a type the API does not read) for a Content-Type header.

    A missing type is read as JSON, as FastAPI does; ``application/*+json`` is JSON.
    """
    media = content_type.split(";", 1)[0].strip().lower()
    if not media or media == "application/json" or (media.startswith("application/") and media.endswith("+json")):
        return "json"
    return "yaml" if media in YAML_TYPES else None


def parse_yaml(body: bytes) -> Any:
    """Parse a YAML body with the spec loader's own (bounded) parser; ApiError(400) when invalid."""
    from gaintune.spec import parse_json_or_yaml

    try:
        text = body.decode("utf-8")
    except UnicodeDecodeError:
        raise ApiError(400, "The request body is not valid UTF-8.") from None
    try:
        data = parse_json_or_yaml(text)
    except ValueError as exc:
        raise ApiError(400, f"The request body is not valid YAML: {str(exc)[:300]}") from None
    _reject_nonfinite(data)
    return data


def _reject_nonfinite(data: Any) -> None:
    """YAML's .nan and .inf are floats: refuse them as the JSON parser refuses NaN and Infinity."""
    stack = [data]
    while stack:
        node = stack.pop()
        if isinstance(node, float) and not math.isfinite(node):
            raise ApiError(400, "The request body holds a NaN or infinite number; numbers must be finite.")
        if isinstance(node, dict):
            stack.extend(node.values())
        elif isinstance(node, list):
            stack.extend(node)


def _declare_json(request: Request) -> None:
    """Tell FastAPI the (already parsed) body is JSON, so it validates ``request._json``."""
    headers = [(k, v) for k, v in request.scope["headers"] if k != b"content-type"]
    request.scope["headers"] = [*headers, (b"content-type", b"application/json")]
    request.__dict__.pop("_headers", None)


class StrictJSONRoute(APIRoute):
    """APIRoute that pre-checks JSON bodies (limits from ``app.state.settings``)."""

    def get_route_handler(self) -> Callable:
        """FastAPI's handler, after the body checks (size, depth, array lengths, content type)."""
        handler = super().get_route_handler()

        async def strict_handler(request: Request) -> Response:
            if request.method in ("POST", "PUT", "PATCH"):
                body = await request.body()
                kind = body_kind(request.headers.get("content-type", ""))
                if body and kind is not None:
                    data = parse_strict(body) if kind == "json" else parse_yaml(body)
                    s = request.app.state.settings
                    check_shape(data, s.max_json_depth, s.max_array_items)
                    request._json = data  # starlette caches the parsed body here; FastAPI reuses it
                    if kind == "yaml":
                        _declare_json(request)
                elif body:
                    raise ApiError(415, "Send the body as JSON with 'Content-Type: application/json' "
                                        "(a spec may also be sent as YAML with 'Content-Type: application/yaml').",
                                   errors=[{"loc": "header.content-type",
                                            "msg": "send application/json or application/yaml"}])
            return await handler(request)

        return strict_handler
