"""The one evaluation path: gains in, plain cost and requirement violation out.

Per scenario::

    cost_s = perf + effort_weight*int((u-u0)^2) + tv_weight*TV(u)
             + overshoot_weight*max(0, overshoot - overshoot_limit)
             + settling_weight*settling_time

``perf`` is IAE, ISE or ITAE of the outer loop. Scenario costs are summed by
scenario weight. A diverged simulation costs :data:`DIVERGED_COST`. With
several plant draws per gain set (robust mode) the draws are aggregated by
their mean, worst case or CVaR.

The spec's requirements (and closed-loop stability) are **constraints**, not
terms of the cost. :meth:`Evaluator.evaluate` returns both, as :class:`Scores`:
the plain cost and a non-negative *violation* (0 when every requirement holds on
the nominal plant and every corner of the randomisation box, graded otherwise,
see :func:`gaintune.verification.quick.requirement_violation`). The limits it checks are the
search's aim: ``requirements.backoff`` inside the limits the verdict judges. Every consumer ranks
candidates the same way, **feasibility first** (:attr:`Scores.merit`):

1. a feasible candidate always ranks above an infeasible one;
2. among feasible candidates the plain cost decides;
3. among infeasible candidates the violation decides.

The RL reward (:mod:`gaintune.envs.problem`), every optimiser
(:mod:`gaintune.baselines`), the reference optimum, the search monitor and the
final answer all call :meth:`Evaluator.evaluate`; tables, reports and the API
show the plain cost, never a penalised figure.
"""

from __future__ import annotations

import dataclasses
import sys
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass
from typing import Any

import numpy as np

from gaintune.lti.arrays import finite
from gaintune.plants.plant import LinearModel, Plant
from gaintune.provenance import cpus_here
from gaintune.sim import SimResult, Simulator
from gaintune.sim import draws as draws_mod
from gaintune.sim.draws import Draws
from gaintune.spec import ObjectiveSpec, ScenarioSpec, TuningSpec

__all__ = [
    "is_mimo_sim",
    "mimo_requirement_scores",
    "DIVERGED_COST",
    "INFEASIBLE_MERIT",
    "DIVERGED_VIOLATION",
    "TRIP_VIOLATION",
    "MAX_PENALTY_CORNERS",
    "Scores",
    "scenario_cost",
    "aggregate",
    "merit",
    "Evaluator",
]

#: Cost given to a diverged run: finite, so optimisers can rank it, and far above any real cost. A cost is in
#: the plant's own units and can be large: a load step on a process gain of 1e4 over 200 s has an IAE of
#: 2.7e6, which a cap of 1e6 once called divergence, so every candidate "diverged" and the search was blind
#: (``test_a_large_real_cost_is_not_divergence_and_the_search_still_finds_the_boundary``). Divergence is the
#: simulator's flag (a state beyond ``safety.divergence_bound``, NaN or inf) or a non-finite cost.
DIVERGED_COST = 1e30
#: Merit of an infeasible candidate is this times (1 + its violation): above every feasible cost, and a
#: product, not a sum, so that the violation's ordering survives at this magnitude.
INFEASIBLE_MERIT = 1e31
#: Smallest violation of a run whose simulation diverged (as an unstable closed loop).
DIVERGED_VIOLATION = 10.0
#: Violation added when the safety monitor tripped (a trip is never an acceptable answer).
TRIP_VIOLATION = 1.0
#: At most this many corners of the randomisation box enter the violation.
MAX_PENALTY_CORNERS = 8


def merit(cost: np.ndarray, violation: np.ndarray) -> np.ndarray:
    """Feasibility-first scalar (lower is better): the cost when feasible, else INFEASIBLE_MERIT * (1 + violation).

    Every optimiser here (CMA-ES, DE, Nelder-Mead, random search, the monitor's best-so-far)
    only compares values, so this scalar encodes the ranking exactly.
    """
    cost = np.asarray(cost, dtype=float)
    violation = np.asarray(violation, dtype=float)
    return np.where(violation > 0, INFEASIBLE_MERIT * (1.0 + violation), np.minimum(cost, DIVERGED_COST))


