"""Spec validation: every bad input fails with an error naming the field; good input gets defaults."""

from __future__ import annotations

import json
from typing import Any

import pytest
from pydantic import ValidationError

from gaintune.errors import SpecError, problem_details
from gaintune.plants import build_plant
from gaintune.plants.checks import validate_against_plant
from gaintune.spec import MAX_ORDER, MAX_STEPS, TuningSpec, load_spec

TF3 = {"tf": {"num": [1], "den": "(s+1)^3"}}


def spec_with(**overrides: Any) -> dict[str, Any]:
    base: dict[str, Any] = {"plant": TF3, "loops": [{"type": "pid"}]}
    base.update(overrides)
    return base


def build(plant: dict[str, Any]):
    return build_plant(TuningSpec.model_validate(spec_with(plant=plant)).plant)


def error_locs(exc: Exception) -> str:
    """All 'loc: msg' entries of a ValidationError/SpecError as one searchable string."""
    return "\n".join(f"{d['loc']}: {d['msg']}" for d in problem_details(exc))


def assert_names(exc: Exception, *fragments: str) -> None:
    text = error_locs(exc)
    for frag in fragments:
        assert frag in text, f"{frag!r} not in error:\n{text}"


def fails(data: dict[str, Any], *fragments: str, build_too: bool = True) -> Exception:
    """Expect load_spec (or, when the schema accepts it, build_plant) to reject ``data``."""
    try:
        spec = load_spec(data)
    except (ValidationError, SpecError) as exc:
        assert_names(exc, *fragments)
        return exc
    assert build_too, "schema accepted an input it should reject"
    with pytest.raises(SpecError) as info:
        build_plant(spec.plant)
    assert_names(info.value, *fragments)
    return info.value


# ------------------------------------------------------------ plant errors


@pytest.mark.parametrize(
    "tf, fragments",
    [
        ({"num": [1, 0, 0], "den": [1, 1]}, ("plant.tf", "improper")),
        ({"num": "s^2", "den": "s + 1"}, ("plant.tf", "improper")),
        ({"num": [1], "den": [0, 1, 1]}, ("plant.tf.den", "leading denominator coefficient is zero")),
        ({"num": [1], "den": "0*s"}, ("plant.tf.den",)),
        ({"num": [1], "den": [2]}, ("plant.tf.den", "static gain")),
        ({"num": [1], "den": []}, ("plant.tf.den", "at least one")),
        ({"num": [float("nan")], "den": [1, 1]}, ("plant.tf.num", "finite")),
        ({"num": [1], "den": [1, float("inf")]}, ("plant.tf.den", "finite")),
        ({"num": [1], "den": [1, "1e308*10"]}, ("plant.tf.den", "NaN or inf")),
        ({"num": ["nan"], "den": [1, 1]}, ("plant.tf.num[0]", "unknown name 'nan'")),
        ({"num": [1], "den": f"(s+1)^{MAX_ORDER + 1}"}, ("plant.tf.den", "exceeds the limit")),
        ({"num": [1], "den": "(s+1)/s"}, ("plant.tf.den", "not a polynomial")),
        ({"num": [1], "den": "__import__('os')"}, ("plant.tf.den",)),
    ],
)
def test_bad_transfer_function(tf: dict[str, Any], fragments: tuple[str, ...]) -> None:
    fails(spec_with(plant={"tf": tf}), *fragments)


def test_nan_from_yaml_and_json_text() -> None:
    with pytest.raises(ValidationError) as info:
        load_spec("plant: {tf: {num: [.nan], den: [1, 1]}}\nloops: [{type: pi}]\n")
    assert_names(info.value, "plant.tf.num", "finite")
    text = '{"plant": {"tf": {"num": [1], "den": [1, Infinity]}}, "loops": [{"type": "pi"}]}'
    with pytest.raises(ValidationError) as info:
        load_spec(text + "\n")
    assert_names(info.value, "plant.tf.den", "finite")


SS_OK = {"A": [[0, 1], [-2, -3]], "B": [[0], [1]], "C": [[1, 0]]}


