"""The search monitor: best gains, training curve, progress reports and every stop condition of a search."""

from __future__ import annotations

import time
from collections.abc import Callable
from typing import Protocol

import numpy as np
from stable_baselines3.common.callbacks import BaseCallback

from gaintune.envs.problem import GainProblem, Scored
from gaintune.evaluation.evaluator import DIVERGED_COST
from gaintune.search.result import CurvePoint, Progress

__all__ = ["Cancel", "SearchMonitor", "StopCallback"]


class Cancel(Protocol):
    """Anything with ``is_set()`` (e.g. ``threading.Event``): the search stops once it is set."""

    def is_set(self) -> bool:
        """Whether the search must stop."""
        ...


class SearchMonitor:
    """Tracks best gains, the training curve and every stop condition of a search."""

    def __init__(
        self,
        problem: GainProblem,
        budget: int,
        wall_time: float | None,
        progress: Callable[[Progress], bool | None] | None,
        cancel: Cancel | None,
        patience: int | None,
        total_budget: int | None = None,
    ) -> None:
        self.problem = problem
        self.budget = budget
        self.total_budget = total_budget if total_budget is not None else budget  # search.budget: what progress shows
        self.wall_time = wall_time
        self.progress = progress
        self.cancel = cancel
        self.patience = patience
        self.t0 = time.perf_counter()
        self.sims0 = problem.n_sims
        self.best_merit = np.inf
        self.best_cost = np.inf  # plain cost of the best-ranked candidate
        self.best_feasible = False
        self.best_tuned: np.ndarray | None = None
        self.best_at = 0
        self.curve: list[CurvePoint] = []
        self.n_diverged = 0
        self.n_tripped = 0
        self.stopped = "budget"
        self._last_report = 0.0

    @property
    def sims(self) -> int:
        """Simulations since the monitor was made (the search's own)."""
        return self.problem.n_sims - self.sims0

    @property
    def elapsed(self) -> float:
        """Seconds since the monitor was made."""
        return time.perf_counter() - self.t0

    def on_batch(self, tuned: np.ndarray, s: Scored) -> None:
        """Record the batch's best candidate, feasibility first (see :func:`gaintune.evaluation.evaluator.merit`)."""
        self.n_diverged += int(s.diverged.sum())
        self.n_tripped += int(s.tripped.sum())
        m = s.merit
        i = int(np.argmin(m))
        # progress that resets the patience: the first batch, the first feasible answer, or a feasible cost
        # 0.1 % lower (a lower violation alone is not: the search may creep along an infeasible region)
        first = not np.isfinite(self.best_merit)
        if first or (s.feasible[i] and (not self.best_feasible or m[i] < self.best_merit * (1 - 1e-3))):
            self.best_at = self.sims
        if m[i] < self.best_merit:
            self.best_merit = float(m[i])
            self.best_cost = float(s.cost[i])
            self.best_feasible = bool(s.feasible[i])
            self.best_tuned = tuned[i].copy()
        self.curve.append(CurvePoint(sims=self.sims, best_cost=float(min(self.best_cost, DIVERGED_COST)),
                                     feasible=self.best_feasible, wall_time=self.elapsed))
        self.report()

    def report(self, force: bool = False, phase: str = "search") -> None:
        """Send a :class:`Progress` to the callback (at most every 0.2 s unless ``force``); a False answer cancels."""
        if self.progress is None:
            return
        now = self.elapsed
        if not force and now - self._last_report < 0.2:
            return
        self._last_report = now
        rate = self.sims / now if now > 0 else 0.0
        # an ETA only while the search runs, never below 0: settle, refine and verify are not paced by the budget
        eta = max(0.0, (self.budget - self.sims) / rate) if rate > 0 and phase == "search" else None
        # every simulation of the run (set-up, search, settle, refine), as the result's ``sims`` counts them
        total = self.problem.n_sims
        keep = self.progress(
            Progress(sims=total, budget=max(self.total_budget, total), elapsed=now, eta=eta, phase=phase,
                     best_cost=self.best_cost if self.best_feasible else None)
        )
        if keep is False:
            self.stopped = "cancelled"

    def keep_going(self, next_batch: int) -> bool:
        """Whether the search may run ``next_batch`` more simulations; else ``stopped`` says why not."""
        if self.stopped == "cancelled" or (self.cancel is not None and self.cancel.is_set()):
            self.stopped = "cancelled"
            return False
        if self.sims + next_batch > self.budget:
            self.stopped = "budget"
            return False
        if self.wall_time is not None and self.elapsed > self.wall_time:
            self.stopped = "wall_time"
            return False
        if self.patience is not None and self.sims - self.best_at > self.patience:
            self.stopped = "converged"
            return False
        return True


class StopCallback(BaseCallback):
    """Stops SB3's ``learn`` once the monitor says so (checked before every rollout step)."""

    def __init__(self, monitor: SearchMonitor, batch: int) -> None:
        super().__init__()
        self.monitor = monitor
        self.batch = batch

    def _on_step(self) -> bool:
        return self.monitor.keep_going(self.batch)
