"""Strict JSON request bodies: no NaN/Infinity literals, no overflowing numbers, bounded depth and array length.

Python's ``json`` accepts ``NaN``, ``Infinity`` and ``1e999`` (-> inf); JSON
does not. :class:`StrictJSONRoute` parses the body once with hooks that
reject them (400) and checks nesting depth and array length (422 with the
path), before FastAPI validates it against the pydantic model.
"""

from __future__ import annotations

import json
import math
from typing import Any, Callable

from fastapi import Request, Response
from fastapi.routing import APIRoute

from gaintune_api.problems import ApiError

__all__ = ["StrictJSONRoute", "parse_strict", "check_shape"]


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
        raise ApiError(400, f"The request body is not valid JSON: {exc.msg} at line {exc.lineno} column {exc.colno}.") from None
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
                                   errors=[{"loc": ".".join(map(str, path)), "msg": f"array has {len(node)} items; at most {max_items}"}])
                stack.extend((v, (*path, i), depth + 1) for i, v in enumerate(node) if isinstance(v, (dict, list)))
            else:
                stack.extend((v, (*path, k), depth + 1) for k, v in node.items() if isinstance(v, (dict, list)))


class StrictJSONRoute(APIRoute):
    """APIRoute that pre-checks JSON bodies (limits from ``app.state.settings``)."""

    def get_route_handler(self) -> Callable:
        handler = super().get_route_handler()

        async def strict_handler(request: Request) -> Response:
            if request.method in ("POST", "PUT", "PATCH"):
                body = await request.body()
                ctype = request.headers.get("content-type", "")
                if body and (not ctype or "json" in ctype):
                    data = parse_strict(body)
                    s = request.app.state.settings
                    check_shape(data, s.max_json_depth, s.max_array_items)
                    request._json = data  # starlette caches the parsed body here; FastAPI reuses it
            return await handler(request)

        return strict_handler