#: What -inf becomes in a violation or shortfall (numpy.nan_to_num's default: the lowest float).
_LOWEST = float(np.finfo(float).min)


@dataclass
class Scores:
    """Scores of B gain sets from :meth:`Evaluator.evaluate`.

    Attributes
    ----------
    cost
        (B,) plain cost aggregated over the robust draws; DIVERGED_COST when any draw diverged.
    violation
        (B,) requirement violation, >= 0; 0 means feasible.
    diverged, tripped
        (B,) any draw diverged / tripped the safety monitor.
    metrics
        First scenario's metrics of each gain set's first draw, each (B,).
    results
        The raw per-scenario simulation results (B*K rows, draw-major per gain set).
    """

    cost: np.ndarray
    violation: np.ndarray
    diverged: np.ndarray
    tripped: np.ndarray
    metrics: dict[str, np.ndarray]
    results: list[SimResult]

    @property
    def feasible(self) -> np.ndarray:
        """(B,) bool: every requirement met, stable, not diverged, no trip."""
        return self.violation <= 0

    @property
    def merit(self) -> np.ndarray:
        """(B,) feasibility-first scalar, see :func:`merit`."""
        return merit(self.cost, self.violation)


def scenario_cost(m: dict[str, np.ndarray], obj: ObjectiveSpec, sc: ScenarioSpec) -> np.ndarray:
    """Cost of one scenario's metrics (each (B,)); diverged runs get DIVERGED_COST."""
    settle = np.where(np.isnan(m["settling_time"]), sc.resolved_horizon, m["settling_time"])
    # inf * 0 weight on diverged rows, or a weight of 1e300: replaced below
    with np.errstate(invalid="ignore", over="ignore"):
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


def is_mimo_sim(sim: object) -> bool:
    """Whether ``sim`` is the MIMO simulator (:class:`gaintune.sim.mimo.MimoSimulator`)."""
    mimo = sys.modules.get("gaintune.sim.mimo")  # not imported (a single-input problem): no MimoSimulator exists
    return mimo is not None and isinstance(sim, mimo.MimoSimulator)


def mimo_requirement_scores(ev: Evaluator, tuned: np.ndarray, stability: bool = True) -> tuple[np.ndarray, np.ndarray]:
    """(violation, shortfall) of B gain sets of a MIMO spec, each (B,): the worst over
    :attr:`Evaluator.mimo_constraint_plants` (the nominal plant, and the randomisation box corners).

    The same loop, report and requirement lines as the MIMO verdict (the exact sampled loop of
    :mod:`gaintune.verification.mimo_sampled_report`, or with ``verify.sampled: false`` the continuous
    one of :mod:`gaintune.verification.mimo_spec`),
    the limits at the search's aim (``requirements.backoff``), graded as the single-loop case
    (:func:`gaintune.verification.mimo_spec.graded`): 0 exactly when every line holds with
    FEASIBILITY_MARGIN to spare on every plant judged. ``stability=False`` (the repair's trial scales, whose
    answer is checked in full) skips the closed-loop eigenvalues of the sampled loop on every plant, as the
    single-loop estimate skips its stability count; the continuous check always counts. The verdict's robust
    set (:mod:`gaintune.verification.mimo_robust`) also has ``verify.robust_samples`` Monte-Carlo draws and,
    with more than 3 randomised parameters, corners beyond the first MAX_PENALTY_CORNERS, which this check
    does not judge: a worst case there can still fail the verdict.
    """
    plants = ev.mimo_constraint_plants  # the plant sides, built once: every candidate reuses their plant-only work
    skip = not stability and ev.spec.verify.sampled  # only the sampled check can leave its stability out
    full = ev.layout.full(tuned)
    keys = [row.tobytes() + (b"-" if skip else b"") for row in full]
    grades = {k: ev._mimo_memo[k] for k in keys if k in ev._mimo_memo}
    found = _check_rows(ev, plants, {k: row for k, row in zip(keys, full, strict=True) if k not in grades}, skip)
    if len(ev._mimo_memo) + len(found) > 4096:
        ev._mimo_memo.clear()
    ev._mimo_memo.update(found)
    grades.update(found)
    out = np.array([grades[k] for k in keys]).reshape(len(keys), 2).T
    return out[0], out[1]


