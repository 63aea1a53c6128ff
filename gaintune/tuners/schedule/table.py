"""The gain schedule itself: one loop's gains at grid points of a scheduling variable, and their interpolation.

A :class:`GainSchedule` holds the tuning spec, the scheduling variable ``var`` (a plant
parameter, e.g. the water tank's operating level ``H0``), the increasing ``grid`` of its
values, and the loop's gains at each grid point, in the loop's own (parallel) form. Between
grid points the gains are interpolated linearly in ``var``, clamped at the ends
(:func:`gains_between`); every export and the Python law do the same
(:mod:`gaintune.export.schedule`). Its JSON form is versioned (:data:`SCHEDULE_VERSION`).
"""

from __future__ import annotations

import json
import math
from collections.abc import Callable
from pathlib import Path
from typing import Any, Literal

import numpy as np
from pydantic import BaseModel, ConfigDict, Field, PrivateAttr, ValidationError

from gaintune.errors import GaintuneError, SpecError, problem_details
from gaintune.export.common import _version
from gaintune.export.schedule import MAX_BREAKPOINTS, ScheduleTable
from gaintune.files import read_text_bounded
from gaintune.spec import Gains, TuningSpec, load_spec
from gaintune.tuners.schedule.law import interp

__all__ = ["SCHEDULE_VERSION", "GainSchedule", "parse_grid", "check_grid", "spec_at", "build_schedule",
           "gains_between", "load_schedule", "schedule_table", "schedules_on_measurement"]

#: Version of the schedule file's layout; a file of another version is refused (field ``version``).
SCHEDULE_VERSION = 1


class GainSchedule(BaseModel):
    """One loop's gains over a grid of a scheduling variable (JSON round trip: :meth:`to_json`, :func:`load_schedule`).

    Attributes
    ----------
    spec
        The tuning spec (as data), its scenarios' ``dt`` and horizon resolved at the nominal plant.
    var
        The scheduling variable: a plant parameter.
    grid
        Its values, strictly increasing.
    loop
        The scheduled loop (the spec's only loop).
    gains
        The loop's gains at each grid point, ``{gain: value}`` in the loop's form.
    dt
        The sample time the schedule runs (and is verified) at.
    method
        How the gains at the grid points were found (free text).
    fitted
        The factor :func:`~gaintune.tuners.schedule.fit.fit_midpoints` applied to the gains answered at each
        grid point so that the midpoints pass (None: not fitted).
    """

    model_config = ConfigDict(extra="forbid", ser_json_inf_nan="strings")

    format: Literal["gaintune-gain-schedule"] = "gaintune-gain-schedule"
    version: int = SCHEDULE_VERSION
    spec: dict[str, Any]
    var: str
    grid: list[float]
    loop: str
    gains: list[dict[str, float]]
    dt: float = Field(gt=0)
    method: str = ""
    fitted: list[float] | None = None
    generator: str = Field(default_factory=lambda: f"gaintune {_version()}")
    _spec: TuningSpec | None = PrivateAttr(None)

    @property
    def tuning_spec(self) -> TuningSpec:
        """The spec as a validated :class:`TuningSpec` (built once)."""
        if self._spec is None:
            self._spec = load_spec(self.spec)
        return self._spec

    @property
    def midpoints(self) -> list[float]:
        """The value halfway between each pair of neighbouring grid points."""
        return [0.5 * (a + b) for a, b in zip(self.grid, self.grid[1:], strict=False)]

    def table(self, name: str) -> list[float]:
        """The column of gain ``name`` over the grid (0.0 where a point has no such gain)."""
        return [float(g.get(name, 0.0)) for g in self.gains]

    def to_json(self) -> str:
        """The schedule as JSON text (:func:`load_schedule` reads it back)."""
        return self.model_dump_json(indent=2) + "\n"


# ------------------------------------------------------------------------------------------- grid


def check_grid(values: list[float]) -> list[float]:
    """``values`` as floats when they are 2 .. MAX_BREAKPOINTS finite, strictly increasing numbers; else SpecError."""
    try:
        grid = [float(v) for v in values]
    except (TypeError, ValueError):
        raise SpecError("grid", f"every grid value must be a number, got {values!r}") from None
    if not 2 <= len(grid) <= MAX_BREAKPOINTS:
        raise SpecError("grid", f"needs 2 to {MAX_BREAKPOINTS} points, got {len(grid)}")
    if not all(math.isfinite(v) for v in grid):
        raise SpecError("grid", f"every grid value must be finite, got {grid}")
    if any(b <= a for a, b in zip(grid, grid[1:], strict=False)):
        raise SpecError("grid", f"values must be strictly increasing, got {grid}")
    return grid


