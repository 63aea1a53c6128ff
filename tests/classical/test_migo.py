"""MIGO PI reference optimum: Ms accuracy, active constraint, brute-force maximality, AMIGO plausibility."""

from __future__ import annotations

import warnings

import control
import numpy as np
import pytest

from gaintune.classical import migo as M
from gaintune.classical.migo import PiPoint, boundary_optimum, ki_max_on_boundary, migo_pi, pi_sensitivity_peak

W = np.geomspace(1e-3, 1e2, 1000)
MS_MAX = 1.4
s = control.tf("s")


def fotd(L: float, T: float):
    return lambda w: np.exp(-1j * w * L) / (1 + 1j * w * T)


def G3(w):
    return 1 / (1j * w + 1) ** 3


# name -> (G(jw), delay-free python-control model, delay)
PLANTS = {
    "1/(s+1)^3": (G3, 1 / (s + 1) ** 3, 0.0),
    "e^-s/(1+10s)": (fotd(1, 10), 1 / (1 + 10 * s), 1.0),
    "e^-s/(1+s)": (fotd(1, 1), 1 / (1 + s), 1.0),
    "(1-0.5s)/(s+1)^3": (lambda w: (1 - 0.5j * w) / (1j * w + 1) ** 3, (1 - 0.5 * s) / (s + 1) ** 3, 0.0),
}


@pytest.fixture(scope="module")
def migo_points() -> dict[str, PiPoint]:
    return {name: migo_pi(G, MS_MAX, W) for name, (G, _, _) in PLANTS.items()}


def dense_ms(G, kp, ki, w=np.geomspace(1e-4, 1e3, 1_000_000)):
    """Brute force: max of 1/|1 + L| on a million log-spaced frequencies."""
    return float(np.max(1 / np.abs(1 + (kp + ki / (1j * w)) * G(w))))


def closed_loop_poles(kp, ki, plant, delay):
    """Closed-loop poles of the PI loop, delay as a 10th-order Pade approximation."""
    if delay:
        plant = plant * control.tf(*control.pade(delay, 10))
    return control.poles(control.feedback((kp + ki / s) * plant, 1))


# 1. Ms accuracy -------------------------------------------------------------------------------------------------


@pytest.mark.parametrize("kp, ki", [(0.2, 0.1), (0.36, 0.373), (0.8, 0.5), (0.05, 0.02)])
def test_ms_matches_dense_grid_with_exact_delay(kp, ki):
    G = fotd(1, 1)
    assert float(pi_sensitivity_peak(G, kp, ki, W)) == pytest.approx(dense_ms(G, kp, ki), rel=1e-4)


@pytest.mark.parametrize("kp, ki", [(0.2, 0.1), (0.63, 0.33), (1.0, 0.6), (2.0, 0.2)])
def test_ms_matches_python_control_stability_margin(kp, ki):
    sm = control.stability_margins((kp + ki / s) / (s + 1) ** 3)[2]
    assert float(pi_sensitivity_peak(G3, kp, ki, W)) == pytest.approx(1 / sm, rel=1e-4)


def test_ms_broadcasts_over_gain_arrays():
    kp, ki = np.array([[0.2], [1.0]]), np.array([0.1, 0.6, 0.3])
    ms = pi_sensitivity_peak(G3, kp, ki, W)
    assert ms.shape == (2, 3)
    assert ms[1, 1] == pytest.approx(float(pi_sensitivity_peak(G3, 1.0, 0.6, W)), rel=1e-12)


@pytest.mark.parametrize("integrating", [False, True])
def test_nyquist_count_matches_closed_loop_poles(integrating):
    """The winding count used for the stability check equals the RHP closed-loop pole count."""
    plant = 1 / (s * (s + 1)) if integrating else 1 / (s + 1) ** 3
    G = (lambda w: 1 / (1j * w * (1j * w + 1))) if integrating else G3
    P = M._plant(G, W, MS_MAX, 0)
    for kp in (0.1, 1.0, 5.0, 12.0):
        for ki in (0.01, 0.5, 3.0, 20.0):
            z = int(M._evaluate(G, W, P.Gw, kp, ki, 1 + P.n_int)[1])
            assert z == int(np.sum(closed_loop_poles(kp, ki, plant, 0).real > 0)), (kp, ki)


