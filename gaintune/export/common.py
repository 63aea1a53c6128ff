"""What every export module shares: :class:`ExportError`, the gains type, sample-time checks and text helpers.

The helpers with a leading underscore are private to :mod:`gaintune.export`: its
submodules import them from here.
"""

from __future__ import annotations

import math
from typing import Any

from gaintune.errors import GaintuneError
from gaintune.spec import Gains, TuningSpec
from gaintune.spec.names import ident as _ident
from gaintune.spec.names import unsafe_char

__all__ = ["ExportError", "Gains", "is_mimo"]



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
    """``text`` on one line: runs of whitespace (newlines too) become one space, other control characters ``?``.

    Free text (names, verdict reasons) written into a comment of a generated file goes through
    this, so it cannot start a line of code there, even when the spec predates the name rules
    of :mod:`gaintune.spec.names`.
    """
    flat = " ".join(str(text).split())
    return "".join("?" if unsafe_char(ch) is not None else ch for ch in flat)


def _unique_idents(names: list[str], style: str) -> None:
    """ExportError when two loop names give one identifier (``style``: "c" upper-cases, "matlab" keeps case).

    Validation rejects such specs (loops[i].name); this guards specs built without it.
    """
    seen: dict[str, str] = {}
    for i, name in enumerate(names):
        key = _ident(name).upper() if style == "c" else _ident(name)
        if key in seen:
            raise ExportError(f"loops.{i}.name", f"loop name {name!r} and {seen[key]!r} both become the identifier "
                                                 f"{key}; rename one so they differ after non-alphanumerics become _")
        seen[key] = name


def is_mimo(spec: TuningSpec) -> bool:
    """Whether ``spec`` runs on the MIMO simulator (several plant inputs, a loop graph, actuators or a decoupler)."""
    from gaintune.plants import build_plant
    from gaintune.sim.simulator import needs_mimo

    if spec.plant.tf_matrix is not None or spec.actuators is not None or spec.decoupler is not None:
        return True
    if any(lp.drives is not None for lp in spec.loops):
        return True
    return needs_mimo(spec, build_plant(spec.plant))
