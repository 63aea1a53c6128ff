"""A schedule against the best single fixed PI over the same operating range.

**The level step.** At a tested level ``v`` (every grid point and every midpoint) the plant
starts in equilibrium with ``var = v`` and the controller in steady state there (its
integrator at the operating input); the reference is the spec's first scenario reference
(for the water tank: +2 m at t = 10 s, 200 s horizon) on top of the operating output, on the
nonlinear plant with the actuator limits. Its IAE is the figure compared. Both controllers
run through the same code (:meth:`~gaintune.tuners.schedule.sweep.ScheduleModel.run`): the
fixed PI as a table whose entries are all equal, the schedule re-interpolated at every sample.

**The best single fixed PI** (:func:`best_fixed_pi`) is the robust design for a plant whose
``var`` is only known to lie in ``[grid[0], grid[-1]]``, held to the same standard as the
schedule: it minimises the *worst* level-step cost over the tested levels (the spec's objective,
IAE plus its effort term; the robust aggregate ``worst`` of ``search.robust`` over fixed draws at
exactly those levels, other parameters nominal), subject to the requirements of the spec
*frozen at each tested level* (on its nominal plant and the corners of its randomisation box),
ranked feasibility first as every gaintune search is. The per-level requirements matter: the
spec with ``randomize.params[var] = [lo, hi]`` alone would resolve ``mks_max: auto`` once, at
the nominal level, and a PI meeting that misses the noise limit of the higher levels, where
the tank's gain is larger. The optimiser is the CMA-ES baseline (:mod:`gaintune.baselines`),
without the exact boundary step (which would judge the robust spec's single noise limit); the
answer is then verified at every tested level like the schedule. "The schedule is better at
every level" thus means better than the fixed PI whose weakest level is as good as a fixed PI
can make it.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable, Mapping
from dataclasses import replace
from typing import Any

import numpy as np
from pydantic import BaseModel, Field

from gaintune.errors import SpecError
from gaintune.export.schedule import ScheduleTable
from gaintune.plants.plant import Plant
from gaintune.spec import Gains, TuningSpec, load_spec
from gaintune.tuners.schedule.law import ScheduledPid
from gaintune.tuners.schedule.sweep import Run, ScheduleModel
from gaintune.tuners.schedule.table import GainSchedule, spec_at

__all__ = ["grid_and_midpoints", "require_nonlinear", "level_step", "constant_table", "LevelComparison",
           "ScheduleComparison", "compare_fixed", "FixedDesign", "robust_spec", "best_fixed_pi", "cma_gains_at"]

#: Per-point CMA-ES budget of :func:`cma_gains_at`, and per tested level of :func:`best_fixed_pi` (simulations).
POINT_BUDGET = 600


def grid_and_midpoints(schedule: GainSchedule) -> list[tuple[float, str]]:
    """Every grid point and midpoint, ascending, each with its kind ("grid" or "midpoint")."""
    return sorted([(v, "grid") for v in schedule.grid] + [(v, "midpoint") for v in schedule.midpoints])


def _refuse_unless_nonlinear(plant: Plant) -> None:
    """SpecError naming ``compare`` unless ``plant`` is a nonlinear (ODE) model: its level steps step the ODE."""
    kind = getattr(plant, "kind", None)
    if kind != "nonlinear":
        what = "an LTI model" if kind == "lti" else f"a {kind} plant"
        raise SpecError("compare", f"the comparison with a fixed PI sweeps a nonlinear plant's operating range "
                        f"(level steps on its ODE model), and this plant is {what}; for an LTI family use the "
                        "schedule without --compare (or give a nonlinear model)")


def require_nonlinear(spec: TuningSpec) -> None:
    """Check that a schedule of ``spec`` can be compared with a fixed PI (:func:`best_fixed_pi`, :func:`compare_fixed`).

    Parameters
    ----------
    spec
        The schedule's spec (a spec tuner's own).

    Raises
    ------
    SpecError
        Naming ``compare``: the spec's plant is not a nonlinear (ODE) model, so it has no operating
        range whose level steps the comparison could simulate.
    """
    from gaintune.plants import build_plant

    _refuse_unless_nonlinear(build_plant(spec.plant))


def _reference(model: ScheduleModel, y0: float, step: float | None) -> np.ndarray:
    """The first scenario's reference on top of ``y0`` (or a step of ``step`` at the scenario's reference time)."""
    from gaintune.sim.build import profile_pieces

    sc = model.spec.scenarios[0]
    n, dt = sc.n_steps, model.dt
    if step is None:
        pieces = profile_pieces(sc.reference, dt, n)
    else:
        pieces = [(int(round(sc.reference.time / dt)), n + 1, float(step), 0.0)]
    k = np.arange(n)
    r = np.zeros(n)
    for k0, k1, off, slope in pieces:  # the simulator's additive pieces (gaintune.sim.kernel.signals)
        r += np.where((k >= k0) & (k < k1), off + slope * ((k - k0) * dt), 0.0)
    return r + y0


def level_step(model: ScheduleModel, table: ScheduleTable, level: float, step: float | None = None) -> Run:
    """The level step at ``level`` (module docstring) under the law of ``table``."""
    _, u0, y0 = model.operating(level)
    ref = _reference(model, y0, step)
    return model.run(ScheduledPid(table), ref, np.full(ref.size, float(level)), i0=u0)


def constant_table(table: ScheduleTable, gains: dict[str, float]) -> ScheduleTable:
    """``table`` with the same ``gains`` (``{Kp, Ki, Kd}``) at every breakpoint: a fixed controller."""
    n = len(table.grid)
    return replace(table, kp=(float(gains.get("Kp", 0.0)),) * n, ki=(float(gains.get("Ki", 0.0)),) * n,
                   kd=(float(gains.get("Kd", 0.0)),) * n)


class LevelComparison(BaseModel):
    """Level-step IAE of the schedule and of the fixed PI at one level."""

    level: float
    kind: str
    iae_scheduled: float
    iae_fixed: float

    @property
    def ratio(self) -> float:
        """Scheduled IAE / fixed IAE (< 1: the schedule is better)."""
        return self.iae_scheduled / self.iae_fixed if self.iae_fixed > 0 else math.inf

    @property
    def better(self) -> bool:
        """The schedule's IAE is lower."""
        return self.iae_scheduled < self.iae_fixed


