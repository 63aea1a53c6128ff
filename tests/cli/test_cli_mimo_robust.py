"""`gaintune verify` on a MIMO spec that randomises plant parameters: the worst case and its draw in the
table and the JSON, exit 3 when it fails; a randomised parameter the plant lacks exits 2 naming the field."""

from __future__ import annotations

import json
import sys
from pathlib import Path

import yaml
from typer.testing import CliRunner

from gaintune import cli

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "verification"))
from test_mimo_robust import GAINS, RANDOM_K11, wood_berry_k11  # noqa: E402

runner = CliRunner()


def _files(tmp_path: Path, spec: dict) -> tuple[str, str]:
    (tmp_path / "spec.yaml").write_text(yaml.safe_dump(spec, sort_keys=False))
    (tmp_path / "gains.json").write_text(json.dumps(GAINS))
    return str(tmp_path / "spec.yaml"), str(tmp_path / "gains.json")


def test_cli_verify_of_a_randomised_mimo_spec_shows_the_worst_case_and_its_draw(tmp_path: Path) -> None:
    spec, gains = _files(tmp_path, wood_berry_k11(randomize=RANDOM_K11, mimo_ms_max=2.0))
    res = runner.invoke(cli.app, ["verify", spec, "--gains", gains])
    assert res.exit_code == 3, res.output
    assert "PASS mimo_ms_max ms=1.953 limit 2 margin +0.04745 at input/nominal" in res.output
    assert "FAIL mimo_ms_max ms=2.081 limit 2 margin -0.08122 at input/worst (draw K11=10)" in res.output
    assert "MIMO         inputs   worst Ms 2.081" in res.output and "xD           y        worst GM" in res.output
    res = runner.invoke(cli.app, ["verify", spec, "--gains", gains, "--json"])
    rep = json.loads(res.output)
    assert rep["verdict"] == "fail" and rep["robust"]["n_samples"] == 18
    assert [(q["case"], q["draw"]) for q in rep["requirements"]] == [("nominal", None), ("worst", {"K11": 10.0})]
    res = runner.invoke(cli.app, ["verify", spec, "--gains", gains, "--no-robust"])
    assert res.exit_code == 0, res.output


def test_cli_verify_of_a_mimo_spec_randomising_an_unknown_parameter_exits_2_naming_it(tmp_path: Path) -> None:
    spec, gains = _files(tmp_path, wood_berry_k11(randomize={"params": {"K21": {"low": 1.0, "high": 2.0}}}))
    res = runner.invoke(cli.app, ["verify", spec, "--gains", gains])
    assert res.exit_code == 2, res.output
    assert "randomize.params.K21" in res.output and "Traceback" not in res.output
