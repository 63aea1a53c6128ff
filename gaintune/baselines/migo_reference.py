"""The MIGO boundary optimum of a PI problem with an Ms limit: the exact per-plant reference.

Max ki subject to Ms <= limit, then the plain cost minimised along the constraint boundary
``ki = ki_max(kp)`` (:func:`gaintune.classical.migo.boundary_optimum`), computed on the loop
verification analyses (the sampled loop: ZOH plant with its delay and the backward-Euler
integral; the continuous loop plus dt/2 when ``verify.sampled`` is off) and scored by the
simulator. The ``standard`` benchmark suite and the trained tuners' validation use it.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import numpy as np

__all__ = ["migo_reference"]


class _SampledResponse:
    """The sampled loop verification analyses (ZOH plant, backward-Euler integral) as a frequency response.

    ``integrator(w)`` is the integral law's response (:mod:`gaintune.classical.migo` uses it when present).
    """

    def __init__(self, sp: Any, m: int, dt: float) -> None:
        self.sp, self.m, self.dt = sp, m, dt

    def __call__(self, w: np.ndarray) -> np.ndarray:
        w = np.asarray(w, dtype=float)
        return self.sp.responses(np.exp(1j * w.ravel() * self.dt))[1][:, self.m].reshape(w.shape)

    def integrator(self, w: np.ndarray) -> np.ndarray:
        """dt / (1 - e^{-jw dt}): the backward-Euler integral."""
        return self.dt / (1.0 - np.exp(-1j * np.asarray(w, dtype=float) * self.dt))


def _migo_loop(spec: Any, plant: Any, lin: Any, m: int, dt: float) -> tuple[Callable[[np.ndarray], np.ndarray], float]:
    """The loop's frequency response as verification sees it, and the top of its frequency range (rad/s)."""
    from gaintune.lti.modes import plant_state_response
    from gaintune.verification.analysis import sampling_delay
    from gaintune.verification.sampled import sample_plant

    if spec.verify.sampled:
        sp = sample_plant(lin, dt, spec.verify.compute_delay, plant.kind == "nonlinear")
        return _SampledResponse(sp, m, dt), np.pi / dt
    T = lin.delay + sampling_delay(spec)

    def G(w: np.ndarray) -> np.ndarray:
        w = np.asarray(w, dtype=float)
        s = 1j * w.ravel()
        y = plant_state_response(lin, s) @ lin.C[m] + lin.D[m, 0]
        return (y * np.exp(-s * T)).reshape(w.shape)

    return G, 10 * np.pi / dt


def _migo_grid(lin: Any, dt: float, w_top: float, sampled: bool) -> np.ndarray:
    """2,000 log-spaced frequencies from 1/1000 of the slowest pole (or 1/(delay + dt)) to the top."""
    poles = np.linalg.eigvals(lin.A) if lin.A.size else np.zeros(0)
    T_all = lin.delay + dt
    fast = max([abs(p) for p in poles if abs(p) > 1e-9] + [1.0 / T_all] + [1e-3])
    slow = min([abs(p) for p in poles if abs(p) > 1e-9] + [fast])
    top = w_top * (1 - 1e-9) if sampled else min(fast * 100.0, w_top)  # sampled: up to pi/dt
    return np.geomspace(slow / 1000.0, top, 2000)


def migo_reference(problem: Any, evaluator: Any) -> dict[str, Any] | None:
    """The MIGO boundary optimum of a PI problem with an Ms limit, scored by ``evaluator``.

    The loop is the one verification analyses: the plant's linearisation, its delay plus
    the dt/2 sample-and-hold delay, and C = kp + ki/s. Returns ``{"gains", "cost", "method",
    "migo": {...}, "feasible"}`` or None when the problem is not a single parallel PI loop
    with an Ms limit, or MIGO has no point for it (a reverse-acting plant, no stable PI under the limit).
    """
    from gaintune.classical.migo import boundary_optimum

    spec = evaluator.spec
    loop = spec.loops[0]
    ms = spec.requirements.ms_max
    if len(spec.loops) != 1 or loop.type != "pi" or loop.form != "parallel" or ms is None:
        return None
    lin = evaluator.plant.linearize()
    m = lin.output_index(loop.measure) if loop.measure else 0
    dt = max(sc.dt for sc in spec.scenarios)
    G, w_top = _migo_loop(spec, evaluator.plant, lin, m, dt)
    w = _migo_grid(lin, dt, w_top, spec.verify.sampled)

    def cost(kp: np.ndarray, ki: np.ndarray) -> np.ndarray:
        tuned = np.column_stack([kp, ki])
        n0 = evaluator.n_sims
        s = evaluator.evaluate(tuned)
        evaluator.n_sims = n0  # the reference's own scoring is not a search budget
        return np.where(s.diverged, np.nan, s.cost)

    if [sl.name for sl in evaluator.layout.tuned_slots] != ["Kp", "Ki"]:
        return None
    try:
        migo, best = boundary_optimum(G, ms, w, cost)
    except ValueError:  # no MIGO point (a reverse-acting plant, no stable PI under the limit): it does not apply
        return None
    gains = {loop.name: {"Kp": float(best.kp), "Ki": float(best.ki)}}
    s = evaluator.evaluate(np.array([[best.kp, best.ki]]))
    return {
        "gains": gains,
        "cost": float(s.cost[0]),
        "feasible": bool(s.feasible[0]),
        "method": "MIGO boundary optimum (max ki s.t. Ms <= limit, then IAE along ki = ki_max(kp))",
        "migo": {"kp": migo.kp, "ki": migo.ki, "ms": migo.ms, "cost": migo.cost},
        "ms": float(best.ms),
    }
