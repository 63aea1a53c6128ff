"""The tuning problem as the environments see it: gains in, reward and metrics out, batched.

:class:`GainProblem` builds the plant, the gain layout (bounds from a classical
rule when the spec gives none), the simulator and the cost evaluator once, and
scores a batch of gain sets in ONE simulator call per scenario. Every env in
:mod:`gaintune.envs` and the search share it, so reward arithmetic lives here only.

Reward of one gain set (all terms are O(1))::

    reward = -( min(cost * (1 + margin_weight * requirement_penalty) / cost_scale, COST_CAP)
                + divergence_penalty * diverged
                + trip_penalty * tripped )

``cost`` is the objective of :mod:`gaintune.objective` (aggregated over the
robust draws), ``cost_scale`` the cost of the classical-rule gains on the
nominal plant, and ``requirement_penalty`` the cheap frequency-domain estimate
of how far the gains are from the spec's requirements (0 when they pass).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from gaintune.controllers.layout import GainLayout, search_layout
from gaintune.objective import DIVERGED_COST, Evaluator, aggregate, penalized, scenario_cost
from gaintune.plants import build_plant
from gaintune.plants.checks import validate_against_plant
from gaintune.sim import Simulator
from gaintune.sim import draws as draws_mod
from gaintune.sim.draws import Draws
from gaintune.spec import TuningSpec

__all__ = ["COST_CAP", "GainProblem", "Scored"]

#: Cost ratios above this are clipped, so failures cannot swamp the learning signal.
COST_CAP = 10.0



@dataclass
class Scored:
    """Scores of B gain sets."""

    reward: np.ndarray  # (B,)
    cost: np.ndarray  # (B,) search objective: aggregated cost x (1 + w * penalty); DIVERGED_COST when diverged
    diverged: np.ndarray  # (B,) bool: any draw diverged
    tripped: np.ndarray  # (B,) bool: the safety monitor tripped on any draw
    margin_penalty: np.ndarray  # (B,)
    metrics: dict[str, np.ndarray]  # first scenario, first draw of each gain set


class GainProblem:
    """Plant, layout, simulator and reward for one spec.

    Parameters
    ----------
    spec
        The tuning problem.
    use_auto_bounds
        Centre log-scale bounds on a classical rule where the spec gives none.
    """

    def __init__(self, spec: TuningSpec, use_auto_bounds: bool = True) -> None:
        self.spec = spec
        plant = build_plant(spec.plant)
        validate_against_plant(spec, plant)
        self.layout = search_layout(spec, plant) if use_auto_bounds else GainLayout(spec, plant.states)
        self.plant = plant
        self.sim = Simulator(spec, plant, self.layout)
        self.evaluator = Evaluator(spec, self.sim)
        self.lin = plant.linearize()
        self.k = spec.search.robust.samples
        self._score_sims = 0
        self.randomized = spec.randomize.active
        self.obs_size = draws_mod.context_size(spec)
        self.cost_scale = self._cost_scale()
        #: Optional hook called as ``on_score(tuned, scored)`` after every env scoring (search monitor).
        self.on_score = None

    @property
    def n_sims(self) -> int:
        """Every closed-loop simulation run for this problem (env batches and evaluator calls)."""
        return self._score_sims + self.evaluator.n_sims

    @property
    def dim(self) -> int:
        return self.layout.n_tuned

    def _cost_scale(self) -> float:
        """Cost of the initial (classical-rule) gains, or the median of random finite costs."""
        c = float(self.evaluator(self.layout.initial_tuned()[None])[0])
        if 0 < c < DIVERGED_COST:
            return c
        rng = np.random.default_rng(self.spec.search.seed)
        costs = self.evaluator(self.layout.action_to_tuned(rng.uniform(-1, 1, (64, self.dim))))
        ok = costs[costs < DIVERGED_COST]
        return float(np.median(ok)) if ok.size else 1.0

    # ------------------------------------------------------------- draws
    def draw(self, rng: np.random.Generator, n: int) -> Draws:
        """n episodes' draws: sampled from spec.randomize, or nominal when nothing is randomised."""
        if self.randomized:
            return draws_mod.sample(self.spec, self.plant, rng, n)
        d = draws_mod.nominal(self.spec, self.plant, n)
        return draws_mod.take(d, np.arange(n)) if n else d

    def context(self, d: Draws) -> np.ndarray:
        """Observation rows for draws (constant zeros when nothing is randomised)."""
        return draws_mod.context(self.spec, self.plant, d)

    # ------------------------------------------------------------- score
    def score(self, tuned: np.ndarray, draws: Draws) -> Scored:
        """Score B tuned-gain vectors; ``draws`` has B*K rows (K robust draws per gain set, draw-major)."""
        tuned = np.atleast_2d(np.asarray(tuned, dtype=float))
        B = tuned.shape[0]
        K = len(draws) // B
        full = np.repeat(self.layout.full(tuned), K, axis=0)
        total = np.zeros(B * K)
        diverged = np.zeros(B * K, dtype=bool)
        tripped = np.zeros(B * K, dtype=bool)
        first = None
        spec = self.spec
        for i, sc in enumerate(spec.scenarios):
            res = self.sim.run(full, draws, i)
            total += sc.weight * scenario_cost(res.metrics, spec.objective, sc)
            diverged |= res.metrics["diverged"]
            tripped |= res.metrics["tripped"]
            if first is None:
                first = {k: v[::K] for k, v in res.metrics.items()}
        self._score_sims += B * K * len(spec.scenarios)
        rob = spec.search.robust
        cost = aggregate(np.minimum(total, DIVERGED_COST).reshape(B, K), rob.aggregate, rob.alpha)
        div = diverged.reshape(B, K).any(axis=1)
        trip = tripped.reshape(B, K).any(axis=1)
        obj = spec.objective
        margin = self.evaluator.requirement_penalty(tuned)
        cost = penalized(cost, margin, obj.margin_weight)
        ratio = np.minimum(cost / self.cost_scale, COST_CAP)
        reward = -(ratio + obj.divergence_penalty * div + obj.trip_penalty * trip)
        assert first is not None
        scored = Scored(reward.astype(np.float64), cost, div, trip, margin, first)
        if self.on_score is not None:
            self.on_score(tuned, scored)
        return scored

    def draws_for(self, d: Draws) -> Draws:
        """Expand B episode draws to B*K rows: the episode's draw plus K-1 extra robust draws."""
        if self.k == 1:
            return d
        rng = np.random.default_rng(int(d.noise_seed[0]) % (2**32))
        extra = self.draw(rng, len(d) * (self.k - 1))
        rows = []
        for i in range(len(d)):
            rows.append(draws_mod.take(d, np.array([i])))
            rows.append(draws_mod.take(extra, np.arange(i * (self.k - 1), (i + 1) * (self.k - 1))))
        return Draws(*(np.concatenate([getattr(r, f) for r in rows]) for f in Draws.__dataclass_fields__))
