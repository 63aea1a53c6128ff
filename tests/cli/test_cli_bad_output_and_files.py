"""Bugs a fuzzer found in the CLI (tenth session): each exited 1 with a traceback; now exit 2 naming the input."""

from __future__ import annotations

import json
from pathlib import Path

import pytest
from typer.testing import CliRunner

from gaintune import cli
from gaintune.plants.library import load_model
from gaintune.report import result_from_gains
from gaintune.spec import load_spec

runner = CliRunner()
SPEC = {"plant": {"tf": {"num": [1], "den": "(s+1)^2"}}, "loops": [{"type": "pi"}],
        "scenario": {"dt": 0.05, "horizon": 5}, "search": {"budget": 64, "n_envs": 8}}


def _exit_2(res, *needles: str) -> None:
    assert res.exit_code == 2, res.output
    assert "Traceback" not in res.output
    assert res.exception is None or isinstance(res.exception, SystemExit)
    for n in needles:
        assert n in res.output, res.output


@pytest.fixture(scope="module")
def result_file(tmp_path_factory) -> Path:
    good = result_from_gains(load_spec(load_model("lag_n").example_spec()),
                             {"main": {"Kp": 0.6485, "Ki": 0.3957, "Kd": 0.3751}}, algo="ppo")
    p = tmp_path_factory.mktemp("res") / "result.json"
    p.write_text(good.model_dump_json())
    return p


def test_tune_out_is_an_existing_file_exits_2_before_the_search(tmp_path: Path, monkeypatch) -> None:
    """The check runs before tuning: the search (which took the whole budget before failing) is never started."""
    spec, taken = tmp_path / "pi.json", tmp_path / "taken.json"
    spec.write_text(json.dumps(SPEC))
    taken.write_text("{}")
    monkeypatch.setattr(cli, "_get_tune", lambda: pytest.fail("the search started"))
    _exit_2(runner.invoke(cli.app, ["tune", str(spec), "--out", str(taken)]), "out:", "is a file")
    _exit_2(runner.invoke(cli.app, ["tune", str(spec), "--out", str(taken / "sub")]), "out:", "is a file")
    _exit_2(runner.invoke(cli.app, ["demo", "--out", str(taken)]), "out:", "is a file")


@pytest.mark.parametrize("command", ["export", "report"])
def test_unwritable_output_file_exits_2_naming_output(result_file: Path, tmp_path: Path, command: str) -> None:
    blocker = tmp_path / "plain_file"
    blocker.write_text("")
    target = blocker / "x.out"  # a file where a folder should be
    _exit_2(runner.invoke(cli.app, [command, str(result_file), "-o", str(target)]), "output:", "cannot write")
    if Path("/dev/full").exists():  # a device (through a link, so a regression cannot rename over /dev/full)
        device = tmp_path / "full"
        device.symlink_to("/dev/full")
        _exit_2(runner.invoke(cli.app, [command, str(result_file), "-o", str(device)]), "output:", "not a regular file")


def test_deeply_nested_gains_or_spec_file_exits_2_not_recursion_error(tmp_path: Path) -> None:
    spec, deep_json, deep_yaml = tmp_path / "pi.json", tmp_path / "deep.json", tmp_path / "deep.yaml"
    spec.write_text(json.dumps(SPEC))
    deep_json.write_text('{"a":' * 100_000 + "1" + "}" * 100_000)
    deep_yaml.write_text("a: " + "[" * 100_000 + "]" * 100_000 + "\n")
    _exit_2(runner.invoke(cli.app, ["verify", str(spec), "-g", str(deep_json)]), "gains:", "nested too deeply")
    _exit_2(runner.invoke(cli.app, ["tune", str(deep_yaml)]), "spec:", "nested too deeply")


@pytest.mark.parametrize("args, needle", [
    (["--workers", "-1"], "--workers"), (["--port", "99999"], "--port"), (["--port", "-1"], "--port"),
    (["--host", "999.999.1.1", "--port", "8123"], "host:"),
])
def test_serve_with_invalid_options_exits_2_before_starting(args: list[str], needle: str) -> None:
    _exit_2(runner.invoke(cli.app, ["serve", *args]), needle)


def test_seed_outside_numpys_range_exits_2_naming_search_seed(tmp_path: Path) -> None:
    spec = tmp_path / "pi.json"
    spec.write_text(json.dumps(SPEC))
    _exit_2(runner.invoke(cli.app, ["tune", str(spec), "--seed", str(2**32)]), "search.seed")
    _exit_2(runner.invoke(cli.app, ["tune", str(spec), "--seed", "-1"]), "search.seed")
