"""Keep the Gaussian policy's mean inside the action box on one plant (PPO, A2C).

The env scores actions in ``[-1, 1]`` (each gain's search bounds); stable-baselines3 clips every
sampled action to that box before the env sees it. A sample beyond a bound therefore scores exactly
like the bound, so once the policy's mean has drifted beyond a bound (an early step that paid off
overshoots), that gain's samples all score alike, the policy gradient no longer pulls its mean back,
and the gain stays on the bound whatever the rest of the search finds.

Bug: on the six-loop cascade (12 gains), seed 1, the outer loop's Kp went to its upper bound by 2,400
simulations; its pre-clip mean then wandered between 1.36 and 2.28 action units for the rest of the
search, so every sample of that gain sat on the bound, and RL alone ended at 1.118 x the reference in
another basin (the optimum has that Kp at 0.59). Held at the bound, the mean came back inside by
8,000 simulations and the search ended at 1.019 (docs/search.md,
"Search at scale").

On one plant the observation is constant, so the mean is a free vector: the mean's excess beyond the
box is taken off the output layer's bias before every rollout, which puts the mean on the bound (the
mean is affine in that bias). A randomised family's mean is a function of the context, which one
bias cannot place, so it is left alone there.
"""

from __future__ import annotations

import numpy as np
import torch
from stable_baselines3.common.callbacks import BaseCallback
from stable_baselines3.common.policies import ActorCriticPolicy

__all__ = ["MeanInBox", "hold_mean_in_box"]


def hold_mean_in_box(policy: ActorCriticPolicy, obs: np.ndarray) -> np.ndarray:
    """Shift ``policy``'s action-net bias so its mean for ``obs`` lies inside ``[-1, 1]``, in place.

    Parameters
    ----------
    policy
        A Gaussian actor-critic policy (PPO's or A2C's).
    obs
        One observation row, (1, obs_size).

    Returns
    -------
    numpy.ndarray
        The excess taken off each action's mean (zeros where the mean was inside already).
    """
    with torch.no_grad():
        obs_t = policy.obs_to_tensor(obs)[0]
        mean = policy.get_distribution(obs_t).mode()[0]  # a Gaussian's mode is its mean
        excess = mean - mean.clamp(-1.0, 1.0)
        bias = policy.action_net.bias
        assert isinstance(bias, torch.Tensor)
        bias.sub_(excess)
    return excess.numpy()


class MeanInBox(BaseCallback):
    """Holds the policy's mean for the constant observation ``obs`` inside the box before every rollout.

    Parameters
    ----------
    obs
        The observation every episode of the search sees (one plant: the nominal context).
    """

    def __init__(self, obs: np.ndarray) -> None:
        super().__init__()
        self.obs = np.atleast_2d(np.asarray(obs, dtype=np.float32))

    def _on_rollout_start(self) -> None:
        policy = self.model.policy
        assert isinstance(policy, ActorCriticPolicy)
        hold_mean_in_box(policy, self.obs)

    def _on_step(self) -> bool:
        return True
