"""``tune(spec) -> TuneResult``: RL gain search with budgets, progress, early stop and a verified answer.

Flow: build the :class:`~gaintune.envs.GainProblem`; train an SB3 agent on the
batched VecEnv (every call scores ``n_envs`` gain sets in one simulator call);
freeze the gains (deterministic policy output for the nominal context, and the
best gains seen during training); optionally polish them with a short local
CMA-ES (reported separately: ``rl_cost`` is the agent's own figure); verify.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from pathlib import Path
from typing import Any, Protocol

import numpy as np
from stable_baselines3.common.callbacks import BaseCallback

from gaintune.envs.problem import GainProblem, Scored
from gaintune.envs.vec import BatchedGainVecEnv
from gaintune.evaluation.evaluator import DIVERGED_COST, merit
from gaintune.search.agent_file import save_agent
from gaintune.search.agents import load_agent, load_weights, make_agent
from gaintune.search.budget import refine_reserve, rollout_sims
from gaintune.search.budget import rl_budget as rl_budget_of
from gaintune.evaluation.boundary_exact import onto_boundary_exact, violation_after
from gaintune.baselines.cma import load_cma
from gaintune.search.diagnosis import diagnose
from gaintune.search.result import CurvePoint, Progress, Provenance, SettleInfo, TuneResult
from gaintune.spec import Gains, TuningSpec
from gaintune.provenance import versions

# The polish's optimiser, imported with this module: a CLI process still runs one thread here,
# so gaintune.baselines.cma can skip scipy.stats (~0.3 s of every tune).
CMA = load_cma()

__all__ = ["tune", "policy_gains", "SearchMonitor"]


class Cancel(Protocol):
    def is_set(self) -> bool: ...


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
        return self.problem.n_sims - self.sims0

    @property
    def elapsed(self) -> float:
        return time.perf_counter() - self.t0

    def on_batch(self, tuned: np.ndarray, s: Scored) -> None:
        """Record the batch's best candidate, feasibility first (see :func:`gaintune.evaluation.evaluator.merit`)."""
        self.n_diverged += int(s.diverged.sum())
        self.n_tripped += int(s.tripped.sum())
        m = s.merit
        i = int(np.argmin(m))
        if m[i] < self.best_merit * (1 - 1e-3):
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


class _StopCallback(BaseCallback):
    def __init__(self, monitor: SearchMonitor, batch: int) -> None:
        super().__init__()
        self.monitor = monitor
        self.batch = batch

    def _on_step(self) -> bool:
        return self.monitor.keep_going(self.batch)


def _nominal_obs(problem: GainProblem) -> np.ndarray:
    from gaintune.sim import draws as draws_mod

    return problem.context(draws_mod.nominal(problem.spec, problem.plant, 1))


ITERATIVE_HORIZON = 5


def _iterative_rollout(agent, spec: TuningSpec, problem: GainProblem, horizon: int) -> np.ndarray:
    """Deterministic policy of the iterative env: roll it out once from the start gains (nominal plant)."""
    from gaintune.envs.iterative import IterativeGainTuningEnv

    env = IterativeGainTuningEnv(spec, problem=problem, horizon=horizon)
    obs, _ = env.reset(seed=spec.search.seed)
    for _ in range(horizon):
        obs, *_ = env.step(agent.predict(obs[None], deterministic=True)[0][0])
    return env._a.copy()


def _refine(problem: GainProblem, start: np.ndarray, sims: int, seed: int) -> tuple[np.ndarray, float, int]:
    """Local CMA-ES polish in action space around ``start``; returns (action, cost, sims used)."""
    d = problem.dim
    opt = CMA(mean=np.clip(start, -1, 1), sigma=0.05, bounds=np.tile([-1.0, 1.0], (d, 1)), seed=seed,
              population_size=max(8, 4 + int(3 * np.log(d))))
    ev = problem.evaluator
    n0 = ev.n_sims
    best_a, best_c = start, float(ev.cost_of_action(start[None])[0])
    while ev.n_sims - n0 + opt.population_size <= sims and not opt.should_stop():
        xs = np.array([opt.ask() for _ in range(opt.population_size)])
        cs = ev.cost_of_action(xs)
        opt.tell(list(zip(xs, cs)))
        i = int(np.argmin(cs))
        if cs[i] < best_c:
            best_a, best_c = xs[i], float(cs[i])
    return best_a, best_c, ev.n_sims - n0


