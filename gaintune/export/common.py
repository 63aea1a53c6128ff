"""What every export module shares: :class:`ExportError`, the gains type, sample-time checks and text helpers.

The helpers with a leading underscore are private to :mod:`gaintune.export`: its
submodules import them from here.
"""

from __future__ import annotations

import math
import re
from typing import Any

from gaintune.errors import GaintuneError

__all__ = ["ExportError", "Gains"]

Gains = dict[str, dict[str, float]]


class ExportError(GaintuneError):
    """An export was asked for something it cannot produce."""


def _version() -> str:
    try:
        from importlib.metadata import version

        return version("gaintune")
    except Exception:  # pragma: no cover - not installed
        return "unknown"


def _same_dt(a: float, b: float) -> bool:
    return math.isclose(a, b, rel_tol=1e-9, abs_tol=0.0)


def _fmt_dt(dt: float) -> str:
    return format(float(dt), ".10g")


def _check_dt(dt: Any) -> float:
    try:
        dt = float(dt)
    except (TypeError, ValueError):
        raise ExportError("dt", f"sample time must be a number of seconds, got {dt!r}") from None
    if not (math.isfinite(dt) and dt > 0):
        raise ExportError("dt", f"sample time must be > 0 seconds, got {dt}")
    return dt


def _one_line(text: str) -> str:
    return " ".join(str(text).split())


def _ident(name: str) -> str:
    s = re.sub(r"[^0-9A-Za-z_]", "_", name)
    return s if s and not s[0].isdigit() else f"_{s}"
