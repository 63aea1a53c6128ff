"""Plant builders and the built-in model library, checked against python-control and hand derivations."""

from __future__ import annotations

import math
from typing import Any

import control
import numpy as np
import pytest

from gaintune.controllers.layout import GainLayout
from gaintune.errors import SpecError
from gaintune.plants import build_plant
from gaintune.plants.checks import validate_against_plant
from gaintune.plants.library import list_models, load_model, models_dir
from gaintune.spec import PlantSpec, load_spec

MODELS = list_models()
#: The single-input models (the MIMO ones, with named inputs, are tested in tests/plants/test_mimo_models.py).
SISO_MODELS = [m for m in MODELS if not load_model(m).inputs]
W = np.array([1e-3, 0.1, 1.0, 7.0, 50.0, 400.0])  # rad/s


def plant_of(data: dict[str, Any]):
    return build_plant(PlantSpec.model_validate(data))


def freqresp(sys: control.LTI, w: np.ndarray = W) -> np.ndarray:
    """Complex response of a SISO system at frequencies w (rad/s)."""
    return np.array([complex(control.evalfr(sys, 1j * wk)) for wk in w])


def lin_tf(lin, output: str | int = 0) -> control.StateSpace:
    """The SISO map u -> output of a LinearModel as a python-control system."""
    idx = lin.output_index(output) if isinstance(output, str) else output
    return control.ss(lin.A, lin.B, lin.C[idx : idx + 1], lin.D[idx : idx + 1])


def assert_same_response(a: control.LTI, b: control.LTI, w: np.ndarray = W) -> None:
    ra, rb = freqresp(a, w), freqresp(b, w)
    np.testing.assert_allclose(ra, rb, rtol=1e-8, atol=1e-12 * np.abs(rb).max())


# ----------------------------------------------------------- the library


def test_library_has_the_documented_models() -> None:
    expected = {"dc_motor", "mass_spring_damper", "water_tank", "cart_pole", "quadrotor_axis", "thermal_fotd", "lag_n"}
    assert expected <= set(MODELS)


@pytest.mark.parametrize("name", SISO_MODELS)
def test_model_loads_builds_and_example_is_a_complete_problem(name: str) -> None:
    model = load_model(name)
    assert model.name == name and model.title and model.description
    plant = build_plant(model.plant)
    # Documentation matches the plant exactly.
    assert list(model.outputs) == plant.outputs
    assert set(model.parameters) == set(plant.params)
    assert all(p.unit and p.description for p in model.parameters.values())
    assert model.input.unit != "-" or name == "lag_n"
    lin = plant.linearize()
    for m in (lin.A, lin.B, lin.C, lin.D, lin.x0, lin.y0):
        assert np.all(np.isfinite(m))
    n = plant.order
    assert lin.A.shape == (n, n) and lin.B.shape == (n, 1) and lin.C.shape == (len(plant.outputs), n)
    assert math.isfinite(lin.u0) and lin.delay >= 0

    spec = load_spec(model.example_spec())
    assert spec.plant.model is not None and spec.plant.model.name == name
    built = build_plant(spec.plant)
    validate_against_plant(spec, built)
    # Every loop says what it measures; the example is a sensible, fully specified problem.
    assert all(loop.measure in built.outputs for loop in spec.loops)
    assert spec.actuator.limits is not None
    assert spec.randomize.params, "example should randomise at least one parameter"
    for k, dist in spec.randomize.params.items():
        lo, hi = dist.box
        assert lo < plant.params[k] < hi, f"{k}: nominal outside the randomised range"
    for sc in spec.scenarios:
        assert sc.n_steps >= 100
    GainLayout(spec, built.states)  # gain names/bounds consistent with the loops


@pytest.mark.parametrize("name", SISO_MODELS)
def test_example_loops_satisfy_cascade_conventions(name: str) -> None:
    spec = load_spec(load_model(name).example_spec())
    outer, inner = spec.loops[:-1], spec.loops[-1]
    for loop in outer:  # an outer loop's output is an inner setpoint: bounded
        assert loop.output_limits is not None
    assert inner.output_limits is None  # the innermost loop uses the actuator limits


