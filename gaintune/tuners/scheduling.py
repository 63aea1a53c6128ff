"""A gain schedule answered by a trained tuner: ``gaintune tuner schedule DIR --var H0 --grid 2:20:10``.

A spec tuner whose context includes the scheduling variable ``var`` (e.g. one trained with
``randomize: {params: {H0: [2, 20]}}``) answers the gains at each grid point: the tuner is queried
at ``{var: value}`` (its other context variables at the spec's nominal values), and its answer,
moved onto that plant's requirement boundary, is the grid point's gains. The schedule is then fitted
at the midpoints (:func:`~gaintune.tuners.schedule.fit.fit_midpoints`) and verified like any
schedule (:func:`~gaintune.tuners.schedule.check.verify_schedule`).
"""

from __future__ import annotations

from collections.abc import Callable

from gaintune.errors import SpecError
from gaintune.spec import Gains, TuningSpec
from gaintune.tuners.problems import SpecProblem
from gaintune.tuners.schedule import GainSchedule, build_schedule, fit_midpoints
from gaintune.tuners.schedule.table import check_grid
from gaintune.tuners.tuner import Tuner, TunerAnswer

__all__ = ["value_at", "tuner_gains_at", "schedule_from_tuner"]


def value_at(spec: TuningSpec, var: str) -> float:
    """The value of the plant parameter ``var`` in ``spec`` (a model's own parameters included)."""
    from gaintune.plants import build_plant

    return float(build_plant(spec.plant).params[var])


def tuner_gains_at(tuner: Tuner, var: str, answers: list[TunerAnswer] | None = None) -> Callable[[TuningSpec], Gains]:
    """A ``gains_at`` for :func:`~gaintune.tuners.schedule.table.build_schedule`: the tuner's answer at ``var``.

    Each answer is appended to ``answers`` when given (the CLI shows their verdicts).
    """

    def gains_at(spec: TuningSpec) -> Gains:
        answer = tuner.query({var: value_at(spec, var)})
        if answers is not None:
            answers.append(answer)
        return answer.gains

    return gains_at


def _check(tuner: Tuner, var: str, grid: list[float]) -> SpecProblem:
    """The tuner's problem, when it is a spec tuner over ``var`` and ``grid`` lies in its range; SpecError otherwise."""
    problem = tuner.problem
    if not isinstance(problem, SpecProblem):
        raise SpecError("tuner", f"{tuner.name} is a ready-made family tuner; a gain schedule needs a tuner trained "
                        "on a spec whose randomize block varies the scheduling variable ('gaintune tuner train SPEC')")
    ranges = {v.name: v for v in problem.variables}
    if var not in ranges:
        raise SpecError("var", f"{var!r} is not a context variable of {tuner.name}; it was trained over "
                        f"{', '.join(ranges)}")
    v = ranges[var]
    outside = [x for x in grid if not v.contains(x)]
    if outside:
        raise SpecError("grid", f"{var} = {outside[0]:g} is outside the range the tuner was trained over "
                        f"({v.lo:g} to {v.hi:g}); give a grid inside it")
    return problem


def schedule_from_tuner(tuner: Tuner, var: str, grid: list[float], answers: list[TunerAnswer] | None = None,
                        ) -> tuple[GainSchedule, GainSchedule, list[str]]:
    """The schedule of ``tuner`` over ``grid`` of ``var``: (as answered, fitted at the midpoints, the fit's notes).

    Raises
    ------
    SpecError
        Naming ``tuner`` (not a spec tuner), ``var`` (not one of its context variables) or ``grid``
        (a value outside its training range, or not a valid grid).
    """
    grid = check_grid(grid)
    problem = _check(tuner, var, grid)
    raw = build_schedule(problem.spec, var, grid, tuner_gains_at(tuner, var, answers),
                         method=f"trained tuner {tuner.name}, queried at each grid point")
    fitted, notes = fit_midpoints(raw)
    return raw, fitted, notes
