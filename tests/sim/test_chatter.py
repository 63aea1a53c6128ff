"""Chattering saturation is flagged, not called a working loop (issue 12: ±24 V chatter was 'not diverged')."""

from __future__ import annotations

import json

import numpy as np
from typer.testing import CliRunner

from gaintune.cli import app
from gaintune.sim.chatter import CHATTER_SWITCHES, is_chattering, saturation_switches


def test_saturation_switches_counts_limit_to_limit_reversals_only():
    lim = (-24.0, 24.0)
    assert saturation_switches(np.array([0, 24, 24, 5, -24, -24, 24]), lim) == 2
    assert saturation_switches(np.array([0, 24, 3, 24, 24]), lim) == 0  # leaving and re-entering one limit
    assert saturation_switches(np.array([0, 24, -24] * 10), None) == 0
    assert is_chattering(np.tile([24.0, -24.0], CHATTER_SWITCHES), lim)


def test_simulate_flags_bang_bang_chatter_of_an_over_aggressive_loop(tmp_path):
    spec = {"plant": {"tf": {"num": [1], "den": "(s+1)^3"}}, "loops": [{"type": "pid"}],
            "actuator": {"limits": [-24, 24]}, "scenario": {"dt": 0.05, "horizon": 20}}
    path = tmp_path / "spec.json"
    path.write_text(json.dumps(spec))
    hot = json.dumps({"loop0": {"Kp": 200.0, "Ki": 50.0, "Kd": 30.0}})  # far beyond Ku: bounded limit cycle
    res = CliRunner().invoke(app, ["simulate", str(path), "--gains", hot, "--json"])
    assert res.exit_code == 0, res.output
    m = json.loads(res.output)["nominal"]["metrics"]
    assert not m["diverged"] and m["chattering"] and m["saturation_switches"] >= CHATTER_SWITCHES
    calm = json.dumps({"loop0": {"Kp": 1.0, "Ki": 0.4, "Kd": 0.5}})
    m = json.loads(CliRunner().invoke(app, ["simulate", str(path), "--gains", calm, "--json"]).output)["nominal"]["metrics"]
    assert not m["chattering"]
