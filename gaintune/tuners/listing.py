"""What ``gaintune tuner list`` and ``GET /v1/tuners`` show of a tuner folder, read without torch.

:func:`summary` reads a tuner folder (:func:`gaintune.tuners.artefact.load`: the format, version
and policy hash are checked) and returns plain JSON-ready data: the family and controller, the
Ms limit, the context ranges (for a family tuner the dimensionless shape as the ratio users know,
e.g. ``L/T`` for FOTD), the held-out validation figures, the training record and the folder's
size. :func:`shipped` does it for every ready-made tuner (:data:`gaintune.tuners.artefact.SHIPPED_DIR`).
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

from gaintune.tuners import artefact
from gaintune.tuners.problems import FamilyProblem, SpecProblem, TunerProblem

__all__ = ["folder_bytes", "context_ranges", "summary", "shipped"]

#: How a family's shape variable reads as a ratio of its physical parameters.
_RATIO_NAMES = {("fotd", "tau"): "L/T", ("ipd", "tau"): "L/T", ("sotd", "tau"): "L/(T1+T2)",
                ("sotd", "r"): "min(T1,T2)/max(T1,T2)"}


def _num(x: Any) -> float | None:
    """``x`` as a float, None when missing or not finite (JSON has no infinity)."""
    if isinstance(x, bool) or not isinstance(x, (int, float)) or not math.isfinite(x):
        return None
    return float(x)


def folder_bytes(folder: str | Path) -> int:
    """Total size of the regular files in ``folder`` (not following links)."""
    return sum(p.stat().st_size for p in Path(folder).rglob("*") if p.is_file() and not p.is_symlink())


def context_ranges(problem: TunerProblem) -> list[dict[str, Any]]:
    """The training range of each context variable, ``[{"name", "lo", "hi", "variable"}]``.

    For a family tuner ``tau = L/(L+T)`` reads as ``L/T = tau/(1 - tau)``; ``variable`` keeps the
    context variable's own name.
    """
    out = []
    for v in problem.variables:
        lo, hi, name = v.lo, v.hi, v.name
        if isinstance(problem, FamilyProblem):
            name = _RATIO_NAMES.get((problem.family.name, v.name), v.name)
            if v.name == "tau":
                lo, hi = lo / (1.0 - lo), hi / (1.0 - hi)
        out.append({"name": name, "lo": lo, "hi": hi, "variable": v.name})
    return out


def _problem_fields(problem: TunerProblem) -> dict[str, Any]:
    """Family, model, controller, Ms limit and the parameters a query gives."""
    if isinstance(problem, FamilyProblem):
        fam = problem.family
        return {"kind": "family", "family": fam.name, "model": fam.title, "controller": problem.ctype,
                "ms_max": problem.ms_max, "params": list(fam.params)}
    assert isinstance(problem, SpecProblem)
    spec = problem.spec
    return {"kind": "spec", "family": "spec", "model": spec.name, "controller": ",".join(lp.type for lp in spec.loops),
            "ms_max": _num(spec.requirements.ms_max), "params": [v.name for v in problem.variables]}


def summary(folder: str | Path, name: str | None = None) -> dict[str, Any]:
    """The tuner at ``folder`` as JSON-ready data (SpecError naming ``tuner``/``version`` when it is no tuner)."""
    folder = Path(folder)
    art = artefact.load(folder)
    val, tr = art.validation, art.training
    return {
        "name": name or art.name,
        **_problem_fields(art.problem),
        "context": context_ranges(art.problem),
        "validation": {"n": int(val.get("n") or 0), "median_ratio": _num(val.get("median_ratio")),
                       "worst_ratio": _num(val.get("worst_ratio")), "passed": int(val.get("passed") or 0)},
        "training": {"episodes": int(tr.get("episodes") or 0), "sims": int(tr.get("sims") or 0),
                     "wall_s": _num(tr.get("wall_s")), "resumed": int(tr.get("resumed") or 0)},
        "size_kb": round(folder_bytes(folder) / 1024, 1),
        "version": artefact.VERSION,
    }


def shipped() -> list[dict[str, Any]]:
    """:func:`summary` of every ready-made tuner, by name."""
    return [summary(artefact.SHIPPED_DIR / n, n) for n in artefact.shipped_names()]
