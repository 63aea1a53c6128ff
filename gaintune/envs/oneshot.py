"""One-shot gain-tuning environment: one action = every tuned gain; one episode = one closed-loop run."""

from __future__ import annotations

from typing import Any

import gymnasium as gym
import numpy as np

from gaintune.envs.problem import GainProblem
from gaintune.sim.draws import Draws
from gaintune.spec import TuningSpec

__all__ = ["GainTuningEnv"]


class GainTuningEnv(gym.Env):
    """A control loop around a plant whose actions are the loop gains.

    ==================  ==========================================================
    Action space        ``Box(-1, 1, (d,))``: every tuned gain of every loop, mapped
                        log-uniformly onto the gain's bounds inside the env
    Observation space   ``Box(-inf, inf, (c,))``: the episode's normalised context
                        (randomised plant parameters, delay, actuator scale,
                        reference kind/amplitude, disturbance); constant 0 when
                        nothing is randomised
    Reward              ``-(cost/cost_scale + penalties)``, see
                        :mod:`gaintune.envs.problem`; O(1) for sensible gains
    Episode end         after one step (one closed-loop simulation per scenario)
    Info                ``cost``, ``diverged``, ``tripped``, ``violation``,
                        ``gains`` (nested dict) and the first scenario's metrics
    ==================  ==========================================================

    Each reset draws a new plant/scenario from ``spec.randomize`` using the
    env's seeded ``np_random``, so two envs seeded alike give identical rollouts.
    """

    metadata = {"render_modes": []}

    def __init__(self, spec: TuningSpec | dict, problem: GainProblem | None = None) -> None:
        if isinstance(spec, dict):
            spec = TuningSpec.model_validate(spec)
        self.problem = problem or GainProblem(spec)
        self.tuning_spec = spec  # (``self.spec`` is gymnasium's EnvSpec)
        d, c = self.problem.dim, self.problem.obs_size
        self.action_space = gym.spaces.Box(-1.0, 1.0, (d,), dtype=np.float32)
        self.observation_space = gym.spaces.Box(-5.0, 5.0, (c,), dtype=np.float32)
        self._draw: Draws | None = None
        self._obs = np.zeros(c, dtype=np.float32)

    def reset(self, *, seed: int | None = None, options: dict[str, Any] | None = None):
        """Draw a new episode (plant and scenario); the observation is its context."""
        super().reset(seed=seed)
        self._draw = self.problem.draws_for(self.problem.draw(self.np_random, 1))
        self._obs = self.problem.context(self._draw)[0]
        return self._obs.copy(), {}

    def step(self, action: np.ndarray):
        """Score the gains ``action`` encodes on this episode; the episode ends here."""
        if self._draw is None:
            raise RuntimeError("call reset() before step()")
        tuned = self.problem.layout.action_to_tuned(np.asarray(action, dtype=float)[None])
        s = self.problem.score(tuned, self._draw)
        info = {
            "cost": float(s.cost[0]),
            "diverged": bool(s.diverged[0]),
            "tripped": bool(s.tripped[0]),
            "violation": float(s.violation[0]),
            "gains": self.problem.layout.to_dict(self.problem.layout.full(tuned[0])),
            # NaN (e.g. no trip time) becomes None, so infos compare equal across identical rollouts.
            "metrics": {k: (float(v[0]) if np.isfinite(v[0]) else None) for k, v in s.metrics.items()},
        }
        return self._obs.copy(), float(s.reward[0]), True, False, info