def _check_rows(ev: Evaluator, plants: list[tuple[Any, Any]], rows: dict[bytes, np.ndarray],
                skip: bool) -> dict[bytes, tuple[float, float]]:
    """:func:`_mimo_worst_grade` of each row, on a thread per CPU when there are several rows: a check's time
    is mostly LAPACK (eigenvalues, solves), which runs outside the GIL, and gaintune keeps BLAS on one thread
    (:mod:`gaintune`), so the other CPUs would sit idle. Each row's figures are its own: the order of the work
    changes none of them."""
    def grade(row: np.ndarray) -> tuple[float, float]:
        if not np.all(np.isfinite(row)):
            return DIVERGED_VIOLATION, DIVERGED_VIOLATION
        return _mimo_worst_grade(ev, plants, row, skip)

    workers = min(len(rows), cpus_here())
    if workers < 2:
        return {k: grade(row) for k, row in rows.items()}
    with ThreadPoolExecutor(workers) as pool:
        return dict(zip(rows, pool.map(grade, rows.values()), strict=True))


def _mimo_worst_grade(ev: Evaluator, plants: list[tuple[Any, Any]], row: np.ndarray,
                      skip: bool) -> tuple[float, float]:
    """The worst (violation, shortfall) of one gain vector over ``plants`` ((plant, loop frame) pairs)."""
    from gaintune.verification.mimo_sampled_report import sampled_margins
    from gaintune.verification.mimo_spec import graded, spec_margins

    worst = (-np.inf, -np.inf)
    for plant, frame in plants:
        # the loop the verdict judges: the exact sampled loop by default (verify.sampled), else continuous + dt/2
        if ev.spec.verify.sampled:
            _, rep, lines = sampled_margins(ev.spec, plant, ev.layout, row, aimed=True, frame=frame,
                                            stability=not skip)
        else:
            _, rep, lines = spec_margins(ev.spec, plant, ev.layout, row, aimed=True, frame=frame)
        v, short = graded(rep, lines)
        worst = (max(worst[0], v), max(worst[1], short))
    return worst


