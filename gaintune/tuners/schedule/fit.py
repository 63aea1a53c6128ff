"""Make the interpolated gains pass between grid points: scale the gains of the grid points next to a failing midpoint.

Per-point gains tuned onto a requirement boundary lie *on* it; the boundary is in general
curved in the scheduling variable, and linear interpolation between two boundary points
cuts outside a convex one. On the water tank the noise limit (``mks_max: auto``, ``Mks <=
10/|K|`` with the plant gain ``K = 2 b sqrt(H0)/a``) admits a largest ``Kp`` proportional to
``1/sqrt(H0)``, a convex curve: halfway between 2 m and 4 m the interpolated ``Kp`` exceeds
the limit by about ``0.375/H0^2`` of it (4 % at 3 m), more than the search's 1 % back-off.

:func:`fit_midpoints` closes that gap without changing the grid: for each midpoint that fails
its frozen-parameter verification, it finds by bisection the largest loop-gain scale
``alpha <= 1`` (every gain of the loop times alpha, the move of
:mod:`gaintune.evaluation.boundary_exact`) at which the interpolated gains pass there, and
scales the gains of both neighbouring grid points by it (a point between two failing
midpoints takes the smaller factor). Rounds repeat until every midpoint passes. The factors
are recorded in :attr:`GainSchedule.fitted`; :func:`~gaintune.tuners.schedule.check.verify_schedule`
then verifies the result as any schedule.
"""

from __future__ import annotations

from gaintune.tuners.schedule.check import verify_point
from gaintune.tuners.schedule.table import GainSchedule

__all__ = ["fit_midpoints", "ALPHA_MIN", "ALPHA_TOL"]

#: Smallest scale tried: below it the midpoint is reported as not fitted.
ALPHA_MIN = 0.5
#: Bisection stops when the bracket is this narrow.
ALPHA_TOL = 1e-3


def _scaled(schedule: GainSchedule, factors: list[float]) -> GainSchedule:
    gains = [{k: v * f for k, v in g.items()} for g, f in zip(schedule.gains, factors, strict=True)]
    fitted = [a * f for a, f in zip(schedule.fitted or [1.0] * len(factors), factors, strict=True)]
    return schedule.model_copy(update={"gains": gains, "fitted": fitted})


def _passes(schedule: GainSchedule, i: int, alpha: float) -> bool:
    """Whether the midpoint after grid point ``i`` passes with both neighbours' gains times ``alpha``."""
    factors = [1.0] * len(schedule.grid)
    factors[i] = factors[i + 1] = alpha
    return verify_point(_scaled(schedule, factors), schedule.midpoints[i], "midpoint").verdict == "pass"


def _largest_passing_scale(schedule: GainSchedule, i: int) -> float | None:
    """The largest alpha in [ALPHA_MIN, 1) at which midpoint ``i`` passes (bisection), None if not even ALPHA_MIN."""
    if not _passes(schedule, i, ALPHA_MIN):
        return None
    lo, hi = ALPHA_MIN, 1.0  # lo passes, hi fails
    while hi - lo > ALPHA_TOL * hi:
        mid = 0.5 * (lo + hi)
        lo, hi = (mid, hi) if _passes(schedule, i, mid) else (lo, mid)
    return lo


def fit_midpoints(schedule: GainSchedule, max_rounds: int = 4) -> tuple[GainSchedule, list[str]]:
    """The schedule with the gains next to failing midpoints scaled down until those pass (module docstring).

    Returns the fitted schedule and one note per change (or per midpoint that could not be
    fitted); the schedule is returned unchanged when every midpoint passes already.
    """
    notes: list[str] = []
    for _ in range(max_rounds):
        failing = [i for i, m in enumerate(schedule.midpoints)
                   if verify_point(schedule, m, "midpoint").verdict != "pass"]
        if not failing:
            break
        factors = [1.0] * len(schedule.grid)
        for i in failing:
            alpha = _largest_passing_scale(schedule, i)
            mid = f"{schedule.var} = {schedule.midpoints[i]:g}"
            if alpha is None:
                notes.append(f"midpoint {mid} fails even with the neighbouring gains halved: refine the grid there")
                continue
            factors[i], factors[i + 1] = min(factors[i], alpha), min(factors[i + 1], alpha)
            notes.append(f"midpoint {mid}: gains at {schedule.var} = {schedule.grid[i]:g} and "
                         f"{schedule.grid[i + 1]:g} scaled by {alpha:.4f}")
        if all(f == 1.0 for f in factors):
            break
        schedule = _scaled(schedule, factors)
    return schedule, notes
