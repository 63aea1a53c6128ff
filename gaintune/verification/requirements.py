"""The report's requirement lines: each requirement at its binding break point, nominal or worst case."""

from __future__ import annotations

import math
from typing import Literal

from gaintune.spec import TuningSpec
from gaintune.verification.margins import judged_pm
from gaintune.verification.report import LoopFigures, RequirementLine, WorstCase

__all__ = ["REQUIREMENTS", "requirement_lines", "not_applicable", "noise_line", "failing_reasons"]

#: requirement field -> (figure attribute, kind) ; kind "min": value >= limit, "max": value <= limit.
REQUIREMENTS: dict[str, tuple[str, str]] = {
    "gm_min_db": ("gm_db", "min"),
    "pm_min_deg": ("pm_deg", "min"),
    "dm_min": ("delay_margin", "min"),
    "ms_max": ("ms", "max"),
    "mt_max": ("mt", "max"),
    "wc_min": ("pm_freq", "min"),
    "wc_max": ("pm_freq", "max"),
}

#: (figure value, loop, break point, case) of one candidate for a requirement line.
_Candidate = tuple[float, str, str, Literal["nominal", "worst"]]


def _candidates(attr: str, loops: list[LoopFigures], worst: list[WorstCase] | None) -> list[_Candidate]:
    """The figure ``attr`` at every break point, nominal and (when given) worst case."""
    raw: list[tuple[float | None, str, str, Literal["nominal", "worst"]]] = [
        (getattr(f, attr), f.loop, f.break_point, "nominal") for f in loops]
    if worst and attr != "pm_freq":  # the robust set records no crossover frequencies
        raw += [(getattr(w, attr), w.loop, w.break_point, "worst") for w in worst]
    out = [(0.0 if v is None else v, loop, brk, case) for v, loop, brk, case in raw]  # no gain crossover: wc = 0
    return [(judged_pm(v), loop, brk, case) for v, loop, brk, case in out] if attr == "pm_deg" else out


def _binding(cands: list[_Candidate], limit: float, kind: str) -> tuple[float, _Candidate]:
    """The candidate of least margin (the first among ties) and its margin; NaN counts as -inf."""
    best: tuple[float, _Candidate] | None = None
    for cand in cands:
        value = cand[0]
        margin = (value - limit) if kind == "min" else (limit - value)
        if math.isnan(margin):
            margin = -math.inf
        # ties (within rounding: e.g. a single loop's two identical break points) keep the first
        tol = 1e-12 * max(1.0, abs(best[0])) if best is not None and math.isfinite(best[0]) else 0.0
        if best is None or margin < best[0] - tol:
            best = (margin, cand)
    if best is None:
        raise ValueError("a requirement line needs at least one break point")
    return best


def requirement_lines(spec: TuningSpec, loops: list[LoopFigures],
                      worst: list[WorstCase] | None) -> list[RequirementLine]:
    """One line per requirement the spec sets, at its binding break point (least margin), then Mks."""
    req = spec.requirements
    lines = []
    for name, (attr, kind) in REQUIREMENTS.items():
        limit = getattr(req, name)
        if limit is None:
            continue
        margin, (value, loop, brk, case) = _binding(_candidates(attr, loops, worst), limit, kind)
        lines.append(RequirementLine(requirement=name, figure=attr, limit=float(limit), value=float(value),
                                     margin=float(margin), passed=margin >= 0, loop=loop, break_point=brk, case=case))
    mks = noise_line(loops, worst)
    if mks is not None:
        lines.append(mks)
    return lines


def not_applicable(lines: list[RequirementLine], *, nominal_stable: bool, robust_stable: bool) -> list[RequirementLine]:
    """Mark the lines read on an unstable closed loop as not applicable (never pass): the instability is the reason."""
    stable = {"nominal": nominal_stable, "worst": robust_stable and nominal_stable}
    return [q if stable[q.case] else q.model_copy(update={"applicable": False, "passed": False}) for q in lines]


def noise_line(loops: list[LoopFigures], worst: list[WorstCase] | None) -> RequirementLine | None:
    """The Mks requirement at its binding loop: limits differ per loop, so the one with the least
    relative margin binds (the line states that loop's limit)."""
    limit = {f.loop: f.mks_max for f in loops if f.break_point == "controller_output" and f.mks_max is not None}
    cands = [(f.mks, f.loop, f.break_point, "nominal") for f in loops if f.loop in limit]
    cands += [(w.mks, w.loop, w.break_point, "worst") for w in (worst or []) if w.loop in limit and w.mks is not None]
    best = None
    for value, loop, brk, case in cands:
        v = math.inf if value is None or math.isnan(value) else value
        rel = (limit[loop] - v) / limit[loop]
        if best is None or rel < best[0] - 1e-12:
            best = (rel, v, loop, brk, case)
    if best is None:
        return None
    _, value, loop, brk, case = best
    margin = limit[loop] - value
    return RequirementLine(requirement="mks_max", figure="mks", limit=float(limit[loop]), value=float(value),
                           margin=float(margin), passed=margin >= 0, loop=loop, break_point=brk, case=case)


def failing_reasons(lines: list[RequirementLine]) -> list[str]:
    """A verdict reason per applicable line that fails, tightest (least relative margin) first."""
    failing = sorted((q for q in lines if q.applicable and not q.passed),
                     key=lambda q: q.margin / max(abs(q.limit), 1e-12))
    return [f"{q.requirement}: {q.figure} = {q.value:.4g} vs limit {q.limit:.4g} (margin {q.margin:+.4g}) "
            f"at {q.loop}/{q.break_point} ({q.case})" for q in failing]