def tune(
    spec: TuningSpec,
    *,
    progress: Callable[[Progress], bool | None] | None = None,
    out_dir: str | Path | None = None,
    verify: bool = True,
    baselines: bool = False,
    cancel: Cancel | None = None,
    warm_start: str | Path | None = None,
    agent_overrides: dict[str, Any] | None = None,
    command: str = "",
) -> TuneResult:
    """Search the gains of ``spec`` with a stable-baselines3 agent and return the frozen, verified result.

    Parameters
    ----------
    spec
        The tuning problem; ``spec.search`` sets algorithm, budget, seed, parallel envs.
    progress
        Called with a :class:`Progress` a few times per second; return False to stop.
    out_dir
        When given, the agent is saved there as ``agent.zip``.
    verify
        Run :func:`gaintune.verification.verify` on the frozen gains (the gate).
    baselines
        Also score the classical rules for the report's comparison table.
    cancel
        An object with ``is_set()`` (e.g. ``threading.Event``) that stops the search.
    warm_start
        A saved agent zip: training continues from it ("learning on"). With a zero
        budget its policy is used as is ("learning off"). The file is read as weights
        only, into the agent this spec builds (:func:`gaintune.search.agents.load_weights`).
    agent_overrides
        SB3 hyper-parameters replacing the defaults of :mod:`gaintune.search.agents`.
    """
    return _tune(spec, progress, out_dir, verify, baselines, cancel, warm_start, agent_overrides, command)


