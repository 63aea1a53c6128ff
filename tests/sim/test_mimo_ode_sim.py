"""The MIMO simulator on a nonlinear several-input ODE (the quadruple tank) against scipy's solve_ivp.

The reference integrates the tank equations written here in numpy (not the spec's expressions)
with the same held inputs: sample-and-hold over each step, the PI law of the kernel at the
samples. RK4 at dt = 0.5 s on time constants of 20-90 s agrees to ~1e-10 V.
"""

from __future__ import annotations

import numpy as np
import pytest
from scipy.integrate import solve_ivp

from gaintune.plants import quadtank as qt
from gaintune.plants.library import load_model
from gaintune.sim import Simulator
from gaintune.spec import TuningSpec

DT, HORIZON = 0.5, 200.0
P = qt.MIN_PHASE


def _rhs(x: np.ndarray, v: np.ndarray, dstate: np.ndarray) -> np.ndarray:
    a, A, g = P.a, P.A, P.g
    q = [ai * np.sqrt(2 * g * max(h, 0.0)) for ai, h in zip(a, x, strict=True)]
    f1, f2 = P.k1 * v[0], P.k2 * v[1]
    return np.array([(-q[0] + q[2] + P.gamma1 * f1) / A[0], (-q[1] + q[3] + P.gamma2 * f2) / A[1],
                     (-q[2] + (1 - P.gamma2) * f2) / A[2], (-q[3] + (1 - P.gamma1) * f1) / A[3]]) + dstate


def _reference(gains: np.ndarray, dist_v1: float, dist_h3: float, ref_y1: float, delay1: int = 0) -> np.ndarray:
    """y (n, 2) deviations at the samples: PI (parallel, b = 1) on each loop, solve_ivp between samples;
    pump 1 applies its command ``delay1`` samples late (0 before)."""
    op = qt.operating_point(P, 3.0, 3.0)
    x, v0 = np.array(op.h), np.array(op.v)
    y0 = P.kc * x[:2]
    kp, ki = gains[[0, 2]], gains[[1, 3]]
    integ, n = np.zeros(2), int(round(HORIZON / DT))
    ys = np.zeros((n, 2))
    sent = []
    for k in range(n):
        y = P.kc * x[:2] - y0
        ys[k] = y
        e = np.array([ref_y1, 0.0]) - y
        integ = integ + ki * DT * e
        cmd = kp * e + integ
        sent.append(cmd[0])
        cmd[0] = sent[k - delay1] if k >= delay1 else 0.0
        v = v0 + cmd + np.array([dist_v1, 0.0])
        sol = solve_ivp(lambda t, z, v=v: _rhs(z, v, np.array([0, 0, dist_h3, 0])), (0.0, DT), x,
                        rtol=1e-11, atol=1e-12, method="DOP853")
        x = sol.y[:, -1]
    return ys


def _spec(dist: dict, ref: float, actuators: dict | None = None) -> TuningSpec:
    d = load_model("quadruple_tank").example_spec()
    d.pop("actuators")
    if actuators is not None:
        d["actuators"] = actuators
    d["scenarios"] = [{"name": "s", "dt": DT, "horizon": HORIZON,
                       "reference": {"loop": "y1", "kind": "step", "amplitude": ref} if ref else {"kind": "none"},
                       "disturbance": dist}]
    return TuningSpec.model_validate(d)


def _sim_traces(spec: TuningSpec, gains: np.ndarray) -> np.ndarray:
    res = Simulator(spec).run(gains[None], traces=True)
    return np.stack([res.traces["y.y1"][0], res.traces["y.y2"][0]], axis=1)


@pytest.mark.parametrize(("dist", "dv1", "dh3"), [
    ({"kind": "step", "amplitude": 0.5, "input": "v1"}, 0.5, 0.0),
    ({"kind": "step", "amplitude": 0.01, "state": "h3"}, 0.0, 0.01),
])
def test_nonlinear_quadruple_tank_open_loop_matches_solve_ivp(dist, dv1, dh3) -> None:
    gains = np.zeros(4)  # no control: the held inputs are the operating point plus the disturbance
    got = _sim_traces(_spec(dist, 0.0), gains)
    want = _reference(gains, dv1, dh3, 0.0)
    assert np.max(np.abs(want)) > 0.05  # the disturbance moves the levels
    np.testing.assert_allclose(got, want, atol=1e-9)


def test_nonlinear_quadruple_tank_closed_loop_pi_matches_solve_ivp() -> None:
    gains = np.array([3.0, 3.0 / 30, 2.7, 2.7 / 40])  # Johansson's PI, K = 3.0, Ti = 30 s and K = 2.7, Ti = 40 s
    got = _sim_traces(_spec({"kind": "none"}, 1.0), gains)
    want = _reference(gains, 0.0, 0.0, 1.0)
    assert want[-1, 0] == pytest.approx(1.0, abs=0.05)
    np.testing.assert_allclose(got, want, atol=1e-9)