def parse_grid(text: str) -> list[float]:
    """Grid points from ``start:stop:count`` (``count`` evenly spaced points, both ends included) or ``a,b,c``.

    >>> parse_grid("2:20:10")
    [2.0, 4.0, 6.0, 8.0, 10.0, 12.0, 14.0, 16.0, 18.0, 20.0]
    >>> parse_grid("2, 5, 10")
    [2.0, 5.0, 10.0]
    """
    if not isinstance(text, str) or not text.strip():
        raise SpecError("grid", "give start:stop:count (e.g. 2:20:10) or a comma list (e.g. 2,5,10)")
    if ":" in text:
        parts = text.split(":")
        if len(parts) != 3:
            raise SpecError("grid", f"{text!r}: give start:stop:count, e.g. 2:20:10")
        try:
            start, stop = float(parts[0]), float(parts[1])
            count = int(parts[2])
        except ValueError:
            raise SpecError("grid", f"{text!r}: start and stop must be numbers and count an integer, "
                                    "e.g. 2:20:10") from None
        if not 2 <= count <= MAX_BREAKPOINTS:
            raise SpecError("grid", f"{text!r}: count must be 2 .. {MAX_BREAKPOINTS}, got {count}")
        if not (math.isfinite(start) and math.isfinite(stop)) or not start < stop:
            raise SpecError("grid", f"{text!r}: needs finite start < stop")
        return check_grid([float(v) for v in np.linspace(start, stop, count)])
    try:
        values = [float(p) for p in text.split(",")]
    except ValueError:
        raise SpecError("grid", f"{text!r}: a comma list of numbers, e.g. 2,5,10") from None
    return check_grid(values)


# ------------------------------------------------------------------------------------------- spec


def _check_problem(spec: TuningSpec, var: str) -> None:
    """SpecError unless the spec has one PID loop in parallel form and ``var`` is one of its plant's parameters."""
    from gaintune.plants import build_plant

    if len(spec.loops) != 1:
        raise SpecError("loops", f"a gain schedule is for one loop; this spec has {len(spec.loops)} "
                                 "(schedule a single-loop spec)")
    loop = spec.loops[0]
    if loop.is_lq:
        raise SpecError("loops.0.type", f"a gain schedule interpolates PID gains; a {loop.type} loop has none "
                                        "(use p, pi, pd or pid)")
    if loop.form != "parallel":
        raise SpecError("loops.0.form", "a gain schedule interpolates the parallel gains Kp, Ki, Kd; "
                                        "set form: parallel")
    params = build_plant(spec.plant).params
    if var not in params:
        raise SpecError("var", f"{var!r} is not a parameter of the plant; its parameters are "
                               f"{', '.join(params) or 'none'}")


def spec_at(spec: TuningSpec, var: str, value: float) -> TuningSpec:
    """``spec`` with the plant parameter ``var`` frozen at ``value`` (and no longer randomised)."""
    d = spec.model_dump()
    plant = d["plant"]
    model = plant.get("model")
    if isinstance(model, dict) and var in (model.get("params") or {}):
        model["params"][var] = float(value)  # a model's own overrides win over plant.params
    else:
        plant.setdefault("params", {})[var] = float(value)
    d["randomize"]["params"].pop(var, None)
    try:
        return load_spec(d)
    except ValidationError as exc:
        first = problem_details(exc)[0]
        raise SpecError("grid", f"at {var} = {value:g}: {first['loc']}: {first['msg']}") from None


def schedules_on_measurement(spec: TuningSpec, var: str, grid: list[float]) -> bool:
    """Whether ``var`` is the operating level of the loop's measured output at every grid point.

    Then the controller schedules on its own measurement (the water tank's ``H0`` is the level
    ``h`` at the operating point); otherwise on a measured value of ``var`` itself.
    """
    from gaintune.plants import build_plant

    plant = build_plant(spec.plant)
    m = plant.outputs.index(spec.loops[0].measure) if spec.loops[0].measure else 0
    for v in grid:
        y0 = float(plant.linearize(plant.with_params({var: v})).y0[m])
        if not abs(y0 - v) <= 1e-9 * max(1.0, abs(v)):
            return False
    return True


