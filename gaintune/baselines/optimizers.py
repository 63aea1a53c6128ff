"""Black-box optimisers over the tuned-gain vector, on the same cost as the RL search.

All optimisers work in the unit box ``z in [0, 1]^d`` that maps log-uniformly
onto the layout's bounds, ``gain = exp(log_lo + z (log_hi - log_lo))``, and
stop at a simulation budget counted by the evaluator's ``n_sims`` (falling
back to the number of gain sets evaluated).

The evaluator interface (see :mod:`gaintune.evaluation.evaluator`)::

    ev.layout          GainLayout (log_lo, log_hi, n_tuned, initial_tuned())
    ev.n_sims          simulations done so far
    ev.evaluate(tuned) (B, d) tuned gains -> Scores (plain cost, violation, merit)
    ev(tuned)          (B, d) tuned gains -> (B,) merit, lower is better (used when there is no evaluate)

Every optimiser minimises the **feasibility-first merit**: it only compares values,
so a feasible candidate always wins over an infeasible one, feasible candidates
compare by plain cost and infeasible ones by their requirement violation. The
result carries the plain cost and feasibility of the best candidate.

Settings (defaults):

* ``random``: uniform in the unit box (batches of 256), plus the layout's initial point.
* ``cmaes``: :class:`cmaes.CMA` from the layout's initial point, sigma0 = 0.25,
  population 16 (budget < 1,500) or 32, one batched evaluation per generation,
  restarts from a random point when CMA-ES reports convergence.
* ``de``: :func:`scipy.optimize.differential_evolution`, ``vectorized=True``
  (one call per generation), ``updating="deferred"``, about 24 members,
  best1bin, mutation (0.5, 1), recombination 0.7, no polishing, x0 = the initial point.
* ``nelder_mead``: :func:`scipy.optimize.minimize` Nelder-Mead with bounds,
  initial simplex of side 0.1, restarted from its best point while budget remains.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from gaintune.baselines.cma import load_cma

__all__ = [
    "OptResult", "BudgetExhausted", "Budgeted", "random_search", "cmaes_search", "de_search", "nelder_mead_search",
    "optimize", "OPTIMIZERS",
]

#: Cost substituted for non-finite costs inside the optimisers (ranks stay meaningful).
BAD_COST = 1e12


class BudgetExhausted(Exception):
    """Raised inside an optimiser's objective when the simulation budget is spent."""


@dataclass
class OptResult:
    """Best tuned-gain vector found, with its cost and the spend."""

    method: str
    tuned: np.ndarray
    cost: float
    n_sims: int
    n_evals: int
    wall_time: float
    #: (simulations, cost of the best candidate) from the first feasible candidate on
    history: list[tuple[int, float]] = field(default_factory=list)
    details: dict[str, Any] = field(default_factory=dict)
    feasible: bool = True
    violation: float = 0.0


def _n_sims(ev) -> int | None:
    v = getattr(ev, "n_sims", None)
    return int(v) if v is not None else None


