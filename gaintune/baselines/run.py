"""One entry point for every baseline: :func:`run_baseline(spec, method) <run_baseline>`."""

from __future__ import annotations

import math
import time
from typing import Any

import numpy as np
from pydantic import BaseModel, ConfigDict, Field

from gaintune.baselines.optimizers import optimize
from gaintune.classical.fotd import NoModelError
from gaintune.classical.timescale import resolve_scenarios
from gaintune.classical.tuning import CLASSICAL_METHODS, tune_classical
from gaintune.evaluation.boundary_exact import onto_boundary_exact, violation_after
from gaintune.evaluation.evaluator import DIVERGED_COST
from gaintune.spec import Gains, TuningSpec

__all__ = ["METHODS", "BaselineResult", "run_baseline", "make_evaluator"]

#: Every baseline name accepted by :func:`run_baseline`.
METHODS: tuple[str, ...] = (*CLASSICAL_METHODS, "random", "cmaes", "de", "nelder_mead", "reference")


class BaselineResult(BaseModel):
    """Outcome of one baseline on one spec (JSON-serialisable)."""

    model_config = ConfigDict(extra="forbid")

    method: str
    gains: Gains | None = Field(None, description="{loop: {gain: value}}; None when the method does not apply.")
    reason: str | None = Field(None, description="Why gains is None.")
    fotd: dict[str, dict[str, Any]] = Field(default_factory=dict, description="FOTD model per loop (rule methods).")
    ultimate: dict[str, dict[str, float]] = Field(default_factory=dict, description="Ku, Pu per loop (zn_ultimate).")
    n_sims: int = Field(0, description="Simulations spent (search and scoring).")
    wall_time: float = 0.0
    cost: float | None = Field(None, description="Plain cost of the gains (lower is better); None without evaluator.")
    feasible: bool | None = Field(
        None, description="The gains met every requirement (search estimate); None without evaluator."
    )
    violation: float | None = Field(None, description="Requirement violation of the gains (0 = feasible).")
    settle: dict[str, Any] | None = Field(None, description="What the exact boundary step did (optimisers only).")
    history: list[tuple[int, float]] = Field(
        default_factory=list,
        description="(simulations, best feasible cost so far) for optimisers, from the first feasible candidate on.",
    )
    details: dict[str, Any] = Field(default_factory=dict)


def make_evaluator(spec: TuningSpec) -> Any:
    """The evaluator every baseline searches with: the problem's default search box.

    See :mod:`gaintune.evaluation.search_box`.
    """
    from gaintune.evaluation.search_box import make_evaluator as on_search_box

    return on_search_box(spec)


def _tuned_from_gains(layout: Any, gains: Gains) -> np.ndarray:
    full = layout.from_dict(gains)
    return np.asarray(full)[layout.tuned_idx]


def _finite(c: float | None) -> float | None:
    return float(c) if c is not None and math.isfinite(c) else None


def run_baseline(
    spec: TuningSpec,
    method: str,
    *,
    budget: int | None = None,
    seed: int | None = None,
    evaluator: Any = None,
    settle_answer: bool = True,
    **options: Any,
) -> BaselineResult:
    """Run baseline ``method`` (one of :data:`METHODS`) on ``spec``.

    Parameters
    ----------
    budget
        Simulation budget of the optimisers (default ``spec.search.budget``);
        ignored by rules. ``reference`` uses its own (``restarts`` x ``sims_per_restart``).
    seed
        Default ``spec.search.seed``.
    evaluator
        Cost function (default ``gaintune.evaluation.evaluator.Evaluator(spec)``). Rules are
        scored with it when available; optimisers need it.
    settle_answer
        Settle an optimiser's answer on the requirements by exact verification
        (:func:`gaintune.evaluation.boundary_exact.onto_boundary_exact`), as the RL search does.
    options
        Passed to the optimiser (e.g. ``popsize``) or :func:`reference_optimum`.

    A rule that does not apply (LQ loop, unstable or oscillatory path, negative
    gain, ...) gives ``gains=None`` and a ``reason``; it never raises.
    """
    if method not in METHODS:
        raise ValueError(f"unknown baseline {method!r}; choose from {', '.join(METHODS)}")
    t0 = time.perf_counter()
    seed = spec.search.seed if seed is None else seed
    spec = resolve_scenarios(spec, getattr(evaluator, "plant", None))  # dt/horizon left out: from the plant
    ev = evaluator if evaluator is not None else make_evaluator(spec)
    if method in CLASSICAL_METHODS:
        out = _run_rule(spec, method, ev)
    else:
        out = _run_optimiser(spec, method, ev, budget or spec.search.budget, seed, settle_answer, options)
    out.wall_time = time.perf_counter() - t0
    return out


