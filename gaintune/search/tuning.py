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
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from stable_baselines3.common.callbacks import BaseCallback
from stable_baselines3.common.preprocessing import get_action_dim
from stable_baselines3.common.vec_env import VecEnv

from gaintune.baselines.cma import load_cma
from gaintune.envs.problem import GainProblem
from gaintune.envs.vec import BatchedGainVecEnv
from gaintune.evaluation.boundary_exact import ExactMove, onto_boundary_exact, violation_after
from gaintune.evaluation.evaluator import Evaluator, Scores, merit
from gaintune.provenance import versions
from gaintune.search.agent_file import save_agent
from gaintune.search.agents import load_agent, load_weights, make_agent
from gaintune.search.budget import refine_reserve, rollout_sims
from gaintune.search.budget import rl_budget as rl_budget_of
from gaintune.search.diagnosis import diagnose
from gaintune.search.mean_in_box import MeanInBox
from gaintune.search.monitor import Cancel, SearchMonitor, StopCallback
from gaintune.search.result import Progress, Provenance, SettleInfo, TuneResult
from gaintune.spec import Gains, TuningSpec

# The polish's optimiser, imported with this module: a CLI process still runs one thread here,
# so gaintune.baselines.cma can skip scipy.stats (~0.3 s of every tune).
CMA = load_cma()

__all__ = ["tune", "TuneOptions", "policy_gains", "SearchMonitor"]


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
    return env.action


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
        opt.tell(list(zip(xs, cs, strict=True)))
        i = int(np.argmin(cs))
        if cs[i] < best_c:
            best_a, best_c = xs[i], float(cs[i])
    return best_a, best_c, ev.n_sims - n0


