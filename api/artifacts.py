"""Optional features provided by other gaintune modules, imported lazily: HTML report and gain exports.

Missing modules give 501 problems rather than import errors at start-up.
"""

from __future__ import annotations

import importlib
from pathlib import Path
from typing import Any

from gaintune_api.problem_details import ApiError

__all__ = ["render_report", "render_report_html", "export_gains", "export_verdict", "EXPORT_MEDIA"]

EXPORT_MEDIA = {
    "json": ("application/json", "json"),
    "yaml": ("application/yaml", "yaml"),
    "c": ("text/x-c", "h"),
    "matlab": ("text/x-matlab", "m"),
    "python": ("text/x-python", "py"),
}


def _module(name: str, feature: str):
    try:
        return importlib.import_module(name)
    except ImportError as exc:
        raise ApiError(501, f"{feature} is not available in this installation ({name}: {exc}).") from None


def render_report(result: Any, path: Path) -> Path:
    """Render ``result``'s HTML report to ``path`` with :mod:`gaintune.report` (501 when not installed)."""
    mod = _module("gaintune.report", "The HTML report")
    fn = getattr(mod, "render_report", None)
    if fn is None:
        raise ApiError(501, "The HTML report is not available in this installation "
                            "(gaintune.report.render_report missing).")
    out = fn(result, path)
    return Path(out) if isinstance(out, (str, Path)) else path


def render_report_html(result: Any) -> str | None:
    """The HTML report as text, written nowhere (None when this installation cannot render it in memory).

    Used when the data directory cannot cache the report (read-only or full disk): the report is still served.
    """
    mod = _module("gaintune.report", "The HTML report")
    fn = getattr(mod, "render_html", None)
    return fn(result) if callable(fn) else None


def export_verdict(result: Any, dt: float | None, max_steps: int | None = None) -> tuple[str | None, Any]:
    """``(verdict, report)`` of ``result``'s gains at sample time ``dt`` (re-verified unless it is the
    verified one), via :func:`gaintune.export.result_verdict_at_dt`. Raises its ``ExportError`` for a bad ``dt``."""
    mod = _module("gaintune.export", "Gain export")
    fn = getattr(mod, "result_verdict_at_dt", None)
    if fn is None:
        raise ApiError(501, "Gain export is not available in this installation "
                            "(gaintune.export.result_verdict_at_dt missing).")
    return fn(result, dt, max_steps=max_steps)


def export_gains(result: Any, fmt: str, dt: float | None = None,
                 checked: tuple[str | None, Any] | None = None) -> str | bytes:
    """Text of ``result``'s gains in ``fmt`` at sample time ``dt`` via :mod:`gaintune.export`.

    ``checked``: the ``(verdict, report)`` of :func:`export_verdict` for the same ``dt``.
    """
    mod = _module("gaintune.export", "Gain export")
    fn = getattr(mod, "export_result", None)
    if callable(fn):
        return fn(result, fmt, dt=dt, checked=checked)
    raise ApiError(501, "Gain export is not available in this installation (gaintune.export.export_result missing).")
