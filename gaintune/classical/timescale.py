"""Default sample time and horizon of a scenario, derived from the plant's time scale.

A scenario that leaves ``dt`` or ``horizon`` out gets values scaled to the plant, so the
cost sees the whole closed-loop response whatever the plant's speed (a fixed 20 s would
cut a 60 s process short, and a slow integral action would look free). Each loop's path
(actuator to its measured output, other loops open) gives two times:

* the **settling scale** ``S``: ``T + L`` of the path's FOTD model (:func:`fit_fotd`),
  ``8 L`` for an integrating path (the SIMC integral time with ``tau_c = L``), or, where no
  FOTD model applies, the slowest pole's time constant (damped to at least :data:`DAMPING`)
  plus the delay, and with integrators at least ``8 (delay + every lag)``; an outer loop's
  ``S`` is at least that of the loop inside it;
* the **fast scale**: the FOTD dead time ``L`` (plant delay plus the smaller lags), the
  part of the path that bounds the closed loop's speed.

Then (for a cascade, the outer loop's path sets the horizon and the fastest loop ``dt``)::

    horizon = last reference/disturbance event + HORIZON_FACTOR x max S
    dt      = min(L / DELAY_SAMPLES, S_loop x HORIZON_FACTOR / MIN_STEPS over the loops)

with horizon/dt held to at most :data:`STEP_CAP` steps (``dt`` is raised, which is exact for a
linear plant: it is stepped by its ZOH discretisation). A nonlinear plant is stepped by one RK4
step per sample, so its ``dt`` also stays below ``RK4_SPAN / |fastest pole|`` of its
linearisation, up to the spec's :data:`~gaintune.spec.MAX_STEPS`. ``dt`` is rounded down and the
horizon up to two significant digits. A plant with no time scale at all (a static gain, a pure
integrator without delay) keeps the fixed defaults :data:`FALLBACK_DT` and :data:`FALLBACK_HORIZON`.

Values a scenario gives are kept. The delay used is the largest the spec allows (the top of
``randomize.delay``); plant parameters are at their nominal values.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

import numpy as np

from gaintune.classical.fotd import NoModelError, fit_fotd, path_poles_zeros, siso_minreal
from gaintune.controllers.direction import measured_indices
from gaintune.errors import SpecError
from gaintune.lti.statespace import StateSpace, one_stable_lag
from gaintune.plants.plant import Plant, build_plant, is_mimo_plant
from gaintune.spec import MAX_STEPS, ScenarioDefault, ScenarioSpec, TuningSpec

__all__ = ["LoopScale", "PlantScale", "plant_scale", "resolve_scenarios", "scenario_defaults",
           "HORIZON_FACTOR", "DELAY_SAMPLES", "MIN_STEPS", "STEP_CAP", "RK4_SPAN", "FALLBACK_DT", "FALLBACK_HORIZON"]

#: Horizon = this many settling scales after the last event.
HORIZON_FACTOR = 10.0
#: Samples per FOTD dead time (the fast end of a loop).
DELAY_SAMPLES = 20
#: Least samples per loop horizon (resolves a delay-free loop made much faster than its plant).
MIN_STEPS = 2000
#: Most samples per derived scenario (simulation cost); dt is raised above it.
STEP_CAP = 20_000
#: Least samples a derived horizon keeps after the scenario's last event: with fewer, the response to it is not
#: simulated (a step at 1 s on a plant of 1e-12 s was simulated to 1 s exactly, and its cost 0 passed).
MIN_WINDOW_STEPS = 50
#: A nonlinear plant's dt stays below RK4_SPAN / |fastest pole| (accuracy of one RK4 step).
RK4_SPAN = 0.5
#: Least damping assumed of an oscillatory pole in closed loop (the scale of a path with no FOTD model).
DAMPING = 0.5
#: Used when the plant has no time scale (static gain, pure integrator without delay).
FALLBACK_DT = 0.01
FALLBACK_HORIZON = 20.0


@dataclass(frozen=True)
class LoopScale:
    """Time scales of one loop's path: ``settle`` (S) and ``fast`` (L), in seconds, and how they were read."""

    loop: str
    settle: float
    fast: float
    basis: str


@dataclass(frozen=True)
class PlantScale:
    """The derived ``dt`` and horizon (after t = 0) for a spec's plant, and why."""

    dt: float
    horizon: float
    loops: tuple[LoopScale, ...]
    #: Why this horizon, and why this dt.
    why_horizon: str
    why_dt: str
    #: Largest dt a nonlinear plant's RK4 step allows (inf for a linear plant).
    dt_max: float = math.inf


