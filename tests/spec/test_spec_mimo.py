"""MIMO spec forms (gaintune.spec.mimo): what they accept, and every bad input named by field with its fix."""

from __future__ import annotations

import copy
from typing import Any

import numpy as np
import pytest
from pydantic import ValidationError

from gaintune.controllers.layout import GainLayout
from gaintune.errors import GainError, SpecError
from gaintune.plants import build_plant
from gaintune.plants.checks import validate_against_plant
from gaintune.plants.library import load_model
from gaintune.plants.mimo import MimoPlant
from gaintune.spec import load_spec

E = {"num": [1.0], "den": [10.0, 1.0], "delay": 1.0}
TFM = {"inputs": [{"name": "R", "unit": "lb/min"}, {"name": "S", "unit": "lb/min"}],
       "outputs": [{"name": "xD", "unit": "mol%"}, {"name": "xB", "unit": "mol%"}],
       "entries": [[E, {**E, "num": [-2.0]}], [{**E, "num": [0.5]}, {**E, "num": [-1.0]}]]}
GOOD: dict[str, Any] = {
    "plant": {"tf_matrix": TFM},
    "loops": [{"name": "a", "measure": "xD", "drives": "R", "type": "pi"},
              {"name": "b", "measure": "xB", "drives": "S", "type": "pi"}],
    "scenarios": [{"name": "s1", "dt": 0.1, "horizon": 50.0, "reference": {"loop": "a"}},
                  {"name": "s2", "dt": 0.1, "horizon": 50.0, "reference": {"loop": "b"}}],
}


def spec_with(**changes: Any) -> dict[str, Any]:
    data = copy.deepcopy(GOOD)
    for path, value in changes.items():
        node = data
        keys = path.split("__")
        for k in keys[:-1]:
            node = node[int(k)] if isinstance(node, list) else node[k]
        last = keys[-1]
        if isinstance(node, list):
            node[int(last)] = value
        else:
            node[last] = value
    return data


def refused(data: dict[str, Any], loc: str, *fragments: str) -> None:
    with pytest.raises(ValidationError) as info:
        load_spec(data)
    errs = info.value.errors()
    text = "\n".join(f"{'.'.join(map(str, e['loc']))}: {e['msg']}" for e in errs)
    assert any(".".join(map(str, e["loc"])) == loc for e in errs), text
    for frag in fragments:
        assert frag in text, text


def test_good_mimo_spec_builds_a_mimo_plant() -> None:
    spec = load_spec(GOOD)
    plant = build_plant(spec.plant)
    assert isinstance(plant, MimoPlant)
    assert plant.input_names == ["R", "S"] and plant.outputs == ["xD", "xB"]
    np.testing.assert_allclose(plant.lti().dcgain(), [[1.0, -2.0], [0.5, -1.0]])
    validate_against_plant(spec, plant)
    assert load_spec(spec.model_dump(mode="json")).content_hash() == spec.content_hash()


def test_single_chain_spec_dump_has_no_mimo_fields() -> None:
    data = {"plant": {"tf": {"num": [1], "den": "(s+1)^3"}}, "loops": [{"type": "pi"}]}
    dumped = load_spec(data).model_dump(mode="json")
    for key in ("actuators", "ties", "decoupler"):
        assert key not in dumped
    assert "drives" not in dumped["loops"][0] and "loop" not in dumped["scenarios"][0]["reference"]
    assert "tf_matrix" not in dumped["plant"] and "mimo_ms_max" not in dumped["requirements"]


@pytest.mark.parametrize("data, loc, fragments", [
    (spec_with(plant__tf_matrix__entries=[TFM["entries"][0]]), "plant.tf_matrix.entries",
     ("1 rows but there are 2 outputs", "one row per output")),
    (spec_with(plant__tf_matrix__entries=[[E], TFM["entries"][1]]), "plant.tf_matrix.entries.0",
     ("1 entries but there are 2 inputs", "one entry per input")),
    (spec_with(plant__tf_matrix__entries=[[E, 3.0], TFM["entries"][1]]), "plant.tf_matrix.entries.0.1",
     ("must be 0",)),
    (spec_with(loops__0__drives="Q"), "loops.0.drives", ("no input 'Q'", "inputs: R, S")),
    (spec_with(loops__0__drives="loop:zz"), "loops.0.drives", ("no loop named 'zz'",)),
    (spec_with(loops__0__drives="loop:b", loops__1__drives="loop:a"), "loops.0.drives", ("cycle", "a -> b -> a")),
    (spec_with(loops__1__drives="R"), "loops.1.drives", ("already drives 'R'", "decoupler")),
    (spec_with(loops__1__drives=None), "loops.1.drives", ("every loop must",)),
    (spec_with(loops__0__measure="xQ"), "loops.0.measure", ("no output 'xQ'", "xD, xB")),
    (spec_with(ties=[["a.Kp", "b.Ki"]]), "ties.0", ("different kinds",)),
    (spec_with(ties=[["a.Kp", "c.Kp"]]), "ties.0.1", ("not <loop>.<gain>",)),
    (spec_with(ties=[["a.Kd", "b.Kd"]]), "ties.0.0", ("no gain 'Kd'",)),
    (spec_with(actuators={"Q": {"limits": [0, 1]}}), "actuators.Q", ("no input 'Q'",)),
    (spec_with(decoupler={"inputs": ["R", "S"], "matrix": [[1, 0]]}), "decoupler.matrix", ("must be 2x2",)),
    (spec_with(scenarios__0__reference={"loop": "nope"}), "scenarios.0.reference.loop", ("no loop named",)),
    (spec_with(scenarios__0__disturbance={"kind": "step", "input": "Q"}), "scenarios.0.disturbance.input",
     ("no input 'Q'",)),
    (spec_with(plant={"tf_matrix": TFM, "delay": 1.0}), "plant.delay", ("per path",)),
])
def test_bad_mimo_input_names_the_field(data: dict, loc: str, fragments: tuple[str, ...]) -> None:
    refused(data, loc, *fragments)


