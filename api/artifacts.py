"""Optional features provided by other gaintune modules, imported lazily: HTML report and gain exports.

Missing modules give 501 problems rather than import errors at start-up.
"""

from __future__ import annotations

import importlib
import inspect
from pathlib import Path
from typing import Any

from api.problems import ApiError

__all__ = ["render_report", "export_gains", "EXPORT_MEDIA"]

EXPORT_MEDIA = {
    "json": ("application/json", "json"),
    "yaml": ("application/yaml", "yaml"),
    "c": ("text/x-c", "h"),
    "matlab": ("text/x-matlab", "m"),
}


def _module(name: str, feature: str):
    try:
        return importlib.import_module(name)
    except ImportError as exc:
        raise ApiError(501, f"{feature} is not available in this installation ({name}: {exc}).") from None


def render_report(result: Any, path: Path) -> Path:
    mod = _module("gaintune.report", "The HTML report")
    fn = getattr(mod, "render_report", None)
    if fn is None:
        raise ApiError(501, "The HTML report is not available in this installation (gaintune.report.render_report missing).")
    out = fn(result, path)
    return Path(out) if isinstance(out, (str, Path)) else path


def export_gains(result: Any, fmt: str) -> str | bytes:
    """Text of ``result``'s gains in ``fmt`` via :mod:`gaintune.export`."""
    mod = _module("gaintune.export", "Gain export")
    for name in ("export_result", "export_gains", "export", "render", "dumps", "to_format"):
        fn = getattr(mod, name, None)
        if callable(fn) and not inspect.isclass(fn):
            return fn(result, fmt)
    per_format = getattr(mod, f"to_{fmt}", None)
    if callable(per_format):
        return per_format(result)
    raise ApiError(501, "Gain export is not available in this installation (no export function in gaintune.export).")
