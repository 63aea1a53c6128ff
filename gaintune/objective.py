"""Cost of a gain set: performance vs effort plus penalties, over scenarios and plant draws.

Per scenario::

    cost_s = perf + effort_weight*int((u-u0)^2) + tv_weight*TV(u)
             + overshoot_weight*max(0, overshoot - overshoot_limit)
             + settling_weight*settling_time

``perf`` is IAE, ISE or ITAE of the outer loop. Scenario costs are summed by
scenario weight. A diverged simulation costs :data:`DIVERGED_COST`. With
several plant draws per gain set (robust mode) the draws are aggregated by
their mean, worst case or CVaR. The search objective multiplies the cost by
``1 + margin_weight * requirement_penalty`` (:func:`penalized`), so every
optimiser is steered to gains that pass verification and compares like with like.

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

__all__ = ["DIVERGED_COST", "MAX_PENALTY_CORNERS", "scenario_cost", "aggregate", "penalized", "Evaluator"]

#: Cost given to a diverged run: finite, so optimisers can rank it, and far above any real cost.
DIVERGED_COST = 1e6
#: At most this many corners of the randomisation box enter the requirement penalty.
MAX_PENALTY_CORNERS = 8
#: How far inside the spec's limits the search aims (the penalty is an estimate; verification is exact).
DESIGN_MARGIN = {"gm_db": 0.5, "pm_deg": 2.0, "dm_factor": 1.05, "peak_factor": 0.97}


def penalized(cost: np.ndarray, penalty: np.ndarray, weight: float) -> np.ndarray:
    """The search objective: ``cost * (1 + weight * penalty)``; equal to the cost when the requirements hold.

    ``penalty`` is the cheap requirement estimate of :func:`gaintune.verify.quick.requirement_penalty`
    (0 when every requirement passes). Diverged runs stay at DIVERGED_COST.
    """
    out = np.minimum(cost * (1.0 + weight * np.asarray(penalty)), DIVERGED_COST)
    return np.where(cost >= DIVERGED_COST, DIVERGED_COST, out)


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

    @property
    def penalty_models(self) -> list:
        """Linear models the requirement penalty is checked on: nominal plus the randomisation box corners.

        Verification gates on the worst case over these corners (and Monte-Carlo draws), so the
        search objective sees the same corners.
        """
        if getattr(self, "_penalty_models", None) is None:
            import dataclasses

            spec, plant = self.spec, self.plant
            models = [plant.linearize()]
            if spec.randomize.params or spec.randomize.delay:
                c = draws_mod.corners(spec, plant, max_corners=MAX_PENALTY_CORNERS)
                for i in range(len(c)):
                    lin = plant.linearize(dict(zip(plant.param_names, c.params[i])))
                    models.append(dataclasses.replace(lin, delay=float(c.delay[i])))
            self._penalty_models = models
        return self._penalty_models

    def _design_spec(self) -> TuningSpec:
        """The spec with requirements tightened by :data:`DESIGN_MARGIN`.

        The penalty is a cheap estimate (coarse frequency grid, box corners only) while
        verification also checks Monte-Carlo draws: aiming slightly inside the limits
        makes the frozen gains pass instead of landing on the boundary.
        """
        if getattr(self, "_design", None) is None:
            r = self.spec.requirements
            m = DESIGN_MARGIN
            tight = r.model_copy(update={
                "gm_min_db": None if r.gm_min_db is None else r.gm_min_db + m["gm_db"],
                "pm_min_deg": None if r.pm_min_deg is None else r.pm_min_deg + m["pm_deg"],
                "dm_min": None if r.dm_min is None else r.dm_min * m["dm_factor"],
                "ms_max": None if r.ms_max is None else max(1.0 + 1e-6, r.ms_max * m["peak_factor"]),
                "mt_max": None if r.mt_max is None else r.mt_max * m["peak_factor"],
            })
            self._design = self.spec.model_copy(update={"requirements": tight})
        return self._design

    def requirement_penalty(self, tuned: np.ndarray) -> np.ndarray:
        """(B,) worst-case requirement penalty over :attr:`penalty_models` (0 when all requirements hold)."""
        tuned = np.atleast_2d(np.asarray(tuned, dtype=float))
        if self.spec.objective.margin_weight <= 0:
            return np.zeros(tuned.shape[0])
        from gaintune.verify.quick import requirement_penalty

        full = self.layout.full(tuned)
        spec = self._design_spec()
        pens = [requirement_penalty(spec, self.plant, self.layout, full, lin) for lin in self.penalty_models]
        return np.nan_to_num(np.max(pens, axis=0), nan=10.0, posinf=10.0)

    def run(
        self, tuned: np.ndarray, traces: bool = False, penalize: bool = True
    ) -> tuple[np.ndarray, list[SimResult]]:
        """Costs (B,) and the raw per-scenario results (batch of B*K rows, draw-major per gain set).

        With ``penalize`` (default) the cost is the search objective :func:`penalized`;
        otherwise the plain objective.
        """
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
        cost = aggregate(total.reshape(B, K), rob.aggregate, rob.alpha)
        if penalize and self.spec.objective.margin_weight > 0:
            cost = penalized(cost, self.requirement_penalty(tuned), self.spec.objective.margin_weight)
        return cost, results

    def __call__(self, tuned: np.ndarray) -> np.ndarray:
        """Search objective (B,) of B tuned-gain vectors (lower is better)."""
        return self.run(tuned)[0]

    def cost_of_action(self, action: np.ndarray) -> np.ndarray:
        """Costs of actions in [-1, 1]^d (the RL parameterisation)."""
        return self(self.layout.action_to_tuned(action))
