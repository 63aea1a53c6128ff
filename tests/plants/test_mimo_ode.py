"""Nonlinear ODE plants with several inputs: spec forms, bad inputs, operating point, linearisation."""

from __future__ import annotations

import numpy as np
import pytest
from pydantic import ValidationError

from gaintune.errors import SpecError
from gaintune.plants import build_plant
from gaintune.plants import quadtank as qt
from gaintune.plants.library import load_model
from gaintune.spec import PlantSpec, TuningSpec


def _two_tank(**ode) -> dict:
    """Two tanks in series, each with its own pump: a small two-input ODE."""
    base = {"states": ["h1", "h2"], "inputs": [{"name": "q1", "unit": "cm^3/s"}, "q2"],
            "rhs": {"h1": "(q1 - a*sqrt(max(h1, 0)))/A", "h2": "(q2 + a*sqrt(max(h1, 0)) - a*sqrt(max(h2, 0)))/A"},
            "outputs": {"y1": "h1", "y2": "h2"}, "x0": {"h1": 4.0, "h2": 4.0}}
    return {"ode": base | ode, "params": {"a": 1.0, "A": 10.0}}


@pytest.mark.parametrize(("model", "linear", "setting"), [
    ("quadruple_tank", "quadruple_tank_min", qt.MIN_PHASE),
    ("quadruple_tank_nmp_ode", "quadruple_tank_nmp", qt.NON_MIN_PHASE),
])
def test_nonlinear_quadruple_tank_linearises_to_the_linearised_models(model, linear, setting) -> None:
    nl = build_plant(PlantSpec(model=model))
    lin = build_plant(PlantSpec(model=linear)).lti()
    got = nl.lti()
    assert nl.input_names == ["v1", "v2"] and nl.outputs == ["y1", "y2"]
    np.testing.assert_allclose(got.A, lin.A, rtol=1e-12, atol=1e-15)
    np.testing.assert_allclose(got.B, lin.B, rtol=1e-12, atol=1e-15)
    np.testing.assert_allclose(got.C, lin.C, rtol=1e-12, atol=1e-15)
    # and the transfer-function matrix of gaintune.plants.quadtank at the same operating point
    x0, u0, y0 = nl.operating_point()
    op = qt.operating_point(setting, *u0)
    np.testing.assert_allclose(x0, op.h, rtol=1e-12)
    w = np.array([1e-3, 1e-2, 0.1])
    G, paper = got.freqresp(w), qt.linearise(setting, op).freqresp(w)
    for i in range(2):  # the diagonal; the paper writes the cross terms with c1, c2 (k1 for pump 2's path)
        np.testing.assert_allclose(G[:, i, i], paper[:, i, i], rtol=1e-9)
    np.testing.assert_allclose(G[:, 0, 1], paper[:, 0, 1] * setting.k2 / setting.k1, rtol=1e-9)
    np.testing.assert_allclose(G[:, 1, 0], paper[:, 1, 0] * setting.k1 / setting.k2, rtol=1e-9)


def test_several_inputs_u0_is_solved_by_least_squares_when_omitted() -> None:
    spec = PlantSpec.model_validate(_two_tank())
    plant = build_plant(spec)
    x0, u0, y0 = plant.operating_point()
    np.testing.assert_allclose(u0, [2.0, 0.0], atol=1e-8)  # q1 = a sqrt(4), q2 balances h2 with q2 = 0
    np.testing.assert_allclose(y0, [4.0, 4.0])
    assert plant.inputs[0].unit == "cm^3/s" and plant.input_names == ["q1", "q2"]


def test_several_inputs_u0_given_per_input() -> None:
    plant = build_plant(PlantSpec.model_validate(_two_tank(u0={"q1": 2.0, "q2": 0.0})))
    np.testing.assert_allclose(plant.operating_point()[1], [2.0, 0.0])


def test_single_input_ode_spec_dumps_and_hashes_as_before() -> None:
    ode = {"states": ["x"], "rhs": {"x": "-x + u"}, "outputs": {"y": "x"}}
    spec = TuningSpec.model_validate({"plant": {"ode": ode}, "loops": [{"type": "pi"}]})
    dumped = spec.model_dump()["plant"]["ode"]
    assert "inputs" not in dumped and "output_units" not in dumped
    assert set(dumped) == {"states", "input", "rhs", "outputs", "x0", "u0"}


def test_unknown_input_in_an_expression_is_refused_by_name() -> None:
    spec = PlantSpec.model_validate(_two_tank(rhs={"h1": "(q3 - sqrt(h1))/A", "h2": "q2 - h2"}))
    with pytest.raises(SpecError, match="plant.ode.rhs.h1") as exc:
        build_plant(spec)
    assert "q3" in str(exc.value)


@pytest.mark.parametrize(("u0", "words"), [
    ({"q1": 1.0}, "missing ['q2']"),
    ({"q1": 1.0, "q2": 0.0, "q9": 1.0}, "unknown ['q9']"),
    (1.0, "maps each input"),
])
def test_u0_of_the_wrong_length_is_refused(u0, words) -> None:
    with pytest.raises(ValidationError, match="u0") as exc:
        PlantSpec.model_validate(_two_tank(u0=u0))
    assert words in str(exc.value)