def _g(x: float) -> str:
    return f"{x:.3g}"


def _one_lag(sys: StateSpace) -> float | None:
    """The time constant T = -1/a of a path that is one stable lag (:func:`gaintune.lti.statespace.one_stable_lag`),
    with L = the delay what :func:`~gaintune.classical.fotd.fit_fotd`'s half rule gives it; else None."""
    a = one_stable_lag(sys.A, sys.B, sys.C, sys.D)
    return None if a is None else -1.0 / a


def _path_scale(name: str, sys: StateSpace, delay: float) -> LoopScale:
    """Settling and fast scales of one SISO path (delay-free part ``sys`` plus ``delay`` s)."""
    lag = _one_lag(sys)
    if lag is not None:  # fit_fotd's model, read directly
        return LoopScale(name, lag + delay, delay, f"FOTD T {_g(lag)} s, L {_g(delay)} s, S = T + L")
    try:
        m = fit_fotd(sys, delay)
    except (NoModelError, ValueError, ArithmeticError, np.linalg.LinAlgError):
        m = None
    if m is not None and m.integrating:
        return LoopScale(name, 8.0 * m.L, m.L, f"integrating, FOTD dead time L {_g(m.L)} s, S = 8 L")
    if m is not None:
        return LoopScale(name, m.T + m.L, m.L, f"FOTD T {_g(m.T)} s, L {_g(m.L)} s, S = T + L")
    try:
        p, _ = path_poles_zeros(siso_minreal(sys))
    except (ValueError, ArithmeticError, np.linalg.LinAlgError):
        p = np.linalg.eigvals(np.asarray(sys.A, float)) if np.size(sys.A) else np.zeros(0)
    moving = np.abs(p) > 1e-12 * max(1.0, float(np.max(np.abs(p), initial=0.0)))
    p, n_int = p[moving], int(np.sum(~moving))
    # a pole's decay time once the loop damps it to at least DAMPING (a real pole: 1/|p|)
    zeta = np.maximum(np.abs(p.real) / np.abs(p), DAMPING) if p.size else p.real
    taus = 1.0 / (np.abs(p) * zeta)
    slow = float(np.max(taus, initial=0.0))
    settle, basis = slow + delay, f"slowest pole {_g(slow)} s (damping >= {DAMPING:g}), delay {_g(delay)} s"
    if n_int:  # integrators: as an integrating path, every lag counted as dead time (S = 8 L)
        settle = max(settle, 8.0 * (delay + float(np.sum(taus))))
        basis += f", {n_int} integrator(s): S = max(slowest + delay, 8 (delay + lags))"
    else:
        basis += ", S = slowest + delay"
    return LoopScale(name, settle, delay, "no FOTD model; " + basis)


def _round_down(x: float) -> float:
    """``x`` rounded down to two significant digits."""
    e = math.floor(math.log10(x)) - 1
    return float(f"{math.floor(x / 10.0**e * (1 + 1e-9)) * 10.0**e:.12g}")


def _round_up(x: float) -> float:
    """``x`` rounded up to two significant digits."""
    e = math.floor(math.log10(x)) - 1
    return float(f"{math.ceil(x / 10.0**e * (1 - 1e-9)) * 10.0**e:.12g}")


def plant_scale(spec: TuningSpec, plant: Plant) -> PlantScale:
    """The plant-derived ``dt`` and horizon (counted from the last event) of ``spec``'s scenarios."""
    if is_mimo_plant(plant):
        return _scale_of(spec, plant, _mimo_paths(spec, plant), math.inf)
    lin = plant.linearize()
    delay = float(lin.delay)
    if spec.randomize.delay is not None:
        delay = max(delay, float(spec.randomize.delay.box[1]))
    A, B, C, D = (np.asarray(x, float) for x in (lin.A, lin.B, lin.C, lin.D))
    loops = []
    for j, m in enumerate(measured_indices(spec, list(lin.outputs))):
        sys = StateSpace(A, B, C[m:m + 1, :], D[m:m + 1, :])
        loops.append(_path_scale(spec.loops[j].name or f"loop{j}", sys, delay))
    for j in range(len(loops) - 2, -1, -1):  # an outer loop is no faster than the loop inside it
        if loops[j].settle < loops[j + 1].settle:
            loops[j] = replace(loops[j], settle=loops[j + 1].settle,
                               basis=loops[j].basis + f"; raised to S of the inner loop {loops[j + 1].loop}")
    dt_max = math.inf
    if plant.kind == "nonlinear" and A.size:
        fastest = float(np.max(np.abs(np.linalg.eigvals(A)), initial=0.0))
        dt_max = RK4_SPAN / fastest if fastest > 0 else math.inf
    return _scale_of(spec, plant, loops, dt_max)