class ScheduleComparison(BaseModel):
    """Result of :func:`compare_fixed`."""

    var: str
    fixed_gains: dict[str, float]
    step: str = Field(description="The level step compared.")
    levels: list[LevelComparison]

    @property
    def better_everywhere(self) -> bool:
        """The schedule is better at every tested level."""
        return all(lv.better for lv in self.levels)


def _loop_gains(gains: Mapping[str, Any], loop: str) -> dict[str, float]:
    """The loop's gains from ``{loop: {gain: value}}`` or from ``{gain: value}``."""
    inner = gains.get(loop)
    return {k: float(v) for k, v in (inner if isinstance(inner, Mapping) else gains).items()}


def compare_fixed(schedule: GainSchedule, fixed_gains: Gains | dict[str, float],
                  levels: list[tuple[float, str]] | None = None, step: float | None = None,
                  model: ScheduleModel | None = None) -> ScheduleComparison:
    """Level-step IAE of the schedule and of ``fixed_gains`` at each level (default: :func:`grid_and_midpoints`).

    ``fixed_gains``: the loop's gains, or ``{loop: gains}``. ``step``: a reference step amplitude
    instead of the first scenario's reference.

    Raises
    ------
    SpecError
        Naming ``compare``: the schedule's plant is not a nonlinear (ODE) model (:func:`require_nonlinear`).
    """
    model = model if model is not None else ScheduleModel(schedule)
    _refuse_unless_nonlinear(model.plant)
    fixed = _loop_gains(fixed_gains, schedule.loop)
    fixed_table = constant_table(model.table, fixed)
    out = []
    for v, kind in levels if levels is not None else grid_and_midpoints(schedule):
        out.append(LevelComparison(level=v, kind=kind, iae_scheduled=level_step(model, model.table, v, step).iae,
                                   iae_fixed=level_step(model, fixed_table, v, step).iae))
    sc = model.spec.scenarios[0]
    what = (f"the reference of scenario {sc.name!r}" if step is None else f"a step of {step:g}") + \
        f" from equilibrium at each level, {sc.resolved_horizon:g} s at dt = {model.dt:g} s, nonlinear plant"
    return ScheduleComparison(var=schedule.var, fixed_gains=fixed, step=what, levels=out)


# ------------------------------------------------------------------------------------- the fixed PI


class FixedDesign(BaseModel):
    """The best single fixed PI over the range (:func:`best_fixed_pi`)."""

    gains: Gains
    cost: float | None = Field(description="Worst level-step cost over the tested levels.")
    feasible: bool | None
    levels: list[float]
    budget: int
    seed: int
    n_sims: int
    wall_time: float
    definition: str


