"""The nonlinear six-joint arm (models/robot_arm6.yaml) and the ODE form's named intermediate expressions."""

from __future__ import annotations

import copy

import numpy as np
import pytest
from pydantic import ValidationError

from gaintune.errors import SpecError
from gaintune.plants import build_plant
from gaintune.plants.library import load_model
from gaintune.sim import Simulator
from gaintune.spec import PlantSpec, load_spec

STATES = [f"{k}{j}" for k in "qwi" for j in range(1, 7)]


def _arm(**params: float):
    return build_plant(PlantSpec(model={"name": "robot_arm6", "params": params}))


def _rhs(plant, x: np.ndarray, u: np.ndarray) -> np.ndarray:
    return np.asarray(plant.ode.f(x, u, plant.param_vector()), dtype=float).ravel()


def _hand_gains() -> dict:
    """Velocity loops near 50 rad/s (inertia / (N Kt)), current loops near 1,000 rad/s."""
    g: dict = {}
    for k in range(1, 7):
        kv = 14.0 if k <= 3 else 0.85
        g |= {f"q{k}": {"Kp": 10.0, "Ki": 1.0, "Kd": 1e-3}, f"w{k}": {"Kp": kv, "Ki": 10 * kv, "Kd": 1e-3},
              f"i{k}": {"Kp": 5.0, "Ki": 1000.0, "Kd": 1e-5}}
    return g


def test_arm_operating_point_holds_gravity_with_the_motor_currents() -> None:
    """At the pose (0, 0.5, -1, 0, 0.3, 0) rad at rest, i_k0 N_k Kt balances gravity and v_k0 = R i_k0."""
    plant = _arm()
    x0, u0, _ = plant.operating_point()
    p = plant.params
    a = p["q2_0"] + p["q3_0"]
    tool = p["mt"] * p["g"] * p["lt"] * np.cos(a + p["q5_0"])
    g2 = p["g"] * ((p["m2"] * p["l2c"] + p["m3"] * p["l2"]) * np.cos(p["q2_0"]) + p["m3"] * p["l3c"] * np.cos(a))
    g3 = p["g"] * p["m3"] * p["l3c"] * np.cos(a)
    i0 = x0[STATES.index("i1"):]
    np.testing.assert_allclose(i0, np.array([0, g2 + tool, g3 + tool, 0, tool, 0]) / (np.array(
        [p[f"N{k}"] for k in range(1, 7)]) * p["Kt"]), rtol=1e-12, atol=1e-15)
    np.testing.assert_allclose(u0, np.r_[p["R"] * i0, 0.0], atol=1e-9)
    np.testing.assert_allclose(_rhs(plant, x0, u0), 0.0, atol=1e-9)


def test_arm_linearisation_matches_a_finite_difference_jacobian_of_the_dynamics() -> None:
    plant = _arm()
    x0, u0, _ = plant.operating_point()
    G = plant.lti()
    h = 1e-6
    A = np.column_stack([(_rhs(plant, x0 + h * e, u0) - _rhs(plant, x0 - h * e, u0)) / (2 * h)
                         for e in np.eye(len(x0))])
    B = np.column_stack([(_rhs(plant, x0, u0 + h * e) - _rhs(plant, x0, u0 - h * e)) / (2 * h)
                         for e in np.eye(len(u0))])
    np.testing.assert_allclose(G.A, A, rtol=1e-6, atol=1e-6)
    np.testing.assert_allclose(G.B, B, rtol=1e-6, atol=1e-6)
    assert G.inputs == ("v1", "v2", "v3", "v4", "v5", "v6", "dm") and list(G.outputs) == STATES


def test_arm_without_the_tool_linearises_exactly_to_robot_arm6_lin() -> None:
    """The tool (mt) is what the nonlinear arm adds; without it, the linearisation is the linear model's."""
    got = _arm(mt=0.0).lti()
    lin = build_plant(PlantSpec(model="robot_arm6_lin")).lti()
    for name in "ABC":
        np.testing.assert_allclose(getattr(got, name), getattr(lin, name), rtol=1e-12, atol=1e-12)


