"""Nonlinear plants (casadi tape + RK4) against scipy's solve_ivp and against their linearisation."""

from __future__ import annotations

import numpy as np
import pytest
import scipy.integrate

from gaintune.plants.library import load_model
from gaintune.sim import Simulator
from gaintune.spec import load_spec


def tank_spec(**scenario) -> dict:
    spec = load_model("water_tank").example_spec()
    spec["scenarios"] = [{"name": "s", "dt": 0.1, "horizon": 60.0, "reference": {"kind": "step", "amplitude": 2.0, "time": 1.0}, **scenario}]
    spec.pop("randomize", None)
    return spec


GAINS = {"level": {"Kp": 1.0, "Ki": 0.05}}


def test_water_tank_matches_solve_ivp_with_the_same_zoh_input() -> None:
    sim = Simulator(load_spec(tank_spec()))
    res = sim.run(sim.layout.from_dict(GAINS)[None], traces=True)
    p = sim.plant.params
    A, a, b = p["A"], p["a"], p["b"]
    u = res.traces["u"][0]
    assert u.max() > u[0] + 0.5  # the input really moves
    dt = 0.1
    h = np.empty(len(u))
    x = np.array([p["H0"]])
    for k in range(len(u)):
        h[k] = x[0]
        sol = scipy.integrate.solve_ivp(
            lambda t, x, uk=u[k]: [(b * uk - a * np.sqrt(max(x[0], 0.0))) / A],
            (k * dt, (k + 1) * dt), x, method="DOP853", rtol=1e-12, atol=1e-12,
        )
        x = sol.y[:, -1]
    y = res.traces["y.level"][0]
    np.testing.assert_allclose(y, h, rtol=0, atol=1e-6 * np.abs(h - p["H0"]).max())
    assert res.metrics["y_final"][0] == pytest.approx(12.0, abs=0.05)


def test_water_tank_starts_at_its_operating_point() -> None:
    sim = Simulator(load_spec(tank_spec(reference={"kind": "none"})))
    res = sim.run(sim.layout.from_dict(GAINS)[None], traces=True)
    p = sim.plant.params
    u0 = p["a"] * np.sqrt(p["H0"]) / p["b"]
    np.testing.assert_allclose(res.traces["y.level"][0], p["H0"], atol=1e-9)
    np.testing.assert_allclose(res.traces["u"][0], u0, atol=1e-9)
    assert res.metrics["iae"][0] < 1e-7 and res.metrics["effort"][0] < 1e-12


def test_small_signal_response_matches_the_linearised_model() -> None:
    amp = 0.01
    sim = Simulator(load_spec(tank_spec(reference={"kind": "step", "amplitude": amp, "time": 1.0}, horizon=100.0)))
    res = sim.run(sim.layout.from_dict(GAINS)[None], traces=True)
    lin = sim.plant.linearize()
    lti = {
        "plant": {"ss": {"A": lin.A.tolist(), "B": lin.B.tolist(), "C": lin.C.tolist(), "outputs": ["level"]}},
        "loops": [{"name": "level", "type": "pi"}],
        "actuator": {"limits": [-10.0, 10.0]},
        "scenarios": [{"dt": 0.1, "horizon": 100.0, "reference": {"kind": "step", "amplitude": amp, "time": 1.0}}],
    }
    sl = Simulator(load_spec(lti))
    rl = sl.run(sl.layout.from_dict(GAINS)[None], traces=True)
    dy_nl = res.traces["y.level"][0] - lin.y0[0]
    dy_lin = rl.traces["y.level"][0]
    # deviation variables agree up to second-order terms (relative error O(amp / H0))
    np.testing.assert_allclose(dy_nl, dy_lin, rtol=0, atol=2e-3 * amp)
    np.testing.assert_allclose(res.traces["u"][0] - lin.u0, rl.traces["u"][0], rtol=0, atol=5e-3 * np.abs(rl.traces["u"][0]).max())
    assert res.metrics["iae"][0] == pytest.approx(rl.metrics["iae"][0], rel=2e-3)
    assert res.metrics["overshoot"][0] == pytest.approx(rl.metrics["overshoot"][0], abs=0.2)


def test_nonlinear_delay_is_rounded_to_whole_samples() -> None:
    spec = tank_spec()
    sims = {}
    for delay in (0.3, 0.32):  # both round to 3 samples of 0.1 s
        s = dict(spec, plant={"model": {"name": "water_tank"}, "delay": delay})
        sim = Simulator(load_spec(s))
        sims[delay] = sim.run(sim.layout.from_dict(GAINS)[None], traces=True)
    np.testing.assert_array_equal(sims[0.3].traces["y.level"], sims[0.32].traces["y.level"])
    y = sims[0.3].traces["y.level"][0]
    u = sims[0.3].traces["u"][0]
    k_move = int(np.argmax(u != u[0]))  # the first input change reaches the level 3 + 1 samples later
    assert np.all(y[: k_move + 4] == y[0]) and y[k_move + 4] != y[0]


def test_state_bound_safety_monitor_on_the_tank() -> None:
    spec = tank_spec(reference={"kind": "step", "amplitude": 25.0, "time": 1.0}, horizon=200.0)
    spec["actuator"] = {"limits": [0, 10], "safe_value": 0.0}
    sim = Simulator(load_spec(spec))  # example safety: state_bounds {h: 30}
    res = sim.run(sim.layout.from_dict({"level": {"Kp": 5.0, "Ki": 0.5}})[None], traces=True)
    assert bool(res.metrics["tripped"][0])
    y, u = res.traces["y.level"][0], res.traces["u"][0]
    k = int(round(res.metrics["trip_time"][0] / 0.1))
    assert y[k - 1] <= 30.0 < y[k] and np.all(u[k:] == 0.0)
