"""Mode splits of gaintune.lti.modes against hand-built models."""

from __future__ import annotations

import numpy as np
import pytest

from gaintune.lti.modes import observable_split


@pytest.mark.parametrize("c", [1.0, 1e-6, 1e-9, 1e-14])
def test_a_small_sensor_gain_still_observes_the_integrator_it_measures(c):
    """Regression: the rank test's threshold was absolute below a C of norm 1, so an integrating plant
    K e^{-Ls}/(s (T s + 1)) with K = 1e-6 and T = 1e3 s (its C row 1e-9) counted its integrator as unmeasured,
    and the verification called the stable loop the ready-made tuner gave it unstable."""
    A = np.array([[-1e-3, 0.0], [1.0, 0.0]])
    assert observable_split(A, np.array([[0.0, c]])) is None


def test_an_unmeasured_mode_is_split_off_whatever_the_sensor_scale():
    A = np.diag([-1.0, 0.0])  # the integrator (second state) is not measured
    for c in (1.0, 1e-9):
        split = observable_split(A, np.array([[c, 0.0]]))
        assert split is not None
        V1, V2 = split
        assert V1.shape == (2, 1) and np.allclose(np.linalg.eigvals(V2.T @ A @ V2), [0.0])
    assert observable_split(A, np.zeros((1, 2))) is not None  # nothing measured: nothing observable