@pytest.mark.parametrize(
    "change, fragments",
    [
        ({"A": [[0, 1, 0], [-2, -3, 0]]}, ("plant.ss.A", "square")),
        ({"A": [[0, 1], [-2]]}, ("plant.ss.A", "different lengths")),
        ({"B": [[0], [1], [2]]}, ("plant.ss.B", "2x1")),
        ({"B": [[0, 1], [1, 0]]}, ("plant.ss.B", "2x1")),
        ({"C": [[1, 0, 0]]}, ("plant.ss.C", "2 columns")),
        ({"D": [[0, 0]]}, ("plant.ss.D", "1x1")),
        ({"D": [[0], [0]]}, ("plant.ss.D", "1x1")),
        ({"A": [[0, float("nan")], [-2, -3]]}, ("plant.ss.A", "finite")),
        ({"A": [[0, "1/z"], [-2, -3]], "outputs": ["y"]}, ("plant.ss.A[0][1]", "unknown name 'z'")),
        ({"outputs": ["a", "b"]}, ("plant.ss.outputs",)),
        ({"states": ["only_one"]}, ("plant.ss.states",)),
        ({"A": [[-1.0] * (MAX_ORDER + 1)] * (MAX_ORDER + 1), "B": [[1]] * (MAX_ORDER + 1), "C": [[1] * (MAX_ORDER + 1)]},
         ("plant.ss.A", "exceeds the limit")),  # fmt: skip
    ],
)
def test_bad_state_space(change: dict[str, Any], fragments: tuple[str, ...]) -> None:
    fails(spec_with(plant={"ss": {**SS_OK, **change}}), *fragments)


ODE_OK = {"states": ["h"], "rhs": {"h": "-h + u"}, "outputs": {"y": "h"}}


@pytest.mark.parametrize(
    "change, fragments",
    [
        ({"rhs": {}}, ("plant.ode", "no expression for state")),
        ({"rhs": {"h": "-h", "q": "u"}}, ("plant.ode", "unknown state")),
        ({"outputs": {}}, ("plant.ode", "at least one output")),
        ({"rhs": {"h": "-h + u + k"}}, ("plant.ode.rhs.h", "unknown name 'k'")),
        ({"rhs": {"h": "h.real"}}, ("plant.ode.rhs.h", "attribute")),
        ({"outputs": {"y": "open('x')"}}, ("plant.ode.outputs.y", "open")),
        ({"rhs": {"h": "h^2 + 1"}}, ("plant.ode.x0", "not an equilibrium")),
        ({"states": [f"x{i}" for i in range(MAX_ORDER + 1)],
          "rhs": {f"x{i}": "u" for i in range(MAX_ORDER + 1)}}, ("plant.ode.states", "exceeds the limit")),  # fmt: skip
    ],
)
def test_bad_ode(change: dict[str, Any], fragments: tuple[str, ...]) -> None:
    fails(spec_with(plant={"ode": {**ODE_OK, **change}}), *fragments)


def test_ode_param_clashing_with_state() -> None:
    fails(spec_with(plant={"ode": ODE_OK, "params": {"h": 1.0}}), "plant.params.h", "clashes")


@pytest.mark.parametrize(
    "plant, fragments",
    [
        ({}, ("plant", "exactly one of tf, tf_matrix, ss, ode or model")),
        ({**TF3, "ss": SS_OK}, ("plant", "exactly one")),
        ({**TF3, "delay": -0.5}, ("plant.delay", ">= 0")),
        ({**TF3, "delay": float("inf")}, ("plant.delay", "finite")),
        ({**TF3, "delay": "-Td", "params": {"Td": 1.0}}, ("plant.delay", ">= 0")),
        ({**TF3, "delay": "Tq"}, ("plant.delay", "unknown name 'Tq'")),
        ({**TF3, "params": {"K": float("nan")}}, ("plant.params", "finite")),
        ({"tf": {"num": [1], "den": [1, 1], "typo": 1}}, ("plant.tf.typo", "Extra inputs")),
    ],
)
def test_bad_plant(plant: dict[str, Any], fragments: tuple[str, ...]) -> None:
    fails(spec_with(plant=plant), *fragments)


# -------------------------------------------------------- scenario errors


@pytest.mark.parametrize(
    "scenario, fragments",
    [
        ({"dt": 0}, ("scenarios.0", "dt must be > 0")),
        ({"dt": -0.01}, ("scenarios.0", "dt must be > 0")),
        ({"horizon": 0}, ("scenarios.0", "horizon must be > 0")),
        ({"horizon": -5}, ("scenarios.0", "horizon must be > 0")),
        ({"dt": float("nan")}, ("scenarios.0.dt", "finite number")),
        ({"dt": 1e-4, "horizon": MAX_STEPS * 1e-4 * 1.01}, ("scenarios.0", "exceeds the limit")),
        ({"dt": 1.0, "horizon": 1.0}, ("scenarios.0", "at least 2 samples")),
        ({"reference": {"kind": "sequence"}}, ("scenarios.0.reference", "points")),
        ({"reference": {"kind": "sequence", "points": [[2, 1], [1, 0]]}}, ("scenarios.0.reference", "increasing")),
        ({"reference": {"kind": "chirp"}}, ("scenarios.0.reference.kind",)),
        ({"noise_std": -1}, ("scenarios.0.noise_std",)),
    ],
)
def test_bad_scenario(scenario: dict[str, Any], fragments: tuple[str, ...]) -> None:
    fails(spec_with(scenarios=[scenario]), *fragments)


