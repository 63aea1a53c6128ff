"""Plant coefficients as numbers: matrices and polynomials of numbers or parameter expressions.

Shared by the single-input plants (:mod:`gaintune.plants.plant`) and the MIMO plants
(:mod:`gaintune.plants.mimo`), so both read coefficients by one rule.
"""

from __future__ import annotations

import numpy as np

from gaintune.errors import SpecError
from gaintune.plants import expr
from gaintune.spec import Coef

__all__ = ["coef_matrix", "poly"]


def coef_matrix(rows: list[list[Coef]], p: dict[str, float], field: str) -> np.ndarray:
    """A matrix of numbers or parameter expressions as floats (SpecError naming ``field`` otherwise)."""
    if not rows or not all(isinstance(r, list) for r in rows):
        raise SpecError(field, "must be a non-empty list of rows")
    width = len(rows[0])
    if any(len(r) != width for r in rows):
        raise SpecError(field, "rows have different lengths")
    out = np.array([[expr.to_float(v, p, f"{field}[{i}][{j}]") for j, v in enumerate(r)] for i, r in enumerate(rows)])
    if not np.all(np.isfinite(out)):
        raise SpecError(field, "contains NaN or inf; give finite numbers")
    return out


def poly(value: list[Coef] | str, p: dict[str, float], field: str) -> np.ndarray:
    """Polynomial coefficients (descending powers of s) of a coefficient list or an expression in s."""
    if isinstance(value, str):
        coefs = expr.to_polynomial(value, p, field)
    else:
        coefs = np.array([expr.to_float(v, p, f"{field}[{i}]") for i, v in enumerate(value)], dtype=float)
    if not np.all(np.isfinite(coefs)):
        raise SpecError(field, "contains NaN or inf coefficients; give finite numbers")
    return coefs
