"""Iterative gain-tuning environment: the agent refines the gains over a few steps.

The observation is the current gains (as actions in [-1, 1]) plus their
value (the one-shot reward of :mod:`gaintune.envs.problem`, feasibility first)
and requirement violation, both divided by COST_CAP, and the episode context;
the action is a bounded multiplicative change of every tuned gain (at most a
factor ``exp(max_step * log-range / 2)`` per step). The reward is the
improvement of that value in each step, so an episode's return is the total
improvement from the starting gains (the classical-rule centre of the bounds).
"""

from __future__ import annotations

from typing import Any

import gymnasium as gym
import numpy as np

from gaintune.envs.problem import COST_CAP, VIOLATION_CAP, GainProblem
from gaintune.sim.draws import Draws
from gaintune.spec import TuningSpec

__all__ = ["IterativeGainTuningEnv"]


class IterativeGainTuningEnv(gym.Env):
    """Refine gains step by step; see the module docstring for the spaces and reward."""

    metadata = {"render_modes": []}

    def __init__(
        self, spec: TuningSpec | dict, problem: GainProblem | None = None, horizon: int = 5, max_step: float = 0.25
    ) -> None:
        if isinstance(spec, dict):
            spec = TuningSpec.model_validate(spec)
        self.problem = problem or GainProblem(spec)
        self.horizon = horizon
        self.max_step = max_step
        d, c = self.problem.dim, self.problem.obs_size
        self.action_space = gym.spaces.Box(-1.0, 1.0, (d,), dtype=np.float32)
        self.observation_space = gym.spaces.Box(-5.0, 5.0, (d + 2 + c,), dtype=np.float32)
        self._a = np.zeros(d)
        self._t = 0
        self._value = 0.0
        self._draw: Draws | None = None
        self._ctx = np.zeros(c, dtype=np.float32)
        self._margin = 0.0

    @property
    def action(self) -> np.ndarray:
        """The current gains as an action in [-1, 1] (a copy): where the steps so far have moved them."""
        return self._a.copy()

    def _obs(self) -> np.ndarray:
        obs = np.concatenate([self._a, [-self._value / COST_CAP, self._margin / COST_CAP], self._ctx])
        return np.clip(obs, -5, 5).astype(np.float32)

    def _evaluate(self, a: np.ndarray) -> tuple[float, dict[str, Any]]:
        tuned = self.problem.layout.action_to_tuned(a[None])
        if self._draw is None:
            raise RuntimeError("call reset() before step()")
        s = self.problem.score(tuned, self._draw)
        self._margin = float(min(s.violation[0], VIOLATION_CAP))
        info = {"cost": float(s.cost[0]), "diverged": bool(s.diverged[0]), "tripped": bool(s.tripped[0]),
                "gains": self.problem.layout.to_dict(self.problem.layout.full(tuned[0]))}
        return float(s.reward[0]), info

    def reset(self, *, seed: int | None = None, options: dict[str, Any] | None = None):
        """Draw a new episode (plant and scenario) and start from the centre of the bounds."""
        super().reset(seed=seed)
        self._draw = self.problem.draws_for(self.problem.draw(self.np_random, 1))
        self._ctx = self.problem.context(self._draw)[0]
        self._a = np.zeros(self.problem.dim)  # the classical-rule centre of the bounds
        self._t = 0
        self._value, info = self._evaluate(self._a)
        return self._obs(), info

    def step(self, action: np.ndarray):
        """Move the gains by ``action`` (bounded), score them and reward the improvement."""
        if self._draw is None:
            raise RuntimeError("call reset() before step()")
        step = self.max_step * np.clip(np.asarray(action, dtype=float), -1.0, 1.0)
        self._a = np.clip(self._a + step, -1.0, 1.0)
        value, info = self._evaluate(self._a)
        span = COST_CAP + VIOLATION_CAP  # the whole reward range
        reward = float(np.clip(value - self._value, -span, span))
        self._value = value
        self._t += 1
        return self._obs(), reward, False, self._t >= self.horizon, info
