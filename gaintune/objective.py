"""Cost of a gain set: performance vs effort plus penalties, over scenarios and plant draws.

Per scenario::

    cost_s = perf + effort_weight*int((u-u0)^2) + tv_weight*TV(u)
             + overshoot_weight*max(0, overshoot - overshoot_limit)
             + settling_weight*settling_time

``perf`` is IAE, ISE or ITAE of the outer loop. Scenario costs are summed by
scenario weight. A diverged simulation costs :data:`DIVERGED_COST`. With
several plant draws per gain set (robust mode) the draws are aggregated by
their mean, worst case or CVaR.

:class:`Evaluator` is the one batched cost function that the RL search, the
black-box baselines and the reference optimum all share.
"""

from __future__ import annotations

import numpy as np

from gaintune.plants.plant import Plant
from gaintune.sim import SimResult, Simulator
from gaintune.sim import draws as draws_mod
from gaintune.sim.draws import Draws
from gaintune.spec import ObjectiveSpec, ScenarioSpec, TuningSpec

__all__ = ["DIVERGED_COST", "scenario_cost", "aggregate", "Evaluator"]

#: Cost given to a diverged run: finite, so optimisers can rank it, and far above any real cost.
DIVERGED_COST = 1e6


def scenario_cost(m: dict[str, np.ndarray], obj: ObjectiveSpec, sc: ScenarioSpec) -> np.ndarray:
    """Cost of one scenario's metrics (each (B,)); diverged runs get DIVERGED_COST."""
    settle = np.where(np.isnan(m["settling_time"]), sc.horizon, m["settling_time"])
    with np.errstate(invalid="ignore"):  # inf * 0 weight on diverged rows; those rows are replaced below
        cost = (
            m[obj.measure]
            + obj.effort_weight * m["effort"]
            + obj.tv_weight * m["tv"]
            + obj.overshoot_weight * np.maximum(0.0, np.nan_to_num(m["overshoot"]) - obj.overshoot_limit)
            + obj.settling_weight * settle
        )
    bad = m["diverged"] | ~np.isfinite(cost)
    return np.where(bad, DIVERGED_COST, np.minimum(cost, DIVERGED_COST))


def aggregate(costs: np.ndarray, how: str, alpha: float = 0.2) -> np.ndarray:
    """Aggregate (B, K) costs over the K draws: mean, worst (max) or CVaR of the worst alpha."""
    if how == "mean":
        return costs.mean(axis=1)
    if how == "worst":
        return costs.max(axis=1)
    k = max(1, int(np.ceil(alpha * costs.shape[1])))
    return np.sort(costs, axis=1)[:, -k:].mean(axis=1)


class Evaluator:
    """Batched cost of tuned-gain vectors for one spec.

    Each gain set is simulated on every scenario and on K plant draws (K =
    ``spec.search.robust.samples``; K = 1 uses the nominal plant). The draws are
    fixed at construction (common random numbers), so the cost is a
    deterministic function of the gains: what the optimisers need.

    Attributes
    ----------
    n_sims : int
        Closed-loop simulations run so far (gain sets x draws x scenarios).
    """

    def __init__(self, spec: TuningSpec, sim: Simulator | None = None, draws: Draws | None = None) -> None:
        self.spec = spec
        if sim is None:
            from gaintune.controllers.layout import search_layout
            from gaintune.plants import build_plant

            plant = build_plant(spec.plant)
            sim = Simulator(spec, plant, search_layout(spec, plant))
        self.sim = sim
        self.plant: Plant = self.sim.plant
        self.layout = self.sim.layout
        rob = spec.search.robust
        if draws is None:
            if rob.samples > 1:
                rng = np.random.default_rng(spec.search.seed + 7919)
                draws = draws_mod.sample(spec, self.plant, rng, rob.samples)
            else:
                draws = self.sim.nominal_draws(1)
        self.draws = draws
        self.n_sims = 0

    @property
    def dim(self) -> int:
        return self.layout.n_tuned

    def run(self, tuned: np.ndarray, traces: bool = False) -> tuple[np.ndarray, list[SimResult]]:
        """Costs (B,) and the raw per-scenario results (batch of B*K rows, draw-major per gain set)."""
        tuned = np.atleast_2d(np.asarray(tuned, dtype=float))
        B, K = tuned.shape[0], len(self.draws)
        full = np.repeat(self.layout.full(tuned), K, axis=0)
        d = draws_mod.take(self.draws, np.tile(np.arange(K), B))
        total = np.zeros(B * K)
        diverged = np.zeros(B * K, dtype=bool)
        results = []
        for i, sc in enumerate(self.spec.scenarios):
            res = self.sim.run(full, d, i, traces=traces)
            cost = scenario_cost(res.metrics, self.spec.objective, sc)
            total += sc.weight * cost
            diverged |= cost >= DIVERGED_COST
            results.append(res)
        self.n_sims += B * K * len(self.spec.scenarios)
        # a diverged simulation costs DIVERGED_COST whatever its scenario's weight
        total = np.where(diverged, DIVERGED_COST, np.minimum(total, DIVERGED_COST))
        rob = self.spec.search.robust
        return aggregate(total.reshape(B, K), rob.aggregate, rob.alpha), results

    def __call__(self, tuned: np.ndarray) -> np.ndarray:
        """Costs (B,) of B tuned-gain vectors (lower is better)."""
        return self.run(tuned)[0]

    def cost_of_action(self, action: np.ndarray) -> np.ndarray:
        """Costs of actions in [-1, 1]^d (the RL parameterisation)."""
        return self(self.layout.action_to_tuned(action))
