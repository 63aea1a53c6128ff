"""A one-lag path's leading term is read directly: the same PathGain the expansion gives it."""

from __future__ import annotations

import numpy as np

from gaintune.controllers.direction import PathGain, path_gain


def _expanded(a: float, b: float, c: float) -> PathGain | None:
    """path_gain of the same path with a second state it neither drives nor sees: the general expansion."""
    return path_gain(np.array([[a, 0.0], [0.0, -1.0]]), np.array([b, 0.0]), np.array([c, 0.0]), 0.0)


def test_a_one_lag_path_gets_the_expansions_path_gain_to_the_bit() -> None:
    rng = np.random.default_rng(5)
    for _ in range(300):
        a = -10.0 ** rng.uniform(-6, 6)
        b, c = 10.0 ** rng.uniform(-4, 4, 2) * rng.choice([-1.0, 1.0], 2)
        got = path_gain(np.array([[a]]), np.array([b]), np.array([c]), 0.0)
        assert got == _expanded(a, b, c) and got is not None and got.order == 0 and got.rhp_real == 0
