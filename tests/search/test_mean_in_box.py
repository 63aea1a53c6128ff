"""The policy's mean is held inside the action box on one plant (gaintune.search.mean_in_box).

Bug: SB3 clips every sampled action to [-1, 1], so a sample beyond a bound scores like the bound and a
mean that drifted beyond it got no gradient back: on the six-loop cascade, seed 1, the outer loop's Kp
sat on its upper bound from 2,400 simulations on (pre-clip mean 1.36 to 2.28) and RL alone ended at
1.118 x the reference optimum in another basin; held at the bound, it ended at 1.019.
"""

from __future__ import annotations

import numpy as np
import torch

from gaintune.envs.problem import GainProblem
from gaintune.envs.vec import BatchedGainVecEnv
from gaintune.search import tune
from gaintune.search.agents import load_agent, make_agent
from gaintune.search.mean_in_box import hold_mean_in_box
from gaintune.spec import load_spec

# A PI loop on 1/(s+1)^2 whose Kp bounds stop far below the best Kp: the best samples lie beyond the upper bound.
CAPPED = {
    "plant": {"tf": {"num": [1], "den": "(s+1)^2"}},
    "loops": [{"type": "pi", "gains": {"Kp": {"bounds": [0.01, 0.05]}, "Ki": {"bounds": [0.05, 5.0]}}}],
    "scenarios": [{"name": "step", "dt": 0.05, "horizon": 15.0, "reference": {"kind": "step", "amplitude": 1.0}}],
    "requirements": {"gm_min_db": None, "pm_min_deg": None, "ms_max": None},
    "search": {"budget": 2000, "n_envs": 8, "seed": 0, "refine": False},
}


def _raw_mean(agent, obs: np.ndarray) -> np.ndarray:
    with torch.no_grad():
        return agent.policy.get_distribution(agent.policy.obs_to_tensor(obs)[0]).distribution.mean[0].numpy()


def test_hold_mean_in_box_puts_a_mean_beyond_a_bound_on_it_and_leaves_the_rest():
    problem = GainProblem(load_spec(CAPPED))
    agent = make_agent("ppo", BatchedGainVecEnv(problem, 8, seed=0), 0, 100)
    obs = np.zeros((1, problem.obs_size), dtype=np.float32)
    with torch.no_grad():
        agent.policy.action_net.bias.add_(torch.tensor([1.7, -0.3]))
    before = _raw_mean(agent, obs)
    excess = hold_mean_in_box(agent.policy, obs)
    after = _raw_mean(agent, obs)
    assert before[0] > 1.5
    np.testing.assert_allclose(after, [1.0, before[1]], atol=1e-6)
    np.testing.assert_allclose(excess, [before[0] - 1.0, 0.0], atol=1e-6)


def test_search_with_the_best_gain_beyond_its_bound_keeps_the_policy_mean_on_the_bound(tmp_path):
    spec = load_spec(CAPPED)
    tune(spec, verify=False, out_dir=tmp_path)
    agent = load_agent(tmp_path / "agent.zip", spec)
    mean = _raw_mean(agent, np.zeros((1, agent.observation_space.shape[0]), dtype=np.float32))
    # held at the bound before every rollout; without the hold it drifted to 1.72 (1.16 at 1,000 simulations)
    assert mean[0] < 1.1
