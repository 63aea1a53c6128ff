"""Gain-tuning environments: checkers, seeding, reward arithmetic, safety monitor, batched VecEnv."""

from __future__ import annotations

import gymnasium as gym
import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env as gym_check_env
from stable_baselines3.common.env_checker import check_env as sb3_check_env

from gaintune.envs import ENV_IDS, BatchedGainVecEnv, GainProblem, GainTuningEnv, IterativeGainTuningEnv
from gaintune.envs.problem import COST_CAP, VIOLATION_CAP, rank_reward
from gaintune.evaluation.evaluator import DIVERGED_VIOLATION, TRIP_VIOLATION, merit, scenario_cost
from gaintune.spec import load_spec

LAG3 = {"plant": {"tf": {"num": [1], "den": "(s+1)^3"}}, "loops": [{"type": "pid"}], "scenario": {"horizon": 15}}
RANDOMIZED = {
    "plant": {"tf": {"num": ["K"], "den": "(T*s+1)^2"}, "params": {"K": 1.0, "T": 1.0}, "delay": 0.2},
    "loops": [{"type": "pi"}],
    "actuator": {"limits": [-3, 3]},
    "scenario": {"horizon": 15},
    "randomize": {
        "params": {"K": [0.8, 1.2], "T": {"dist": "loguniform", "low": 0.7, "high": 1.4}},
        "delay": [0.1, 0.3],
        "actuator_scale": [0.8, 1.2],
        "reference_kinds": ["step", "ramp", "impulse"],
    },
}


@pytest.fixture(scope="module")
def lag3() -> GainProblem:
    return GainProblem(load_spec(LAG3))


@pytest.fixture(scope="module")
def randomized() -> GainProblem:
    return GainProblem(load_spec(RANDOMIZED))


@pytest.mark.filterwarnings("ignore::UserWarning")
@pytest.mark.parametrize("which", ["lag3", "randomized"])
@pytest.mark.parametrize("kind", [GainTuningEnv, IterativeGainTuningEnv])
def test_env_checkers(which, kind, request):
    problem = request.getfixturevalue(which)
    env = kind(problem.spec, problem=problem)
    gym_check_env(env, skip_render_check=True)
    sb3_check_env(env, warn=False)


@pytest.mark.parametrize("env_id", ENV_IDS)
def test_registered_ids_make(env_id):
    env = gym.make(env_id, spec=LAG3)
    obs, _ = env.reset(seed=3)
    assert env.observation_space.contains(obs)
    _, reward, *_ = env.step(env.action_space.sample())
    assert np.isfinite(reward)


def test_seeded_envs_give_identical_rollouts(randomized):
    a = GainTuningEnv(randomized.spec, problem=randomized)
    b = GainTuningEnv(randomized.spec, problem=randomized)
    rng = np.random.default_rng(0)
    for episode in range(4):
        oa, _ = a.reset(seed=42 + episode)
        ob, _ = b.reset(seed=42 + episode)
        np.testing.assert_array_equal(oa, ob)
        action = rng.uniform(-1, 1, a.action_space.shape)
        ra = a.step(action)
        rb = b.step(action)
        assert ra[1] == rb[1]
        assert ra[4]["cost"] == rb[4]["cost"]
    # and different seeds draw different contexts
    assert not np.array_equal(a.reset(seed=1)[0], a.reset(seed=2)[0])


def test_observation_is_constant_without_randomisation(lag3):
    env = GainTuningEnv(lag3.spec, problem=lag3)
    assert np.array_equal(env.reset(seed=0)[0], env.reset(seed=1)[0])


def test_reward_arithmetic_matches_hand_computation(lag3):
    env = GainTuningEnv(lag3.spec, problem=lag3)
    env.reset(seed=0)
    action = np.array([-0.5, -0.6, -0.45])  # well inside the box centre (itself near the boundary): feasible
    _, reward, terminated, truncated, info = env.step(action)
    assert terminated and not truncated
    # independent computation: map the action by hand and simulate
    lay = lag3.layout
    tuned = np.exp(lay.log_lo + (action + 1) / 2 * (lay.log_hi - lay.log_lo))
    res = lag3.sim.run(lay.full(tuned[None]))
    sc = lag3.spec.scenarios[0]
    m = res.metrics
    cost = m["iae"][0] + 0.01 * m["effort"][0]
    assert cost == pytest.approx(scenario_cost(m, lag3.spec.objective, sc)[0], rel=1e-12)
    assert info["cost"] == pytest.approx(cost, rel=1e-12)  # the plain cost, no penalty terms
    assert info["violation"] == 0.0  # these gains meet the default requirements
    assert reward == pytest.approx(-cost / lag3.cost_scale, rel=1e-9)
    # an aggressive gain set violates them: rewarded below every feasible one, graded by the violation
    tuned2 = lay.action_to_tuned(np.array([[0.9, 0.9, -1.0]]))
    s2 = lag3.score(tuned2, lag3.draw(np.random.default_rng(0), 1))
    assert s2.violation[0] > 0
    assert s2.reward[0] == pytest.approx(-(COST_CAP + min(s2.violation[0], VIOLATION_CAP)))


