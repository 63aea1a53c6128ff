"""Biproper plants in the sampled verification: the same timing as the simulator.

The output is sampled before the control update, so the feedthrough D reaches the controller one
sample late through the hold: the sampled plant is ``C (zI - Ad)^-1 Bd z^-d + D z^-(d+1)``
(``control.c2d(..., 'zoh')`` for Ad, Bd). Checked against python-control and a hand
derivation, and against the simulator (the nonlinear check) at the stability limit.
"""

from __future__ import annotations

import math

import control as ct
import numpy as np
import pytest

from gaintune.spec import load_spec
from gaintune.verification import verify

#: 3(s+10)/(s+2) = 3 + 24/(s+2): D = 3, C = 24 in the controller canonical form.
BIPROPER = {"tf": {"num": "3*(s+10)", "den": "s+2"}}


def spec_of(plant: dict, loop_type: str, dt: float, horizon: float):
    return load_spec({"plant": plant, "loops": [{"type": loop_type}], "scenario": {"dt": dt, "horizon": horizon}})


def fig(rep):
    return next(f for f in rep.loops if f.loop == "loop0" and f.break_point == "controller_output")


def sampled_plant(dt: float, d: int) -> ct.TransferFunction:
    """c2d of the strictly proper part times z^-d, plus D z^-(d+1): the measurement before the update."""
    z = ct.tf([1, 0], [1], dt)
    strict = ct.c2d(ct.tf([24.0], [1.0, 2.0]), dt, "zoh")
    return strict * z ** (-d) + 3.0 * z ** (-(d + 1))


@pytest.mark.filterwarnings("ignore:stability_margins")
@pytest.mark.parametrize("gains, d", [({"Kp": 0.1, "Ki": 2.0}, 0), ({"Kp": 0.05, "Ki": 1.0}, 2)])
def test_biproper_plant_sampled_margins_match_python_control(gains, d) -> None:
    """GM, PM, Ms, their frequencies, the stability verdict and the spectral radius to 1e-6.

    python-control 0.10 does not report a phase crossing at z = -1 itself: the Nyquist end
    point's GM, 1/|L(-1)| when L(-1) < 0, is taken from L evaluated there (the feedthrough, one
    sample late, makes L(-1) negative: -(Kp + Ki dt/2)(3 + 12 tanh(dt)) z^-d at z = -1)."""
    dt = 0.01
    plant = {**BIPROPER, **({"delay": d * dt} if d else {})}
    rep = verify(spec_of(plant, "pi", dt, 3.0), {"loop0": gains}, nonlinear=False)
    f = fig(rep)
    z = ct.tf([1, 0], [1], dt)
    L = sampled_plant(dt, d) * (gains["Kp"] + gains["Ki"] * dt * z / (z - 1))
    gm, pm, sm, wpc, wgc, _ = ct.stability_margins(L)
    poles = ct.feedback(L, 1).poles()
    assert rep.sampled and rep.stability.domain == "z"
    assert rep.stability.stable == bool(np.all(np.abs(poles) < 1))
    assert rep.stability.spectral_radius == pytest.approx(np.abs(poles).max(), rel=1e-9)
    l_nyq = complex(L(-1.0 + 0j))
    assert abs(l_nyq.imag) < 1e-12 and l_nyq.real < 0
    if 1.0 / abs(l_nyq.real) < gm or not np.isfinite(gm):
        gm, wpc = 1.0 / abs(l_nyq.real), math.pi / dt
    assert f.gm_db == pytest.approx(abs(20 * np.log10(gm)), rel=1e-6)
    assert f.gm_freq == pytest.approx(wpc, rel=1e-6)
    assert f.pm_deg == pytest.approx(pm, rel=1e-6)
    assert f.pm_freq == pytest.approx(wgc, rel=1e-6)
    assert f.ms == pytest.approx(1.0 / sm, rel=1e-6)


def test_biproper_p_loop_stability_limit_is_hand_derived_and_the_simulator_agrees() -> None:
    """P control on 3 + 24/(s+2) at dt: L(-1) = -K (3 + 24 tanh(dt)/2), since the lag samples to
    24 (1 - a)/(2 (z - a)) with a = e^{-2 dt} and the feedthrough to 3/z. So the upper GM, at
    pi/dt, is 1/(K (3 + 12 tanh(dt))), and the loop is unstable above K* = 1/(3 + 12 tanh(dt)):
    the feedthrough, one sample late, rings at the Nyquist frequency. (With the feedthrough
    seen at once, u = K (r - 24 x) / (1 + 3 K) would be stable for every K > 0.)"""
    dt = 0.01
    k_star = 1.0 / (3.0 + 12.0 * math.tanh(dt))
    spec = spec_of(BIPROPER, "p", dt, 10.0)
    below = verify(spec, {"loop0": {"Kp": 0.9 * k_star}})
    f = fig(below)
    assert below.stability.stable
    assert f.gm_freq == pytest.approx(math.pi / dt, rel=1e-12) and f.gm_binding == "increase"
    assert f.gm_db == pytest.approx(20 * math.log10(1 / 0.9), rel=1e-9)
    assert below.nonlinear.ran and not below.nonlinear.diverged
    # the closed-loop transition matrix on (x, u[k-1]): u = K (r - 24 x - 3 u[k-1])
    a, g = math.exp(-2 * dt), (1 - math.exp(-2 * dt)) / 2
    for scale in (0.9, 1.1):
        K = scale * k_star
        M = np.array([[a - 24 * g * K, -3 * g * K], [-24 * K, -3 * K]])
        rep = verify(spec, {"loop0": {"Kp": K}}, nonlinear=False)
        assert rep.stability.spectral_radius == pytest.approx(np.abs(np.linalg.eigvals(M)).max(), rel=1e-9)
    above = verify(spec, {"loop0": {"Kp": 1.1 * k_star}})
    assert not above.stability.stable and above.verdict == "fail"
    assert above.nonlinear.ran and above.nonlinear.diverged  # the simulator rings out too


def test_biproper_plant_without_delay_is_accepted_and_verified() -> None:
    """The whole verification (including the simulated check) runs on 3(s+10)/(s+2) without a delay."""
    rep = verify(spec_of(BIPROPER, "pi", 0.01, 3.0), {"loop0": {"Kp": 0.1, "Ki": 2.0}})
    assert rep.verdict == "pass", rep.reasons
    assert rep.stability.stable and rep.nonlinear.ran and not rep.nonlinear.diverged
