"""Nonlinear check: simulate the frozen gains with saturation, rate limits and every scenario.

Uses :mod:`gaintune.sim` (imported lazily): ``Simulator(spec, plant, layout).run(full, None, i)``
for every scenario ``i`` when available, else ``simulate(spec, gains_full (B, n_gains), draws=None,
traces=False)`` returning one ``SimResult`` or a list of them (one per scenario), each with
``metrics`` a dict of (B,) arrays including ``diverged`` and ``tripped``. Nominal plant draw.
The check passes when no run diverges and the safety monitor never trips.

``verify.compute_delay = c`` samples of computation delay are simulated as c*dt of extra
input delay on the nominal draw (whole samples: the same z^-c the sampled analysis uses).
"""

from __future__ import annotations

import importlib
from dataclasses import replace
from typing import TYPE_CHECKING, Any

import numpy as np

from gaintune.controllers.layout import GainLayout
from gaintune.errors import SpecError
from gaintune.plants.plant import Plant
from gaintune.spec import ScenarioSpec, TuningSpec
from gaintune.verification.report import NonlinearReport

if TYPE_CHECKING:  # gaintune.sim loads numba: imported where it runs
    from gaintune.sim import SimResult, Simulator

__all__ = ["nonlinear_check", "settling_notes"]

_SUMMARY = ("iae", "overshoot", "settling_time", "sat_frac")


def _run_all(sim: Simulator, spec: TuningSpec, full: np.ndarray, compute_delay: int) -> list[SimResult]:
    """Every scenario on the nominal draw (the computation delay as extra input delay)."""
    if not compute_delay:
        return [sim.run(full, None, i) for i in range(len(spec.scenarios))]
    base = sim.nominal_draws(full.shape[0])
    return [sim.run(full, replace(base, delay=base.delay + compute_delay * _dt(sc)), i)
            for i, sc in enumerate(spec.scenarios)]


def _dt(sc: ScenarioSpec) -> float:
    """The scenario's sample time (SpecError before it is derived from the plant)."""
    if sc.dt is None:
        raise SpecError(f"scenario {sc.name!r} dt", "not set yet: derive it from the plant first "
                        "(gaintune.classical.timescale.resolve_scenarios) or give it in the spec")
    return sc.dt


def nonlinear_check(spec: TuningSpec, plant: Plant, layout: GainLayout, full_gains: np.ndarray,
                    sim: Simulator | None = None, compute_delay: int = 0) -> NonlinearReport:
    """Run the simulator on one full gain vector; ``ran=False`` when :mod:`gaintune.sim` is unavailable.

    ``sim``: a :class:`gaintune.sim.Simulator` of this spec to reuse (its discretisation memo stays warm).
    ``compute_delay``: samples of computation delay, simulated as that many samples of extra input delay.
    """
    full = np.atleast_2d(np.asarray(full_gains, dtype=float))
    bound = float(spec.safety.divergence_bound)
    if sim is not None:
        return _report(_run_all(sim, spec, full, compute_delay), bound)
    try:
        simmod = importlib.import_module("gaintune.sim")
        simulate = simmod.simulate
    except (ImportError, AttributeError) as exc:
        return NonlinearReport(ran=False, note=f"simulator unavailable ({exc.__class__.__name__}: {exc})")
    runner = getattr(simmod, "Simulator", None)
    if runner is not None:
        results = _run_all(runner(spec, plant, layout), spec, full, compute_delay)
    else:
        results = simulate(spec, full, draws=None, traces=False)
    return _report(results, bound)


def _report(results: Any, bound: float) -> NonlinearReport:
    """The check's verdict from the simulator's results (one per scenario, or one for all); ``bound`` is the
    spec's ``safety.divergence_bound``, named in the note of a diverged run."""
    if not isinstance(results, (list, tuple)):
        results = [results]
    parts: dict[str, list[np.ndarray]] = {}
    for res in results:
        m = getattr(res, "metrics", None)
        if m is None and isinstance(res, dict):
            m = res.get("metrics", res)
        for k, v in dict(m or {}).items():
            parts.setdefault(k, []).append(np.atleast_1d(np.asarray(v)))
    metrics = {k: np.concatenate(v) for k, v in parts.items()}

    def flag(name: str) -> bool | None:
        if name not in metrics:
            return None
        return bool(np.any(np.asarray(metrics[name]).astype(bool)))

    tripped, diverged = flag("tripped"), flag("diverged")
    summary: dict[str, float] = {"scenarios": float(len(results))}
    for k in _SUMMARY:
        if k in metrics:
            v = np.asarray(metrics[k], dtype=float)
            if v.size and np.all(np.isfinite(v)):
                summary[k] = float(np.max(v))  # worst over scenarios
    passed = not bool(tripped) and not bool(diverged)
    note = ""
    if tripped is None or diverged is None:
        note = "simulator did not report tripped/diverged"
    elif tripped:
        note = "safety monitor tripped"
    elif diverged:
        # a plant whose signals are large in its own units passes a bound that suits a unit plant: say which
        note = (f"simulation diverged (a signal passed safety.divergence_bound = {bound:g}, or became NaN or "
                "inf); where the loop is stable and the plant's signals are this large, raise safety.divergence_bound")
    return NonlinearReport(ran=True, passed=passed, tripped=tripped, diverged=diverged, metrics=summary, note=note)


def settling_notes(spec: TuningSpec, sim: Simulator | None, plant: Plant, layout: GainLayout,
                   full: np.ndarray) -> list[str]:
    """A note per scenario whose response has not settled by its end (:mod:`gaintune.sim.settling`)."""
    from gaintune.sim import Simulator
    from gaintune.sim.settling import settling_messages

    return settling_messages(sim or Simulator(spec, plant, layout), full)
