"""The tuning problem as the environments see it: gains in, reward and scores out, batched.

:class:`GainProblem` builds the plant, the gain layout (bounds from a classical
rule when the spec gives none), the simulator and the evaluator once, and
scores a batch of gain sets with :meth:`gaintune.evaluation.evaluator.Evaluator.evaluate`
(ONE simulator call per scenario). Every env in :mod:`gaintune.envs` and the
search share it, so reward arithmetic lives here only.

Reward of one gain set, feasibility first like every other ranking here::

    feasible:    reward = -min(cost / cost_scale, COST_CAP)
    infeasible:  reward = -(COST_CAP + min(violation, VIOLATION_CAP))

``cost`` is the plain objective of :mod:`gaintune.evaluation.evaluator` (aggregated over
the robust draws), ``cost_scale`` the cost of the start gains on the nominal
plant, and ``violation`` the graded requirement violation (0 when every
requirement holds; >= 10 for an unstable loop or a diverged run). Every
infeasible gain set is rewarded below every feasible one, so the policy learns
the feasible region first and the cost inside it.

On one plant (nothing randomised) the batched env rewards each episode with the
**centred rank** of its merit within the batch instead (:func:`rank_reward`; best
+0.5, worst -0.5): the fitness shaping of natural evolution strategies. With the
values above, feasibility swamps cost: every infeasible sample sits ~10 below the
feasible ones, so after advantage normalisation the cost differences among
feasible samples barely move the policy. Ranks weigh one place in the order the
same wherever it is, as CMA-ES's ranking does. Measured on the 54-gain arm
(docs/search.md, "Search at scale"). With randomised plants the batch mixes
plants whose costs do not compare, so the values above stay.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from gaintune.classical.timescale import scenario_defaults
from gaintune.controllers.layout import GainLayout
from gaintune.evaluation.boundary_estimate import onto_boundary_estimate
from gaintune.evaluation.evaluator import DIVERGED_COST, Evaluator, Scores
from gaintune.evaluation.search_box import search_box
from gaintune.plants import build_plant
from gaintune.plants.checks import validate_against_plant
from gaintune.sim import Simulator
from gaintune.sim import draws as draws_mod
from gaintune.sim.draws import Draws
from gaintune.spec import TuningSpec

__all__ = ["COST_CAP", "VIOLATION_CAP", "GainProblem", "Scored", "rank_reward"]

#: Cost ratios above this are clipped, so failures cannot swamp the learning signal.
COST_CAP = 10.0
#: Violations above this are clipped in the reward (an unstable loop scores 10 and up).
VIOLATION_CAP = 20.0


def rank_reward(merit: np.ndarray) -> np.ndarray:
    """(B,) centred ranks of a batch's merits (lower merit is better): the best +0.5, the worst -0.5, equal
    merits sharing their mean rank.

    >>> rank_reward(np.array([3.0, 1.0, 2.0, 2.0, 10.0]))
    array([-0.25 ,  0.5  ,  0.125,  0.125, -0.5  ])
    """
    m = np.asarray(merit, dtype=float)
    if m.size < 2:
        return np.zeros(m.size)
    values, inverse, counts = np.unique(m, return_inverse=True, return_counts=True)
    mean_rank = np.cumsum(counts) - 0.5 * (counts + 1)  # 0-based mean rank of each distinct value
    return 0.5 - mean_rank[inverse] / (m.size - 1)


@dataclass
class Scored(Scores):
    """:class:`~gaintune.evaluation.evaluator.Scores` of B gain sets plus their RL reward (B,)."""

    reward: np.ndarray = dataclasses.field(default_factory=lambda: np.zeros(0))


class GainProblem:
    """Plant, layout, simulator and reward for one spec.

    Parameters
    ----------
    spec
        The tuning problem. :attr:`spec` is it with every scenario's ``dt``/``horizon`` a number
        (derived from the plant where left out; :attr:`scenario_defaults` records the choice).
    use_auto_bounds
        Centre log-scale bounds on a classical rule where the spec gives none.
    per_loop_repair
        The repair scales only the loops that miss a requirement at their own break point
        (``onto_boundary_estimate(per_loop=True)``) instead of every loop together.
    """

    def __init__(self, spec: TuningSpec, use_auto_bounds: bool = True, per_loop_repair: bool = False) -> None:
        plant = build_plant(spec.plant)
        validate_against_plant(spec, plant)
        # scenarios without dt/horizon get them from the plant; the records say what was chosen and why
        spec, self.scenario_defaults = scenario_defaults(spec, plant)
        self.spec = spec
        if use_auto_bounds:
            box = search_box(spec, plant)
            self.layout, self.box_sims = box.layout, box.sims
        else:
            self.layout, self.box_sims = GainLayout(spec, plant.states), 0
        self.layout.require_tuned()  # a search with nothing to search fails deep in the agent otherwise
        self.plant = plant
        self.sim = Simulator(spec, plant, self.layout)
        self.evaluator = Evaluator(spec, self.sim)
        # the single-input linear model (None for several inputs or a loop graph: gaintune.sim.mimo)
        self.lin = None if self.evaluator.is_mimo else plant.linearize()
        self.k = spec.search.robust.samples
        self.randomized = spec.randomize.active
        self.obs_size = draws_mod.context_size(spec)
        self.cost_scale = self._cost_scale()
        #: Project stable, infeasible samples onto the requirement boundary before scoring
        #: (gaintune.evaluation.boundary_estimate).
        self.repair = spec.search.repair
        self.per_loop_repair = per_loop_repair
        #: Optional hook called as ``on_score(tuned, scored)`` after every env scoring (search monitor).
        self.on_score: Callable[[np.ndarray, Scored], None] | None = None

    @property
    def n_sims(self) -> int:
        """Every closed-loop simulation run for this problem: choosing the search box (counted even
        when the box came from the cache), env batches and evaluator calls."""
        return self.box_sims + self.evaluator.n_sims

    @property
    def dim(self) -> int:
        """Number of tuned gains (the action size)."""
        return self.layout.n_tuned

    def _cost_scale(self) -> float:
        """Plain cost of the start (classical-rule) gains, or the median of random finite costs."""
        c = float(self.evaluator.evaluate(self.layout.initial_tuned()[None]).cost[0])
        if 0 < c < DIVERGED_COST:
            return c
        rng = np.random.default_rng(self.spec.search.seed)
        costs = self.evaluator.evaluate(self.layout.action_to_tuned(rng.uniform(-1, 1, (64, self.dim)))).cost
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
    def reward(self, s: Scores) -> np.ndarray:
        """(B,) reward of scores: feasibility first, see the module docstring."""
        ratio = np.minimum(s.cost / self.cost_scale, COST_CAP)
        return np.where(s.feasible, -ratio, -(COST_CAP + np.minimum(s.violation, VIOLATION_CAP)))

    def repaired(self, tuned: np.ndarray) -> np.ndarray:
        """(B, d) gains as the search scores them: with ``search.repair``, infeasible rows moved onto the boundary."""
        return self._project(tuned)[0]

    def _project(self, tuned: np.ndarray) -> tuple[np.ndarray, np.ndarray | None]:
        """(gains as scored, their estimated violation when the projection computed it, else None)."""
        tuned = np.atleast_2d(np.asarray(tuned, dtype=float))
        if not self.repair:
            return tuned, None
        r = onto_boundary_estimate(self.evaluator, tuned, per_loop=self.per_loop_repair)
        return r.tuned, r.violation

    def score(self, tuned: np.ndarray, draws: Draws) -> Scored:
        """Score B tuned-gain vectors; ``draws`` has B*K rows (K robust draws per gain set, draw-major)."""
        tuned, violation = self._project(tuned)
        s = self.evaluator.evaluate(tuned, draws, violation=violation)
        scored = Scored(**{f.name: getattr(s, f.name) for f in dataclasses.fields(Scores)}, reward=self.reward(s))
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
