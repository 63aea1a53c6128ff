"""The RL algorithms a search can run, by name.

Torch-free on purpose: the CLI lists them in ``gaintune tune --help`` without loading the learner.
:mod:`gaintune.search.agents` maps each name to its stable-baselines3 class, and the spec's
``search.algo`` (:class:`gaintune.spec.SearchSpec`, a lower layer) accepts exactly these names
(``tests/search/test_algos.py`` checks that they agree).
"""

from __future__ import annotations

__all__ = ["ALGO_NAMES"]

#: Every RL algorithm ``search.algo`` may name (stable-baselines3 calls each class by its name in capitals).
ALGO_NAMES: tuple[str, ...] = ("ppo", "sac", "td3", "a2c", "ddpg")
