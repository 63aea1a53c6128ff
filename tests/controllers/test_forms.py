"""Gains in the form engineers use: K/Ti/Td on a parallel loop, zero gains, both forms shown."""

from __future__ import annotations

import json

import pytest
from typer.testing import CliRunner

from gaintune.cli import app
from gaintune.errors import GainError
from gaintune.spec import load_spec
from gaintune.verification import verify
from gaintune.verification.report import format_table

SPEC = {"name": "lag3", "plant": {"tf": {"num": [1], "den": "(s+1)^3"}}, "loops": [{"type": "pid"}],
        "scenario": {"dt": 0.05, "horizon": 20.0}}


@pytest.fixture(scope="module")
def spec():
    return load_spec(SPEC)


def test_gains_in_ideal_form_are_read_on_a_parallel_loop(spec):
    ideal = verify(spec, {"loop0": {"K": 1.0, "Ti": 2.5, "Td": 0.5}}, nonlinear=False)
    parallel = verify(spec, {"loop0": {"Kp": 1.0, "Ki": 0.4, "Kd": 0.5}}, nonlinear=False)
    assert ideal.gains == parallel.gains == {"loop0": {"Kp": 1.0, "Ki": 0.4, "Kd": 0.5}}
    assert ideal.verdict == parallel.verdict


def test_gains_in_parallel_form_are_read_on_an_ideal_loop():
    spec = load_spec({**SPEC, "loops": [{"type": "pi", "form": "ideal"}]})
    rep = verify(spec, {"loop0": {"Kp": 1.0, "Ki": 0.4}}, nonlinear=False)
    assert rep.gains == {"loop0": {"Kp": 1.0, "Ti": 2.5}}


def test_kd_zero_on_a_pid_is_legal(spec):
    rep = verify(spec, {"loop0": {"Kp": 1.0, "Ki": 0.4, "Kd": 0}}, nonlinear=False)
    assert rep.stability.stable and rep.gains["loop0"]["Kd"] == 0.0


def test_ki_zero_on_a_pid_is_legal_and_adds_no_integrator_pole(spec):
    rep = verify(spec, {"loop0": {"Kp": 1.0, "Ki": 0, "Kd": 0.5}}, nonlinear=False)
    assert rep.stability.stable, rep.reasons


def test_ti_zero_is_refused_naming_ti(spec):
    with pytest.raises(GainError) as err:
        verify(spec, {"loop0": {"Kp": 1.0, "Ti": 0.0, "Td": 0.5}})
    assert err.value.field == "gains.loop0.Ti"


def test_negative_kd_still_names_the_direction_fix(spec):
    with pytest.raises(GainError, match="direction: reverse"):
        verify(spec, {"loop0": {"Kp": 1.0, "Ki": 0.4, "Kd": -0.5}})


def test_verify_table_shows_both_forms(spec):
    table = format_table(verify(spec, {"loop0": {"Kp": 1.0, "Ki": 0.4, "Kd": 0.5}}, nonlinear=False))
    assert "(ideal: Ti 2.5 s, Td 0.5 s)" in table.splitlines()[1]


def test_cli_verify_accepts_ideal_form_gains(tmp_path):
    path = tmp_path / "spec.json"
    path.write_text(json.dumps(SPEC))
    res = CliRunner().invoke(app, ["verify", str(path), "--gains", '{"loop0": {"Kp": 1.0, "Ti": 2.5, "Td": 0.5}}'])
    assert res.exit_code == 0, res.output
    assert "Ki 0.4" in res.output