def build_schedule(spec: TuningSpec, var: str, grid: list[float], gains_at: Callable[[TuningSpec], Gains],
                   method: str = "") -> GainSchedule:
    """The schedule of ``spec``'s loop over ``grid``: ``gains_at`` answers the gains at each grid point.

    Parameters
    ----------
    spec
        A single-loop PID spec (parallel form). Its scenarios' ``dt`` and horizon are resolved at the
        nominal plant first, so every grid point runs at one sample time.
    var
        The scheduling variable, a plant parameter.
    grid
        Its values, strictly increasing (see :func:`parse_grid`).
    gains_at
        Called with the spec frozen at each grid point (``plant.params[var]`` set, :func:`spec_at`);
        returns ``{loop: {gain: value}}``.
    method
        How ``gains_at`` finds its gains, recorded in the schedule.

    Raises
    ------
    SpecError
        Naming ``loops``, ``var`` or ``grid`` when the problem cannot be scheduled, or ``gains`` when
        ``gains_at`` answered no finite gains for the loop.
    """
    from gaintune.classical.timescale import resolve_scenarios
    from gaintune.export.verdict import verified_dt

    grid = check_grid(grid)
    _check_problem(spec, var)
    spec = resolve_scenarios(spec)  # one dt and horizon for every grid point: those of the nominal plant
    loop = spec.loop_names[0]
    rows = []
    for v in grid:
        answer = gains_at(spec_at(spec, var, v))
        row = (answer or {}).get(loop)
        if not row or not all(isinstance(g, (int, float)) and math.isfinite(g) for g in row.values()):
            raise SpecError("gains", f"at {var} = {v:g} the gains of loop {loop!r} are missing or not finite: {row}")
        rows.append({k: float(g) for k, g in row.items()})
    return GainSchedule(spec=spec.model_dump(mode="json"), var=var, grid=grid, loop=loop, gains=rows,
                        dt=verified_dt(spec), method=method)


def gains_between(schedule: GainSchedule, value: float) -> Gains:
    """The loop's gains at ``value``: linear interpolation in ``var`` between grid points, clamped at the ends."""
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
        raise SpecError("value", f"the scheduling value must be a finite number, got {value!r}")
    names = list(schedule.gains[0])
    return {schedule.loop: {g: interp(schedule.grid, schedule.table(g), float(value)) for g in names}}


# ------------------------------------------------------------------------------------------- files


def load_schedule(source: GainSchedule | dict[str, Any] | str | Path) -> GainSchedule:
    """A schedule from its JSON (a path, the text, or the parsed dict); SpecError naming the bad field.

    A file of another :data:`SCHEDULE_VERSION` is refused (field ``version``).
    """
    if isinstance(source, GainSchedule):
        return source
    data: Any = source
    if isinstance(source, Path) or (isinstance(source, str) and not source.lstrip().startswith(("{", "["))):
        data = read_text_bounded(source, "schedule")
    if isinstance(data, str):
        try:
            data = json.loads(data)
        except json.JSONDecodeError as exc:
            raise SpecError("schedule", f"not valid JSON: {exc.msg} at line {exc.lineno}") from None
    if not isinstance(data, dict):
        raise SpecError("schedule", "must be a JSON object (a gain schedule written by gaintune)")
    if data.get("version") != SCHEDULE_VERSION:
        raise SpecError("version", f"this gaintune reads gain schedules of version {SCHEDULE_VERSION}, the file has "
                                   f"{data.get('version')!r}; re-create the schedule with this gaintune")
    try:
        sched = GainSchedule.model_validate(data)
    except ValidationError as exc:
        first = problem_details(exc)[0]
        raise SpecError(first["loc"] or "schedule", first["msg"]) from None
    try:
        check_grid(sched.grid)
        _check_problem(sched.tuning_spec, sched.var)
    except ValidationError as exc:
        first = problem_details(exc)[0]
        raise SpecError(f"spec.{first['loc']}", first["msg"]) from None
    if len(sched.gains) != len(sched.grid) or sched.loop not in sched.tuning_spec.loop_names:
        raise SpecError("gains", f"needs one gain set of loop {sched.loop!r} per grid point ({len(sched.grid)})")
    return sched


def schedule_table(schedule: GainSchedule, verdict: str | None = None, reasons: list[str] | None = None,
                   schedule_on: str | None = None) -> ScheduleTable:
    """The schedule as the plain data the exports and the Python law take (gains resolved to parallel form)."""
    from gaintune.plants import build_plant

    spec = schedule.tuning_spec
    loop = spec.loops[0]
    plant = build_plant(spec.plant)
    i0 = [float(plant.linearize(plant.with_params({schedule.var: v})).u0) for v in schedule.grid]
    lo, hi = spec.actuator.limits or (-math.inf, math.inf)
    if schedule_on is None:
        schedule_on = "measurement" if schedules_on_measurement(spec, schedule.var, schedule.grid) else "parameter"
    try:
        return ScheduleTable(
            name=spec.name, var=schedule.var, loop=schedule.loop, measure=loop.measure or plant.outputs[0],
            type=loop.type, grid=tuple(schedule.grid), kp=tuple(schedule.table("Kp")), ki=tuple(schedule.table("Ki")),
            kd=tuple(schedule.table("Kd")), i0=tuple(i0), dt=schedule.dt, b=loop.b, c=loop.c, aw=loop.anti_windup,
            N=loop.filter.N or 10.0, Tf=loop.filter.Tf, tracking_time=loop.tracking_time, lo=float(lo), hi=float(hi),
            rate_limit=spec.actuator.rate_limit, schedule_on=schedule_on, verdict=verdict,
            reasons=tuple(reasons or ()), spec_hash=spec.content_hash())
    except GaintuneError as exc:
        raise SpecError(exc.field, exc.message) from None
