"""Verification of a gain schedule: at every grid point, at every midpoint, and over the operating range.

:func:`verify_schedule` runs :func:`gaintune.verification.verify` with the spec frozen at each
grid value of ``var`` (the gains of that grid point) and at each midpoint between neighbours
(the interpolated gains, :func:`~gaintune.tuners.schedule.table.gains_between`), each against
the spec's own requirements (margins, sensitivity peaks, noise limit, robustness over the
spec's ``randomize`` box, the nonlinear scenario check). Then the nonlinear sweep
(:func:`~gaintune.tuners.schedule.sweep.nonlinear_sweep`) runs the scheduled controller across
the whole range. The schedule passes when every point passes and the sweep does.
"""

from __future__ import annotations

from typing import Literal

from pydantic import BaseModel, Field

from gaintune.tuners.schedule.sweep import ScheduleModel, SweepReport, nonlinear_sweep
from gaintune.tuners.schedule.table import GainSchedule, gains_between, spec_at

__all__ = ["PointCheck", "ScheduleVerification", "verify_point", "verify_schedule"]


class PointCheck(BaseModel):
    """The frozen-parameter verification at one value of the scheduling variable."""

    value: float
    kind: Literal["grid", "midpoint"]
    gains: dict[str, float] = Field(description="The loop's gains there (interpolated at a midpoint).")
    verdict: Literal["pass", "fail"]
    reasons: list[str] = Field(default_factory=list)


class ScheduleVerification(BaseModel):
    """Result of :func:`verify_schedule`."""

    var: str
    dt: float
    passed: bool
    points: list[PointCheck]
    sweep: SweepReport
    reasons: list[str] = Field(default_factory=list, description="Why it failed: each failing point, the sweep.")

    def count(self, kind: str) -> tuple[int, int]:
        """(passed, checked) among the points of ``kind`` ("grid" or "midpoint")."""
        pts = [p for p in self.points if p.kind == kind]
        return sum(p.verdict == "pass" for p in pts), len(pts)

    def summary(self) -> str:
        """One line: the verdict, the counts and the sweep."""
        (gp, gn), (mp, mn) = self.count("grid"), self.count("midpoint")
        sweep = ("passed" if self.sweep.passed else "FAILED") if self.sweep.ran else "not run"
        return (f"{'PASS' if self.passed else 'FAIL'}: grid points {gp}/{gn}, midpoints {mp}/{mn}, "
                f"nonlinear sweep {sweep}")


def verify_point(schedule: GainSchedule, value: float, kind: Literal["grid", "midpoint"]) -> PointCheck:
    """Verify the schedule's gains at ``value`` with the spec frozen there."""
    from gaintune.verification import verify

    gains = gains_between(schedule, value)
    rep = verify(spec_at(schedule.tuning_spec, schedule.var, value), gains)
    return PointCheck(value=value, kind=kind, gains=gains[schedule.loop], verdict=rep.verdict,
                      reasons=list(rep.reasons))


def verify_schedule(schedule: GainSchedule, *, sweep: bool = True, hold: float | None = None,
                    model: ScheduleModel | None = None) -> ScheduleVerification:
    """Verify ``schedule`` at every grid point and midpoint, then sweep it over the range on the nonlinear plant.

    Parameters
    ----------
    schedule
        The schedule.
    sweep
        Run the nonlinear sweep (:func:`~gaintune.tuners.schedule.sweep.nonlinear_sweep`).
    hold
        Seconds each level of the sweep is held (default: the first scenario's horizon).
    model
        A :class:`~gaintune.tuners.schedule.sweep.ScheduleModel` of this schedule to reuse.
    """
    points = sorted([verify_point(schedule, v, "grid") for v in schedule.grid]
                    + [verify_point(schedule, v, "midpoint") for v in schedule.midpoints], key=lambda p: p.value)
    report = nonlinear_sweep(schedule, model, hold) if sweep else SweepReport(ran=False, note="not requested")
    reasons = [f"{schedule.var} = {p.value:g} ({p.kind}): {p.reasons[0] if p.reasons else 'failed'}"
               for p in points if p.verdict != "pass"]
    if report.ran and not report.passed:
        reasons.append(f"nonlinear sweep: {report.note}")
    return ScheduleVerification(var=schedule.var, dt=schedule.dt, passed=not reasons, points=points, sweep=report,
                                reasons=reasons)