def _run_rule(spec: TuningSpec, method: str, ev: Any) -> BaselineResult:
    """A classical rule's gains, scored with ``ev`` (``gains=None`` and a reason when the rule does not apply)."""
    from gaintune.plants import build_plant

    plant = getattr(ev, "plant", None) or build_plant(spec.plant)
    from gaintune.sim.simulator import needs_mimo

    if needs_mimo(spec, plant):  # several inputs or a loop graph: the rule loop by loop, on each loop's own path
        from gaintune.classical.mimo_rules import loop_rule_candidates

        gains = loop_rule_candidates(spec, plant).get(method)
        if gains is None:
            return BaselineResult(method=method, reason=f"{method} does not apply loop by loop here (every loop must "
                                  "drive a plant input on a path the rule can model; no chains, ties or decoupler)")
        out = BaselineResult(method=method, gains=gains, details={"per_loop": True})
    else:
        try:
            res = tune_classical(spec, plant, method)
        except NoModelError as exc:
            return BaselineResult(method=method, reason=str(exc))
        out = BaselineResult(
            method=method,
            gains=res.gains,
            fotd={k: m.to_dict() for k, m in res.fotd.items()},
            ultimate={k: {"Ku": v[0], "Pu": v[1]} for k, v in res.ultimate.items()},
            details={"pid_ideal": {k: {"Kc": p.Kc, "Ti": p.Ti, "Td": p.Td} for k, p in res.pid.items()}},
        )
    if ev is not None and out.gains is not None:
        before = int(getattr(ev, "n_sims", 0))
        tuned = _tuned_from_gains(ev.layout, out.gains)
        sc = ev.evaluate(tuned[None, :])
        out.cost = _finite(float(sc.cost[0]))
        out.violation, out.feasible = float(sc.violation[0]), bool(sc.feasible[0])
        out.n_sims = int(getattr(ev, "n_sims", 0)) - before
        if out.cost is None or out.cost >= DIVERGED_COST:
            out.details["diverged"] = True
    return out


def _run_optimiser(
    spec: TuningSpec, method: str, ev: Any, budget: int, seed: int, settle_answer: bool, options: dict[str, Any]
) -> BaselineResult:
    """An optimiser's (or the reference's) best gains, settled on the requirements when ``settle_answer``."""
    if method == "reference":
        from gaintune.baselines.reference import reference_optimum

        r = reference_optimum(spec, ev, seed=seed, **options)
    else:
        r = optimize(ev, method, budget, seed, **options)
    layout = ev.layout
    tuned, cost, violation, settled = r.tuned, r.cost, r.violation, None
    if settle_answer:
        # the same exact last step as the RL search (gaintune.evaluation.boundary_exact), so methods compare alike
        st = onto_boundary_exact(ev, r.tuned, cost=r.cost if r.feasible else None)
        settled = {"action": st.action, "alpha": st.alpha, "loop": st.loop, "margin": st.margin, "checks": st.checks}
        if st.action in ("pulled_inside", "pushed_to_boundary"):
            sc = ev.evaluate(st.tuned[None, :])
            tuned, cost, violation = st.tuned, float(sc.cost[0]), violation_after(st, sc)
    return BaselineResult(
        method=method,
        gains=layout.to_dict(layout.full(tuned)),
        n_sims=r.n_sims,
        cost=_finite(cost),
        violation=violation,
        feasible=violation <= 0,
        settle=settled,
        history=[(int(a), float(b)) for a, b in r.history if math.isfinite(b)],
        details={**_jsonable(r.details), "n_evals": r.n_evals, "seed": seed},
    )


def _jsonable(d: Any) -> Any:
    if isinstance(d, dict):
        return {str(k): _jsonable(v) for k, v in d.items()}
    if isinstance(d, (list, tuple)):
        return [_jsonable(v) for v in d]
    if isinstance(d, (np.floating, np.integer)):
        return d.item()
    if isinstance(d, np.ndarray):
        return d.tolist()
    return d