def _mimo_paths(spec: TuningSpec, plant) -> list[LoopScale]:
    """Each loop's path of a MIMO plant: from the input its chain ends on to the output it measures."""
    from gaintune.lti.mimo import TfMatrix
    from gaintune.spec.mimo import chain_input

    lti = plant.lti()
    out = []
    for i, lp in enumerate(spec.loops):
        name = lp.name or f"loop{i}"
        j = plant.input_names.index(chain_input(spec, i) or plant.input_names[0])
        o = plant.outputs.index(lp.measure or plant.outputs[0])
        if isinstance(lti, TfMatrix):
            e = lti.entries[o][j]
            if e.is_zero:
                out.append(LoopScale(name, 0.0, 0.0, "no path from its input"))
                continue
            A, B, C, D = e.realisation()
            out.append(_path_scale(name, StateSpace(A, B, C, D), e.delay))
        else:
            sys = StateSpace(lti.A, lti.B[:, j:j + 1], lti.C[o:o + 1, :], lti.D[o:o + 1, j:j + 1])
            out.append(_path_scale(name, sys, float(lti.input_delays[j])))
    return out


def _scale_of(spec: TuningSpec, plant, loops: list[LoopScale], dt_max: float) -> PlantScale:
    """dt and horizon from the loops' path scales (see :func:`plant_scale`)."""
    slow = max(loops, key=lambda s: s.settle)
    if not slow.settle > 0:
        why = "the plant has no time scale (no lag, no delay)"
        return PlantScale(FALLBACK_DT, FALLBACK_HORIZON, tuple(loops), f"{why}: the fixed default horizon",
                          "the fixed default dt", dt_max)
    horizon = _round_up(HORIZON_FACTOR * slow.settle)
    cands = [(s.fast / DELAY_SAMPLES, f"{s.loop} L/{DELAY_SAMPLES}") for s in loops if s.fast > 0]
    cands += [(HORIZON_FACTOR * s.settle / MIN_STEPS, f"{s.loop} {HORIZON_FACTOR:g} S/{MIN_STEPS}")
              for s in loops if s.settle > 0]
    if dt_max < math.inf:
        cands.append((dt_max, f"RK4 step {RK4_SPAN:g}/|fastest pole|"))
    dt, why = min(cands)
    why_h = f"horizon {HORIZON_FACTOR:g} x S of {slow.loop} ({slow.basis})"
    if len(loops) > 1:
        why_h += f"; loops: {', '.join(f'{s.loop} S {_g(s.settle)} s' for s in loops)}"
    return PlantScale(_round_down(dt), horizon, tuple(loops), why_h, f"dt {why}", dt_max)


def _fill(i: int, sc: ScenarioSpec, ps: PlantScale, t_event: float) -> tuple[ScenarioSpec, ScenarioDefault]:
    """Scenario ``i`` (``sc``) with its missing dt/horizon derived from ``ps``, and the record of the choice."""
    notes = []
    horizon = sc.horizon
    if horizon is None:
        horizon = t_event + ps.horizon
        notes.append(ps.why_horizon)
        if t_event > 0:
            notes.append(f"starts after the last event at {t_event:g} s")
    dt = sc.dt
    if dt is None:
        dt = ps.dt
        if sc.horizon is not None and _round_down(horizon / MIN_STEPS) < dt:
            dt = _round_down(horizon / MIN_STEPS)
            notes.append(f"dt = the given horizon/{MIN_STEPS}")
        else:
            notes.append(ps.why_dt)
        if horizon / dt > STEP_CAP:
            # exact for a linear plant (ZOH); a nonlinear one's RK4 step keeps its bound
            cap = _round_up(horizon / STEP_CAP)
            dt = max(dt, cap if ps.dt_max == math.inf else min(cap, _round_down(ps.dt_max)))
            notes.append(f"dt raised to keep horizon/dt <= {STEP_CAP} steps")
    if sc.horizon is None:
        horizon = max(_round_up(horizon), 2 * dt)  # a given dt may be coarse: at least 2 samples
        if horizon - t_event < (1 - 1e-6) * ps.horizon:  # rounding up to two digits (with its 1e-9 guard against
            horizon = t_event + ps.horizon  # float fuzz) took 1 + 1e-11 s down to 1 s: the window after the event
        if horizon / dt > MAX_STEPS:
            horizon = float(f"{MAX_STEPS * dt:.12g}")
            notes.append(f"horizon shortened to the limit of {MAX_STEPS} steps")
        _check_window(i, t_event, horizon, dt, ps)
    elif horizon / dt < 2:
        raise SpecError(f"scenarios[{i}].horizon", f"{horizon:g} s is shorter than 2 samples of the dt derived from "
                        f"the plant ({dt:g} s); give a longer horizon, or a dt")
    filled = sc.model_copy(update={"dt": float(dt), "horizon": float(horizon)})
    reason = "; ".join(notes)
    rec = ScenarioDefault(scenario=sc.name, dt=float(dt), horizon=float(horizon),
                          dt_from="spec" if sc.dt is not None else "plant",
                          horizon_from="spec" if sc.horizon is not None else "plant", reason=reason)
    return filled, rec


