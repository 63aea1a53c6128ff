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


@pytest.mark.parametrize("s", [1.0, 1e-3, 1e-6])
def test_a_companion_form_of_microsecond_lags_is_wholly_observable(s):
    """Regression: the companion form of 1/((s_ T s + 1)(0.3 s_ T s + 1)) at T = 1 us has entries 1 and 3e12;
    scaled by its norm, the coupling the output sees the second state through looked like rounding, the
    lag was split off as unmeasured, and the verification called the stable loop unstable."""
    a1, a0 = (1.3 * s) / (0.3 * s * s), 1.0 / (0.3 * s * s)
    A = np.array([[-a1, -a0], [1.0, 0.0]])
    assert observable_split(A, np.array([[0.0, a0]])) is None


def test_the_unobservable_part_of_a_badly_scaled_model_is_still_found():
    A = np.array([[-1e6, 0.0, 0.0], [1.0, -1e-3, 0.0], [0.0, 0.0, 0.0]])  # the third state is not measured
    split = observable_split(A, np.array([[0.0, 1e6, 0.0]]))
    assert split is not None
    V1, V2 = split
    assert V1.shape == (3, 2) and np.allclose(np.linalg.eigvals(V2.T @ A @ V2), [0.0])
    assert np.allclose(V1.T @ V1, np.eye(2)) and np.allclose(V1.T @ V2, 0.0)


@pytest.mark.parametrize("T", [1.0, 5e-10, 5e-12])
def test_an_integrator_sees_its_nanosecond_lag_through_a_coupling_of_one(T):
    """Regression: the companion form of 1/(s (T s + 1)) at T = 5e-10 s has the entries 1/T = 2e9 and 1 (the
    integrator's input); scaled to norm 1 that coupling is 5e-10, below the rank test's 1e-9 against the
    measured direction, so the lag was split off with B = 0 and the verification called the stable loop
    unstable (the ready-made integrating tuner at a time scale of 1e-8 s, L/T = 19)."""
    A = np.array([[-1.0 / T, 0.0], [1.0, 0.0]])
    assert observable_split(A, np.array([[0.0, 1.0 / T]])) is None


def test_a_mode_with_no_coupling_at_all_stays_unobservable_beside_a_fast_one():
    A = np.array([[-2e9, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, -1.0]])  # the third state: no path to y
    split = observable_split(A, np.array([[0.0, 2e9, 0.0]]))
    assert split is not None and np.allclose(np.linalg.eigvals(split[1].T @ A @ split[1]), [-1.0])