# 2. MIGO: constraint active, loop stable -------------------------------------------------------------------------


@pytest.mark.parametrize("name", list(PLANTS))
def test_migo_constraint_is_active_and_loop_stable(name, migo_points):
    p = migo_points[name]
    G, plant, delay = PLANTS[name]
    assert p.kp > 0 and p.ki > 0
    assert MS_MAX - 0.005 <= p.ms <= MS_MAX
    assert dense_ms(G, p.kp, p.ki) <= MS_MAX * (1 + 1e-6)  # independent of the module's refinement
    assert np.max(closed_loop_poles(p.kp, p.ki, plant, delay).real) < 0
    # the boundary: feasible at ki_max, infeasible just above it
    ki = ki_max_on_boundary(G, p.kp, MS_MAX, W)
    assert ki == pytest.approx(p.ki, rel=1e-5)
    assert float(pi_sensitivity_peak(G, p.kp, ki * (1 + 1e-4), W)) > MS_MAX


def test_ki_max_is_zero_when_kp_alone_violates_the_bound():
    ku = 8.0  # ultimate gain of 1/(s+1)^3
    assert ki_max_on_boundary(G3, 0.95 * ku, MS_MAX, W) == 0.0


# 3. brute force --------------------------------------------------------------------------------------------------


def test_migo_beats_dense_2d_grid(migo_points):
    p = migo_points["1/(s+1)^3"]
    kp = np.geomspace(0.5, 2.0, 200) * p.kp
    ki = np.geomspace(0.7, 1.3, 200) * p.ki
    KP, KI = (a.ravel() for a in np.meshgrid(kp, ki, indexing="ij"))
    w = np.geomspace(0.2, 3.0, 800)  # the peak of |S| for these gains lies well inside
    g, gi = G3(w), G3(w) / (1j * w)
    ms = np.concatenate([1 / np.sqrt(np.min((1 + a[:, None] * g.real + b[:, None] * gi.real) ** 2
                                            + (a[:, None] * g.imag + b[:, None] * gi.imag) ** 2, axis=1))
                         for a, b in zip(np.array_split(KP, 20), np.array_split(KI, 20))])
    # stability from the characteristic polynomial s^4 + 3 s^3 + 3 s^2 + (1 + kp) s + ki, batched
    comp = np.zeros((KP.size, 4, 4))
    comp[:, 0, :] = -np.stack([np.full_like(KP, 3.0), np.full_like(KP, 3.0), 1 + KP, KI], axis=1)
    comp[:, 1, 0] = comp[:, 2, 1] = comp[:, 3, 2] = 1.0
    stable = np.max(np.linalg.eigvals(comp).real, axis=1) < 0
    feasible = (ms <= MS_MAX) & stable
    best = KI[feasible].max()
    assert best <= p.ki * 1.005
    assert best >= p.ki * 0.99  # the grid resolves the optimum, so the check has teeth


# 4. AMIGO plausibility -------------------------------------------------------------------------------------------


def amigo_pi(L: float, T: float, K: float = 1.0) -> tuple[float, float]:
    kc = 0.15 / K + (0.35 - L * T / (L + T) ** 2) * T / (K * L)
    ti = 0.35 * L + 13 * L * T**2 / (T**2 + 12 * L * T + 7 * L**2)
    return kc, kc / ti


