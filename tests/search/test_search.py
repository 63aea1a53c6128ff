"""RL search: end-to-end tune, budgets, progress/cancel, early stop, save/load/warm start, reproducibility."""

from __future__ import annotations

import threading

import numpy as np
import pytest

from gaintune.evaluation.evaluator import Evaluator
from gaintune.search import Progress, policy_gains, tune
from gaintune.search.agents import load_agent
from gaintune.spec import load_spec
from gaintune.verification import VerificationReport

EASY = {
    "plant": {"tf": {"num": ["K"], "den": "(s+1)^2"}, "params": {"K": 1.0}},
    "loops": [{"type": "pi"}],
    "scenario": {"horizon": 10, "dt": 0.02},
    "search": {"budget": 600, "n_envs": 16, "seed": 1},
}


def _spec(**search):
    data = {**EASY, "search": {**EASY["search"], **search}}
    return load_spec(data)


@pytest.fixture(scope="module")
def tuned(tmp_path_factory):
    out = tmp_path_factory.mktemp("tune")
    seen: list[Progress] = []
    result = tune(_spec(), out_dir=out, progress=seen.append)
    return result, seen, out


def test_tune_beats_a_poor_starting_guess(tuned):
    result, _, _ = tuned
    spec = _spec()
    ev = Evaluator(spec)
    poor = ev.layout.from_dict({"loop0": {"Kp": 0.05, "Ki": 0.02}})
    poor_cost = float(ev(poor[ev.layout.tuned_idx][None])[0])
    assert result.cost < 0.5 * poor_cost
    # the RL figure is reported beside the refined one and is itself a clear improvement
    assert result.rl_cost is not None and result.rl_cost < 0.6 * poor_cost
    assert result.cost <= result.rl_cost + 1e-12


def test_budget_progress_and_result_fields(tuned):
    result, seen, _ = tuned
    assert result.sims <= 600
    sims = [p.sims for p in seen if p.phase == "search"]
    assert sims == sorted(sims) and sims[-1] > 0
    assert result.curve and [c.best_cost for c in result.curve] == sorted((c.best_cost for c in result.curve), reverse=True)
    assert result.provenance.seed == 1 and result.provenance.versions["stable-baselines3"]
    assert isinstance(result.verification, VerificationReport) and result.verification.verdict in ("pass", "fail")
    assert set(result.gains) == {"loop0"} and set(result.gains["loop0"]) == {"Kp", "Ki"}
    assert 0 <= result.diverged_episodes <= result.rl_sims and 0 <= result.tripped_episodes <= result.rl_sims

    if result.verdict == "pass":
        assert result.accepted_gains == result.gains
    else:
        assert result.accepted_gains is None


def test_save_load_and_warm_start_round_trip(tuned):
    result, _, out = tuned
    agent_path = out / "agent.zip"
    assert result.agent_path == str(agent_path) and agent_path.exists()
    agent = load_agent(agent_path, _spec())
    action = agent.predict(np.zeros((1, 1), dtype=np.float32), deterministic=True)[0]
    spec = _spec()
    from gaintune.envs import GainProblem

    gp = GainProblem(spec)
    lay = gp.layout  # the policy's gains are scored as its samples were: repaired onto the boundary
    gains = lay.to_dict(lay.full(gp.repaired(lay.action_to_tuned(np.asarray(action).reshape(-1)))[0]))
    assert gains["loop0"]["Kp"] == pytest.approx(result.policy_gains["loop0"]["Kp"], rel=1e-5)
    # learning on: continue on a changed plant
    changed = load_spec({**EASY, "plant": {**EASY["plant"], "params": {"K": 1.5}}, "search": {**EASY["search"], "budget": 200}})
    warm = tune(changed, warm_start=agent_path, verify=False)
    assert warm.rl_sims > 0 and warm.cost < 1e6
    # learning off: the saved policy reused as it is
    off = policy_gains(agent_path, _spec())
    assert off["loop0"]["Kp"] == pytest.approx(result.policy_gains["loop0"]["Kp"], rel=1e-5)


def test_sb3_temp_folder_litter_tune_and_warm_start_create_no_folder(tuned, tmp_path, monkeypatch):
    """Bug: every learn() made an empty SB3-<date> folder in the temp directory (3,734 found)."""
    import tempfile

    _, _, out = tuned
    monkeypatch.setattr(tempfile, "tempdir", str(tmp_path))
    fresh = tune(_spec(budget=200), verify=False)
    warm = tune(_spec(budget=200), warm_start=out / "agent.zip", verify=False)
    assert fresh.rl_sims > 0 and warm.rl_sims > 0  # both agents learned
    assert [p.name for p in tmp_path.iterdir()] == []


