"""The move onto the requirement boundary on the exact verification: the last step of every search.

The search ranks candidates on the fast requirement estimate of
:mod:`gaintune.verification.quick`; the verdict comes from :func:`gaintune.verification.verify`.
Near an active constraint the two may disagree by a fraction of a percent. This
module closes that gap exactly, along one direction: the **loop-gain scale** of the
binding loop (:mod:`gaintune.evaluation.boundary`; the same move on the estimate is
:func:`gaintune.evaluation.boundary_estimate.onto_boundary_estimate`). Multiplying every
tuned gain of a parallel PID loop (Kp, Ki, Kd) by alpha multiplies its controller, hence
its loop transfer function, by alpha; with an ideal-form loop only Kp scales. Margins and
peaks move monotonically with alpha near the boundary of a well-posed design, so
bisection on alpha finds the boundary.

* An answer that fails a requirement (but is stable) is pulled inside: alpha < 1 by
  bisection until the exact verification passes, to within ``ALPHA_TOL``.
* An answer that passes with an almost-active requirement (relative margin below
  ``PUSH_BAND``) is pushed out to the boundary, and the pushed gains are kept only if
  their plain cost is lower and they stay feasible. That is where a constrained
  optimum lies when the constraint is active (Ms = 1.400, not 1.36).

"The boundary" is the search's **aim**: each limit moved inside by ``requirements.backoff``
(:meth:`gaintune.spec.backoff.BackoffSpec.aim`; Ms 1.386 for a limit of 1.4 by default), the
same aim the search estimate uses, so the answer keeps the back-off as its margin to the exact
limits the verdict judges. With ``backoff: 0`` the aim is the limit itself.

The result never claims anything itself: the caller still runs the full verification.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from gaintune.controllers.layout import GainLayout
from gaintune.evaluation.boundary import alpha_floor, loop_gain_exponents
from gaintune.evaluation.evaluator import Evaluator
from gaintune.spec.backoff import BackoffSpec
from gaintune.verification import verify
from gaintune.verification.report import VerificationReport

__all__ = ["ExactMove", "onto_boundary_exact", "violation_after", "normalised_margin", "ALPHA_TOL", "PUSH_BAND"]

#: Bisection stops when the alpha bracket is this narrow (relative): Ms then lands within ~1e-3 of a limit.
ALPHA_TOL = 5e-4
#: A passing answer whose tightest requirement is within this relative margin is pushed to the boundary.
PUSH_BAND = 0.05
#: Relative gain reductions tried in turn when an answer must be pulled inside (then bisection).
PULL_STEPS = (1e-3, 3e-3, 1e-2, 3e-2, 0.1, 0.2, 0.35, 0.5, 0.7, 0.85, 0.95)
#: Largest outward push tried (alpha up to this factor).
MAX_PUSH = 1.5


@dataclass
class ExactMove:
    """Outcome of :func:`onto_boundary_exact`.

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
        Normalised margin of the tightest requirement after settling, to its aimed limit (>= 0: the
        aim is met, so the exact limit is too).
    checks
        Exact verifications run.
    """

    tuned: np.ndarray
    alpha: float
    loop: str | None
    action: str
    margin: float
    checks: int


def normalised_margin(report: VerificationReport, aim: BackoffSpec | None = None) -> tuple[float, str | None]:
    """(tightest requirement margin / |limit|, its loop) ; -inf when the loop is unstable anywhere checked.

    ``aim``: measure each margin to the search's aimed limit (:meth:`BackoffSpec.aim`) instead of the
    report's exact one; the binding point of each requirement is the same (the aim shifts every
    candidate's margin alike).
    """
    if not report.stability.stable or (report.robust is not None and report.robust.n_unstable):
        return -math.inf, None
    worst, loop = math.inf, None
    for line in report.requirements:
        margin, limit = line.margin, line.limit
        if aim is not None and aim.active:  # the aim lies |limit - aimed| inside the limit
            aimed = aim.aim(line.requirement, limit)
            margin, limit = margin - abs(limit - aimed), aimed
        m = margin / max(abs(limit), 1e-12)
        if m < worst:
            worst, loop = m, line.loop
    return worst, loop


def _directions(ev: Evaluator, loop: str | None) -> tuple[str, list[np.ndarray]]:
    """The binding loop's name and the exponent vectors d of its moves ``t * alpha**d`` (alpha < 1).

    In order: (1) the loop gain down (parallel: Kp, Ki, Kd; ideal: Kp), (2) the integral action
    down (Ki, or Ti up), which raises the phase margin at an unchanged crossover, (3) the loop
    gain up. Empty for LQ loops and loops with nothing tuned.
    """
    layout = ev.layout
    names = ev.spec.loop_names
    if loop is None or loop not in names:
        loop = names[-1]  # the plant-input break point: the innermost loop drives the plant
    spec_loop = ev.spec.loops[names.index(loop)]
    if spec_loop.is_lq:
        return loop, []
    slots = layout.tuned_slots

    def vec(weights: dict[str, float]) -> np.ndarray:
        return np.array([weights.get(s.name, 0.0) if s.loop_name == loop else 0.0 for s in slots])

    gain = loop_gain_exponents(ev, loop)
    integral = vec({"Ki": 1.0} if spec_loop.form == "parallel" else {"Ti": -1.0})
    out = [d for d in (gain, integral, -gain) if d.any()]
    return loop, out


def _alpha_min(layout: GainLayout, tuned: np.ndarray, d: np.ndarray) -> float:
    """Smallest alpha < 1 that keeps ``tuned * alpha**d`` inside the search box (0 when d moves nothing)."""
    return float(alpha_floor(layout, tuned, d)[0])


class _ExactProbe:
    """Exact requirement margins of ``tuned * alpha**d``, to the search's aim, counting the verifications run."""

    def __init__(self, ev: Evaluator, tuned: np.ndarray) -> None:
        self.ev, self.tuned, self.checks = ev, tuned, 0
        self.aim = ev.spec.requirements.backoff  # settle onto the search's aim; the verdict judges the exact limits

    def moved(self, d: np.ndarray, a: float) -> np.ndarray:
        """The answer with its gains scaled by ``a**d``."""
        return self.tuned * a**d

    def margin_and_loop(self, t: np.ndarray) -> tuple[float, str | None]:
        """:func:`normalised_margin` of gains ``t`` by exact verification (nominal, linear checks only)."""
        ev = self.ev
        self.checks += 1
        report = verify(ev.spec, ev.layout.full(t), nonlinear=False, plant=ev.plant, layout=ev.layout)
        return normalised_margin(report, self.aim)

    def margin(self, d: np.ndarray, a: float) -> float:
        """The normalised margin of the answer moved by ``a**d``."""
        return self.margin_and_loop(self.moved(d, a))[0]

    def bisect(self, d: np.ndarray, ok: float, bad: float, m_ok: float) -> tuple[float, float]:
        """Narrow the bracket [ok (margin >= 0), bad] to ``ALPHA_TOL``; returns (ok, its margin)."""
        while abs(bad - ok) > ALPHA_TOL * min(ok, bad):
            mid = math.sqrt(ok * bad)
            m = self.margin(d, mid)
            if m >= 0:
                ok, m_ok = mid, m
            else:
                bad = mid
        return ok, m_ok


