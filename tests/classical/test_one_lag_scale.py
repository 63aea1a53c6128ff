"""The time scale of a one-lag path is read directly, with the values fit_fotd's half rule gives it."""

from __future__ import annotations

import numpy as np
import pytest

import gaintune.classical.timescale as ts
from gaintune.lti.statespace import StateSpace


def _general(sys: StateSpace, delay: float, monkeypatch) -> ts.LoopScale:
    with monkeypatch.context() as m:
        m.setattr(ts, "_one_lag", lambda sys: None)
        return ts._path_scale("loop0", sys, delay)


def test_a_one_lag_path_gets_fit_fotds_scale_to_the_bit(monkeypatch) -> None:
    rng = np.random.default_rng(3)
    direct = 0
    for _ in range(300):
        a = -10.0 ** rng.uniform(-6, 6)
        b, c = 10.0 ** rng.uniform(-6, 6, 2) * rng.choice([-1.0, 1.0], 2)
        delay = float(10.0 ** rng.uniform(-4, 3)) * float(rng.integers(0, 2))
        sys = StateSpace(np.array([[a]]), np.array([[b]]), np.array([[c]]), np.zeros((1, 1)))
        direct += ts._one_lag(sys) is not None  # a gain below 1e-9 |a| takes the general path
        assert ts._path_scale("loop0", sys, delay) == _general(sys, delay, monkeypatch)
    assert direct > 250


@pytest.mark.parametrize("A, B, C, D", [
    ([[0.0]], [[1.0]], [[1.0]], [[0.0]]),  # an integrator
    ([[-1e-10]], [[1.0]], [[1.0]], [[0.0]]),  # fit_fotd counts this pole as one
    ([[2.0]], [[1.0]], [[1.0]], [[0.0]]),  # unstable
    ([[-1.0]], [[1.0]], [[0.0]], [[0.0]]),  # no gain: the realisation cancels the state
    ([[-1.0]], [[1.0]], [[1.0]], [[0.5]]),  # feedthrough
    ([[-1.0, 0.0], [1.0, -2.0]], [[1.0], [0.0]], [[0.0, 1.0]], [[0.0]]),  # two lags
])
def test_other_paths_take_the_general_path(A, B, C, D) -> None:
    assert ts._one_lag(StateSpace(np.array(A), np.array(B), np.array(C), np.array(D))) is None