def test_models_dir_env_override(tmp_path, monkeypatch) -> None:
    (tmp_path / "only.yaml").write_text((models_dir() / "lag_n.yaml").read_text().replace("name: lag_n", "name: only"))
    monkeypatch.setenv("GAINTUNE_MODELS", str(tmp_path))
    assert list_models() == ["only"]


# ----------------------------------------------------- model references


def test_unknown_model_name_lists_known_models() -> None:
    with pytest.raises(SpecError) as info:
        plant_of({"model": "dc_motr"})
    assert info.value.field == "plant.model.name"
    assert "dc_motor" in info.value.message and "water_tank" in info.value.message


@pytest.mark.parametrize("bad", ["../spec", "models/dc_motor", "dc motor", ""])
def test_model_name_cannot_escape_the_folder(bad: str) -> None:
    with pytest.raises(SpecError) as info:
        plant_of({"model": bad})
    assert info.value.field == "plant.model.name"


def test_unknown_parameter_override_names_field() -> None:
    with pytest.raises(SpecError) as info:
        plant_of({"model": {"name": "dc_motor", "params": {"Jm": 1.0}}})
    assert info.value.field == "plant.model.params.Jm"
    assert "J" in info.value.message


def test_parameter_override_changes_dynamics() -> None:
    nominal = plant_of({"model": "dc_motor"}).linearize()
    heavier = plant_of({"model": {"name": "dc_motor", "params": {"L": 0.02, "J": 0.002}}})
    assert heavier.params["L"] == 0.02 and heavier.params["R"] == 1.0
    lin = heavier.linearize()
    assert nominal.A[0, 0] == pytest.approx(-100.0)  # -R/L
    assert lin.A[0, 0] == pytest.approx(-50.0)
    assert lin.A[1, 0] == pytest.approx(0.05 / 0.002)  # Kt/J
    assert lin.B[0, 0] == pytest.approx(50.0)  # 1/L


def test_runtime_parameter_values_and_unknown_names() -> None:
    plant = plant_of({"model": "water_tank"})
    assert plant.linearize({"H0": 4.0}).A[0, 0] == pytest.approx(-2.0 / (2 * 20.0 * 2.0))
    assert plant.params["H0"] == 10.0  # nominal unchanged
    with pytest.raises(SpecError) as info:
        plant.linearize({"H1": 4.0})
    assert info.value.field == "params.H1"


def test_delay_is_a_parameter_expression() -> None:
    plant = plant_of({"model": "thermal_fotd"})
    assert plant.delay() == 10.0
    assert plant.delay({"theta": 3.0}) == 3.0
    assert plant.linearize({"theta": 3.0}).delay == 3.0
    assert plant_of({"model": "thermal_fotd", "delay": 2.5}).delay() == 2.5  # spec delay overrides the model's


def test_structural_order_override() -> None:
    plant = plant_of({"model": {"name": "lag_n", "params": {"n": 5}}})
    assert plant.order == 5
    with pytest.raises(SpecError, match="whole power") as info:
        plant_of({"model": {"name": "lag_n", "params": {"n": 2.5}}})
    assert info.value.field == "plant.tf.den"


# ------------------------------------------- LTI vs python-control


@pytest.mark.parametrize(
    "num, den",
    [
        ([1.0], [1.0, 3.0, 3.0, 1.0]),
        ([2.0, 1.0], [1.0, 3.0, 2.0, 1.0]),
        ([1.0, 2.0, 3.0], [1.0, 4.0, 5.0]),  # biproper: D != 0
        ([-0.5, 1.0], [2.0, 1.0]),  # non-minimum phase, non-monic denominator
        ([1.0], [1.0, 0.0, -1.0]),  # unstable
        ([3.0], [1.0, 0.0]),  # integrator
    ],
)
def test_tf_matches_python_control(num: list[float], den: list[float]) -> None:
    lin = plant_of({"tf": {"num": num, "den": den}}).linearize()
    ref = control.tf(num, den)
    assert_same_response(lin_tf(lin), ref)
    assert_same_response(lin_tf(lin), control.tf2ss(num, den))
    # Same characteristic polynomial (compared as coefficients: repeated roots are ill-conditioned).
    np.testing.assert_allclose(np.poly(lin.A), np.array(den) / den[0], atol=1e-9)