def onto_boundary_exact(ev: Evaluator, tuned: np.ndarray, cost: float | None = None) -> ExactMove:
    """Settle ``tuned`` on the spec's requirements by exact verification (see the module docstring).

    Parameters
    ----------
    ev
        The evaluator of the search (its spec, plant and layout; its cost for the push test).
    tuned
        The search's answer (tuned-gain vector).
    cost
        Its plain cost, when known (saves one evaluation).

    Returns
    -------
    ExactMove
        The settled gains and what was done to them.
    """
    if ev.is_mimo:  # TODO(MIMO verification): settle on the MIMO requirements once they are verified exactly
        return ExactMove(np.asarray(tuned, dtype=float), 1.0, None, "unchanged", math.nan, 0)
    probe = _ExactProbe(ev, np.asarray(tuned, dtype=float))
    m0, binding = probe.margin_and_loop(probe.tuned)
    if m0 == -math.inf:
        return ExactMove(probe.tuned, 1.0, None, "not_settled", m0, probe.checks)
    loop, dirs = _directions(ev, binding)
    if not dirs:
        return ExactMove(probe.tuned, 1.0, None, "unchanged" if m0 >= 0 else "not_settled", m0, probe.checks)
    if m0 < 0:
        return _pull_inside(probe, loop, dirs, m0)
    return _push_out(probe, loop, dirs[0], m0, cost)