@pytest.mark.parametrize("name, L, T", [("e^-s/(1+10s)", 1.0, 10.0), ("e^-s/(1+s)", 1.0, 1.0)])
def test_amigo_is_close_to_migo_at_its_own_robustness(name, L, T, migo_points):
    """AMIGO approximates MIGO under the combined-sensitivity circle M = 1.4, a stronger constraint than
    Ms <= 1.4, so its Ms comes out below 1.4 (1.32 and 1.25 here) and MIGO at Ms = 1.4 has a larger ki
    (measured 1.52x and 1.49x AMIGO's). Checks: AMIGO's Ms is near 1.4; it is feasible, so MIGO's ki is at
    least AMIGO's (with a loose 1.6x ceiling against gross errors); and at AMIGO's own Ms, MIGO's ki is
    within 25 % of AMIGO's (measured 1.16x and 1.00x)."""
    G = fotd(L, T)
    kc, ka = amigo_pi(L, T)
    ms_amigo = float(pi_sensitivity_peak(G, kc, ka, W))
    assert 1.2 <= ms_amigo <= 1.6
    p = migo_points[name]
    assert 1.0 <= p.ki / ka <= 1.6
    q = migo_pi(G, ms_amigo, W)
    assert 1.0 - 1e-6 <= q.ki / ka <= 1.25


# 5. boundary optimum ---------------------------------------------------------------------------------------------


def test_boundary_optimum_with_ie_cost_returns_migo(migo_points):
    calls = []

    def ie(kp, ki):
        calls.append(kp.size)
        return 1 / ki

    migo, best = boundary_optimum(G3, MS_MAX, W, ie)
    assert migo.ki == pytest.approx(migo_points["1/(s+1)^3"].ki, rel=1e-6)
    assert migo.cost == pytest.approx(1 / migo.ki)
    assert best.ki == pytest.approx(migo.ki, rel=1e-3)
    assert best.ms <= MS_MAX
    assert calls[0] > 10 and len(calls) == 1 + 4  # one batched scan call (+ MIGO), one per refinement round


def test_boundary_optimum_follows_the_cost_along_the_boundary():
    migo, best = boundary_optimum(G3, MS_MAX, W, lambda kp, ki: 1 / ki - 2.0 * kp)
    assert best.kp > migo.kp
    assert best.cost < migo.cost
    assert best.ms <= MS_MAX and best.ki > 0
    assert float(pi_sensitivity_peak(G3, best.kp, best.ki * 1.001, W)) > MS_MAX  # on the boundary


def test_boundary_optimum_skips_non_finite_costs():
    cost = lambda kp, ki: np.where(kp > 0.5, np.nan, -kp)  # noqa: E731
    migo, best = boundary_optimum(G3, MS_MAX, W, cost, kp_range=(0.1, 2.0), n_scan=21, rounds=2)
    assert best.kp <= 0.5 and np.isfinite(best.cost)


# 6. errors -------------------------------------------------------------------------------------------------------


def test_open_loop_unstable_plant_is_rejected():
    G = lambda w: 1 / (1j * w - 1)  # noqa: E731
    with pytest.raises(ValueError, match="unstable"):
        migo_pi(G, MS_MAX, W, open_loop_rhp_poles=1)
    with pytest.raises(ValueError, match="unstable"):
        ki_max_on_boundary(G, 1.0, MS_MAX, W, open_loop_rhp_poles=1)
    with pytest.raises(ValueError):  # negative static gain, even without the flag
        migo_pi(G, MS_MAX, W)
    # positive static gain, two RHP poles, without the flag: caught by the negative Nyquist count at the
    # kp that stabilise the kp-only loop (partial safeguard only: the flag is the contract)
    with pytest.raises(ValueError, match="RHP"):
        migo_pi(lambda w: 10 * (1j * w + 1) / ((1j * w) ** 2 - 1j * w + 4), MS_MAX, W)


@pytest.mark.parametrize("ms_max", [1.0, 0.8, float("nan"), float("inf")])
def test_ms_max_must_exceed_one(ms_max):
    with pytest.raises(ValueError, match="ms_max"):
        migo_pi(G3, ms_max, W)
    with pytest.raises(ValueError, match="ms_max"):
        boundary_optimum(G3, ms_max, W, lambda kp, ki: 1 / ki)


def test_integrating_plant_supported():
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        p = migo_pi(lambda w: np.exp(-1j * w) / (1j * w), MS_MAX, W)
    assert MS_MAX - 0.005 <= p.ms <= MS_MAX
    assert dense_ms(lambda w: np.exp(-1j * w) / (1j * w), p.kp, p.ki) <= MS_MAX * (1 + 1e-6)
