"""RL search at scale: the exploration that shrinks with the gain count, the per-loop repair in a tune.

Bug (issue 28): on the six-loop cascade (12 gains) the PPO policy started with the exploration of a
single PID loop (log std -1, a factor 3.5 on each gain): every one of 32 samples missed a requirement
and three quarters were unstable, and RL alone ended at 1.07-1.12 x the reference optimum.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from stable_baselines3.common.vec_env import VecEnv

from gaintune.envs.problem import GainProblem
from gaintune.envs.vec import BatchedGainVecEnv
from gaintune.search import tune
from gaintune.search.agents import EXPLORATION_DIM, agent_defaults, exploration_log_std, make_agent
from gaintune.spec import load_spec

CASCADE = {
    "plant": {"ss": {"A": [[-10.0, 0.0], [1.0, -1.0]], "B": [[10.0], [0.0]], "C": [[1.0, 0.0], [0.0, 1.0]],
                     "outputs": ["y1", "y2"], "states": ["x1", "x2"]}},
    "loops": [{"name": "outer", "measure": "y2", "type": "pi"}, {"name": "inner", "measure": "y1", "type": "pi"}],
    "scenarios": [{"name": "step", "dt": 0.02, "horizon": 8.0, "reference": {"kind": "step", "amplitude": 1.0}}],
    "requirements": {"gm_min_db": None, "pm_min_deg": None, "ms_max": 1.6},
    "search": {"budget": 300, "n_envs": 8, "seed": 0, "refine": False},
}


def test_exploration_of_single_loops_is_unchanged():
    assert exploration_log_std(1) == exploration_log_std(2) == exploration_log_std(EXPLORATION_DIM) == -1.0


@pytest.mark.parametrize("dim", [4, 12, 30, 120])
def test_exploration_shrinks_by_a_quarter_per_doubling_of_the_gain_count(dim):
    assert exploration_log_std(dim) == pytest.approx(-1.0 - 0.25 * math.log2(dim / EXPLORATION_DIM), rel=1e-12)
    assert exploration_log_std(2 * dim) == pytest.approx(exploration_log_std(dim) - 0.25, rel=1e-12)
    assert exploration_log_std(dim) < exploration_log_std(dim - 1)


@pytest.mark.parametrize("algo", ["ppo", "a2c"])
def test_six_loop_cascade_policy_starts_with_the_scaled_exploration(algo):
    kw = agent_defaults(algo, 32, 12, 1000)
    assert kw["policy_kwargs"]["log_std_init"] == -1.5


def test_agent_built_for_a_cascade_has_the_scaled_log_std():
    problem = GainProblem(load_spec(CASCADE))
    env: VecEnv = BatchedGainVecEnv(problem, 8, seed=0)
    agent = make_agent("ppo", env, 0, 100)
    log_std = agent.policy.log_std.detach().numpy()
    np.testing.assert_allclose(log_std, exploration_log_std(4), rtol=1e-6)


def test_seeded_search_with_the_per_loop_repair_is_reproducible():
    spec = load_spec(CASCADE)
    a = tune(spec, verify=False, per_loop_repair=True)
    b = tune(spec, verify=False, per_loop_repair=True)
    assert a.gains == b.gains and a.rl_cost == b.rl_cost and a.sims == b.sims