def test_max_steps_boundary_is_accepted() -> None:
    spec = load_spec(spec_with(scenario={"dt": 1e-3, "horizon": MAX_STEPS * 1e-3}))
    assert spec.scenarios[0].n_steps == MAX_STEPS


# ------------------------------------------------------- loops and others


@pytest.mark.parametrize(
    "data, fragments",
    [
        (spec_with(loops=[]), ("loops", "at least 1")),
        (spec_with(loops=[{"type": "pid"}] * 7), ("loops", "at most 6")),
        (spec_with(loops=[{"type": "pdi"}]), ("loops.0.type",)),
        (spec_with(loops=[{"type": "lqr"}, {"type": "pi"}]), ("loops[0]", "innermost")),
        (spec_with(loops=[{"name": "a"}, {"name": "a"}]), ("unique",)),
        (spec_with(loops=[{"output_limits": [1, -1]}]), ("loops.0.output_limits", "low < high")),
        (spec_with(loops=[{"gains": {"Kp": {"bounds": [0, 1]}}}]), ("loops.0.gains.Kp", "0 < low < high")),
        (spec_with(loops=[{"gains": {"Kp": {"tune": False}}}]), ("loops.0.gains.Kp", "needs a value")),
        (spec_with(actuator={"limits": [5, 5]}), ("actuator.limits", "low < high")),
        (spec_with(randomize={"params": {"K": [2, 1]}}), ("randomize.params.K", "low <= high")),
        (spec_with(randomize={"params": {"K": {"dist": "normal", "mean": 1}}}), ("randomize.params.K", "mean and std")),
        (spec_with(randomize={"delay": {"dist": "loguniform", "low": 0, "high": 1}}), ("randomize.delay", "low > 0")),
        (spec_with(scenario={}, scenarios=[{}]), ("either 'scenario' or 'scenarios'",)),
        (spec_with(objective={"measure": "mse"}), ("objective.measure",)),
        (spec_with(requirments={}), ("requirments", "Extra inputs")),
        ({"loops": [{"type": "pi"}]}, ("plant", "Field required")),
    ],
)
def test_bad_spec_fields(data: dict[str, Any], fragments: tuple[str, ...]) -> None:
    fails(data, *fragments, build_too=False)


# ------------------------------------------------ cross-checks with plant


MOTOR = {"model": "dc_motor"}


def check(data: dict[str, Any]) -> None:
    spec = load_spec(data)
    validate_against_plant(spec, build_plant(spec.plant))


@pytest.mark.parametrize(
    "data, field, fragment",
    [
        (spec_with(plant=MOTOR, loops=[{"measure": "position"}, {"measure": "sped"}]),
         "loops[1].measure", "no output 'sped'"),  # fmt: skip
        (spec_with(loops=[{"measure": "position"}]), "loops[0].measure", "outputs: y"),
        (spec_with(plant=MOTOR, randomize={"params": {"Jm": [1e-3, 2e-3]}}), "randomize.params.Jm", "parameters: R, L, J"),
        (spec_with(plant=MOTOR, safety={"state_bounds": {"omega": 10}}), "safety.state_bounds.omega", "states: i, w, theta"),
        (spec_with(safety={"action": "fallback", "fallback_gains": {"outer": {"Kp": 1}}}),
         "safety.fallback_gains.outer", "loops: loop0"),  # fmt: skip
        (spec_with(plant={"model": "lag_n"}, randomize={"params": {"n": [2, 4]}}), "randomize.params.n", "structural"),
        (spec_with(plant={"model": "lag_n"}, randomize={"params": {"n": [2.5, 3.5]}}), "randomize.params.n", "whole power"),
        (spec_with(plant={"model": "lag_n"}, randomize={"params": {"T": [0, 1]}}), "randomize.params.T", "T = 0"),
        (spec_with(plant={"model": "water_tank"}, actuator={"limits": [0, 1]}), "actuator.limits", "u0 = 1.26"),
    ],
)
def test_validate_against_plant_names_field(data: dict[str, Any], field: str, fragment: str) -> None:
    with pytest.raises(SpecError) as info:
        check(data)
    assert info.value.field == field
    assert fragment in info.value.message


def test_validate_against_plant_accepts_valid_names() -> None:
    check(
        spec_with(
            plant=MOTOR,
            loops=[{"measure": "position", "name": "pos"}, {"measure": "speed"}, {"measure": "current"}],
            randomize={"params": {"J": [8e-4, 1.2e-3], "b": {"dist": "normal", "mean": 1e-4, "std": 1e-5}}},
            safety={"state_bounds": {"w": 400}, "action": "fallback", "fallback_gains": {"pos": {"Kp": 1}}},
            actuator={"limits": [-24, 24]},
        )
    )
    check(spec_with(plant={"model": "lag_n"}, randomize={"params": {"n": [3, 3]}}))  # a point range keeps the order