def test_arm_two_link_mass_matrix_and_gravity_by_hand_at_a_pose() -> None:
    """Upper arm horizontal (q2 = 0), forearm vertical (q3 = pi/2), wrist straight, at rest.

    By hand, with the nominal figures: M22 = I2 + m2 l2c^2 + m3 l2^2 + I3 + m3 l3c^2 + N^2 Jm = 2.19,
    M23 = I3 + m3 l3c^2 = 0.22 (cos q3 = 0), M33 = 0.22 + 0.3 = 0.52 kg m^2; gravity on the shoulder
    g (m2 l2c + m3 l2) = 39.24 N m, none on the elbow (the forearm and the tool point up);
    the base inertia I1 + m2 l2c^2 + m3 l2^2 + N^2 Jm = 2.1 kg m^2.
    """
    plant = _arm()
    x = np.zeros(18)
    x[STATES.index("q3")] = np.pi / 2
    u = np.zeros(7)
    M = np.array([[2.19, 0.22], [0.22, 0.52]])
    free = _rhs(plant, x, u)
    np.testing.assert_allclose(free[7:9], np.linalg.solve(M, [-39.24, 0.0]), rtol=1e-12)
    for k, col in ((1, 0), (2, 1)):  # one ampere in motor k: a torque N Kt = 10 N m on joint k
        xi = x.copy()
        xi[STATES.index(f"i{k + 1}")] = 1.0
        np.testing.assert_allclose(_rhs(plant, xi, u)[7:9] - free[7:9], 10.0 * np.linalg.inv(M)[:, col],
                                   rtol=1e-12)
    xi = x.copy()
    xi[STATES.index("i1")] = 1.0
    assert _rhs(plant, xi, u)[6] == pytest.approx(10.0 / 2.1, rel=1e-12)


def _energy(p: dict, x: np.ndarray) -> float:
    """Kinetic plus potential energy of the arm (links, tool and rotors), written from the model's geometry."""
    q1, q2, q3, q4, q5, q6, w1, w2, w3, w4, w5, w6 = x[:12]
    a = q2 + q3
    r2, r3 = p["l2c"] * np.cos(q2), p["l2"] * np.cos(q2) + p["l3c"] * np.cos(a)
    J3 = p["I3"] + p["m3"] * p["l3c"] ** 2
    c3 = p["m3"] * p["l3c"]
    M = np.array([[p["I2"] + p["m2"] * p["l2c"] ** 2 + p["m3"] * p["l2"] ** 2 + J3 + 2 * p["l2"] * c3 * np.cos(q3)
                   + p["N2"] ** 2 * p["Jm"], J3 + p["l2"] * c3 * np.cos(q3)],
                  [J3 + p["l2"] * c3 * np.cos(q3), J3 + p["N3"] ** 2 * p["Jm"]]])
    v = np.array([w2, w3])
    mt, lt = p["mt"], p["lt"]
    T = 0.5 * (p["I1"] + p["m2"] * r2 ** 2 + p["m3"] * r3 ** 2 + p["N1"] ** 2 * p["Jm"]) * w1 ** 2 + 0.5 * v @ M @ v
    T += 0.5 * (p["I4"] + mt * lt ** 2 * np.sin(q5) ** 2 + p["N4"] ** 2 * p["Jm"]) * w4 ** 2
    T += 0.5 * (p["I5"] + mt * lt ** 2 + p["N5"] ** 2 * p["Jm"]) * w5 ** 2
    T += 0.5 * (p["I6"] + p["N6"] ** 2 * p["Jm"]) * w6 ** 2
    height_tool = lt * (np.sin(a) * np.cos(q5) + np.cos(a) * np.sin(q5) * np.cos(q4))
    V = p["g"] * ((p["m2"] * p["l2c"] + p["m3"] * p["l2"]) * np.sin(q2) + c3 * np.sin(a) + mt * height_tool)
    return float(T + V)


def test_arm_swinging_freely_conserves_energy() -> None:
    """Pins the Coriolis, centrifugal and gravity terms: with no friction (b = 0), no back-EMF (Kb = 0) and the
    currents at 0 every joint swings freely (base, arm and wrist together) and the energy T + V of the
    model's geometry stays constant."""
    from scipy.integrate import solve_ivp

    plant = _arm(b=0.0, Kb=0.0)
    x0 = np.zeros(18)
    x0[:12] = [0.0, 0.4, -0.8, 0.3, 0.6, 0.0, 2.0, 1.5, -2.0, 3.0, -2.5, 1.0]
    u = np.zeros(7)
    sol = solve_ivp(lambda t, x: _rhs(plant, x, u), (0.0, 1.0), x0, rtol=1e-11, atol=1e-12, method="DOP853")
    e = [_energy(plant.params, sol.y[:, k]) for k in range(sol.y.shape[1])]
    assert np.ptp(sol.y[7]) > 1.0  # the arm really moves
    assert max(abs(v - e[0]) for v in e) < 1e-7 * (1 + abs(e[0]))
    # and a model missing a Coriolis term does not: drop the elbow's centrifugal term h w2^2
    broken = load_model("robot_arm6").plant.model_copy(deep=True)
    assert broken.ode is not None and broken.ode.defs is not None
    broken.ode.defs["f3"] = broken.ode.defs["f3"].replace(" - hc*w2^2", "")
    bad = build_plant(PlantSpec(ode=broken.ode, params={**plant.params}))
    sol = solve_ivp(lambda t, x: _rhs(bad, x, u), (0.0, 1.0), x0, rtol=1e-11, atol=1e-12, method="DOP853")
    assert abs(_energy(plant.params, sol.y[:, -1]) - e[0]) > 1e-3