class Evaluator:
    """Batched cost and requirement violation of tuned-gain vectors for one spec.

    Each gain set is simulated on every scenario and on K plant draws (K =
    ``spec.search.robust.samples``; K = 1 uses the nominal plant). The default
    draws are fixed at construction (common random numbers), so the scores are a
    deterministic function of the gains: what the optimisers need. The RL
    environments pass their own episode draws. Without ``sim`` the layout has
    the fixed default bounds, which is enough to score given gains; searches
    build theirs on the problem's search box (:func:`gaintune.evaluation.search_box.make_evaluator`).

    Attributes
    ----------
    n_sims : int
        Closed-loop simulations run so far (gain sets x draws x scenarios).
    """

    def __init__(self, spec: TuningSpec, sim: Simulator | None = None, draws: Draws | None = None) -> None:
        if sim is None:  # scoring given gains: any box will do (searches use gaintune.evaluation.search_box)
            from gaintune.controllers.layout import GainLayout
            from gaintune.plants import build_plant

            plant = build_plant(spec.plant)
            sim = Simulator(spec, plant, GainLayout(spec, plant.states, plant=plant))
        self.sim = sim
        if not all(sc.resolved for sc in spec.scenarios):
            # the simulator's: scenario dt/horizon derived from the plant (gaintune.classical.timescale)
            spec = sim.spec
        self.spec = spec
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
        self._constraint_models: list[LinearModel] | None = None
        self._noise_limit: np.ndarray | None = None
        self._mimo_memo: dict[bytes, tuple[float, float]] = {}  # gains -> MIMO (violation, shortfall)
        self._mimo_plants: list[tuple[Any, Any]] | None = None  # the MIMO check's plants and their loop frames
        #: the spec the requirement estimate judges: its limits moved to the search's aim (requirements.backoff)
        self._aim_spec = spec.model_copy(update={"requirements": spec.requirements.aimed()})

    @property
    def dim(self) -> int:
        """Number of tuned gains."""
        return self.layout.n_tuned

    @property
    def constraint_models(self) -> list[LinearModel]:
        """Linear models the requirements are checked on: nominal plus the randomisation box corners.

        Verification gates on the worst case over these corners (and Monte-Carlo draws), so the
        search constraint sees the same corners.
        """
        if self._constraint_models is None:
            spec, plant = self.spec, self.plant
            models = [plant.linearize()]
            if spec.randomize.params or spec.randomize.delay:
                c = draws_mod.corners(spec, plant, max_corners=MAX_PENALTY_CORNERS)
                for i in range(len(c)):
                    lin = plant.linearize(dict(zip(plant.param_names, c.params[i], strict=True)))
                    models.append(dataclasses.replace(lin, delay=float(c.delay[i])))
            self._constraint_models = models
        return self._constraint_models

    @property
    def mimo_constraint_plants(self) -> list[tuple[Any, Any]]:
        """(plant, loop frame) pairs the MIMO requirement check judges (:func:`mimo_requirement_scores`).

        The nominal plant, and with ``randomize.params`` the box corners of the verdict's robust set
        (:func:`gaintune.verification.robust.robust_samples`: the same corners, in its order), the first
        MAX_PENALTY_CORNERS of them, each a drawn plant (:func:`gaintune.verification.mimo_robust.drawn_plant`).
        Each plant's :func:`~gaintune.verification.mimo_spec.loop_frame` is built once, here, so every
        candidate reuses its plant-only work (and the plant's sampled core).

        Raises
        ------
        SpecError
            For a ``randomize`` entry the MIMO robust set does not draw
            (:func:`gaintune.verification.mimo_robust.check_randomize`).
        """
        if self._mimo_plants is None:
            from gaintune.verification.mimo_robust import check_randomize, drawn_plant
            from gaintune.verification.mimo_spec import loop_frame
            from gaintune.verification.robust import robust_samples

            plants: list[tuple[Any, Any]] = [(self.plant, loop_frame(self.spec, self.plant))]
            if self.spec.randomize.params or self.spec.randomize.delay:
                check_randomize(self.spec, self.plant)
                samples, n_corners, _ = robust_samples(self.spec)
                for smp in samples[: min(n_corners, MAX_PENALTY_CORNERS)]:
                    drawn = drawn_plant(self.plant, smp)
                    plants.append((drawn, loop_frame(self.spec, drawn, cache=False)))
            self._mimo_plants = plants
        return self._mimo_plants

    def requirement_violation(self, tuned: np.ndarray) -> np.ndarray:
        """(B,) worst-case requirement violation over :attr:`constraint_models` (a MIMO spec:
        :attr:`mimo_constraint_plants`), 0 when all hold."""
        return self.requirement_scores(tuned)[0]

    def requirement_scores(self, tuned: np.ndarray, stability: bool = True) -> tuple[np.ndarray, np.ndarray]:
        """(violation, shortfall), each (B,), worst case over :attr:`constraint_models` (a MIMO spec:
        :attr:`mimo_constraint_plants`, by :func:`mimo_requirement_scores`).

        See :func:`gaintune.verification.quick.requirement_scores`: the shortfall is signed (<= 0 when
        every requirement holds) and is what :mod:`gaintune.evaluation.boundary_estimate` solves along a gain direction.
        ``stability=False`` skips the closed-loop stability check, for a caller that checks it afterwards.

        The limits are the search's **aim**, ``requirements.backoff`` inside the verdict's limits
        (:meth:`gaintune.spec.RequirementsSpec.aimed`), so the answer keeps that margin.
        """
        from gaintune.verification.quick import noise_limit_array, requirement_scores

        if is_mimo_sim(self.sim):
            return mimo_requirement_scores(self, np.atleast_2d(np.asarray(tuned, dtype=float)), stability)
        if self._noise_limit is None:  # a property of the spec and the nominal plant: resolved once, then aimed
            aim = self.spec.requirements.backoff.aim
            self._noise_limit = np.array([aim("mks_max", x) for x in noise_limit_array(self.spec, self.plant)])
        tuned = np.atleast_2d(np.asarray(tuned, dtype=float))
        full = self.layout.full(tuned)
        vs = [requirement_scores(self._aim_spec, self.plant, self.layout, full, lin, self._noise_limit, stability)
              for lin in self.constraint_models]
        v, short = vs[0] if len(vs) == 1 else (np.max([x[0] for x in vs], axis=0), np.max([x[1] for x in vs], axis=0))
        return (finite(v, DIVERGED_VIOLATION, DIVERGED_VIOLATION, _LOWEST),
                finite(short, DIVERGED_VIOLATION, DIVERGED_VIOLATION, _LOWEST))

    def unstable_violation(self, tuned: np.ndarray) -> np.ndarray:
        """(B,) the requirement violation of gain sets whose margins are known to hold (a single-loop spec):
        0 where the estimate's closed loop is stable on every constraint model, else the unstable grade that
        :meth:`requirement_scores` gives them. The stability check alone: a boundary move's landing points
        sit inside every margin already."""
        from gaintune.verification.quick import unstable_violation

        if is_mimo_sim(self.sim):
            raise ValueError("unstable_violation: a single-loop estimate (MIMO: requirement_scores)")
        full = self.layout.full(np.atleast_2d(np.asarray(tuned, dtype=float)))
        vs = [unstable_violation(self._aim_spec, self.plant, self.layout, full, lin) for lin in self.constraint_models]
        return vs[0] if len(vs) == 1 else np.max(vs, axis=0)

    @property
    def is_mimo(self) -> bool:
        """Whether this evaluator's simulator is the MIMO one (several inputs, or a loop graph)."""
        return is_mimo_sim(self.sim)

    def evaluate(
        self, tuned: np.ndarray, draws: Draws | None = None, traces: bool = False, violation: np.ndarray | None = None
    ) -> Scores:
        """Scores of B tuned-gain vectors: plain cost, violation, divergence, trips, metrics.

        Parameters
        ----------
        tuned
            (B, n_tuned) gains, or one vector.
        draws
            B*K draws (K per gain set, draw-major); default: this evaluator's fixed draws for every gain set.
        traces
            Keep the time traces in ``Scores.results``.
        violation
            The gains' :meth:`requirement_violation`, when the caller already has it (saves computing it again).
        """
        tuned = np.atleast_2d(np.asarray(tuned, dtype=float))
        B = tuned.shape[0]
        if draws is None:
            K = len(self.draws)
            draws = draws_mod.take(self.draws, np.tile(np.arange(K), B))
        else:
            K = len(draws) // B
        full = np.repeat(self.layout.full(tuned), K, axis=0)
        total = np.zeros(B * K)
        diverged = np.zeros(B * K, dtype=bool)
        tripped = np.zeros(B * K, dtype=bool)
        results = []
        for i, sc in enumerate(self.spec.scenarios):
            res = self.sim.run(full, draws, i, traces=traces)
            cost = scenario_cost(res.metrics, self.spec.objective, sc)
            total += sc.weight * cost
            diverged |= cost >= DIVERGED_COST  # scenario_cost's mark of a diverged run (or a non-finite cost)
            tripped |= res.metrics["tripped"]
            results.append(res)
        self.n_sims += B * K * len(self.spec.scenarios)
        # a diverged simulation costs DIVERGED_COST whatever its scenario's weight
        total = np.where(diverged, DIVERGED_COST, np.minimum(total, DIVERGED_COST))
        rob = self.spec.search.robust
        cost = aggregate(total.reshape(B, K), rob.aggregate, rob.alpha)
        div = np.asarray(diverged.reshape(B, K).any(axis=1))
        trip = np.asarray(tripped.reshape(B, K).any(axis=1))
        violation = self.requirement_violation(tuned) if violation is None else np.asarray(violation, dtype=float)
        violation = np.where(div, np.maximum(violation, DIVERGED_VIOLATION), violation)
        violation = violation + TRIP_VIOLATION * trip
        metrics = {k: v[::K] for k, v in results[0].metrics.items()}
        return Scores(cost, violation, div, trip, metrics, results)

    def __call__(self, tuned: np.ndarray) -> np.ndarray:
        """Feasibility-first merit (B,) of B tuned-gain vectors (lower is better)."""
        return self.evaluate(tuned).merit

    def cost_of_action(self, action: np.ndarray) -> np.ndarray:
        """Merit of actions in [-1, 1]^d (the RL parameterisation)."""
        return self(self.layout.action_to_tuned(action))
