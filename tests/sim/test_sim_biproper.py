"""Biproper plants (direct feedthrough, as many zeros as poles) in the simulator.

The convention (docs/simulation.md): the output is sampled before the control update, with
the previous input still held, so ``y[k] = C x[k] + D u[k-1-d]`` for an input delay of
``d dt + f`` (0 <= f < dt). The references below are built independently: the plant by
``control.c2d(..., 'zoh')`` on a grid fine enough for the delay to be whole steps, the PID
law of :mod:`gaintune.controllers.pid` written out, and the output read as the continuous
plant's output just before t_k (the left limit, ``D`` times the input held over the last
fine step).
"""

from __future__ import annotations

import control as ct
import numpy as np
import pytest

from gaintune.errors import SpecError
from gaintune.plants.plant import build_plant
from gaintune.sim import Simulator
from gaintune.spec import load_spec

#: 3(s+10)/(s+2): D = 3, static gain 15.
BIPROPER = {"tf": {"num": "3*(s+10)", "den": "s+2"}}


def reference_loop(num, den, dt: float, n: int, sub: int, m: int, kp: float, ki: float,
                   kd: float = 0.0, tf: float = 0.0) -> tuple[np.ndarray, np.ndarray]:
    """(y, u) of the backward-Euler PID around num/den with an input delay of ``m`` steps of dt/sub.

    The plant is stepped by python-control's ZOH discretisation at h = dt/sub; the controller
    runs every ``sub`` steps on the output just before its update (unit step reference at t = 0).
    """
    h = dt / sub
    P = ct.c2d(ct.ss(ct.tf(num, den)), h, "zoh")
    A, B, C, D = (np.asarray(M, dtype=float) for M in (P.A, P.B, P.C, P.D))
    x = np.zeros(A.shape[0])
    u = np.zeros(n)
    up = np.zeros(n * sub + m + 1)  # plant input per fine step (index shifted by m + 1)
    y = np.zeros(n)
    integ = dfilt = ed_prev = 0.0
    for k in range(n):
        for j in range(k * sub, (k + 1) * sub):
            if j == k * sub:  # sample the output just before the update: the input held over the last fine step
                y[k] = (C @ x)[0] + D[0, 0] * up[j]
                e = 1.0 - y[k]
                integ += ki * dt * e
                if kd:
                    dfilt = tf / (tf + dt) * dfilt + kd / (tf + dt) * (-y[k] - ed_prev)
                    ed_prev = -y[k]
                u[k] = kp * e + integ + dfilt
            src = j - m  # fine step whose controller output reaches the plant now
            up[j + 1] = u[src // sub] if src >= 0 else 0.0
            x = A @ x + B[:, 0] * up[j + 1]
    return y, u


def simulate(plant: dict, loop: dict, gains: dict, dt: float, horizon: float):
    sim = Simulator(load_spec({"plant": plant, "loops": [loop], "scenario": {"dt": dt, "horizon": horizon}}))
    return sim.run(sim.layout.from_dict({"loop0": gains})[None, :], traces=True)


@pytest.mark.parametrize(
    "loop, gains, tf",
    [({"type": "pi"}, {"Kp": 0.1, "Ki": 2.0}, 0.0),
     ({"type": "pid", "filter": {"Tf": 0.05}}, {"Kp": 0.1, "Ki": 2.0, "Kd": 0.01}, 0.05)],
)
def test_biproper_plant_without_delay_matches_c2d_with_feedthrough_one_sample_late(loop, gains, tf) -> None:
    """The feedthrough term sees u[k-1]: 3(s+10)/(s+2) with no delay, against c2d + the documented timing."""
    dt, horizon = 0.01, 3.0
    res = simulate(BIPROPER, loop, gains, dt, horizon)
    n = res.t.size
    y, u = reference_loop([3.0, 30.0], [1.0, 2.0], dt, n, 1, 0, gains["Kp"], gains["Ki"], gains.get("Kd", 0.0), tf)
    scale = np.abs(y).max()
    np.testing.assert_allclose(res.traces["y.loop0"][0], y, rtol=0, atol=1e-10 * scale)
    np.testing.assert_allclose(res.traces["u"][0], u, rtol=0, atol=1e-10 * np.abs(u).max())
    assert res.metrics["iae"][0] == pytest.approx(np.sum(np.abs(1.0 - y)) * dt, rel=1e-9)
    assert not res.metrics["diverged"][0]
    # the first sample sees the initial input only: y[0] = 0, and y[1] = 3 u[0] + the state's response
    assert res.traces["y.loop0"][0][0] == 0.0


@pytest.mark.parametrize("delay_steps, sub", [(3, 1), (5, 2)])
def test_biproper_plant_with_delay_feeds_through_the_input_held_before_the_sample(delay_steps, sub) -> None:
    """With an input delay d dt + f the feedthrough sees u[k-1-d], the input held just before t_k:
    3 whole samples, and 2.5 samples (the fraction resolved on a grid of dt/2)."""
    dt, horizon = 0.01, 2.0
    delay = delay_steps * dt / sub
    res = simulate({**BIPROPER, "delay": delay}, {"type": "pi"}, {"Kp": 0.05, "Ki": 1.0}, dt, horizon)
    y, u = reference_loop([3.0, 30.0], [1.0, 2.0], dt, res.t.size, sub, delay_steps, 0.05, 1.0)
    np.testing.assert_allclose(res.traces["y.loop0"][0], y, rtol=0, atol=1e-10 * np.abs(y).max())
    np.testing.assert_allclose(res.traces["u"][0], u, rtol=0, atol=1e-10 * np.abs(u).max())


def test_biproper_plant_without_delay_is_accepted_by_the_simulator() -> None:
    """Before, building the simulation raised 'direct feedthrough (D != 0); give a delay'."""
    res = simulate({"ss": {"A": [[-2.0]], "B": [[1.0]], "C": [[24.0]], "D": [[3.0]]}}, {"type": "pi"},
                   {"Kp": 0.1, "Ki": 2.0}, 0.01, 3.0)
    tf_res = simulate(BIPROPER, {"type": "pi"}, {"Kp": 0.1, "Ki": 2.0}, 0.01, 3.0)
    np.testing.assert_allclose(res.traces["y.loop0"], tf_res.traces["y.loop0"], rtol=0, atol=1e-12)
    assert res.traces["y.loop0"][0, -1] == pytest.approx(1.0, abs=1e-3)  # integral action: settled at the setpoint


@pytest.mark.parametrize("num, den", [("(s+1)^2", "s+2"), ([1.0, 0.0, 0.0], [1.0, 1.0])])
def test_improper_plant_stays_refused_with_the_degrees_named(num, den) -> None:
    with pytest.raises(SpecError) as err:
        build_plant(load_spec({"plant": {"tf": {"num": num, "den": den}}, "loops": [{"type": "pi"}]}).plant)
    assert err.value.field == "plant.tf"
    assert "improper" in str(err.value) and "numerator degree 2 > denominator degree 1" in str(err.value)
