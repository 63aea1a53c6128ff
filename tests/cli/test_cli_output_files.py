"""What the CLI writes stays in its output folder; what it reads is bounded; a result file's verdict is not trusted.

* Planted symlinks: every output (``tune --out``, ``report -o``, ``export -o``, ``simulate --plot``)
  replaces a symlink at its path, never writes through it (``agent.zip`` is saved by the search:
  tests/search covers it).
* Forged results: ``export`` and ``report`` verify the gains again; the stored verdict of a file
  whose gains and ``verification.gains`` were both edited is never shown or exported as PASS.
* Special files: ``/dev/zero``, ``/dev/urandom``, a FIFO or a file over 10 MB given as spec,
  gains or result is refused (exit 2) naming the limit, before anything is read.
"""

from __future__ import annotations

import json
import os
from pathlib import Path

import pytest
from typer.testing import CliRunner

from gaintune import cli
from gaintune.files import MAX_INPUT_BYTES
from gaintune.plants.library import load_model
from gaintune.report import result_from_gains
from gaintune.spec import load_spec

runner = CliRunner()
AMIGO = {"main": {"Kp": 0.6485, "Ki": 0.3957, "Kd": 0.3751}}
#: Gains ``verify`` calls unstable on the lag_n example (closed loop unstable).
UNSTABLE = {"main": {"Kp": 50.0, "Ki": 50.0, "Kd": 0.3751}}
#: A PI loop that a tiny search tunes to PASS (no RL rollout fits the budget: the search box's start, verified).
TINY = {"plant": {"tf": {"num": [1], "den": "(s+1)^2"}}, "loops": [{"type": "pi"}],
        "scenario": {"dt": 0.05, "horizon": 5}, "search": {"budget": 64, "n_envs": 8}}
PRECIOUS = "precious: must not be overwritten"


def _cli(*args: str):
    return runner.invoke(cli.app, list(args))


def _exit_2(res, *needles: str) -> None:
    assert res.exit_code == 2, res.output
    assert "Traceback" not in res.output
    assert res.exception is None or isinstance(res.exception, SystemExit)
    for n in needles:
        assert n in res.output, res.output


@pytest.fixture(scope="module")
def good_result():
    return result_from_gains(load_spec(load_model("lag_n").example_spec()), AMIGO, algo="ppo")


@pytest.fixture(scope="module")
def result_file(good_result, tmp_path_factory) -> Path:
    p = tmp_path_factory.mktemp("res") / "result.json"
    p.write_text(good_result.model_dump_json())
    return p


@pytest.fixture(scope="module")
def forged_file(good_result, tmp_path_factory) -> Path:
    """A passing result.json with ``gains`` and ``verification.gains`` both set to unstable gains, verdict left at pass."""
    doc = json.loads(good_result.model_dump_json())
    assert doc["verification"]["verdict"] == "pass"
    doc["gains"] = UNSTABLE
    doc["verification"]["gains"] = UNSTABLE
    doc["diagnosis"] = {"status": "pass", "summary": "the gains pass verification (forged)", "hints": []}
    p = tmp_path_factory.mktemp("forged") / "forged.json"
    p.write_text(json.dumps(doc))
    return p


def _plant(folder: Path, names: list[str], outside: Path) -> dict[str, Path]:
    """A symlink ``folder/name`` -> ``outside/name`` (holding PRECIOUS) for every name."""
    outside.mkdir(exist_ok=True)
    folder.mkdir(exist_ok=True)
    targets = {}
    for name in names:
        target = outside / name
        target.write_text(PRECIOUS)
        (folder / name).symlink_to(target)
        targets[name] = target
    return targets


def _written_outside(outside: Path) -> list[str]:
    """Files in ``outside`` whose content is no longer PRECIOUS, and any file that appeared there."""
    return sorted(p.name for p in outside.iterdir() if p.read_text() != PRECIOUS)


# ------------------------------------------------------------ planted symlinks


def test_tune_out_with_planted_symlinks_writes_nothing_outside(tmp_path: Path) -> None:
    spec, out, outside = tmp_path / "base.json", tmp_path / "out", tmp_path / "elsewhere"
    spec.write_text(json.dumps(TINY))
    names = ["result.json", "report.html", "gains.h", "gains.json", "gains.yaml", "gains.m"]
    _plant(out, names, outside)
    res = _cli("tune", str(spec), "--out", str(out))
    assert res.exit_code == 0, res.output  # the tiny search's gains pass: gains.h and gains.m are written too
    assert _written_outside(outside) == [] and sorted(p.name for p in outside.iterdir()) == sorted(names)
    for name in names:
        assert not (out / name).is_symlink() and (out / name).is_file(), name
        assert (out / name).read_text() != PRECIOUS, name
    assert json.loads((out / "result.json").read_text())["verification"]["verdict"] == "pass"


def test_report_o_symlink_not_followed(result_file: Path, tmp_path: Path) -> None:
    outside = tmp_path / "elsewhere"
    _plant(tmp_path, ["report.html"], outside)
    res = _cli("report", str(result_file), "-o", str(tmp_path / "report.html"))
    assert res.exit_code == 0, res.output
    assert _written_outside(outside) == []
    assert not (tmp_path / "report.html").is_symlink() and "<html" in (tmp_path / "report.html").read_text()