def _check_window(i: int, t_event: float, horizon: float, dt: float, ps: PlantScale) -> None:
    """SpecError naming the scenario when the derived horizon and dt leave the response to its last event fewer
    than :data:`MIN_WINDOW_STEPS` samples: after the event, or across the plant's settling window (an event many
    windows after the start, with the step count capped, raises dt past the loop's own time scale: a step at
    1e9 s on a 1 s plant was simulated at dt = 51,000 s)."""
    samples = min((horizon - t_event) / dt, ps.horizon / dt)
    if t_event <= 0 or samples >= MIN_WINDOW_STEPS:
        return
    raise SpecError(f"scenarios[{i}]", f"its last event at {t_event:g} s is {t_event / ps.horizon:.3g} times the "
                    f"plant's settling window ({ps.horizon:.3g} s) after the start; simulated to it in at most "
                    f"{STEP_CAP} steps (dt {dt:g} s), the response to it gets {max(samples, 0.0):.3g} samples; "
                    "put the event nearer t = 0, or give the scenario's dt and horizon")


def _event_time(spec: TuningSpec, sc: ScenarioSpec) -> float:
    t = sc.last_event()
    rz = spec.randomize.disturbance_time
    if rz is not None and sc.disturbance.kind != "none":
        t = max(t, float(rz.box[1]))
    return t


def scenario_defaults(spec: TuningSpec, plant: Plant | None = None) -> tuple[TuningSpec, list[ScenarioDefault]]:
    """``spec`` with every missing scenario ``dt``/``horizon`` derived from the plant, and one record per such scenario.

    The spec is returned as it is (the same object, no records) when every scenario gives both.

    Raises
    ------
    SpecError
        When the plant cannot be built, or a given horizon is shorter than two derived samples.
    """
    todo = [i for i, sc in enumerate(spec.scenarios) if not sc.resolved]
    if not todo:
        return spec, []
    ps = plant_scale(spec, plant if plant is not None else build_plant(spec.plant))
    scenarios = list(spec.scenarios)
    records = []
    for i in todo:
        scenarios[i], rec = _fill(i, scenarios[i], ps, _event_time(spec, scenarios[i]))
        records.append(rec)
    return _with_scenarios(spec, scenarios), records


def _with_scenarios(spec: TuningSpec, scenarios: list[ScenarioSpec]) -> TuningSpec:
    """``spec`` with ``scenarios`` (its own, with dt/horizon filled in), checked as a full validation checks them.

    Only the scenarios' dt and horizon differ from the validated ``spec``, so only the checks that read them
    can fail: each scenario's (horizon/dt within the step limits) and the spec's delay-in-samples bound.
    Those run here on a copy (a full re-validation of the spec cost ~1/20 of a tuner query); should one
    fail, the spec is validated in full, which raises the located error a user sees.
    """
    out = spec.model_copy(update={"scenarios": scenarios})
    try:
        checked = [ScenarioSpec.model_validate(sc.model_dump()) for sc in scenarios]
        out = spec.model_copy(update={"scenarios": checked})
        out._check_delay_steps()
    except ValueError:  # pydantic's ValidationError is one
        return TuningSpec.model_validate(out.model_dump())
    return out


def resolve_scenarios(spec: TuningSpec, plant: Plant | None = None) -> TuningSpec:
    """``spec`` with every scenario's ``dt`` and ``horizon`` a number (see :func:`scenario_defaults`)."""
    return scenario_defaults(spec, plant)[0]