def robust_spec(schedule: GainSchedule, levels: list[float]) -> TuningSpec:
    """The schedule's spec with ``var`` randomised over the grid's range and the worst case over ``levels`` scored."""
    d = schedule.tuning_spec.model_dump()
    d["randomize"]["params"][schedule.var] = [schedule.grid[0], schedule.grid[-1]]
    d["search"]["robust"] = {"samples": len(levels), "aggregate": "worst"}
    return load_spec(d)


def _levelwise_evaluator(schedule: GainSchedule, levels: list[float]) -> Any:
    """The evaluator of :func:`best_fixed_pi`: worst cost over draws at ``levels``; each level's own requirements."""
    from gaintune.evaluation.evaluator import Evaluator
    from gaintune.evaluation.search_box import search_layout
    from gaintune.plants import build_plant
    from gaintune.sim import Simulator
    from gaintune.sim.draws import nominal

    class Levelwise(Evaluator):
        """The requirement estimate is the worst over one evaluator per level, each on the spec frozen there.

        (The robust spec's own estimate resolves ``mks_max: auto`` once, at the nominal level; frozen at a
        level, verification resolves it there, as it does for the schedule's points.)
        """

        per_level: list[Evaluator]

        def requirement_scores(self, tuned: np.ndarray, stability: bool = True) -> tuple[np.ndarray, np.ndarray]:
            vs = [ev.requirement_scores(tuned, stability) for ev in self.per_level]
            return np.max([v[0] for v in vs], axis=0), np.max([v[1] for v in vs], axis=0)

    spec = robust_spec(schedule, levels)
    plant = build_plant(spec.plant)
    layout = search_layout(spec, plant)
    draws = nominal(spec, plant, len(levels))
    draws.params[:, plant.param_names.index(schedule.var)] = levels
    ev = Levelwise(spec, Simulator(spec, plant, layout), draws)
    frozen = [spec_at(schedule.tuning_spec, schedule.var, v) for v in levels]
    ev.per_level = [Evaluator(f, Simulator(f, build_plant(f.plant), layout)) for f in frozen]
    return ev


def best_fixed_pi(schedule: GainSchedule, levels: list[float] | None = None, *, budget: int | None = None,
                  seed: int = 0) -> FixedDesign:
    """The fixed gains that minimise the worst level-step cost over ``levels`` (see the module docstring).

    ``levels`` defaults to every grid point and midpoint; ``budget`` (simulations) to
    :data:`POINT_BUDGET` per level.

    Raises
    ------
    SpecError
        Naming ``compare``: the schedule's plant is not a nonlinear (ODE) model (:func:`require_nonlinear`);
        refused before the search spends its budget.
    """
    from gaintune.baselines.run import run_baseline

    require_nonlinear(schedule.tuning_spec)
    t0 = time.perf_counter()
    levels = levels if levels is not None else [v for v, _ in grid_and_midpoints(schedule)]
    ev = _levelwise_evaluator(schedule, levels)
    budget = budget if budget is not None else POINT_BUDGET * len(levels)
    # no exact boundary step: it verifies the robust spec, whose noise limit is the nominal level's
    res = run_baseline(ev.spec, "cmaes", budget=budget, seed=seed, evaluator=ev, settle_answer=False)
    if res.gains is None:
        raise ValueError(f"the CMA-ES search found no gains: {res.reason}")
    return FixedDesign(gains=res.gains, cost=res.cost, feasible=res.feasible, levels=levels, budget=budget,
                       seed=seed, n_sims=res.n_sims, wall_time=time.perf_counter() - t0,
                       definition=f"CMA-ES, worst level-step cost over {len(levels)} levels of {schedule.var} "
                                  f"in [{schedule.grid[0]:g}, {schedule.grid[-1]:g}], subject to the requirements "
                                  "of the spec frozen at each level (nominal plant and the corners of its "
                                  "randomisation box)")


def cma_gains_at(budget: int = POINT_BUDGET, seed: int = 0) -> Callable[[TuningSpec], Gains]:
    """A ``gains_at`` for :func:`~gaintune.tuners.schedule.table.build_schedule`: a quick CMA-ES search per point.

    The CMA-ES baseline (:func:`gaintune.baselines.run.run_baseline`) on the spec frozen at the
    grid point: the spec's cost and requirements, ``budget`` simulations, the exact boundary step.
    """
    from gaintune.baselines.run import run_baseline

    def gains_at(spec: TuningSpec) -> Gains:
        res = run_baseline(spec, "cmaes", budget=budget, seed=seed)
        if res.gains is None:
            raise ValueError(f"the CMA-ES search found no gains: {res.reason}")
        return res.gains

    return gains_at