# --------------------------------------------------- defaults and loading


def test_minimal_spec_gets_all_defaults() -> None:
    spec = load_spec({"plant": {"tf": {"num": [1], "den": "(s+1)^3"}}, "loops": [{"type": "pid"}]})
    assert spec.name == "untitled"
    (loop,) = spec.loops
    assert (loop.name, loop.measure, loop.form, loop.b, loop.c) == ("loop0", None, "parallel", 1.0, 0.0)
    assert loop.anti_windup == "clamping" and loop.filter.N == 10.0 and loop.gains == {}
    assert spec.actuator.limits is None and spec.actuator.rate_limit is None
    (sc,) = spec.scenarios
    assert (sc.dt, sc.horizon, sc.reference.kind, sc.reference.amplitude, sc.disturbance.kind) == (
        None, None, "step", 1.0, "none")  # fmt: skip
    # dt and horizon left out are derived from the plant's time scale (FOTD T = L = 1.5 s)
    from gaintune.classical.timescale import resolve_scenarios

    (sc,) = resolve_scenarios(spec).scenarios
    assert (sc.dt, sc.horizon, sc.n_steps) == (0.015, 30.0, 2000)
    assert spec.objective.measure == "iae" and spec.objective.effort_weight == 0.01
    assert (spec.requirements.gm_min_db, spec.requirements.pm_min_deg, spec.requirements.ms_max) == (6.0, 45.0, 2.0)
    assert not spec.randomize.active
    assert spec.search.algo == "ppo" and spec.search.budget == 3000
    assert spec.verify.pade_order is None
    assert spec.plant.delay is None and spec.plant.params == {}  # None: 0 s, or the model's own delay


def test_model_string_shorthand_becomes_reference() -> None:
    spec = load_spec(spec_with(plant={"model": "dc_motor"}))
    assert spec.plant.model is not None and spec.plant.model.name == "dc_motor" and spec.plant.model.params == {}


YAML_TEXT = """\
name: yaml-spec
plant:
  tf: {num: [K], den: "(T*s + 1)^2"}
  params: {K: 2, T: 0.5}
  delay: 0.1
loops:
  - {type: pi, gains: {Kp: {bounds: [0.1, 10]}}}
scenario: {dt: 0.02, horizon: 5}
"""


def _expected(spec: TuningSpec) -> None:
    assert spec.name == "yaml-spec"
    assert spec.plant.params == {"K": 2.0, "T": 0.5} and spec.plant.delay == 0.1
    assert spec.loops[0].gains["Kp"].bounds == (0.1, 10.0)
    assert len(spec.scenarios) == 1 and spec.scenarios[0].dt == 0.02 and spec.scenarios[0].n_steps == 250
    lin = build_plant(spec.plant).linearize()
    assert lin.A.shape == (2, 2) and lin.delay == 0.1


def test_load_yaml_string_and_path(tmp_path) -> None:
    _expected(load_spec(YAML_TEXT))
    path = tmp_path / "spec.yaml"
    path.write_text(YAML_TEXT)
    _expected(load_spec(path))
    _expected(load_spec(str(path)))


def test_load_json_string_and_path(tmp_path) -> None:
    import yaml

    text = json.dumps(yaml.safe_load(YAML_TEXT))
    _expected(load_spec(text + "\n"))
    path = tmp_path / "spec.json"
    path.write_text(text)
    _expected(load_spec(path))


def test_scenario_shorthand_equals_list() -> None:
    a = load_spec(spec_with(scenario={"dt": 0.05, "horizon": 3}))
    b = load_spec(spec_with(scenarios=[{"dt": 0.05, "horizon": 3}]))
    assert a == b and a.content_hash() == b.content_hash()


@pytest.mark.parametrize(
    "source, fragment",
    [
        ("does/not/exist.yaml", "cannot read"),
        ("plant: [unclosed\nloops: 1\n", "not valid YAML/JSON"),
        ("- just\n- a list\n", "must be a mapping"),
    ],
)
def test_load_errors_are_spec_errors(source: str, fragment: str) -> None:
    with pytest.raises(SpecError, match=fragment) as info:
        load_spec(source)
    assert info.value.field == "spec"


def test_content_hash_changes_with_content() -> None:
    a = load_spec(spec_with())
    b = load_spec(spec_with(scenario={"dt": 0.02}))
    assert a.content_hash() != b.content_hash()
    assert len(a.content_hash()) == 64