def _pull_inside(probe: _ExactProbe, loop: str, dirs: list[np.ndarray], m0: float) -> ExactMove:
    """Scale a failing answer inside along the first direction that reaches a pass, then bisect onto the boundary.

    Small steps first, since a peak can be non-monotone far from alpha = 1.
    """
    for d in dirs:
        a_min = _alpha_min(probe.ev.layout, probe.tuned, d)
        bad, a, m = 1.0, 1.0, m0
        for step in PULL_STEPS:
            a = max(1.0 - step, a_min)
            if a >= bad:
                break  # the box allows no further move this way
            m = probe.margin(d, a)
            if m >= 0 or a <= a_min:
                break
            bad = a
        if m >= 0:
            a, m = probe.bisect(d, a, bad, m)
            return ExactMove(probe.moved(d, a), a, loop, "pulled_inside", m, probe.checks)
    return ExactMove(probe.tuned, 1.0, loop, "not_settled", m0, probe.checks)


def _push_out(probe: _ExactProbe, loop: str, d: np.ndarray, m0: float, cost: float | None) -> ExactMove:
    """Push an almost-active passing answer out along the loop gain onto the boundary; kept only if it costs less."""
    ev, tuned = probe.ev, probe.tuned
    unchanged = ExactMove(tuned, 1.0, loop, "unchanged", m0, probe.checks)
    a_max = 1.0 / _alpha_min(ev.layout, tuned, -d) if _alpha_min(ev.layout, tuned, -d) > 0 else MAX_PUSH
    if m0 > PUSH_BAND or a_max <= 1.0:
        return unchanged
    # find a failing scale, then bisect back onto the boundary
    a, m, ok, m_ok = 1.0, m0, 1.0, m0
    while m >= 0 and a < min(MAX_PUSH, a_max):
        ok, m_ok = a, m
        a = min(a * (1.0 + max(2.0 * m, 0.01)), MAX_PUSH, a_max)
        m = probe.margin(d, a)
    if m >= 0:
        ok, m_ok = a, m
    else:
        ok, m_ok = probe.bisect(d, ok, a, m_ok)
    unchanged.checks = probe.checks
    if ok == 1.0:
        return unchanged
    base = cost if cost is not None else float(ev.evaluate(tuned[None]).cost[0])
    cand = ev.evaluate(probe.moved(d, ok)[None])
    # the exact check decides the requirements here; the run itself must not diverge or trip
    if not (cand.diverged[0] or cand.tripped[0]) and float(cand.cost[0]) < base:
        return ExactMove(probe.moved(d, ok), ok, loop, "pushed_to_boundary", m_ok, probe.checks)
    return unchanged


def violation_after(settled: ExactMove | None, scores) -> float:
    """Violation of a settled answer: the exact check supersedes the estimate once settling moved it.

    A pulled-in or pushed-out answer meets every aimed limit by the exact verification (margin
    >= 0) while the estimate, which aims :data:`~gaintune.verification.quick.FEASIBILITY_MARGIN`
    inside, may call it a hair short; its run must still neither diverge nor trip.
    """
    if (settled is not None and settled.action in ("pulled_inside", "pushed_to_boundary") and settled.margin >= 0
            and not (scores.diverged[0] or scores.tripped[0])):
        return 0.0
    return float(scores.violation[0])
