"""Spec input that used to hang or be misread (issue 24): YAML alias bombs, NaN/inf from YAML, booleans read as
numbers, and ODE names that hid one another. Each is refused naming the field; the CLI exits 2."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from pydantic import ValidationError
from typer.testing import CliRunner

from gaintune import cli
from gaintune.errors import GainError, SpecError
from gaintune.spec import MAX_YAML_NODES, _lone_surrogate, load_spec, parse_json_or_yaml

BASE = {"plant": {"tf": {"num": [1], "den": "(s+1)^2"}}, "loops": [{"type": "pi"}], "scenario": {"dt": 0.05, "horizon": 5}}
GAINS = '{"loop0": {"Kp": 1, "Ki": 0.5}}'
PLANT_YAML = "plant: {tf: {num: [1], den: \"(s+1)^2\"}}\nloops: [{type: pi}]\nscenario: {dt: 0.05, horizon: 5}\n"


def _laughs(levels: int = 9, width: int = 9) -> str:
    """A "billion laughs": each anchor lists ``width`` aliases of the one before (width^levels strings)."""
    lines = [f'l0: &l0 [{", ".join(["lol"] * width)}]']
    lines += [f'l{i}: &l{i} [{", ".join([f"*l{i - 1}"] * width)}]' for i in range(1, levels + 1)]
    return "\n".join(lines) + f"\n{PLANT_YAML}description: *l{levels}\n"


def _errors(data: Any) -> str:
    with pytest.raises(ValidationError) as info:
        load_spec(data)
    return "\n".join(f"{'.'.join(map(str, e['loc']))}: {e['msg']}" for e in info.value.errors())


# ------------------------------------------------------------ YAML aliases


def test_billion_laughs_yaml_refused() -> None:
    """9 levels of 9 aliases kept `gaintune verify` at 100 % CPU for more than 45 s (9^9 nodes walked)."""
    with pytest.raises(SpecError) as info:
        load_spec(_laughs())
    assert info.value.field == "spec"
    assert f"more than {MAX_YAML_NODES:,} nodes" in info.value.message and "aliases" in info.value.message


def test_billion_laughs_yaml_is_exit_2_from_the_cli(tmp_path: Path) -> None:
    """The timeout only stops a hang; the refusal itself is linear in the file."""
    path = tmp_path / "laughs.yaml"
    path.write_text(_laughs())
    p = subprocess.run([sys.executable, "-m", "gaintune", "verify", str(path), "--gains", GAINS],
                       capture_output=True, text=True, timeout=300)
    assert p.returncode == 2, p.stderr
    assert f"{MAX_YAML_NODES:,}" in p.stderr and "Traceback" not in p.stderr


def test_yaml_aliases_within_the_limit_still_load() -> None:
    text = PLANT_YAML.replace("loops: [{type: pi}]", "loops: [{type: pi, gains: {Kp: {bounds: &b [0.1, 10]}, Ki: {bounds: *b}}}]")
    spec = load_spec(text)
    assert spec.loops[0].gains["Ki"].bounds == (0.1, 10.0)
    assert parse_json_or_yaml(_laughs(levels=3, width=9))["l3"][0][0][0] == ["lol"] * 9  # 9^3 nodes: fine


def test_recursive_yaml_alias_refused() -> None:
    with pytest.raises(SpecError, match="refers to its own anchor"):
        load_spec(PLANT_YAML + "description: &d [1, *d]\n")


def test_lone_surrogate_check_visits_shared_data_once() -> None:
    """The check walked every aliased copy: a list shared n times was iterated n times."""

    class Counted(list):
        walks = 0

        def __iter__(self):
            Counted.walks += 1
            return super().__iter__()

    shared = Counted(["a", "b"])
    data = {"x": [shared] * 50, "y": {"z": shared}}
    assert _lone_surrogate(data, "") is None
    assert Counted.walks == 1
    bad = {"x": [shared] * 3, "y": ["ok", "\ud800"]}
    assert _lone_surrogate(bad, "") == "y.1"


# --------------------------------------------------------------- NaN / inf


def test_yaml_nan_requirement_is_exit_2(tmp_path: Path) -> None:
    """`gm_min_db: .nan` gave "limit nan", a FAIL and exit 3; the API refused it. One schema refuses it now."""
    path = tmp_path / "nan.yaml"
    path.write_text(PLANT_YAML + "requirements: {gm_min_db: .nan}\n")
    res = CliRunner().invoke(cli.app, ["verify", str(path), "--gains", GAINS])
    assert res.exit_code == 2, res.output
    assert "requirements.gm_min_db" in res.output and "finite" in res.output


@pytest.mark.parametrize(
    "yaml_line, loc",
    [
        ("requirements: {pm_min_deg: .nan}", "requirements.pm_min_deg"),
        ("requirements: {ms_max: .inf}", "requirements.ms_max"),
        ("requirements: {mks_max: .inf}", "requirements.mks_max"),
        ("actuator: {safe_value: -.inf}", "actuator.safe_value"),
        ("objective: {effort_weight: .inf}", "objective.effort_weight"),
        ("search: {wall_time: .inf}", "search.wall_time"),
        ("safety: {max_abs_error: .inf}", "safety.max_abs_error"),
        ("design: {crossover: .inf}", "design.crossover"),
    ],
)
def test_non_finite_yaml_numbers_are_refused_in_every_section(yaml_line: str, loc: str) -> None:
    assert loc in _errors(PLANT_YAML + yaml_line + "\n")


def test_loop_output_limits_must_be_finite() -> None:
    assert "loops.0.output_limits" in _errors({**BASE, "loops": [{"type": "pi", "output_limits": [float("-inf"), 1]}]})


# ---------------------------------------------------------------- booleans


@pytest.mark.parametrize(
    "section, value, loc",
    [
        ("loops", [{"type": "pi", "gains": {"Kp": {"value": True, "tune": False}}}], "loops.0.gains.Kp.value"),
        ("loops", [{"type": "pi", "gains": {"Kp": {"bounds": [True, 10]}}}], "loops.0.gains.Kp.bounds"),
        ("plant", {"tf": {"num": [True], "den": [1, 1]}}, "plant.tf.num"),
        ("plant", {"tf": {"num": [1], "den": [1, 1]}, "params": {"K": True}}, "plant.params"),
        ("requirements", {"gm_min_db": True}, "requirements.gm_min_db"),
        ("search", {"budget": True}, "search.budget"),
        ("randomize", {"params": {"K": [False, 2]}}, "randomize.params.K"),
        ("safety", {"fallback_gains": {"loop0": {"Kp": True}}}, "safety.fallback_gains"),
        ("design", {"phase_margin": True}, "design.phase_margin"),
    ],
)
def test_spec_refuses_boolean_numbers(section: str, value: Any, loc: str) -> None:
    """pydantic's lax mode read true as 1.0 (a gain of 1, a budget of 1 ...)."""
    text = _errors({**BASE, section: value})
    assert loc in text and "not a boolean" in text, text