@dataclass(frozen=True)
class TuneOptions:
    """What :func:`tune` does besides the search itself (every keyword argument of :func:`tune`).

    Attributes
    ----------
    progress
        Called with a :class:`Progress` a few times per second; return False to stop.
    out_dir
        When given, the agent is saved there as ``agent.zip``.
    verify
        Settle the answer on the exact requirement boundary and verify it (the gate).
    baselines
        Also score the classical rules for the report's comparison table.
    cancel
        An object with ``is_set()`` that stops the search.
    warm_start
        A saved agent zip whose weights the search starts from.
    agent_overrides
        SB3 hyper-parameters replacing the defaults of :mod:`gaintune.search.agents`.
    command
        The command line recorded in the result's provenance.
    per_loop_repair
        The repair moves only the loops that miss a requirement (docs/search.md, "Scaling").
    """

    progress: Callable[[Progress], bool | None] | None = None
    out_dir: str | Path | None = None
    verify: bool = True
    baselines: bool = False
    cancel: Cancel | None = None
    warm_start: str | Path | None = None
    agent_overrides: dict[str, Any] | None = None
    command: str = ""
    per_loop_repair: bool = False


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
    per_loop_repair: bool = False,
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
    command
        The command line recorded in the result's provenance.
    per_loop_repair
        With ``search.repair``, move only the loops that miss a requirement at their own break
        point onto the boundary (every loop together where that is not enough) instead of every
        loop together (docs/search.md, "Scaling").

    Returns
    -------
    TuneResult
        The frozen gains, their cost and metrics, the verification (when ``verify``) and how they were found.

    Examples
    --------
    A short search (200 simulations) on a third-order lag; the gains are accepted only when they pass:

    >>> from gaintune import load_spec, tune
    >>> spec = load_spec({"plant": {"tf": {"num": [1], "den": "(s+1)^3"}}, "loops": [{"type": "pi"}],
    ...                   "scenario": {"dt": 0.05, "horizon": 20.0}, "search": {"budget": 200, "seed": 0}})
    >>> result = tune(spec)
    >>> sorted(result.gains["loop0"]), result.sims <= 200, result.stopped
    (['Ki', 'Kp'], True, 'budget')
    >>> result.verdict, result.accepted_gains == result.gains
    ('pass', True)
    """
    options = TuneOptions(progress=progress, out_dir=out_dir, verify=verify, baselines=baselines, cancel=cancel,
                          warm_start=warm_start, agent_overrides=agent_overrides, command=command,
                          per_loop_repair=per_loop_repair)
    return _tune(spec, options)


@dataclass(frozen=True)
class _Plan:
    """The simulation budget of one tune, split between set-up, RL and the refinement (gaintune.search.budget)."""

    per_candidate: int  # simulations per gain set: robust draws x scenarios
    batch: int  # simulations of one rollout (the stop callback's step)
    reserve: int  # kept for the local polish
    setup_sims: int  # spent before the search: search box and reward scale
    rl_budget: int
    steps: int  # agent timesteps


def _plan(problem: GainProblem) -> _Plan:
    """Split ``problem.spec.search.budget`` (set-up sims already spent + RL + final evaluations + refinement)."""
    s = problem.spec.search
    per_candidate = problem.k * len(problem.spec.scenarios)
    rl_budget = rl_budget_of(s.budget, problem.n_sims, per_candidate, s.refine)
    return _Plan(per_candidate=per_candidate, batch=rollout_sims(s.n_envs, per_candidate, s.env),
                 reserve=refine_reserve(s.budget, s.refine), setup_sims=problem.n_sims, rl_budget=rl_budget,
                 steps=max(rl_budget // per_candidate, s.n_envs))


def _make_env(problem: GainProblem) -> tuple[VecEnv, int]:
    """The training VecEnv of ``problem`` and its episode horizon (1 for the one-shot env)."""
    s = problem.spec.search
    if s.env != "iterative":
        return BatchedGainVecEnv(problem, s.n_envs, seed=s.seed), 1
    # The multi-step env scores one gain set per env step (no batching across envs).
    from stable_baselines3.common.vec_env import DummyVecEnv

    from gaintune.envs.iterative import IterativeGainTuningEnv

    spec = problem.spec
    env = DummyVecEnv([lambda: IterativeGainTuningEnv(spec, problem=problem, horizon=ITERATIVE_HORIZON)
                       for _ in range(s.n_envs)])
    env.seed(s.seed)
    return env, ITERATIVE_HORIZON


@dataclass(frozen=True)
class _Trained:
    """A trained agent, the monitor of its search, its episode horizon and the simulations it used."""

    agent: Any
    monitor: SearchMonitor
    horizon: int
    rl_sims: int


def _train(problem: GainProblem, plan: _Plan, options: TuneOptions) -> _Trained:
    """Train the spec's agent within ``plan.rl_budget`` (stopped early by budget, time, patience or cancel)."""
    s = problem.spec.search
    monitor = SearchMonitor(problem, plan.rl_budget, s.wall_time, options.progress, options.cancel,
                            s.early_stop_patience, total_budget=s.budget)
    problem.on_score = monitor.on_batch
    env, horizon = _make_env(problem)
    agent = make_agent(s.algo, env, s.seed, plan.steps, options.agent_overrides, horizon=horizon)
    if options.warm_start is not None:  # the spec's agent with the saved weights, read as weights only
        load_weights(agent, options.warm_start)
        agent.set_random_seed(s.seed)
    callbacks: list[BaseCallback] = [StopCallback(monitor, plan.batch)]
    if s.algo in ("ppo", "a2c") and horizon == 1 and not problem.randomized:  # a Gaussian mean on one plant
        callbacks.append(MeanInBox(_nominal_obs(problem)))
    if plan.rl_budget >= plan.batch:
        agent.learn(total_timesteps=plan.steps, callback=callbacks, reset_num_timesteps=options.warm_start is None)
    problem.on_score = None
    return _Trained(agent=agent, monitor=monitor, horizon=horizon, rl_sims=monitor.sims)


@dataclass
class _Answer:
    """The search's answer as it moves through freeze, settle and refine."""

    tuned: np.ndarray
    source: str
    policy_tuned: np.ndarray
    policy_cost: float
    rl_cost: float = 0.0
    rl_feasible: bool = False
    best_merit: float = 0.0
    settled: ExactMove | None = None