def test_seeded_search_is_reproducible():
    a = tune(_spec(budget=200, refine=False), verify=False)
    b = tune(_spec(budget=200, refine=False), verify=False)
    assert a.gains == b.gains and a.rl_cost == b.rl_cost


def test_cancel_and_progress_false_stop_the_search():
    event = threading.Event()
    event.set()
    r = tune(_spec(budget=2000, refine=False), cancel=event, verify=False)
    assert r.stopped == "cancelled" and r.rl_sims <= 16
    r2 = tune(_spec(budget=2000, refine=False), progress=lambda p: False, verify=False)
    assert r2.stopped == "cancelled" and r2.rl_sims < 2000


def test_wall_time_and_early_stop():
    r = tune(_spec(budget=5000, refine=False, wall_time=0.3), verify=False)
    assert r.stopped == "wall_time" and r.rl_sims < 5000
    r2 = tune(_spec(budget=3000, refine=False, early_stop_patience=32), verify=False)
    assert r2.stopped == "converged" and r2.rl_sims < 3000


def test_safety_trips_are_counted_in_the_search_statistics():
    spec = load_spec({**EASY, "safety": {"max_abs_output": 1.3}, "search": {**EASY["search"], "budget": 300, "refine": False}})
    r = tune(spec, verify=False)
    assert r.tripped_episodes > 0  # wide exploration overshoots past |y| = 1.3 at least sometimes
    assert r.tripped_episodes <= r.rl_sims


def test_tune_never_loses_the_start_point():
    """With a budget too small to learn anything, the answer is at least as good as the search box's centre."""
    from gaintune.envs.problem import GainProblem

    spec = load_spec({"plant": {"tf": {"num": [1], "den": "(s+1)^3"}}, "loops": [{"type": "pi"}],
                      "scenario": {"dt": 0.05, "horizon": 20}, "search": {"budget": 64, "n_envs": 8, "refine": False}})
    gp = GainProblem(spec)
    start = gp.evaluator.evaluate(gp.layout.initial_tuned()[None])
    r = tune(spec)
    assert r.violation == 0 and bool(start.feasible[0])
    assert r.cost <= float(start.cost[0]) * (1 + 1e-9)


@pytest.mark.parametrize("algo", ["sac", "td3", "ddpg"])
def test_off_policy_replay_buffer_is_capped_not_sized_by_a_huge_budget(algo):
    # a 1e12-sim budget asked numpy for a 3.6 TiB replay buffer (MemoryError traceback)
    import gymnasium as gym
    from stable_baselines3.common.vec_env import DummyVecEnv

    from gaintune.search.agents import REPLAY_MAX, make_agent

    class Idle(gym.Env):
        observation_space = gym.spaces.Box(-1.0, 1.0, (1,), np.float32)
        action_space = gym.spaces.Box(-1.0, 1.0, (2,), np.float32)

    agent = make_agent(algo, DummyVecEnv([Idle] * 4), 0, 10**12)
    assert agent.replay_buffer.buffer_size * agent.n_envs <= REPLAY_MAX


def test_ppo_with_a_single_env_tunes_instead_of_failing_on_batch_size():
    # n_envs 1 (--workers 1) made SB3's PPO assert `batch_size` > 1: a traceback, a failed API job
    r = tune(_spec(n_envs=1, budget=200), verify=False)
    assert r.rl_sims > 0 and np.isfinite(r.cost)


def test_every_gain_fixed_is_a_spec_error_not_a_reshape_crash():
    from gaintune.errors import SpecError

    data = {**EASY, "loops": [{"type": "pi", "gains": {"Kp": {"value": 1, "tune": False}, "Ki": {"value": 0.5, "tune": False}}}]}
    with pytest.raises(SpecError, match="loops: every gain is fixed"):
        tune(load_spec(data), verify=False)


@pytest.mark.parametrize("key", ["reference_amplitude", "disturbance_size", "disturbance_time"])
def test_randomised_reference_or_disturbance_tunes_with_a_finite_nominal_context(key):
    # the nominal draw keeps each scenario's own value (NaN in the draws), which reached the policy as
    # a NaN observation: torch refused it, and every such tune crashed
    from gaintune.envs import GainProblem
    from gaintune.sim import draws as draws_mod

    scenario = {**EASY["scenario"], "disturbance": {"kind": "step", "time": 2, "amplitude": 0.5}}
    box = [1.0, 3.0] if key == "disturbance_time" else [0.5, 2.0]
    spec = load_spec({**EASY, "scenario": scenario, "randomize": {key: box}, "search": {**EASY["search"], "budget": 300}})
    gp = GainProblem(spec)
    assert np.all(gp.context(draws_mod.nominal(spec, gp.plant, 1)) == 0.0)
    r = tune(spec, verify=False)
    assert r.rl_sims > 0 and np.isfinite(r.cost)