def test_boolean_settings_are_still_booleans() -> None:
    spec = load_spec({**BASE, "search": {"refine": False, "repair": True}, "verify": {"sampled": False}})
    assert spec.search.refine is False and spec.verify.sampled is False


def test_verify_refuses_boolean_gain_vector() -> None:
    from gaintune.verification import verify

    spec = load_spec(BASE)
    for gains in ([True, 0.5], np.array([True, True])):
        with pytest.raises(GainError, match="not booleans"):
            verify(spec, gains)


# ------------------------------------------------------------------- names


def _ode(**changes: Any) -> dict[str, Any]:
    ode = {"states": ["h"], "rhs": {"h": "-h + u"}, "outputs": {"y": "h"}}
    return {**BASE, "plant": {"ode": {**ode, **changes.pop("ode", {})}, **changes}}


def test_ode_state_named_like_input_refused() -> None:
    """`states: [u]` was shadowed by the input: the plant became y = u and the job passed."""
    text = _errors(_ode(ode={"states": ["u"], "rhs": {"u": "-u + u"}, "outputs": {"y": "u"}}))
    assert "plant.ode.states.0" in text and "name of the input" in text


def test_ode_state_named_like_a_custom_input_refused() -> None:
    text = _errors(_ode(ode={"states": ["h", "F"], "input": "F", "rhs": {"h": "F", "F": "-F"}}))
    assert "plant.ode.states.1" in text


@pytest.mark.parametrize("name, clash", [("h", "ode.states[0]"), ("u", "ode.input")])
def test_ode_parameter_named_like_a_state_or_the_input_refused(name: str, clash: str) -> None:
    text = _errors(_ode(params={name: 1.0}))
    assert f"plant.params.{name}" in text and clash in text


def test_tf_parameter_named_s_refused() -> None:
    """In a polynomial expression `s` is the Laplace variable: a parameter s was silently ignored there."""
    text = _errors({**BASE, "plant": {"tf": {"num": ["s"], "den": "s + 1"}, "params": {"s": 2.0}}})
    assert "plant.params.s" in text and "Laplace" in text


def test_ode_state_named_t_is_an_ordinary_state() -> None:
    """ODE plants are autonomous: no time variable exists in the expressions, so `t` hides nothing."""
    from gaintune.plants import build_plant

    spec = load_spec(_ode(ode={"states": ["t"], "rhs": {"t": "-t + u"}, "outputs": {"y": "t"}}))
    assert build_plant(spec.plant).states == ["t"]