def _freeze(problem: GainProblem, trained: _Trained) -> tuple[_Answer, Scores, int]:
    """Rank the policy's answer, the best gains seen and the start point; returns (answer, their scores, its row).

    The policy's answer is scored as its samples were: repaired onto the boundary
    (gaintune.evaluation.boundary_estimate). The start point (the best classical design,
    gaintune.evaluation.search_box) is always a candidate, so the search never loses it.
    """
    layout, agent, best_tuned = problem.layout, trained.agent, trained.monitor.best_tuned
    if problem.spec.search.env == "iterative":
        policy_action = _iterative_rollout(agent, problem.spec, problem, trained.horizon)
    else:
        obs = _nominal_obs(problem)
        policy_action = np.asarray(agent.predict(obs, deterministic=True)[0], dtype=float).reshape(-1)
    cand = {"policy": policy_action}
    if best_tuned is not None:
        cand["best_seen"] = layout.tuned_to_action(best_tuned)
    cand["start"] = layout.tuned_to_action(layout.initial_tuned())
    names = list(cand)
    cand_tuned = problem.repaired(layout.action_to_tuned(np.array([cand[k] for k in names])))
    first = problem.evaluator.evaluate(cand_tuned)
    k = int(np.argmin(first.merit))  # feasibility first, then the plain cost
    policy = names.index("policy")
    answer = _Answer(tuned=cand_tuned[k], source=names[k], policy_tuned=cand_tuned[policy],
                     policy_cost=float(first.cost[policy]), rl_cost=float(first.cost[k]),
                     rl_feasible=bool(first.feasible[k]), best_merit=float(first.merit[k]))
    return answer, first, k


def _settle(ev: Evaluator, answer: _Answer, first: Scores, k: int) -> None:
    """Move the answer onto the exact requirement boundary (gaintune.evaluation.boundary_exact), in place.

    This closes the gap between the fast requirement estimate and the exact verdict. Every
    method gets this exact step, so the RL-only figures include it (but no local polish).
    """
    settled = onto_boundary_exact(ev, answer.tuned, cost=float(first.cost[k]) if first.feasible[k] else None)
    answer.settled = settled
    if settled.action in ("pulled_inside", "pushed_to_boundary"):
        answer.tuned = settled.tuned
        rl = ev.evaluate(answer.tuned[None])
        answer.rl_cost, answer.rl_feasible = float(rl.cost[0]), violation_after(settled, rl) <= 0
        answer.best_merit = float(merit(rl.cost, np.array([violation_after(settled, rl)]))[0])


def _polish(problem: GainProblem, plan: _Plan, answer: _Answer, verify: bool) -> None:
    """Local CMA-ES polish of the answer within the refinement reserve, kept when it ranks better (in place)."""
    s = problem.spec.search
    layout = problem.layout
    start = layout.tuned_to_action(answer.tuned)
    sims = min(plan.reserve, s.budget - problem.n_sims - plan.per_candidate)
    ra, rm, _ = _refine(problem, start, sims, s.seed)
    if rm < answer.best_merit:
        answer.tuned, answer.source = layout.action_to_tuned(ra), "refined"
        if verify:
            answer.settled = onto_boundary_exact(problem.evaluator, answer.tuned)
            if answer.settled.action in ("pulled_inside", "pushed_to_boundary"):
                answer.tuned = answer.settled.tuned