class Budgeted:
    """Wrap an evaluator: unit-box coordinates, budget accounting, best-so-far tracking."""

    def __init__(self, ev, budget: int) -> None:
        self.ev = ev
        self.budget = int(budget)
        lay = ev.layout
        self.lo = np.asarray(lay.log_lo, dtype=float)
        self.hi = np.asarray(lay.log_hi, dtype=float)
        self.d = int(lay.n_tuned)
        self._start = _n_sims(ev)
        self.n_evals = 0
        self.sims_per_eval: float | None = None
        self.best_merit = math.inf
        self.best_cost = math.inf  # plain cost of the best-ranked candidate
        self.best_violation = math.inf
        self.best_z: np.ndarray | None = None
        self.history: list[tuple[int, float]] = []

    # coordinates
    def to_tuned(self, z: np.ndarray) -> np.ndarray:
        """Unit-box coordinates (clipped to [0, 1]) -> tuned gain magnitudes, log-uniformly in the bounds."""
        return np.exp(self.lo + np.clip(z, 0.0, 1.0) * (self.hi - self.lo))

    def to_unit(self, tuned: np.ndarray) -> np.ndarray:
        """Inverse of :meth:`to_tuned`, clipped to the unit box."""
        return np.clip((np.log(np.asarray(tuned, dtype=float)) - self.lo) / (self.hi - self.lo), 0.0, 1.0)

    def initial_z(self) -> np.ndarray:
        """The layout's initial gains in unit-box coordinates."""
        return self.to_unit(self.ev.layout.initial_tuned())

    # accounting
    @property
    def used(self) -> int:
        """Simulations spent so far (the evaluator's count, else the number of gain sets scored)."""
        now = _n_sims(self.ev)
        if now is None or self._start is None:
            return self.n_evals
        return now - self._start

    @property
    def remaining(self) -> int:
        """Simulations left in the budget."""
        return self.budget - self.used

    def rows_left(self) -> int:
        """How many more gain sets fit in the budget."""
        per = self.sims_per_eval or 1.0
        return int(self.remaining // per + 1e-9)

    def __call__(self, z: np.ndarray) -> np.ndarray:
        z = np.atleast_2d(np.asarray(z, dtype=float))
        left = self.rows_left()
        if left <= 0:
            raise BudgetExhausted
        z = z[:left]
        before = self.used
        evaluate = getattr(self.ev, "evaluate", None)
        if evaluate is not None:
            s = evaluate(self.to_tuned(z))
            c, cost, viol = s.merit, s.cost, s.violation
        else:  # a plain cost function: every candidate counts as feasible
            c = np.asarray(self.ev(self.to_tuned(z)), dtype=float).reshape(-1)
            cost, viol = c, np.zeros_like(c)
        spent = self.used - before
        self.n_evals += len(z)
        if self.sims_per_eval is None and spent > 0:
            self.sims_per_eval = spent / len(z)
        k = int(np.argmin(np.where(np.isfinite(c), c, np.inf)))
        if np.isfinite(c[k]) and c[k] < self.best_merit:
            self.best_merit = float(c[k])
            self.best_cost = float(cost[k])
            self.best_violation = float(viol[k])
            self.best_z = z[k].copy()
        if self.best_violation <= 0:  # an anytime curve of feasible costs: an infeasible best is no answer yet
            self.history.append((self.used, self.best_cost))
        return np.where(np.isfinite(c), c, BAD_COST)

    def result(self, method: str, t0: float, **details: Any) -> OptResult:
        """The best candidate so far (the layout's initial gains if none was finite) as an :class:`OptResult`."""
        if self.best_z is None:
            tuned = self.ev.layout.initial_tuned()
        else:
            tuned = self.to_tuned(self.best_z)
        return OptResult(method, tuned, self.best_cost, self.used, self.n_evals, time.perf_counter() - t0, self.history,
                         details, feasible=self.best_violation <= 0, violation=self.best_violation)


# ------------------------------------------------------------------ random


def random_search(ev, budget: int, seed: int = 0, batch: int = 256) -> OptResult:
    """Uniform random search in the log box (the layout's initial point is evaluated first)."""
    t0 = time.perf_counter()
    f = Budgeted(ev, budget)
    rng = np.random.default_rng(seed)
    try:
        f(f.initial_z()[None, :])
        while f.rows_left() > 0:
            f(rng.uniform(size=(min(batch, f.rows_left()), f.d)))
    except BudgetExhausted:
        pass
    return f.result("random", t0)


# ------------------------------------------------------------------ CMA-ES


def cmaes_search(
    ev,
    budget: int,
    seed: int = 0,
    popsize: int | None = None,
    sigma0: float = 0.25,
    x0: np.ndarray | None = None,
    restarts: bool = True,
) -> OptResult:
    """CMA-ES (``cmaes`` package) in the unit box; one batched evaluation per generation.

    ``x0`` is a tuned-gain vector (default: the layout's initial point).
    """
    CMA = load_cma()
    t0 = time.perf_counter()
    f = Budgeted(ev, budget)
    rng = np.random.default_rng(seed)
    pop = popsize or (16 if budget < 1500 else 32)
    d = f.d
    pad = d < 2  # cmaes needs at least 2 dimensions: add an inert one
    dim = max(d, 2)
    mean = f.initial_z() if x0 is None else f.to_unit(x0)
    n_restarts = 0
    gens = 0
    try:
        while f.rows_left() > 0:
            m0 = np.concatenate([mean, [0.5]]) if pad else mean
            opt = CMA(
                mean=np.clip(m0, 1e-6, 1 - 1e-6),
                sigma=sigma0,
                bounds=np.tile([0.0, 1.0], (dim, 1)),
                seed=int(rng.integers(2**31 - 1)),
                population_size=pop,
            )
            while f.rows_left() > 0:
                xs = np.array([opt.ask() for _ in range(opt.population_size)])
                n = min(len(xs), f.rows_left())
                if n < len(xs):  # last partial generation: evaluate what fits, no tell
                    f(xs[:n, :d])
                    break
                vals = f(xs[:, :d])
                opt.tell(list(zip(xs, vals, strict=True)))  # every row fitted the budget (above)
                gens += 1
                if opt.should_stop():
                    break
            if not restarts:
                break
            n_restarts += 1
            mean = rng.uniform(size=d)
    except BudgetExhausted:
        pass
    return f.result("cmaes", t0, popsize=pop, sigma0=sigma0, generations=gens, restarts=max(n_restarts - 1, 0))


# ---------------------------------------------------------------- SciPy DE


def de_search(ev, budget: int, seed: int = 0, members: int = 24) -> OptResult:
    """SciPy differential evolution, vectorised: one evaluator call per generation."""
    from scipy.optimize import differential_evolution

    t0 = time.perf_counter()
    f = Budgeted(ev, budget)
    d = f.d
    popsize = max(1, math.ceil(members / d))
    S = popsize * d
    # Probe the cost of one evaluation so the generation count fits the budget.
    x0 = f.initial_z()
    try:
        f(x0[None, :])
    except BudgetExhausted:
        return f.result("de", t0)
    maxiter = max(0, f.rows_left() // S - 1)
    if f.rows_left() >= S:

        def obj(x: np.ndarray) -> np.ndarray:
            x = np.asarray(x)
            return f(x.T if x.ndim == 2 else x[None, :])

        try:
            differential_evolution(
                obj,
                bounds=[(0.0, 1.0)] * d,
                popsize=popsize,
                maxiter=maxiter,
                vectorized=True,
                updating="deferred",
                polish=False,
                seed=seed,
                tol=0.0,
                atol=0.0,
                x0=x0,
                init="latinhypercube",
            )
        except BudgetExhausted:
            pass
    return f.result("de", t0, members=S, generations=maxiter + 1)


# ------------------------------------------------------------ Nelder-Mead


def nelder_mead_search(ev, budget: int, seed: int = 0, x0: np.ndarray | None = None, step: float = 0.1) -> OptResult:
    """Bounded Nelder-Mead from the layout's initial point, restarted from its best point."""
    from scipy.optimize import minimize

    t0 = time.perf_counter()
    f = Budgeted(ev, budget)
    d = f.d
    z = f.initial_z() if x0 is None else f.to_unit(x0)
    rng = np.random.default_rng(seed)
    runs = 0
    try:
        while f.rows_left() > d + 1:
            simplex = np.vstack([z, z + step * np.eye(d)])
            over = simplex > 1.0
            simplex[over] = simplex[over] - 2 * step  # reflect steps that leave the box
            minimize(
                lambda v: float(f(v[None, :])[0]),
                z,
                method="Nelder-Mead",
                bounds=[(0.0, 1.0)] * d,
                options={"maxfev": f.rows_left(), "xatol": 1e-5, "fatol": 1e-10, "initial_simplex": simplex},
            )
            runs += 1
            prev = z
            z = f.best_z if f.best_z is not None else rng.uniform(size=d)
            if np.allclose(z, prev, atol=1e-6):  # converged to the same point: perturb
                z = np.clip(z + rng.normal(0.0, 0.05, d), 0.0, 1.0)
    except BudgetExhausted:
        pass
    return f.result("nelder_mead", t0, runs=runs)


OPTIMIZERS: dict[str, Callable[..., OptResult]] = {
    "random": random_search,
    "cmaes": cmaes_search,
    "de": de_search,
    "nelder_mead": nelder_mead_search,
}


def optimize(ev, method: str, budget: int, seed: int = 0, **kw: Any) -> OptResult:
    """Run optimiser ``method`` (one of :data:`OPTIMIZERS`) on evaluator ``ev`` for ``budget`` simulations."""
    if method not in OPTIMIZERS:
        raise ValueError(f"unknown optimiser {method!r}; choose from {sorted(OPTIMIZERS)}")
    if budget < 1:
        raise ValueError(f"budget must be >= 1 simulation, got {budget}")
    return OPTIMIZERS[method](ev, budget, seed, **kw)
