"""Settle a search answer on the requirements with the exact verification: the last step of every search.

The search ranks candidates on the fast requirement estimate of
:mod:`gaintune.verify.quick`; the verdict comes from :func:`gaintune.verify.verify`.
Near an active constraint the two may disagree by a fraction of a percent. This
module closes that gap exactly, along one direction: the **loop-gain scale** of the
binding loop. Multiplying every tuned gain of a parallel PID loop (Kp, Ki, Kd) by
alpha multiplies its controller, hence its loop transfer function, by alpha; with an
ideal-form loop only Kp scales. Margins and peaks move monotonically with alpha near
the boundary of a well-posed design, so bisection on alpha finds the boundary.

* An answer that fails a requirement (but is stable) is pulled inside: alpha < 1 by
  bisection until the exact verification passes, to within ``ALPHA_TOL``.
* An answer that passes with an almost-active requirement (relative margin below
  ``PUSH_BAND``) is pushed out to the boundary, and the pushed gains are kept only if
  their plain cost is lower and they stay feasible. That is where a constrained
  optimum lies when the constraint is active (Ms = 1.400, not 1.36).

The result never claims anything itself: the caller still runs the full verification.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from gaintune.objective import Evaluator
from gaintune.verify import verify
from gaintune.verify.report import VerificationReport

__all__ = ["Settled", "settle", "normalised_margin", "ALPHA_TOL", "PUSH_BAND"]

#: Bisection stops when the alpha bracket is this narrow (relative): Ms then lands within ~1e-3 of a limit.
ALPHA_TOL = 5e-4
#: A passing answer whose tightest requirement is within this relative margin is pushed to the boundary.
PUSH_BAND = 0.05
#: Relative gain reductions tried in turn when an answer must be pulled inside (then bisection).
PULL_STEPS = (1e-3, 3e-3, 1e-2, 3e-2, 0.1, 0.2, 0.35, 0.5, 0.7, 0.85, 0.95)
#: Largest outward push tried (alpha up to this factor).
MAX_PUSH = 1.5


@dataclass
class Settled:
    """Outcome of :func:`settle`.

    Attributes
    ----------
    tuned
        The settled tuned-gain vector (the input when nothing changed).
    alpha
        Loop-gain scale applied (1.0 when unchanged).
    loop
        Name of the loop that was scaled, or None.
    action
        "unchanged", "pulled_inside", "pushed_to_boundary" or "not_settled" (no scale passes).
    margin
        Normalised margin of the tightest requirement after settling (>= 0 passes).
    checks
        Exact verifications run.
    """

    tuned: np.ndarray
    alpha: float
    loop: str | None
    action: str
    margin: float
    checks: int


def normalised_margin(report: VerificationReport) -> tuple[float, str | None]:
    """(tightest requirement margin / |limit|, its loop) ; -inf when the loop is unstable anywhere checked."""
    if not report.stability.stable or (report.robust is not None and report.robust.n_unstable):
        return -math.inf, None
    worst, loop = math.inf, None
    for line in report.requirements:
        m = line.margin / max(abs(line.limit), 1e-12)
        if m < worst:
            worst, loop = m, line.loop
    return worst, loop


def _scale_mask(ev: Evaluator, loop: str | None) -> np.ndarray | None:
    """Tuned-vector mask of the gains that scale a loop's controller (None when none do)."""
    layout = ev.layout
    names = [lp.name for lp in ev.spec.loops]
    if loop is None or loop not in names:
        loop = names[-1]  # the plant-input break point: the innermost loop drives the plant
    spec_loop = ev.spec.loops[names.index(loop)]
    if spec_loop.is_lq:
        return None
    scaled = {"Kp", "Ki", "Kd"} if spec_loop.form == "parallel" else {"Kp"}
    mask = np.array([s.loop_name == loop and s.name in scaled for s in layout.tuned_slots])
    return mask if mask.any() else None


def settle(ev: Evaluator, tuned: np.ndarray, cost: float | None = None) -> Settled:
    """Settle ``tuned`` on the spec's requirements by exact verification (see the module docstring).

    Parameters
    ----------
    ev
        The evaluator of the search (its spec, plant and layout; its cost for the push test).
    tuned
        The search's answer (tuned-gain vector).
    cost
        Its plain cost, when known (saves one evaluation).
    """
    tuned = np.asarray(tuned, dtype=float)
    spec, layout = ev.spec, ev.layout
    checks = 0

    def margin_of(t: np.ndarray) -> tuple[float, str | None]:
        nonlocal checks
        checks += 1
        rep = verify(spec, layout.full(t), nonlinear=False, plant=ev.plant, layout=layout)
        return normalised_margin(rep)

    m0, loop = margin_of(tuned)
    if not math.isfinite(m0) and m0 < 0:
        return Settled(tuned, 1.0, None, "not_settled", m0, checks)
    mask = _scale_mask(ev, loop)
    if mask is None:
        return Settled(tuned, 1.0, None, "unchanged" if m0 >= 0 else "not_settled", m0, checks)
    lo_b, hi_b = np.exp(layout.log_lo[mask]), np.exp(layout.log_hi[mask])
    a_min = float(np.max(lo_b / tuned[mask]))  # the box limits how far alpha may go
    a_max = float(np.min(hi_b / tuned[mask]))

    def scaled(a: float) -> np.ndarray:
        t = tuned.copy()
        t[mask] *= a
        return t

    def bisect(ok: float, bad: float, m_ok: float) -> tuple[float, float]:
        while abs(bad - ok) > ALPHA_TOL * ok:
            mid = math.sqrt(ok * bad)
            m, _ = margin_of(scaled(mid))
            if m >= 0:
                ok, m_ok = mid, m
            else:
                bad = mid
        return ok, m_ok

    loop_name = loop if loop in [lp.name for lp in spec.loops] else spec.loops[-1].name
    if m0 < 0:  # pull inside: small steps first, since a peak can be non-monotone in alpha far from 1
        bad, a, m = 1.0, 1.0, m0
        for step in PULL_STEPS:
            a = max(1.0 - step, a_min)
            m, _ = margin_of(scaled(a))
            if m >= 0 or a <= a_min:
                break
            bad = a
        if m < 0:
            return Settled(tuned, 1.0, loop_name, "not_settled", m0, checks)
        a, m = bisect(a, bad, m)
        return Settled(scaled(a), a, loop_name, "pulled_inside", m, checks)
    if m0 > PUSH_BAND or a_max <= 1.0:
        return Settled(tuned, 1.0, loop_name, "unchanged", m0, checks)
    # push out: find a failing scale, then bisect back onto the boundary
    a, m, ok, m_ok = 1.0, m0, 1.0, m0
    while m >= 0 and a < min(MAX_PUSH, a_max):
        ok, m_ok = a, m
        a = min(a * (1.0 + max(2.0 * m, 0.01)), MAX_PUSH, a_max)
        m, _ = margin_of(scaled(a))
    if m >= 0:
        ok, m_ok = a, m
    else:
        ok, m_ok = bisect(ok, a, m_ok)
    if ok == 1.0:
        return Settled(tuned, 1.0, loop_name, "unchanged", m0, checks)
    base = cost if cost is not None else float(ev.evaluate(tuned[None]).cost[0])
    cand = ev.evaluate(scaled(ok)[None])
    # the exact check decides the requirements here; the run itself must not diverge or trip
    if not (cand.diverged[0] or cand.tripped[0]) and float(cand.cost[0]) < base:
        return Settled(scaled(ok), ok, loop_name, "pushed_to_boundary", m_ok, checks)
    return Settled(tuned, 1.0, loop_name, "unchanged", m0, checks)