def _tune(spec: TuningSpec, options: TuneOptions) -> TuneResult:
    """The steps of :func:`tune`: plan the budget, train, freeze, settle, polish, then build the result."""
    t0 = time.perf_counter()
    problem = GainProblem(spec, per_loop_repair=options.per_loop_repair)
    spec = problem.spec  # scenario dt/horizon derived from the plant where the spec left them out
    plan = _plan(problem)
    trained = _train(problem, plan, options)
    monitor = trained.monitor
    answer, first, k = _freeze(problem, trained)
    mimo = problem.evaluator.is_mimo  # several inputs or a loop graph: no single-loop boundary settling
    if options.verify and not mimo:
        monitor.report(force=True, phase="settle")
        _settle(problem.evaluator, answer, first, k)
    if spec.search.refine and monitor.stopped != "cancelled" and plan.reserve > 0:
        monitor.report(force=True, phase="refine")
        _polish(problem, plan, answer, options.verify and not mimo)
    agent_path = None
    if options.out_dir is not None:
        out = Path(options.out_dir)
        out.mkdir(parents=True, exist_ok=True)
        agent_path = str(save_agent(trained.agent, out / "agent.zip"))  # atomic: a symlink is replaced, not followed
    result = _result(problem, plan, trained, answer, options, agent_path)
    if options.verify:  # a MIMO spec gets the MIMO verdict (gaintune.verification.mimo_verdict)
        monitor.report(force=True, phase="verify")
        from gaintune.verification import verify as verify_gains

        result.verification = verify_gains(spec, result.gains, plant=problem.plant, layout=problem.layout)
    if options.baselines:
        from gaintune.baselines import run_baseline

        for method in ("simc", "amigo", "zn_step", "imc"):
            res = run_baseline(spec, method, evaluator=problem.evaluator)
            result.baselines.append(res.model_dump(mode="json"))
    result.diagnosis = diagnose(result, problem.layout, answer.tuned, None if mimo else problem.plant)
    result.wall_time = time.perf_counter() - t0
    return result


def _result(problem: GainProblem, plan: _Plan, trained: _Trained, answer: _Answer, options: TuneOptions,
            agent_path: str | None) -> TuneResult:
    """The unverified result of the search: the answer's gains, cost and metrics, and how they were found."""
    spec, layout, settled, monitor = problem.spec, problem.layout, answer.settled, trained.monitor
    final = problem.evaluator.evaluate(answer.tuned[None])
    metrics = {r.scenario: {k: (float(v[0]) if np.isfinite(v[0]) else None) for k, v in r.metrics.items()}
               for r in final.results}
    best_seen = monitor.best_tuned
    return TuneResult(
        spec=spec.model_dump(mode="json"),
        scenario_defaults=problem.scenario_defaults,
        algo=spec.search.algo,
        gains=layout.to_dict(layout.full(answer.tuned)),
        gains_source=answer.source,
        policy_gains=layout.to_dict(layout.full(answer.policy_tuned)),
        best_seen_gains=layout.to_dict(layout.full(best_seen)) if best_seen is not None else None,
        cost=float(final.cost[0]),
        violation=violation_after(settled, final),
        rl_cost=answer.rl_cost,
        rl_feasible=answer.rl_feasible,
        policy_cost=answer.policy_cost,
        settle=None if settled is None else SettleInfo(action=settled.action, alpha=settled.alpha, loop=settled.loop,
                                                       margin=settled.margin, checks=settled.checks),
        metrics=metrics,
        curve=monitor.curve,
        sims=problem.n_sims,
        setup_sims=plan.setup_sims,
        rl_sims=trained.rl_sims,
        wall_time=0.0,
        stopped=monitor.stopped,
        diverged_episodes=monitor.n_diverged,
        tripped_episodes=monitor.n_tripped,
        agent_path=agent_path,
        warm_start=None if options.warm_start is None else str(options.warm_start),
        provenance=Provenance(spec_hash=spec.content_hash(), seed=spec.search.seed, versions=versions(),
                              command=options.command),
    )


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

        raise SpecError("warm_start",
                        f"agent expects {get_action_dim(agent.action_space)} gains; this spec tunes {problem.dim}")
    action = np.asarray(agent.predict(obs, deterministic=True)[0], dtype=float).reshape(-1)
    tuned = problem.repaired(problem.layout.action_to_tuned(action))[0]
    return problem.layout.to_dict(problem.layout.full(tuned))