def test_tf_polynomial_strings_and_parameters() -> None:
    lin = plant_of({"tf": {"num": ["K", "K*z"], "den": "(T*s + 1)^2*(s + a)"},
                    "params": {"K": 2.0, "z": 0.5, "T": 0.3, "a": 4.0}}).linearize()  # fmt: skip
    s = control.tf("s")
    ref = 2.0 * (s + 0.5) / ((0.3 * s + 1) ** 2 * (s + 4.0))
    assert_same_response(lin_tf(lin), ref)


def test_ss_matches_python_control_ss2tf() -> None:
    A = [[0.0, 1.0, 0.0], [0.0, 0.0, 1.0], [-6.0, -11.0, -6.0]]
    B = [[0.0], [0.0], [1.0]]
    C = [[1.0, 0.0, 0.0], [0.0, 1.0, 1.0]]
    D = [[0.0], [0.5]]
    plant = plant_of({"ss": {"A": A, "B": B, "C": C, "D": D, "outputs": ["p", "q"]}})
    assert plant.outputs == ["p", "q"] and plant.states == ["x0", "x1", "x2"]
    lin = plant.linearize()
    full = control.ss(A, B, C, D)
    for i in range(2):
        ref = control.ss2tf(full[i, 0])
        assert_same_response(lin_tf(lin, i), ref)
    np.testing.assert_allclose(lin.to_control().D, D)


def test_lag_n_matches_python_control() -> None:
    lin = plant_of({"model": {"name": "lag_n", "params": {"K": 3.0, "T": 2.0, "n": 4}}}).linearize()
    den = np.poly1d([2.0, 1.0]) ** 4
    assert_same_response(lin_tf(lin), control.tf([3.0], den.coeffs))
    assert lin.A.shape == (4, 4)


def test_thermal_fotd_with_exact_delay() -> None:
    lin = plant_of({"model": "thermal_fotd"}).linearize()
    w = np.array([1e-3, 1e-2, 0.05, 0.2])
    got = freqresp(lin_tf(lin), w) * np.exp(-1j * w * lin.delay)
    expected = 2.0 * np.exp(-1j * w * 10.0) / (60.0 * 1j * w + 1.0)
    np.testing.assert_allclose(got, expected, rtol=1e-10)


def test_dc_motor_matches_hand_transfer_functions() -> None:
    R, L, J, b, Kt, Ke = 1.0, 0.01, 0.001, 0.0001, 0.05, 0.05
    lin = plant_of({"model": "dc_motor"}).linearize()
    s = control.tf("s")
    char = (L * s + R) * (J * s + b) + Kt * Ke
    assert_same_response(lin_tf(lin, "speed"), Kt / char)
    assert_same_response(lin_tf(lin, "position"), Kt / (s * char))
    assert_same_response(lin_tf(lin, "current"), (J * s + b) / char)
    # Electrical time constant 10 ms: the fast pole is near -R/L.
    poles = np.sort(np.linalg.eigvals(lin.A).real)
    assert poles[0] == pytest.approx(-R / L, rel=0.1)


def test_mass_spring_damper_and_quadrotor_match_hand_transfer_functions() -> None:
    s = control.tf("s")
    msd = plant_of({"model": "mass_spring_damper"}).linearize()
    assert_same_response(lin_tf(msd, "position"), 1 / (1.0 * s**2 + 0.5 * s + 4.0))
    assert_same_response(lin_tf(msd, "velocity"), s / (1.0 * s**2 + 0.5 * s + 4.0))
    quad = plant_of({"model": "quadrotor_axis"}).linearize()
    J, Tm = 0.01, 0.02
    assert_same_response(lin_tf(quad, "rate"), 1 / (J * s * (Tm * s + 1)))
    assert_same_response(lin_tf(quad, "angle"), 1 / (J * s**2 * (Tm * s + 1)))


# --------------------------------------------------- nonlinear plants