def test_diverged_gains_get_capped_cost_plus_penalty():
    spec = load_spec({**LAG3, "loops": [{"type": "p", "gains": {"Kp": {"bounds": [50, 500]}}}]})
    problem = GainProblem(spec)
    env = GainTuningEnv(spec, problem=problem)
    env.reset(seed=0)
    _, reward, *_, info = env.step(np.array([1.0]))  # Kp = 500: far beyond the ultimate gain 8
    assert info["diverged"] and info["violation"] >= DIVERGED_VIOLATION
    assert reward == pytest.approx(-(COST_CAP + min(info["violation"], VIOLATION_CAP)))


def test_safety_monitor_trips_on_unstable_gains():
    spec = load_spec(
        {
            **LAG3,
            "loops": [{"type": "p", "gains": {"Kp": {"bounds": [0.5, 40]}}}],
            "safety": {"max_abs_output": 5.0},
            "actuator": {"safe_value": 0.0},
        }
    )
    problem = GainProblem(spec)
    env = GainTuningEnv(spec, problem=problem)
    env.reset(seed=0)
    _, reward, *_, info = env.step(np.array([1.0]))  # Kp = 40 > Ku = 8: oscillation grows past |y| = 5
    assert info["tripped"] and not info["diverged"]
    assert info["metrics"]["trip_time"] is not None
    assert info["violation"] >= TRIP_VIOLATION and reward <= -(COST_CAP + TRIP_VIOLATION)
    # a stable gain never trips
    env.reset(seed=0)
    _, _, *_, info = env.step(np.array([-1.0]))
    assert not info["tripped"]


def test_vec_env_uses_one_batched_simulation_per_scenario(lag3, monkeypatch):
    calls = []
    real_run = lag3.sim.run

    def counting_run(full, *args, **kwargs):
        calls.append(np.atleast_2d(full).shape[0])
        return real_run(full, *args, **kwargs)

    monkeypatch.setattr(lag3.sim, "run", counting_run)
    venv = BatchedGainVecEnv(lag3, n_envs=16, seed=0)
    venv.reset()
    actions = np.random.default_rng(0).uniform(-1, 1, (16, 3))
    _, rewards, dones, infos = venv.step(actions)
    assert calls == [16]
    assert dones.all() and len(infos) == 16
    # the same actions one by one through the single env give the same scores; on one plant the batched
    # env rewards their centred ranks within the batch (fitness shaping: gaintune.envs.problem)
    env = GainTuningEnv(lag3.spec, problem=lag3)
    env.reset(seed=0)
    merits = []
    for i in range(16):
        info = env.step(actions[i])[4]
        merits.append(float(merit(np.array(info["cost"]), np.array(info["violation"]))))
        assert info["cost"] == pytest.approx(infos[i]["cost"], rel=1e-9)
    np.testing.assert_allclose(rewards, rank_reward(np.array(merits)), rtol=1e-6)


def test_iterative_env_return_is_total_improvement(lag3):
    env = IterativeGainTuningEnv(lag3.spec, problem=lag3, horizon=3)
    obs, info0 = env.reset(seed=0)
    start_value = -COST_CAP * float(obs[lag3.dim])  # the observation holds -value / COST_CAP
    total = 0.0
    for _ in range(3):
        obs, r, terminated, truncated, info = env.step(np.full(lag3.dim, 0.3))
        total += r
    assert truncated and not terminated
    assert total == pytest.approx(-COST_CAP * float(obs[lag3.dim]) - start_value, abs=1e-5)


def test_iterative_env_action_is_where_the_steps_moved_the_gains(lag3):
    """The search reads the iterative policy's answer through ``action`` (it reached into ``env._a`` before)."""
    env = IterativeGainTuningEnv(lag3.spec, problem=lag3, horizon=3)
    obs, _ = env.reset(seed=0)
    assert np.array_equal(env.action, np.zeros(lag3.dim))
    env.step(np.full(lag3.dim, 0.4))
    env.step(np.full(lag3.dim, 0.4))
    moved = env.action
    assert np.allclose(moved, np.clip(2 * env.max_step * 0.4, -1, 1))
    assert np.allclose(env.step(np.zeros(lag3.dim))[0][: lag3.dim], moved)  # the observation shows it too
    moved[:] = 9.0  # a copy: changing it leaves the env alone
    assert np.all(env.action < 1.0)
