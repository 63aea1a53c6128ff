"""gaintune error types. Every user-facing failure names the field and the fix."""

from __future__ import annotations

from typing import Any

__all__ = ["GaintuneError", "SpecError", "GainError", "problem_details"]


class GaintuneError(Exception):
    """Base class for errors caused by user input (never by a bug)."""

    def __init__(self, field: str, message: str) -> None:
        super().__init__(f"{field}: {message}")
        self.field = field
        self.message = message

    def to_dict(self) -> dict[str, str]:
        """``{"loc": field, "msg": message}``, as an API error entry."""
        return {"loc": self.field, "msg": self.message}


class SpecError(GaintuneError):
    """The spec is invalid beyond what the pydantic schema alone can check."""


class GainError(GaintuneError):
    """Gains are NaN, out of range, the wrong count or unknown for the loop structure."""


def problem_details(exc: Exception) -> list[dict[str, Any]]:
    """Turn a pydantic ValidationError or GaintuneError into [{loc, msg}] entries."""
    from pydantic import ValidationError

    if isinstance(exc, ValidationError):
        out = []
        for err in exc.errors(include_url=False, include_input=False):
            loc = ".".join(str(p) for p in err["loc"])
            # a validator's ValueError reads "Value error, <our message>": the prefix is pydantic's, not news
            msg = err["msg"].removeprefix("Value error, ") if err["type"] == "value_error" else err["msg"]
            out.append({"loc": loc, "msg": msg})
        return out
    if isinstance(exc, GaintuneError):
        return [exc.to_dict()]
    return [{"loc": "", "msg": str(exc)}]