def test_nonlinear_actuator_delay_holds_the_command_whole_samples() -> None:
    gains = np.array([3.0, 3.0 / 30, 2.7, 2.7 / 40])
    spec = _spec({"kind": "none"}, 1.0, actuators={"v1": {"delay": 3 * DT}})
    got = _sim_traces(spec, gains)
    np.testing.assert_allclose(got, _reference(gains, 0.0, 0.0, 1.0, delay1=3), atol=1e-9)
    assert np.max(np.abs(got - _reference(gains, 0.0, 0.0, 1.0))) > 1e-3  # the delay shows


def test_randomised_parameters_give_each_candidate_its_own_operating_point() -> None:
    from gaintune.sim import draws

    d = load_model("quadruple_tank").example_spec()
    d["randomize"] = {"params": {"gamma1": [0.65, 0.75], "k1": [3.2, 3.4]}}
    sim = Simulator(TuningSpec.model_validate(d))
    dr = draws.sample(sim.spec, sim.plant, np.random.default_rng(0), 8)
    gains = np.tile([3.0, 0.1, 2.7, 0.0675], (8, 1))
    iae = sim.run(gains, draws=dr).metrics["iae"]
    for i in (0, 5):
        params = dict(zip(sim.plant.param_names, dr.params[i], strict=True))
        d["plant"] = {"model": {"name": "quadruple_tank", "params": {k: params[k] for k in ("gamma1", "k1")}}}
        one = Simulator(TuningSpec.model_validate({**d, "randomize": {}})).run(gains[:1]).metrics["iae"][0]
        assert iae[i] == pytest.approx(one, rel=1e-12)
    assert np.ptp(iae) > 0.1


def test_state_disturbance_on_a_linear_state_space_plant_enters_the_state_derivative() -> None:
    """dx/dt = -x + u + d on the state x: a step d = 1 with u = 0 gives x(t) = 1 - e^{-t}."""
    plant = {"ss": {"A": [[-1.0]], "B": [[1.0, 0.0]], "C": [[1.0]], "inputs": ["u1", "u2"], "states": ["x"]}}
    spec = TuningSpec.model_validate({"plant": plant, "loops": [
        {"name": "l", "drives": "u1", "type": "pi"}], "scenarios": [
        {"dt": 0.01, "horizon": 3.0, "reference": {"kind": "none"},
         "disturbance": {"kind": "step", "amplitude": 1.0, "state": "x"}}]})
    res = Simulator(spec).run(np.zeros((1, 2)), traces=True)
    t = res.t
    np.testing.assert_allclose(res.traces["y.l"][0], 1 - np.exp(-t), atol=1e-12)


def test_state_disturbance_on_a_single_input_cascade_is_simulated_not_ignored() -> None:
    """A spec without drives on a single-input plant runs on the MIMO simulator when a state is disturbed."""
    plant = {"ss": {"A": [[-1.0]], "B": [[1.0]], "C": [[1.0]], "states": ["x"]}}
    spec = TuningSpec.model_validate({"plant": plant, "loops": [{"name": "l", "type": "p"}], "scenarios": [
        {"dt": 0.01, "horizon": 3.0, "reference": {"kind": "none"},
         "disturbance": {"kind": "step", "amplitude": 1.0, "state": "x"}}]})
    res = Simulator(spec).run(np.zeros((1, 1)), traces=True)
    np.testing.assert_allclose(res.traces["y.l"][0], 1 - np.exp(-res.t), atol=1e-12)


def test_single_input_ode_in_a_loop_graph_matches_the_single_input_simulator() -> None:
    d = load_model("water_tank").example_spec()
    d.pop("actuator"), d.pop("randomize"), d.pop("safety")
    cascade = TuningSpec.model_validate(d)
    d["loops"][0]["drives"] = "u"
    graph = TuningSpec.model_validate(d)
    gains = np.array([[1.0, 0.05], [3.0, 0.2]])
    a, b = Simulator(cascade).run(gains, traces=True), Simulator(graph).run(gains, traces=True)
    assert type(Simulator(graph)).__name__ == "MimoSimulator"
    y_abs = a.traces["y.level"]  # the single-input simulator: absolute level; the MIMO one: its deviation
    np.testing.assert_allclose(b.traces["y.level"] + y_abs[:, :1], y_abs, atol=1e-9)
    assert np.ptp(y_abs) > 1.0
    np.testing.assert_allclose(b.metrics["iae"], a.metrics["iae"], rtol=1e-9)
