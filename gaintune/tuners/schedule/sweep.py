"""Closed-loop simulation of a scheduled controller on the nonlinear plant, and the sweep over the operating range.

The simulator (:mod:`gaintune.sim`) runs fixed gains; a schedule re-interpolates its gains
every sample, so this module steps the plant itself, in a plain Python loop, as the
simulator's kernel does: the plant's own casadi right-hand side ``f(x, u, p)`` and output
map ``h(x, u, p)`` (:mod:`gaintune.plants.plant`), RK4 with the input held over the sample,
whole-sample input delay, then the controller (:class:`~gaintune.tuners.schedule.law.ScheduledPid`,
the law of the exported C header) with the actuator limits, anti-windup and rate limit.
For a constant table it reproduces the simulator's trace (a test pins it to 1e-9).

**What the controller schedules on.** When ``var`` is the operating level of the loop's
measured output (the water tank's ``H0`` is the level ``h`` at the operating point), the
gains are interpolated at the *measured* output, sample by sample. The gains of a grid
point were designed for the plant linearised where the plant *is*; the measurement says
where that is, also in the middle of a large step, where the reference would already
apply the gains of the destination level to a plant still at the start (at 2 m the tank's
gain is a third of that at 20 m). A ``var`` that is not an output level (a load, a speed
parameter) is scheduled on its own value, which the sweep changes stepwise.

**The sweep.** From equilibrium at the lowest grid value, ``var`` steps to each grid value
in turn up to the highest and back down, each held ``hold`` seconds (default: the spec's
first scenario horizon, the time it allows a step to settle); the reference is the
operating output at each value (for ``H0``: the level itself). The sweep passes when the
safety monitor never trips, nothing diverges, and at the end of every hold the tracking
error has settled: ``|r - y|`` over the last 10 % of the hold stays within ``settle_band``
(2 %) of the sweep's largest reference step.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from functools import cached_property
from typing import Any

import numpy as np
from pydantic import BaseModel, Field

from gaintune.export.schedule import ScheduleTable
from gaintune.plants.plant import Plant
from gaintune.tuners.schedule.law import ScheduledPid
from gaintune.tuners.schedule.table import GainSchedule, schedule_table

__all__ = ["Run", "ScheduleModel", "SweepSegment", "SweepReport", "sweep_levels", "nonlinear_sweep"]

SETTLE_BAND = 0.02
#: Fraction of each hold whose error must stay within the band.
TAIL = 0.1


@dataclass
class Run:
    """One closed-loop run: the traces up to where it stopped, and why it stopped."""

    r: np.ndarray
    y: np.ndarray
    u: np.ndarray
    x: np.ndarray  # the scheduling value each sample
    dt: float
    tripped: bool = False
    diverged: bool = False
    stop_time: float | None = None
    note: str = ""

    @property
    def iae(self) -> float:
        """Integral of ``|r - y|`` (as the simulator's ``iae``); inf when the run stopped early."""
        return math.inf if self.stop_time is not None else float(np.sum(np.abs(self.r - self.y)) * self.dt)


@dataclass
class _Rk4:
    """The plant's RK4 step with the input held over the sample, and its output map, as casadi Functions."""

    plant: Plant
    dt: float
    step: Any = field(init=False)  # casadi.Function (no type stubs)

    def __post_init__(self) -> None:
        import casadi as ca

        f = self.plant.f
        if f is None:
            raise ValueError("the scheduled simulation steps ODE plants only")
        n, npar = self.plant.order, len(self.plant.params)
        x, u, p = ca.SX.sym("x", n), ca.SX.sym("u"), ca.SX.sym("p", npar)
        h = 0.5 * self.dt
        k1 = f(x, u, p)
        k2 = f(x + h * k1, u, p)
        k3 = f(x + h * k2, u, p)
        k4 = f(x + self.dt * k3, u, p)
        xn = x + self.dt / 6.0 * (k1 + 2.0 * k2 + 2.0 * k3 + k4)  # the kernel's update_rk4, term for term
        self.step = ca.Function("rk4", [x, u, p], [xn])


class ScheduleModel:
    """What every run of one schedule shares: the plant, its stepper, the safety limits, the operating points."""

    def __init__(self, schedule: GainSchedule, table: ScheduleTable | None = None) -> None:
        from gaintune.plants import build_plant

        self.schedule = schedule
        self.spec = spec = schedule.tuning_spec
        self.table = table if table is not None else schedule_table(schedule)
        self.plant = plant = build_plant(spec.plant)
        self.dt = schedule.dt
        self.on_measurement = self.table.schedule_on == "measurement"
        self.meas = plant.outputs.index(self.table.measure)
        self.ivar = plant.param_names.index(schedule.var)
        sf = spec.safety
        self.max_err = sf.max_abs_error or math.inf
        self.max_out = sf.max_abs_output or math.inf
        self.xbound = np.array([sf.state_bounds.get(s, math.inf) for s in plant.states])
        self.div = sf.divergence_bound

    @cached_property
    def rk4(self) -> _Rk4:
        """The plant's sample step (built on first use: casadi)."""
        if self.plant.kind != "nonlinear":
            raise ValueError("the scheduled simulation steps ODE plants only")
        return _Rk4(self.plant, self.dt)

    def operating(self, value: float) -> tuple[np.ndarray, float, float]:
        """(x0, u0, y0 of the measured output) of the plant with ``var`` at ``value``."""
        lin = self.plant.linearize({self.schedule.var: float(value)})
        return np.array(lin.x0, dtype=float), float(lin.u0), float(lin.y0[self.meas])

    def _check(self, x: np.ndarray, y_all: np.ndarray, r: float, y: float) -> str:
        """Why the run must stop at this sample ('' when it goes on): divergence, then the safety monitor."""
        if not (np.all(np.abs(x) <= self.div) and np.all(np.abs(y_all) <= self.div)):
            return "diverged"
        if abs(r - y) > self.max_err or abs(y) > self.max_out or np.any(np.abs(x) > self.xbound):
            return "tripped"
        return ""

    def run(self, law: ScheduledPid, ref: np.ndarray, values: np.ndarray, i0: float | None = None) -> Run:
        """Simulate from equilibrium at ``values[0]``: reference ``ref[k]``, ``var`` = ``values[k]`` each sample.

        ``i0``: the integrator start (default: the table's, interpolated at the first scheduling value).
        """
        step, h = self.rk4.step, self.plant.h
        assert h is not None  # an ODE plant has its output map
        x, u0, _ = self.operating(values[0])
        p = self.plant.param_vector({self.schedule.var: float(values[0])})
        d = int(round(self.plant.delay() / self.dt))  # whole samples, as the simulator's nonlinear plants
        n = len(ref)
        out = {k: np.zeros(n) for k in ("y", "u", "x")}

        def applied(j: int) -> float:  # the input applied at sample j; the operating input before the start
            return float(out["u"][j]) if j >= 0 else u0

        for k in range(n):
            if values[k] != p[self.ivar]:
                p[self.ivar] = values[k]
            y_all = np.asarray(h(x, applied(k - 1 - d), p), dtype=float).ravel()
            y = float(y_all[self.meas])
            why = self._check(x, y_all, float(ref[k]), y)
            if why:
                return self._stopped(out, ref, k, why)
            xs = y if self.on_measurement else float(values[k])
            if k == 0:
                law.reset(xs, i0)
            out["u"][k] = law.step(float(ref[k]), y, xs)
            out["y"][k], out["x"][k] = y, xs
            x = np.asarray(step(x, applied(k - d), p), dtype=float).ravel()
        return Run(np.asarray(ref, dtype=float), out["y"], out["u"], out["x"], self.dt)

    def _stopped(self, out: dict[str, np.ndarray], ref: np.ndarray, k: int, why: str) -> Run:
        t = k * self.dt
        note = (f"the safety monitor tripped at t = {t:g} s" if why == "tripped"
                else f"the simulation diverged at t = {t:g} s")
        return Run(np.asarray(ref[:k], dtype=float), out["y"][:k], out["u"][:k], out["x"][:k], self.dt,
                   tripped=why == "tripped", diverged=why == "diverged", stop_time=t, note=note)


# ---------------------------------------------------------------------------------------------- sweep


class SweepSegment(BaseModel):
    """One hold of the sweep: the step into ``level`` and how it settled."""

    start: float = Field(description="Time the hold starts (s).")
    level_from: float
    level: float
    iae: float = Field(description="Integral of |r - y| over the hold.")
    final_error: float = Field(description="|r - y| at the end of the hold.")
    tail_error: float = Field(description="Largest |r - y| over the last 10 % of the hold.")
    settled: bool


class SweepReport(BaseModel):
    """The nonlinear sweep of a schedule over its operating range (see the module docstring)."""

    ran: bool
    passed: bool = False
    schedule_on: str = ""
    hold: float = 0.0
    dt: float = 0.0
    settle_tol: float = 0.0
    tripped: bool = False
    diverged: bool = False
    stop_time: float | None = None
    note: str = ""
    segments: list[SweepSegment] = Field(default_factory=list)


def sweep_levels(grid: list[float]) -> list[float]:
    """The sweep's values of ``var``: every grid value upward, then back down to the first."""
    return [*grid, *grid[-2::-1]]


def _segments(run: Run, levels: list[float], refs: list[float], k_hold: int, tol: float) -> list[SweepSegment]:
    e = np.abs(run.r - run.y)
    tail = max(1, int(round(TAIL * k_hold)))
    out = []
    for j, lev in enumerate(levels):
        seg = e[j * k_hold:(j + 1) * k_hold]
        if seg.size < k_hold:
            break
        out.append(SweepSegment(start=j * k_hold * run.dt, level_from=levels[max(j - 1, 0)], level=lev,
                                iae=float(seg.sum() * run.dt), final_error=float(seg[-1]),
                                tail_error=float(seg[-tail:].max()), settled=bool(seg[-tail:].max() <= tol)))
    return out


def nonlinear_sweep(schedule: GainSchedule, model: ScheduleModel | None = None, hold: float | None = None,
                    settle_band: float = SETTLE_BAND) -> SweepReport:
    """Sweep the schedule's controller over the operating range on the nonlinear plant (module docstring)."""
    model = model if model is not None else ScheduleModel(schedule)
    if model.plant.kind != "nonlinear":
        return SweepReport(ran=False, note="the sweep needs a nonlinear (ODE) plant; an LTI plant is verified at "
                                           "the frozen grid points and midpoints only")
    spec = model.spec
    hold = float(hold if hold is not None else spec.scenarios[0].resolved_horizon)
    k_hold = max(2, int(round(hold / model.dt)))
    levels = sweep_levels(schedule.grid)
    refs = [model.operating(v)[2] for v in levels]
    values = np.repeat(levels, k_hold)
    ref = np.repeat(refs, k_hold)
    steps = [abs(b - a) for a, b in zip(refs, refs[1:], strict=False)]
    tol = settle_band * (max(steps) if max(steps, default=0.0) > 0 else max(1.0, max(abs(r) for r in refs)))
    run = model.run(ScheduledPid(model.table), ref, values)
    segs = _segments(run, levels, refs, k_hold, tol)
    stopped = run.tripped or run.diverged
    unsettled = [s for s in segs if not s.settled]
    note = run.note or (f"not settled within {tol:.3g} at the end of the hold at {schedule.var} = "
                        f"{unsettled[0].level:g} (error {unsettled[0].tail_error:.3g})" if unsettled else "")
    return SweepReport(ran=True, passed=not stopped and not unsettled, schedule_on=model.table.schedule_on,
                       hold=hold, dt=model.dt, settle_tol=tol, tripped=run.tripped, diverged=run.diverged,
                       stop_time=run.stop_time, note=note, segments=segs)