def _spec(scenarios: list[dict], plant: dict | None = None) -> dict:
    d = load_model("robot_arm6").example_spec()
    d["scenarios"] = scenarios
    if plant is not None:
        d["plant"] = plant
    return d


def _run(d: dict, loops: list[str]) -> dict[str, np.ndarray]:
    sim = Simulator(load_spec(d))
    res = sim.run(sim.layout.from_dict(_hand_gains())[None], scenario=0, traces=True)
    return {k: np.asarray(res.traces[f"y.{k}"])[0] for k in loops}


def test_arm_base_load_torque_moves_the_base_joint_only() -> None:
    """The example's base_load scenario (4 rad/s^2 on dw1/dt at t = 0.1 s) moves q1, not the other joints."""
    sc = next(s for s in load_model("robot_arm6").example["scenarios"] if s["name"] == "base_load")
    y = _run(_spec([sc]), [f"q{k}" for k in range(1, 7)])
    assert np.all(y["q1"][:100] == 0.0) and np.max(np.abs(y["q1"])) > 1e-4
    for k in range(2, 7):  # the base's rotation couples to the arm only through w1^2: second order here
        assert np.max(np.abs(y[f"q{k}"])) < 1e-3 * np.max(np.abs(y["q1"]))


def _lin_plant() -> dict:
    G = _arm().lti()
    return {"ss": {"A": G.A.tolist(), "B": G.B.tolist(), "C": G.C.tolist(), "states": STATES, "outputs": STATES,
                   "inputs": [{"name": n} for n in G.inputs]}}


@pytest.mark.parametrize(("amplitude", "close"), [(0.01, True), (1.0, False)])
def test_arm_closed_loop_follows_its_linearisation_for_a_small_step_and_departs_for_a_large_one(
        amplitude: float, close: bool) -> None:
    """A shoulder step under the hand gains, nonlinear arm against its linearisation at the pose.

    The stiff cascade keeps the angles close either way (within 0.4 % of the step at 1 rad); the gravity
    the shoulder motor holds shows the nonlinearity: its current differs by < 1 % of its swing for a
    0.01 rad step, by > 10 % for 1 rad (gravity goes as cos q2, the linearisation as its slope at 0.5 rad).
    """
    sc = [{"name": "s", "dt": 0.001, "horizon": 0.5, "reference": {"loop": "q2", "kind": "step",
                                                                   "amplitude": amplitude}}]
    names = ["q2", "i2"]
    nl = _run(_spec(sc), names)
    lin = _run(_spec(sc, _lin_plant()), names)
    assert np.max(np.abs(nl["q2"] - lin["q2"])) < 0.01 * amplitude
    gap = np.max(np.abs(nl["i2"] - lin["i2"])) / np.max(np.abs(lin["i2"]))
    assert (gap < 0.01 if close else gap > 0.1), gap


def test_ode_defs_are_shared_named_expressions() -> None:
    ode = {"states": ["x"], "inputs": ["u", "v"], "defs": {"k": "a*2", "k2": "k*k"}, "rhs": {"x": "-k2*x + u + v"},
           "outputs": {"y": "x"}}
    plant = build_plant(PlantSpec.model_validate({"ode": ode, "params": {"a": 1.5}}))
    assert plant.lti().A[0, 0] == pytest.approx(-9.0)
    single = {"states": ["x"], "defs": {"k": "a*2"}, "rhs": {"x": "-k*x + u"}, "outputs": {"y": "x"}}
    assert build_plant(PlantSpec.model_validate({"ode": single, "params": {"a": 1.5}})).linearize().A[0, 0] == -3.0


@pytest.mark.parametrize(("defs", "where"), [
    ({"x": "1"}, "defs"), ({"u": "1"}, "defs"), ({"1k": "1"}, "defs"), ({"_k": "1"}, "defs"),
])
def test_ode_defs_naming_a_state_or_an_input_or_not_an_identifier_are_refused(defs, where) -> None:
    ode = {"states": ["x"], "inputs": ["u", "v"], "defs": defs, "rhs": {"x": "-x + u"}, "outputs": {"y": "x"}}
    with pytest.raises(ValidationError, match=where):
        PlantSpec.model_validate({"ode": ode})


def test_ode_defs_naming_a_parameter_or_using_a_later_name_are_refused_by_field() -> None:
    ode = {"states": ["x"], "inputs": ["u", "v"], "defs": {"a": "2"}, "rhs": {"x": "-x + u"}, "outputs": {"y": "x"}}
    with pytest.raises(SpecError, match="plant.ode.defs.a"):
        build_plant(PlantSpec.model_validate({"ode": ode, "params": {"a": 1.0}}))
    ode = copy.deepcopy(ode) | {"defs": {"k": "k2 + 1", "k2": "2"}}
    with pytest.raises(SpecError, match="plant.ode.defs.k"):
        build_plant(PlantSpec.model_validate({"ode": ode}))