def test_export_o_symlink_not_followed(result_file: Path, tmp_path: Path) -> None:
    outside = tmp_path / "elsewhere"
    _plant(tmp_path, ["gains.h"], outside)
    res = _cli("export", str(result_file), "-f", "c", "-o", str(tmp_path / "gains.h"))
    assert res.exit_code == 0, res.output
    assert _written_outside(outside) == []
    assert not (tmp_path / "gains.h").is_symlink() and "#define GT_VERIFIED 1\n" in (tmp_path / "gains.h").read_text()


def test_simulate_plot_symlink_not_followed(tmp_path: Path) -> None:
    spec, outside = tmp_path / "base.json", tmp_path / "elsewhere"
    spec.write_text(json.dumps(TINY))
    _plant(tmp_path, ["plot.svg"], outside)
    res = _cli("simulate", str(spec), "--gains", '{"loop0": {"Kp": 1, "Ki": 0.5}}', "--plot", str(tmp_path / "plot.svg"))
    assert res.exit_code == 0, res.output
    assert _written_outside(outside) == []
    assert not (tmp_path / "plot.svg").is_symlink() and "<svg" in (tmp_path / "plot.svg").read_text()


def test_export_o_link_to_a_device_is_refused_not_written_or_replaced(result_file: Path, tmp_path: Path) -> None:
    """``-o`` naming a device (here through a link to /dev/null) is refused: the device is neither written nor
    replaced by a rename (as root, renaming over /dev/null would remove the device)."""
    link = tmp_path / "sink"
    link.symlink_to("/dev/null")
    _exit_2(_cli("export", str(result_file), "-o", str(link)), "output:", "not a regular file")
    assert link.is_symlink() and os.readlink(link) == "/dev/null"


# ------------------------------------------------------------ forged results


def test_forged_result_json_export_reverifies_and_refuses_verified_define(forged_file: Path, tmp_path: Path) -> None:
    out = tmp_path / "gains.h"
    res = runner.invoke(cli.app, ["export", str(forged_file), "-f", "c", "-o", str(out)])
    assert res.exit_code == 3, res.output
    assert not out.exists() and "#define GT_VERIFIED 1" not in res.stdout
    assert "claims PASS" in res.stderr and "FAILED" in res.stderr and "closed loop unstable" in res.stderr
    # exported anyway on request: marked FAILED, never verified
    res = runner.invoke(cli.app, ["export", str(forged_file), "-f", "c", "--allow-unverified"])
    assert res.exit_code == 0, res.output
    assert "#define GT_VERIFIED 0\n" in res.stdout and '#define GT_VERDICT "fail"' in res.stdout
    assert "#define GT_VERIFIED 1" not in res.stdout


def test_forged_result_json_report_shows_fail(forged_file: Path, tmp_path: Path) -> None:
    out = tmp_path / "report.html"
    res = runner.invoke(cli.app, ["report", str(forged_file), "-o", str(out)])
    assert res.exit_code == 0, res.output
    html = out.read_text()
    assert 'id="verdict" class="verdict fail">FAILED<' in html and 'id="failed-banner"' in html
    assert "closed loop unstable" in html and "verified when this report was rendered" in html
    assert "the gains pass verification" not in html  # the stored diagnosis, written from the forged verdict, is dropped
    assert "claims verdict 'pass'" in res.stderr


def test_genuine_result_export_and_report_still_pass(result_file: Path, tmp_path: Path) -> None:
    res = runner.invoke(cli.app, ["export", str(result_file), "-f", "c"])
    assert res.exit_code == 0 and "#define GT_VERIFIED 1\n" in res.stdout
    assert "re-verified at dt = 0.01 s: PASS" in res.stderr
    res = runner.invoke(cli.app, ["report", str(result_file), "-o", str(tmp_path / "r.html")])
    assert res.exit_code == 0 and 'class="verdict pass">PASS<' in (tmp_path / "r.html").read_text()


# ------------------------------------------------------------ special files


def test_verify_dev_zero_refused_naming_limit() -> None:
    _exit_2(_cli("verify", "/dev/zero", "--gains", json.dumps(AMIGO)), "spec:", "not a regular file", "10 MB")


def test_verify_gains_dev_zero_refused_naming_limit(tmp_path: Path) -> None:
    spec = tmp_path / "base.json"
    spec.write_text(json.dumps(TINY))
    _exit_2(_cli("verify", str(spec), "--gains", "/dev/zero"), "gains:", "not a regular file", "10 MB")


def test_export_dev_urandom_refused() -> None:
    _exit_2(_cli("export", "/dev/urandom"), "result:", "not a regular file", "10 MB")
    _exit_2(_cli("report", "/dev/urandom"), "result:", "not a regular file")


def test_fifo_as_spec_gains_or_result_refused_without_hang(tmp_path: Path) -> None:
    """A FIFO nobody writes to: opening it to read would block forever; it is refused at once."""
    fifo, spec = tmp_path / "pipe.yaml", tmp_path / "base.json"
    os.mkfifo(fifo)
    spec.write_text(json.dumps(TINY))
    _exit_2(_cli("verify", str(fifo), "--gains", "{}"), "spec:", "not a regular file")
    _exit_2(_cli("verify", str(spec), "--gains", str(fifo)), "gains:", "not a regular file")
    _exit_2(_cli("export", str(fifo)), "result:", "not a regular file")


def test_oversized_spec_file_refused_naming_limit(tmp_path: Path) -> None:
    big = tmp_path / "big.yaml"
    with open(big, "wb") as f:  # sparse: no 10 MB of disk
        f.truncate(MAX_INPUT_BYTES + 1)
    _exit_2(_cli("verify", str(big), "--gains", "{}"), "spec:", "the limit is 10 MB")