def test_input_and_inputs_together_are_refused() -> None:
    with pytest.raises(ValidationError, match="not both"):
        PlantSpec.model_validate(_two_tank(input="u"))


def test_a_map_u0_with_one_input_is_refused() -> None:
    ode = {"states": ["x"], "rhs": {"x": "-x + u"}, "outputs": {"y": "x"}, "u0": {"u": 1.0}}
    with pytest.raises(ValidationError, match="several inputs"):
        PlantSpec.model_validate({"ode": ode})


def test_plant_delay_with_several_ode_inputs_is_refused() -> None:
    with pytest.raises(ValidationError, match="actuators"):
        PlantSpec.model_validate(_two_tank() | {"delay": 1.0})


def _graph_spec(plant: dict, dist: dict) -> dict:
    return {"plant": plant, "loops": [{"name": "l1", "measure": "y1", "drives": "q1", "type": "pi"},
                                      {"name": "l2", "measure": "y2", "drives": "q2", "type": "pi"}],
            "scenarios": [{"dt": 0.1, "horizon": 10.0, "disturbance": {"kind": "step", "amplitude": 1.0} | dist}]}


def test_a_disturbance_at_an_unknown_state_is_refused_by_name() -> None:
    with pytest.raises(ValidationError, match=r"scenarios\.0\.disturbance\.state") as exc:
        TuningSpec.model_validate(_graph_spec(_two_tank(), {"state": "h9"}))
    assert "no state 'h9'" in str(exc.value) and "h1, h2" in str(exc.value)


def test_a_disturbance_at_a_state_of_a_transfer_function_is_refused() -> None:
    plant = {"tf_matrix": {"inputs": ["q1", "q2"], "outputs": ["y1", "y2"],
                           "entries": [[{"num": [1], "den": [1, 1]}, 0], [0, {"num": [1], "den": [1, 1]}]]}}
    with pytest.raises(ValidationError, match="no named states"):
        TuningSpec.model_validate(_graph_spec(plant, {"state": "x0"}))


def test_loop_graph_on_integrating_dc_motor_does_not_raise_singular_matrix() -> None:
    """Regression: drives on every loop of dc_motor raised LinAlgError (dcgain of an integrator)."""
    from gaintune.controllers.direction import resolve_directions
    from gaintune.sim import Simulator

    d = load_model("dc_motor").example_spec()
    d["loops"][0]["drives"], d["loops"][1]["drives"], d["loops"][2]["drives"] = "loop:speed", "loop:current", "u"
    spec = TuningSpec.model_validate(d)
    dirs = resolve_directions(spec, build_plant(spec.plant))
    assert [x.sign for x in dirs] == [1, 1, 1]
    assert dirs[0].rule == "velocity_gain" and dirs[0].gain == pytest.approx(1.0)
    assert [x.rule for x in dirs[1:]] == ["static_gain", "static_gain"]
    Simulator(spec)  # built without a LinAlgError


def test_loop_graph_direction_of_a_reversed_integrator_is_negative() -> None:
    from gaintune.controllers.direction import resolve_directions

    plant = {"ss": {"A": [[0, 1], [0, -1]], "B": [[0], [-2]], "C": [[1, 0], [0, 1]], "outputs": ["pos", "vel"]}}
    spec = TuningSpec.model_validate({"plant": plant, "loops": [
        {"name": "p", "measure": "pos", "drives": "u", "type": "pd"}]})
    (d,) = resolve_directions(spec, build_plant(spec.plant))
    assert d.sign == -1 and d.rule == "velocity_gain" and d.gain == pytest.approx(-2.0)


def test_a_disturbance_at_an_unknown_state_of_a_model_is_refused_by_name() -> None:
    from gaintune.plants.checks import validate_against_plant

    d = load_model("quadruple_tank").example_spec()
    d["scenarios"][0]["disturbance"] = {"kind": "step", "state": "h7"}
    spec = TuningSpec.model_validate(d)  # a model's states are known once it is built
    with pytest.raises(SpecError, match=r"scenarios\[0\]\.disturbance\.state") as exc:
        validate_against_plant(spec, build_plant(spec.plant))
    assert "h1, h2, h3, h4" in str(exc.value)


def test_mimo_verification_reads_the_nonlinear_tank_as_its_linearised_model() -> None:
    from gaintune.verification.mimo import mimo_report
    from gaintune.verification.mimo_loop import PidLoop, decentralised_pid

    loops = [PidLoop("y1", "y1", 0, Kp=3.0, Ki=0.1), PidLoop("y2", "y2", 1, Kp=2.7, Ki=2.7 / 40)]
    reps = []
    for name in ("quadruple_tank", "quadruple_tank_min"):
        lti = build_plant(PlantSpec(model=name)).lti()
        reps.append(mimo_report(lti, decentralised_pid(lti, loops), loops))
    nl, lin = reps
    assert nl.stability.stable and lin.stability.stable
    assert nl.ms_output.value == pytest.approx(lin.ms_output.value, rel=1e-9)
    assert nl.disk_input.alpha == pytest.approx(lin.disk_input.alpha, rel=1e-9)
    assert 0 < nl.disk_input.alpha < np.inf