def test_tie_between_gains_of_different_units_is_refused() -> None:
    tfm = copy.deepcopy(TFM)
    tfm["outputs"][1]["unit"] = "K"  # xB in kelvin, xD in mol%: Kp of the two loops differ in unit
    refused(spec_with(plant__tf_matrix=tfm, ties=[["a.Kp", "b.Kp"]]), "ties.0", "different units",
            "(lb/min)/(mol%)", "(lb/min)/(K)")


def test_reference_on_an_inner_loop_is_refused() -> None:
    data = spec_with(loops__1__drives="loop:a", loops__0__drives="R", scenarios__1__reference={"loop": "b"})
    refused(data, "scenarios.0.reference.loop", "takes its setpoint from another loop")


def test_state_space_inputs_must_match_b() -> None:
    ss = {"A": [[-1.0]], "B": [[1.0, 2.0]], "C": [[1.0]], "inputs": ["u1"]}
    refused({"plant": {"ss": ss}, "loops": [{"drives": "u1"}]}, "plant.ss.inputs", "one input per column of B")
    ss2 = {"A": [[-1.0]], "B": [[1.0, 2.0]], "C": [[1.0]], "inputs": ["u1", "u2"], "input_delays": [1.0]}
    refused({"plant": {"ss": ss2}, "loops": [{"drives": "u1"}]}, "plant.ss.input_delays", "one per input")


def test_state_space_with_named_inputs_and_delays_is_a_mimo_plant() -> None:
    ss = {"A": [[-1.0, 0.0], [0.0, -2.0]], "B": [[1.0, 0.0], [0.0, 1.0]], "C": [[1.0, 0.0], [0.0, 1.0]],
          "inputs": [{"name": "u1", "unit": "V"}, "u2"], "input_delays": [0.5, "T"], "outputs": ["y1", "y2"]}
    spec = load_spec({"plant": {"ss": ss, "params": {"T": 0.25}},
                      "loops": [{"name": "a", "measure": "y1", "drives": "u1"},
                                {"name": "b", "measure": "y2", "drives": "u2"}]})
    plant = build_plant(spec.plant)
    assert isinstance(plant, MimoPlant) and plant.inputs[0].unit == "V"
    np.testing.assert_allclose(plant.lti().input_delays, [0.5, 0.25])


def test_seven_loops_in_one_cascade_are_still_refused() -> None:
    refused({"plant": {"tf": {"num": [1], "den": [1, 1]}}, "loops": [{"type": "pid"}] * 7}, "loops", "at most 6")


def test_improper_matrix_entry_is_refused_at_build() -> None:
    spec = load_spec(spec_with(plant__tf_matrix__entries__0__0={"num": [1, 0], "den": [1, 1]}))
    with pytest.raises(SpecError) as info:
        build_plant(spec.plant)
    assert info.value.field == "plant.tf_matrix.entries[0][0]" and "strictly proper" in info.value.message


def test_model_reference_checks_names_against_the_built_plant() -> None:
    data = load_model("wood_berry").example_spec()
    data["loops"][1]["drives"] = "Q"
    spec = load_spec(data)  # the model's inputs are known only once it is built
    with pytest.raises(SpecError) as info:
        validate_against_plant(spec, build_plant(spec.plant))
    assert info.value.field == "loops[1].drives" and "no input 'Q'" in info.value.message


def test_mimo_plant_without_drives_says_what_to_add() -> None:
    data = spec_with(loops__0__drives=None, loops__1__drives=None)
    spec = load_spec(data)
    with pytest.raises(SpecError) as info:
        validate_against_plant(spec, build_plant(spec.plant))
    assert info.value.field == "loops" and "say what each loop drives" in info.value.message


def test_ties_share_one_tuned_gain() -> None:
    spec = load_spec(spec_with(ties=[["a.Kp", "b.Kp"]]))
    plant = build_plant(spec.plant)
    layout = GainLayout(spec, plant.states, plant=plant)
    assert layout.directions == (1, -1)
    assert layout.n_gains == 4 and layout.n_tuned == 3
    full = layout.full(np.array([[0.5, 0.1, 0.2]]))[0]
    gains = layout.to_dict(full)
    assert gains["a"]["Kp"] == 0.5 and gains["b"]["Kp"] == -0.5  # one magnitude, each loop's own sign
    back = layout.from_dict({"a": {"Kp": 0.5, "Ki": 0.1}, "b": {"Ki": -0.2}})
    np.testing.assert_allclose(back, full)
    with pytest.raises(GainError) as info:
        layout.from_dict({"a": {"Kp": 0.5, "Ki": 0.1}, "b": {"Kp": -0.7, "Ki": -0.2}})
    assert info.value.field == "gains.b.Kp" and "tied to a.Kp" in info.value.message


def test_example_spec_edits_do_not_leak_into_the_model_cache() -> None:
    first = load_model("wood_berry").example_spec()
    first["loops"][0]["drives"] = "loop:xB"
    assert load_model("wood_berry").example_spec()["loops"][0]["drives"] == "R"
