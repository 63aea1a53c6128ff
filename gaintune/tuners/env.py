"""The training environment of a tuner: one step per episode, one context per episode, its own cost.

Every episode draws a context (a plant of the family), shows the policy its features, takes
the policy's action as gains in the tuner's box, moves them onto that plant's requirement
boundary from either side (:func:`gaintune.evaluation.boundary_both.onto_boundary`) and
scores them on that plant alone. The reward is ``-log(cost)`` of that context's plant:
the per-context optimum is the reward's maximum for every context, and the log removes the
family's cost scale (the value network learns each context's level). Gains that no scale makes
feasible earn a reward just below the worst feasible one of their context's batch. No aggregate over the family enters:
that is a robust design, which ``gaintune tune`` makes.

The ``n_envs`` episodes of a step share ``n_envs / contexts_per_step`` contexts, so each
context's gain sets are repaired and simulated as one batch (the batched simulator); every
rollout of ``n_steps`` steps still sees ``n_steps * contexts_per_step`` contexts.
"""

from __future__ import annotations

from typing import Any

import gymnasium as gym
import numpy as np
from stable_baselines3.common.vec_env import VecEnv

from gaintune.evaluation.boundary_both import onto_boundary
from gaintune.evaluation.evaluator import Evaluator
from gaintune.tuners.problems import TunerProblem

__all__ = ["ContextBanditVecEnv", "FLOOR_REWARD", "reward_of"]

#: Reward of gains that no loop-gain scale makes feasible (below -log of any real cost here).
FLOOR_REWARD = -12.0


def reward_of(cost: np.ndarray, feasible: np.ndarray) -> np.ndarray:
    """``-log(cost)`` where feasible; one below the worst feasible reward of the batch (one context) otherwise.

    The step below the feasible ones is kept small on purpose: a critic smooths a cliff of many
    units into the feasible side next to it and the actor then learns to keep away from the
    boundary where the optimum lies. :data:`FLOOR_REWARD` when nothing in the batch is feasible.
    """
    with np.errstate(divide="ignore", invalid="ignore"):
        r = -np.log(np.maximum(cost, 1e-300))
    ok = feasible & np.isfinite(r)
    floor = float(np.min(r[ok])) - 1.0 if ok.any() else FLOOR_REWARD
    return np.where(ok, np.maximum(r, FLOOR_REWARD + 1.0), max(floor, FLOOR_REWARD))


class ContextBanditVecEnv(VecEnv):
    """SB3 vectorised env over the contexts of ``problem`` (see the module docstring)."""

    def __init__(self, problem: TunerProblem, n_envs: int = 32, contexts_per_step: int = 4, seed: int = 0) -> None:
        if problem.box is None:
            raise ValueError("the problem needs its gain box")
        if n_envs % contexts_per_step:
            raise ValueError(f"n_envs {n_envs} is not a multiple of contexts_per_step {contexts_per_step}")
        self.problem = problem
        self.group = n_envs // contexts_per_step
        self.k = contexts_per_step
        n_obs, n_act = len(problem.variables), len(problem.box.slots)
        obs_space = gym.spaces.Box(-3.0, 3.0, (n_obs,), np.float32)
        act_space = gym.spaces.Box(-1.0, 1.0, (n_act,), np.float32)
        self.render_mode = None  # SB3 asks for it while initialising
        super().__init__(n_envs, obs_space, act_space)
        self.rng = np.random.default_rng(seed)
        self.n_sims = 0
        self.episodes = 0
        self.last: dict[str, Any] = {}
        self._contexts: list[dict[str, float]] = []
        self._actions = np.zeros((n_envs, n_act))

    def _new_contexts(self) -> np.ndarray:
        self._contexts = self.problem.draw(self.rng, self.k)
        feats = np.vstack([self.problem.features(c) for c in self._contexts])
        return np.repeat(feats, self.group, axis=0).astype(np.float32)

    def reset(self) -> np.ndarray:
        self._obs = self._new_contexts()
        return self._obs

    def step_async(self, actions: np.ndarray) -> None:
        self._actions = np.asarray(actions, dtype=float)

    def score(self, context: dict[str, float], actions: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(reward, cost) of ``actions`` (B, d) at one context, after the move onto its boundary."""
        assert self.problem.box is not None
        ev = Evaluator(self.problem.spec_at(context))
        move = onto_boundary(ev, self.problem.box.to_tuned(actions))
        self.n_sims += ev.n_sims
        s = move.scores
        return reward_of(s.cost, s.feasible), s.cost

    def step_wait(self) -> Any:
        rewards = np.zeros(self.num_envs, dtype=np.float32)
        costs = np.zeros(self.num_envs)
        for i, ctx in enumerate(self._contexts):
            sl = slice(i * self.group, (i + 1) * self.group)
            r, c = self.score(ctx, self._actions[sl])
            rewards[sl], costs[sl] = r, c
        self.episodes += self.num_envs
        self.last = {"reward": float(np.mean(rewards)), "contexts": list(self._contexts)}
        old = self._obs
        self._obs = self._new_contexts()
        dones = np.ones(self.num_envs, dtype=bool)
        infos = [{"terminal_observation": old[i], "cost": float(costs[i]),
                  "TimeLimit.truncated": False} for i in range(self.num_envs)]
        return self._obs, rewards, dones, infos

    def close(self) -> None:
        pass

    def get_attr(self, attr_name: str, indices: Any = None) -> list[Any]:
        return [getattr(self, attr_name)] * self._count(indices)

    def set_attr(self, attr_name: str, value: Any, indices: Any = None) -> None:
        setattr(self, attr_name, value)

    def env_method(self, method_name: str, *args: Any, indices: Any = None, **kwargs: Any) -> list[Any]:
        return [getattr(self, method_name)(*args, **kwargs)] * self._count(indices)

    def env_is_wrapped(self, wrapper_class: Any, indices: Any = None) -> list[bool]:
        return [False] * self._count(indices)

    def seed(self, seed: int | None = None) -> list[int | None]:
        self.rng = np.random.default_rng(seed)
        return [seed] * self.num_envs

    def _count(self, indices: Any) -> int:
        if indices is None:
            return self.num_envs
        return 1 if isinstance(indices, int) else len(list(indices))

