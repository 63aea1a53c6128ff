"""A biproper plant through the CLI: tuned, verified and exported; an improper one refused (exit 2)."""

from __future__ import annotations

import json
from pathlib import Path

import yaml
from typer.testing import CliRunner

from gaintune import cli

runner = CliRunner()
#: 3(s+10)/(s+2): direct feedthrough D = 3, no delay (refused by the simulator before).
BIPROPER = {"plant": {"tf": {"num": "3*(s+10)", "den": "s+2"}}, "loops": [{"type": "pi"}],
            "scenario": {"dt": 0.01, "horizon": 3.0}, "search": {"budget": 64, "n_envs": 8}}


def _cli(*args: str):
    return runner.invoke(cli.app, list(args))


def test_biproper_plant_without_delay_is_tuned_verified_and_exported(tmp_path: Path) -> None:
    spec = tmp_path / "biproper.yaml"
    spec.write_text(yaml.safe_dump(BIPROPER))
    out = tmp_path / "out"
    res = _cli("tune", str(spec), "--out", str(out), "--json")
    assert res.exit_code == 0, res.output
    result = json.loads(res.stdout)
    assert result["verification"]["verdict"] == "pass"
    assert result["verification"]["nonlinear"]["ran"] and not result["verification"]["nonlinear"]["diverged"]
    gains = out / "gains.json"
    assert gains.is_file() and (out / "gains.h").is_file()
    res = _cli("verify", str(spec), "--gains", str(gains))
    assert res.exit_code == 0, res.output
    res = _cli("export", str(out / "result.json"), "--format", "c", "-o", str(tmp_path / "g.h"))
    assert res.exit_code == 0, res.output
    assert "gt_step" in (tmp_path / "g.h").read_text()


def test_improper_plant_is_refused_with_exit_2_naming_plant_tf(tmp_path: Path) -> None:
    spec = tmp_path / "improper.yaml"
    spec.write_text(yaml.safe_dump({**BIPROPER, "plant": {"tf": {"num": "(s+1)^2", "den": "s+2"}}}))
    res = _cli("verify", str(spec), "--gains", '{"loop0": {"Kp": 0.1, "Ki": 2.0}}')
    assert res.exit_code == 2, res.output
    assert "plant.tf" in res.output and "improper" in res.output and "Traceback" not in res.output
