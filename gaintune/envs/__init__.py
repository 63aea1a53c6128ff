"""Gymnasium environments whose actions are controller gains.

Registered ids (pass ``spec=`` to :func:`gymnasium.make`):

* ``gaintune/GainTuning-v0`` - :class:`GainTuningEnv`, one-shot;
* ``gaintune/IterativeGainTuning-v0`` - :class:`IterativeGainTuningEnv`.

:class:`BatchedGainVecEnv` is the SB3 VecEnv that evaluates all sub-envs in one simulator call.
"""

import gymnasium as gym

from gaintune.envs.iterative import IterativeGainTuningEnv
from gaintune.envs.oneshot import GainTuningEnv
from gaintune.envs.problem import GainProblem
from gaintune.envs.vec import BatchedGainVecEnv

__all__ = ["GainTuningEnv", "IterativeGainTuningEnv", "BatchedGainVecEnv", "GainProblem", "ENV_IDS"]

ENV_IDS = ("gaintune/GainTuning-v0", "gaintune/IterativeGainTuning-v0")

if ENV_IDS[0] not in gym.registry:
    gym.register(ENV_IDS[0], entry_point="gaintune.envs.oneshot:GainTuningEnv")
    gym.register(ENV_IDS[1], entry_point="gaintune.envs.iterative:IterativeGainTuningEnv", max_episode_steps=5)
