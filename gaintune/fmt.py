"""One number formatter for tables (CLI, report, benchmark Markdown)."""

from __future__ import annotations

import math
import numbers
from typing import Any

__all__ = ["fmt"]


def fmt(x: Any, digits: int = 4) -> str:
    """Compact table cell: None/NaN -> '-', bools -> yes/no, +-inf -> 'inf'/'-inf', floats to ``digits`` significant
    figures."""
    if x is None:
        return "-"
    if isinstance(x, bool):
        return "yes" if x else "no"
    if isinstance(x, str):
        return x
    if isinstance(x, numbers.Integral):  # numpy integers register here: no numpy import for --help
        return str(int(x))
    if isinstance(x, numbers.Real):
        x = float(x)
        if math.isnan(x):
            return "-"
        if math.isinf(x):
            return "inf" if x > 0 else "-inf"
        return f"{x:.{digits}g}"
    return str(x)