def _tune(spec, progress, out_dir, verify, baselines, cancel, warm_start, agent_overrides, command) -> TuneResult:
    t0 = time.perf_counter()
    s = spec.search
    problem = GainProblem(spec)
    spec = problem.spec  # scenario dt/horizon derived from the plant where the spec left them out
    per_candidate = problem.k * len(spec.scenarios)
    n_envs = s.n_envs
    batch = rollout_sims(n_envs, per_candidate, s.env)
    # Budget: set-up sims already spent + RL + the final evaluations + the refinement reserve (gaintune.search.budget).
    reserve = refine_reserve(s.budget, s.refine)
    setup_sims = problem.n_sims
    rl_budget = rl_budget_of(s.budget, setup_sims, per_candidate, s.refine)
    monitor = SearchMonitor(problem, rl_budget, s.wall_time, progress, cancel, s.early_stop_patience, total_budget=s.budget)
    problem.on_score = monitor.on_batch
    horizon = 1
    if s.env == "iterative":
        # The multi-step env scores one gain set per env step (no batching across envs).
        from stable_baselines3.common.vec_env import DummyVecEnv

        from gaintune.envs.iterative import IterativeGainTuningEnv

        horizon = ITERATIVE_HORIZON
        env = DummyVecEnv([lambda: IterativeGainTuningEnv(spec, problem=problem, horizon=horizon) for _ in range(n_envs)])
        env.seed(s.seed)
    else:
        env = BatchedGainVecEnv(problem, n_envs, seed=s.seed)
    steps = max(rl_budget // per_candidate, n_envs)
    agent = make_agent(s.algo, env, s.seed, steps, agent_overrides, horizon=horizon)
    if warm_start is not None:  # the spec's agent with the saved weights, read as weights only (nothing is executed)
        load_weights(agent, warm_start)
        agent.set_random_seed(s.seed)
    if rl_budget >= batch:
        agent.learn(total_timesteps=steps, callback=_StopCallback(monitor, batch), reset_num_timesteps=warm_start is None)
    rl_sims = monitor.sims

    # Freeze: deterministic policy output for the nominal context, and the best gains seen.
    layout = problem.layout
    ev = problem.evaluator
    problem.on_score = None
    if s.env == "iterative":
        policy_action = _iterative_rollout(agent, spec, problem, horizon)
    else:
        obs = _nominal_obs(problem)
        policy_action = np.asarray(agent.predict(obs, deterministic=True)[0], dtype=float).reshape(-1)
    cand = {"policy": policy_action}
    if monitor.best_tuned is not None:
        cand["best_seen"] = layout.tuned_to_action(monitor.best_tuned)
    # the search never loses the start point (the best classical design, gaintune.evaluation.search_box)
    cand["start"] = layout.tuned_to_action(layout.initial_tuned())
    names = list(cand)
    # the policy's answer is scored as its samples were: repaired onto the boundary (gaintune.evaluation.boundary_estimate)
    cand_tuned = problem.repaired(layout.action_to_tuned(np.array([cand[k] for k in names])))
    first = ev.evaluate(cand_tuned)
    k = int(np.argmin(first.merit))  # feasibility first, then the plain cost
    source = names[k]
    policy_cost = float(first.cost[names.index("policy")])
    policy_tuned = cand_tuned[names.index("policy")]
    tuned = cand_tuned[k]
    settled = None
    if verify:
        # Close the gap between the fast requirement estimate and the exact verdict (gaintune.evaluation.boundary_exact).
        # Every method gets this exact step, so the RL-only figure includes it (but no local polish).
        monitor.report(force=True, phase="settle")
        settled = onto_boundary_exact(ev, tuned, cost=float(first.cost[k]) if first.feasible[k] else None)
        if settled.action in ("pulled_inside", "pushed_to_boundary"):
            tuned = settled.tuned
            rl = ev.evaluate(tuned[None])
            rl_cost, rl_feasible = float(rl.cost[0]), violation_after(settled, rl) <= 0
            best_merit = float(merit(rl.cost, np.array([violation_after(settled, rl)]))[0])
        else:
            rl_cost, rl_feasible, best_merit = float(first.cost[k]), bool(first.feasible[k]), float(first.merit[k])
    else:
        rl_cost, rl_feasible, best_merit = float(first.cost[k]), bool(first.feasible[k]), float(first.merit[k])
    if s.refine and monitor.stopped != "cancelled" and reserve > 0:
        monitor.report(force=True, phase="refine")
        start = layout.tuned_to_action(tuned)
        ra, rm, _ = _refine(problem, start, min(reserve, s.budget - problem.n_sims - per_candidate), s.seed)
        if rm < best_merit:
            tuned, source = layout.action_to_tuned(ra), "refined"
            if verify:
                settled = onto_boundary_exact(ev, tuned)
                if settled.action in ("pulled_inside", "pushed_to_boundary"):
                    tuned = settled.tuned
    final = ev.evaluate(tuned[None])
    full = layout.full(tuned)
    gains = layout.to_dict(full)
    metrics = {
        r.scenario: {k: (float(v[0]) if np.isfinite(v[0]) else None) for k, v in r.metrics.items()} for r in final.results
    }
    agent_path = None
    if out_dir is not None:
        out = Path(out_dir)
        out.mkdir(parents=True, exist_ok=True)
        agent_path = str(save_agent(agent, out / "agent.zip"))  # atomic: a symlink there is replaced, not followed
    result = TuneResult(
        spec=spec.model_dump(mode="json"),
        scenario_defaults=problem.scenario_defaults,
        algo=s.algo,
        gains=gains,
        gains_source=source,
        policy_gains=layout.to_dict(layout.full(policy_tuned)),
        best_seen_gains=layout.to_dict(layout.full(monitor.best_tuned)) if monitor.best_tuned is not None else None,
        cost=float(final.cost[0]),
        violation=violation_after(settled, final),
        rl_cost=rl_cost,
        rl_feasible=rl_feasible,
        policy_cost=policy_cost,
        settle=None if settled is None else SettleInfo(action=settled.action, alpha=settled.alpha, loop=settled.loop,
                                                       margin=settled.margin, checks=settled.checks),
        metrics=metrics,
        curve=monitor.curve,
        sims=problem.n_sims,
        setup_sims=setup_sims,
        rl_sims=rl_sims,
        wall_time=0.0,
        stopped=monitor.stopped,
        diverged_episodes=monitor.n_diverged,
        tripped_episodes=monitor.n_tripped,
        agent_path=agent_path,
        warm_start=None if warm_start is None else str(warm_start),
        provenance=Provenance(spec_hash=spec.content_hash(), seed=s.seed, versions=versions(), command=command),
    )
    if verify:
        monitor.report(force=True, phase="verify")
        from gaintune.verification import verify as verify_gains

        result.verification = verify_gains(spec, gains, plant=problem.plant, layout=layout)
    if baselines:
        from gaintune.baselines import run_baseline

        for method in ("simc", "amigo", "zn_step", "imc"):
            res = run_baseline(spec, method, evaluator=ev)
            result.baselines.append(res.model_dump(mode="json"))
    result.diagnosis = diagnose(result, layout, tuned, problem.plant)
    result.wall_time = time.perf_counter() - t0
    return result


def policy_gains(agent_path: str | Path, spec: TuningSpec, context: np.ndarray | None = None) -> Gains:
    """"Learning off": the saved agent's deterministic gains for ``spec`` (nominal context by default).

    The spec must have the same loop structure (gain layout) as the one the agent was trained on.
    The gains are **not verified** and carry no verdict: pass them to :func:`gaintune.verification.verify`
    before handing them out, or run ``tune(spec, warm_start=agent_path)``, whose result is verified.
    """
    problem = GainProblem(spec)
    agent = load_agent(agent_path, spec, BatchedGainVecEnv(problem, spec.search.n_envs, seed=spec.search.seed))
    obs = _nominal_obs(problem) if context is None else np.atleast_2d(context).astype(np.float32)
    if agent.action_space.shape != (problem.dim,) or agent.observation_space.shape != obs.shape[1:]:
        from gaintune.errors import SpecError

        raise SpecError("warm_start", f"agent expects {agent.action_space.shape[0]} gains; this spec tunes {problem.dim}")
    action = np.asarray(agent.predict(obs, deterministic=True)[0], dtype=float).reshape(-1)
    tuned = problem.repaired(problem.layout.action_to_tuned(action))[0]
    return problem.layout.to_dict(problem.layout.full(tuned))
