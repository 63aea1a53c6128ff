"""A stable-baselines3 VecEnv that scores every sub-environment's gains in ONE batched simulation.

With one-step episodes every ``step`` finishes all episodes at once: the
actions of all n sub-environments become one (n, d) batch for the compiled
simulator, and the next episodes' draws are sampled together. There is no
per-env Python simulation and no subprocess.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import gymnasium as gym
import numpy as np
from stable_baselines3.common.vec_env import VecEnv
from stable_baselines3.common.vec_env.base_vec_env import VecEnvStepReturn

from gaintune.envs.problem import GainProblem, Scored, rank_reward
from gaintune.sim.draws import Draws

__all__ = ["BatchedGainVecEnv"]


class BatchedGainVecEnv(VecEnv):
    """n one-shot gain-tuning envs evaluated together.

    Parameters
    ----------
    problem
        The shared problem (simulator, layout, reward).
    n_envs
        Number of sub-environments (episodes per batched call).
    seed
        Seed of the episode-draw generator.
    """

    def __init__(self, problem: GainProblem, n_envs: int, seed: int = 0) -> None:
        self.problem = problem
        obs_space = gym.spaces.Box(-5.0, 5.0, (problem.obs_size,), dtype=np.float32)
        act_space = gym.spaces.Box(-1.0, 1.0, (problem.dim,), dtype=np.float32)
        super().__init__(n_envs, obs_space, act_space)
        self._rng = np.random.default_rng(seed)
        self._actions: np.ndarray | None = None
        self._draws: Draws | None = None
        self._obs = np.zeros((n_envs, problem.obs_size), dtype=np.float32)

    def _new_episodes(self) -> np.ndarray:
        d = self.problem.draw(self._rng, self.num_envs)
        self._draws = self.problem.draws_for(d)
        self._obs = self.problem.context(d)
        return self._obs.copy()

    def seed(self, seed: int | None = None) -> Sequence[int | None]:
        """Reseed the episode draws."""
        if seed is not None:
            self._rng = np.random.default_rng(seed)
        return [seed] * self.num_envs

    def reset(self) -> np.ndarray:
        """Start a new episode in every env; returns their observations."""
        return self._new_episodes()

    def step_async(self, actions: np.ndarray) -> None:
        """Keep the actions for :meth:`step_wait`."""
        self._actions = np.asarray(actions, dtype=float).reshape(self.num_envs, -1)

    def step_wait(self) -> VecEnvStepReturn:
        """Score the actions of :meth:`step_async` (one simulator call) and start a new episode in every env."""
        assert self._actions is not None and self._draws is not None
        tuned = self.problem.layout.action_to_tuned(self._actions)
        s: Scored = self.problem.score(tuned, self._draws)
        last_obs = self._obs
        new_obs = self._new_episodes()
        infos: list[dict[str, Any]] = [
            {"cost": float(s.cost[i]), "violation": float(s.violation[i]), "diverged": bool(s.diverged[i]),
             "tripped": bool(s.tripped[i]), "terminal_observation": last_obs[i], "TimeLimit.truncated": False}
            for i in range(self.num_envs)
        ]
        # one plant: the batch's centred ranks (fitness shaping, see gaintune.envs.problem)
        reward = s.reward if self.problem.randomized else rank_reward(s.merit)
        return new_obs, reward.astype(np.float32), np.ones(self.num_envs, dtype=bool), infos

    def close(self) -> None:
        """Nothing to release: the envs share one in-process simulator."""

    def get_attr(self, attr_name: str, indices=None) -> list[Any]:
        """The attribute of this (shared) env, once per index."""
        return [getattr(self, attr_name, None)] * len(self._idx(indices))

    def set_attr(self, attr_name: str, value: Any, indices=None) -> None:
        """Set the attribute on this (shared) env."""
        setattr(self, attr_name, value)

    def env_method(self, method_name: str, *args, indices=None, **kwargs) -> list[Any]:
        """Call the method of this (shared) env once per index."""
        return [getattr(self, method_name)(*args, **kwargs) for _ in self._idx(indices)]

    def env_is_wrapped(self, wrapper_class, indices=None) -> list[bool]:
        """Always False: the batched env wraps nothing."""
        return [False] * len(self._idx(indices))

    def _idx(self, indices) -> list[int]:
        if indices is None:
            return list(range(self.num_envs))
        return [indices] if isinstance(indices, int) else list(indices)