@pytest.mark.parametrize("H0, a, b, A", [(10.0, 2.0, 5.0, 20.0), (2.5, 1.5, 4.0, 10.0)])
def test_water_tank_linearisation(H0: float, a: float, b: float, A: float) -> None:
    plant = plant_of({"model": {"name": "water_tank", "params": {"H0": H0, "a": a, "b": b, "A": A}}})
    lin = plant.linearize()
    np.testing.assert_allclose(lin.A, [[-a / (2 * A * math.sqrt(H0))]], rtol=1e-9)
    np.testing.assert_allclose(lin.B, [[b / A]], rtol=1e-12)
    np.testing.assert_allclose(lin.C, [[1.0]])
    np.testing.assert_allclose(lin.D, [[0.0]])
    assert lin.u0 == pytest.approx(a * math.sqrt(H0) / b, rel=1e-8)  # solved equilibrium input
    np.testing.assert_allclose(lin.x0, [H0])
    np.testing.assert_allclose(lin.y0, [H0])


def test_water_tank_is_finite_below_empty() -> None:
    plant = plant_of({"model": "water_tank"})
    xdot = float(plant.f([-0.5], 1.0, plant.param_vector()))
    assert xdot == pytest.approx(5.0 * 1.0 / 20.0)  # no outflow from an empty tank, no NaN


@pytest.mark.parametrize("M, m, l, g", [(1.0, 0.1, 0.5, 9.81), (2.0, 0.5, 1.2, 9.81)])
def test_cart_pole_upright_linearisation(M: float, m: float, l: float, g: float) -> None:
    plant = plant_of({"model": {"name": "cart_pole", "params": {"M": M, "m": m, "l": l, "g": g}}})
    lin = plant.linearize()
    A = [[0, 1, 0, 0], [0, 0, -m * g / M, 0], [0, 0, 0, 1], [0, 0, (M + m) * g / (M * l), 0]]
    B = [[0], [1 / M], [0], [-1 / (M * l)]]
    np.testing.assert_allclose(lin.A, A, atol=1e-12)
    np.testing.assert_allclose(lin.B, B, atol=1e-12)
    np.testing.assert_allclose(lin.C, [[1, 0, 0, 0], [0, 0, 1, 0]])
    assert lin.u0 == pytest.approx(0.0, abs=1e-9)
    assert max(np.linalg.eigvals(lin.A).real) > 0  # upright is unstable


def test_cart_pole_dynamics_match_lagrange_equations() -> None:
    # Independent check away from the equilibrium: solve the mass-matrix form of
    # the Euler-Lagrange equations for (x'', theta'') and compare with the model.
    M, m, l, g = 1.0, 0.1, 0.5, 9.81
    plant = plant_of({"model": "cart_pole"})
    for x, xd, th, thd, F in [(0.3, -0.2, 0.4, 1.5, 2.0), (-1.0, 0.5, -2.0, -0.7, -5.0), (0, 0, math.pi, 0, 0)]:
        mass = np.array([[M + m, m * l * math.cos(th)], [math.cos(th), l]])
        rhs = np.array([F + m * l * math.sin(th) * thd**2, g * math.sin(th)])
        xdd, thdd = np.linalg.solve(mass, rhs)
        got = np.asarray(plant.f([x, xd, th, thd], F, plant.param_vector())).ravel()
        np.testing.assert_allclose(got, [xd, xdd, thd, thdd], rtol=1e-10, atol=1e-12)


def test_ode_operating_point_u0_given() -> None:
    plant = plant_of({"ode": {"states": ["h"], "rhs": {"h": "-k*h + u"}, "outputs": {"y": "2*h"},
                              "x0": {"h": 3.0}, "u0": "k*3"}, "params": {"k": 0.5}})  # fmt: skip
    lin = plant.linearize()
    assert lin.u0 == 1.5 and lin.y0[0] == 6.0
    np.testing.assert_allclose([lin.A[0, 0], lin.B[0, 0], lin.C[0, 0]], [-0.5, 1.0, 2.0])


def test_tf2ss_is_bit_identical_to_scipy():
    """The hand-written controller canonical form (it spares importing scipy.signal) equals scipy's."""
    import scipy.signal

    from gaintune.plants.plant import _tf2ss

    rng = np.random.default_rng(0)
    for n in range(1, 9):
        for m in range(n + 1):
            num, den = rng.normal(size=m + 1), rng.normal(size=n + 1)
            for a, b in zip(scipy.signal.tf2ss(num, den), _tf2ss(num, den)):
                np.testing.assert_array_equal(a, b)
