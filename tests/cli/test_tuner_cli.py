"""``gaintune tuner ...``: query (table, JSON, exit codes, no torch), list, train (resumable), update, schedule.

The tuners are the tiny ones of ``tests/conftest.py`` (trained for a few hundred episodes: their gains are
poor, every code path is the real one).
"""

from __future__ import annotations

import json
import os
import re
import shlex
import shutil
import subprocess
import sys
import zipfile
from pathlib import Path

import pytest
import yaml
from typer.testing import CliRunner

from gaintune import cli
from gaintune.cli import tuner as tuner_cli
from gaintune.tuners import artefact
from gaintune.tuners.tuner import Tuner

runner = CliRunner()
PLANT = ["-p", "K=2", "-p", "T=60", "-p", "L=10"]
#: A small LTI family: PI on K/(s+1)^2, K from 0.5 to 2 (fast to simulate).
LAG2 = {"name": "lag2_family", "plant": {"tf": {"num": ["K"], "den": "(s+1)^2"}, "params": {"K": 1.0}},
        "loops": [{"type": "pi"}], "scenario": {"dt": 0.05, "horizon": 10.0},
        "randomize": {"params": {"K": [0.5, 2.0]}}}


def run(*args: str):
    return runner.invoke(cli.app, [str(a) for a in args])


def _ok_or_fail(res) -> None:
    assert res.exit_code in (0, 3), res.output
    assert "Traceback" not in res.output


def _spec_file(folder: Path, spec: dict, name: str = "spec.yaml") -> Path:
    p = folder / name
    p.write_text(yaml.safe_dump(spec, sort_keys=False))
    return p


@pytest.fixture
def tiny_settings(monkeypatch, tiny_training: dict) -> dict:
    """The commands train with the tests' tiny PPO sizes (episodes and seed still from the command line)."""
    monkeypatch.setattr(tuner_cli, "TRAIN_DEFAULTS", tiny_training)
    return tiny_training


# ------------------------------------------------------------------------------------------ query


def test_tuner_query_prints_the_gains_verdict_cost_and_timings(tiny_fotd_tuner: Path) -> None:
    res = run("tuner", "query", tiny_fotd_tuner, *PLANT)
    _ok_or_fail(res)
    head = next(ln for ln in res.stdout.splitlines() if "verdict" in ln)
    assert re.findall(r"\w[\w/ ]*\w", head) == ["Kp", "Ki", "verdict", "cost", "L/T", "policy ms", "answer ms", "sims"]
    row = re.findall(r"[^\s│]+", next(ln for ln in res.stdout.splitlines() if "PASS" in ln or "FAIL" in ln))
    assert row[2] in ("PASS", "FAIL") and row[4] == "0.1667" and int(row[-1]) > 0, row
    assert (res.exit_code == 0) == (row[2] == "PASS")
    assert "fotd_pi: K = 2, T = 60, L = 10" in res.stdout


def test_tuner_query_json_is_the_answer_of_the_library(tiny_fotd_tuner: Path) -> None:
    res = run("tuner", "query", tiny_fotd_tuner, *PLANT, "--json")
    _ok_or_fail(res)
    doc = json.loads(res.stdout)
    again = Tuner.load(tiny_fotd_tuner).query({"K": 2, "T": 60, "L": 10})
    assert doc["gains"] == again.gains  # deterministic: same policy, same boundary move
    assert doc["params"] == {"K": 2.0, "T": 60.0, "L": 10.0} and doc["context"]["tau"] == pytest.approx(10 / 70)
    assert doc["verdict"] == again.verdict
    assert doc["accepted_gains"] == (doc["gains"] if doc["verdict"] == "pass" else None)
    assert (res.exit_code == 0) == (doc["verdict"] == "pass")


def test_tuner_query_refine_spends_at_most_n_simulations(tiny_fotd_tuner: Path) -> None:
    doc = json.loads(run("tuner", "query", tiny_fotd_tuner, *PLANT, "--json", "--refine", "40").stdout)
    assert 0 < doc["refined_sims"] <= 40


def _failing_copy(src: Path, dst: Path) -> Path:
    """A copy of a FOTD tuner whose gain box holds only unstable gains: every answer fails verification."""
    shutil.copytree(src, dst)
    doc = json.loads((dst / "tuner.json").read_text())
    doc["box"]["lo"], doc["box"]["hi"] = [200.0, 200.0], [400.0, 400.0]  # Kp, Ki on the unit plant
    (dst / "tuner.json").write_text(json.dumps(doc))
    return dst


def test_tuner_query_failing_verdict_exits_3_and_accepts_no_gains(tiny_fotd_tuner: Path, tmp_path: Path) -> None:
    bad = _failing_copy(tiny_fotd_tuner, tmp_path / "bad")
    res = run("tuner", "query", bad, *PLANT, "--json")
    assert res.exit_code == 3, res.output
    doc = json.loads(res.stdout)
    assert doc["verdict"] == "fail" and doc["accepted_gains"] is None and doc["gains"]
    res = run("tuner", "query", bad, *PLANT)
    assert res.exit_code == 3 and "│ FAIL " in res.stdout and "\nFAIL: " in res.stdout


@pytest.mark.parametrize("args, needle", [
    (["-p", "K=abc", "-p", "T=60", "-p", "L=10"], "error: --param: K: the value must be a number"),
    (["-p", "K", "-p", "T=60"], "error: --param: expected NAME=VALUE"),
    (["-p", "K=inf", "-p", "T=60", "-p", "L=10"], "error: --param: K: the value must be finite"),
    (["-p", "K=2", "-p", "T=60", "-p", "L=10", "-p", "Z=1"], "error: params.Z: not a parameter of the fotd family"),
    (["-p", "K=2", "-p", "T=60"], "error: params.L: the fotd family needs K, T, L"),
    (["-p", "K=-2", "-p", "T=60", "-p", "L=10"], "error: params.K: must be > 0"),
    # a time scale of 1e200 s ended in an OverflowError's traceback; K = 1e308 named internal spec fields
    (["-p", "K=1", "-p", "T=1e200", "-p", "L=1e200"], "error: params: the plant's time scale L + T = 2e+200 s"),
    (["-p", "K=1e308", "-p", "T=60", "-p", "L=10"], "error: params.K: the plant's gain K = 1e+308 is outside"),
    (["-p", "K=2", "-p", "T=1e-12", "-p", "L=1e-12"], "give the times in other units"),
])
def test_tuner_query_bad_parameter_exits_2_naming_it(tiny_fotd_tuner: Path, args: list[str], needle: str) -> None:
    res = run("tuner", "query", tiny_fotd_tuner, *args)
    assert res.exit_code == 2 and needle in res.stderr, res.output
    assert "Traceback" not in res.output


def test_an_error_echoes_the_input_as_typed_not_as_an_emoji(tiny_fotd_tuner: Path) -> None:
    """Regression: rich read ':b:' in the echoed input as an emoji code ('a:b:c' printed as 'a\U0001f171c')."""
    res = run("tuner", "query", tiny_fotd_tuner, "-p", "K=a:b:c", "-p", "T=60", "-p", "L=10")
    assert res.exit_code == 2 and "got 'a:b:c'" in res.stderr, res.stderr


def test_tuner_query_outside_the_family_is_refused_naming_l_over_t(tiny_fotd_tuner: Path,
                                                                    tiny_tank_tuner: Path) -> None:
    res = run("tuner", "query", tiny_fotd_tuner, "-p", "K=2", "-p", "T=60", "-p", "L=1000")
    assert res.exit_code == 2, res.output
    assert "error: params.tau: L/T = 16.7 is outside the family this tuner was trained on (L/T from 0.05 to 10)" \
        in res.stderr
    res = run("tuner", "query", tiny_tank_tuner, "-p", "H0=50")
    assert res.exit_code == 2 and "error: params.H0: H0 = 50 is outside the family" in res.stderr, res.output


def test_tuner_query_unknown_tuner_exits_2_naming_tuner(tmp_path: Path) -> None:
    res = run("tuner", "query", "no_such_tuner", *PLANT)
    assert res.exit_code == 2 and "error: tuner: no_such_tuner is neither a tuner folder" in res.stderr, res.output
    (tmp_path / "tuner.json").write_text('{"format": "gaintune-tuner", "version": 99}')
    res = run("tuner", "query", tmp_path, *PLANT)
    assert res.exit_code == 2 and "error: version: " in res.stderr, res.output


def _imported(args: list[str]) -> tuple[subprocess.CompletedProcess, set[str]]:
    """Run ``python -X importtime -m gaintune ARGS`` in a fresh process: (the run, the top-level modules imported)."""
    proc = subprocess.run([sys.executable, "-X", "importtime", "-m", "gaintune", *map(str, args)],
                          capture_output=True, text=True, timeout=600)
    mods = set(re.findall(r"^import time:\s+\d+ \|\s+\d+ \|\s+([\w.]+)$", proc.stderr, re.M))
    return proc, {m.split(".")[0] for m in mods}


def test_tuner_query_imports_no_torch(tiny_fotd_tuner: Path) -> None:
    """The answer path (NumPy policy, boundary move, verification) loads neither torch nor stable-baselines3."""
    proc, top = _imported(["tuner", "query", tiny_fotd_tuner, *PLANT, "--json"])
    assert proc.returncode in (0, 3), proc.stderr[-2000:]
    assert json.loads(proc.stdout)["gains"]
    assert "numpy" in top and "gaintune" in top  # the import log is read
    assert not top & {"torch", "stable_baselines3", "gymnasium"}, sorted(top & {"torch", "stable_baselines3"})
    proc, top = _imported(["tuner", "query", "no_such_tuner", *PLANT])
    assert proc.returncode == 2 and "torch" not in top


# ------------------------------------------------------------------------------------------- list


@pytest.fixture
def shipped(tiny_fotd_tuner: Path, tmp_path: Path, monkeypatch) -> Path:
    """A shipped-tuners folder holding the tiny FOTD tuner as ``fotd_pi_ms1.4``."""
    folder = tmp_path / "shipped"
    shutil.copytree(tiny_fotd_tuner, folder / "fotd_pi_ms1.4")
    monkeypatch.setattr(artefact, "SHIPPED_DIR", folder)
    return folder


def test_tuner_list_shows_each_shipped_tuner_and_query_takes_its_name(shipped: Path) -> None:
    res = run("tuner", "list")
    assert res.exit_code == 0, res.output
    assert "fotd_pi_ms1.4" in res.stdout and "L/T 0.05 .. 10" in res.stdout
    items = json.loads(run("tuner", "list", "--json").stdout)
    assert [i["name"] for i in items] == ["fotd_pi_ms1.4"]
    item = items[0]
    assert (item["family"], item["controller"], item["ms_max"]) == ("fotd", "pi", 1.4)
    assert item["context"] == [{"name": "L/T", "lo": pytest.approx(0.05), "hi": pytest.approx(10.0), "variable": "tau"}]
    assert item["validation"]["n"] == 2 and item["validation"]["median_ratio"] > 0
    assert item["training"]["episodes"] >= 512 and item["training"]["wall_s"] > 0
    size = sum(p.stat().st_size for p in (shipped / "fotd_pi_ms1.4").iterdir()) / 1024
    assert item["size_kb"] == pytest.approx(size, abs=0.1)
    _ok_or_fail(run("tuner", "query", "fotd_pi_ms1.4", *PLANT))


def test_tuner_list_without_shipped_tuners_says_how_to_train_one(tmp_path: Path, monkeypatch) -> None:
    monkeypatch.setattr(artefact, "SHIPPED_DIR", tmp_path / "none")
    res = run("tuner", "list")
    assert res.exit_code == 0 and "gaintune tuner train --family" in res.stdout
    assert json.loads(run("tuner", "list", "--json").stdout) == []


# ------------------------------------------------------------------------------------------ train


def test_tuner_train_resumes_after_a_kill(tiny_settings: dict, tmp_path: Path) -> None:
    """A run killed after its first checkpoint: the same command continues from it (``training.resumed``)."""
    from gaintune.spec import load_spec
    from gaintune.tuners.problems import SpecProblem
    from gaintune.tuners.train import TrainSettings, train

    out = tmp_path / "lag2"
    seen = []

    def killed(done: int, total: int, info: dict) -> None:
        if seen:  # the first report after a checkpoint was saved
            raise KeyboardInterrupt
        if "ratio" in info:
            seen.append(done)

    with pytest.raises(KeyboardInterrupt):
        train(SpecProblem(load_spec(LAG2)), out, TrainSettings(episodes=1024, **tiny_settings), on_progress=killed)
    assert seen == [512] and not out.exists()
    res = run("tuner", "train", _spec_file(tmp_path, LAG2), "--out", out, "--episodes", "1024")
    assert res.exit_code == 0, res.output
    doc = json.loads((out / "tuner.json").read_text())
    assert doc["training"]["resumed"] == 1 and doc["training"]["episodes"] == 1024
    assert [p["episodes"] for p in doc["training"]["curve"]] == [0, 512, 1024]  # 0: where the run started
    assert f"wrote tuner {out}" in res.stdout and "resumed 1x" in res.stdout and "KB" in res.stdout
    assert "validation on 2 held-out plants" in res.stdout
    assert Tuner.load(out).query({"K": 1.3}).verdict in ("pass", "fail")


@pytest.mark.parametrize("args, needle", [
    (["--out", "X"], "error: spec: give either SPEC"),
    (["SPEC", "--family", "fotd", "--out", "X"], "error: spec: give either SPEC"),
    (["--family", "foo", "--out", "X"], "error: family: unknown family 'foo'"),
    (["--family", "fotd", "--ctype", "pd", "--out", "X"], "error: --ctype: must be pi or pid"),
    (["--family", "fotd", "--ms", "0.9", "--out", "X"], "error: --ms: the Ms limit must be a number > 1"),
    (["SPEC", "--ctype", "pid", "--out", "X"], "error: --ctype: only with --family"),
    (["NOFAMILY", "--out", "X"], "error: randomize.params: a tuner needs a family"),
    (["--family", "fotd", "--out", "FILE"], "error: out: "),
])
def test_tuner_train_bad_input_exits_2_naming_it(tmp_path: Path, args: list[str], needle: str) -> None:
    (tmp_path / "FILE").write_text("x")
    subst = {"SPEC": str(_spec_file(tmp_path, LAG2)), "X": str(tmp_path / "t"), "FILE": str(tmp_path / "FILE"),
             "NOFAMILY": str(_spec_file(tmp_path, {**LAG2, "randomize": {}}, "plain.yaml"))}
    res = run("tuner", "train", *[subst.get(a, a) for a in args])
    assert res.exit_code == 2 and needle in res.stderr, res.output
    assert not (tmp_path / "t").exists() and "Traceback" not in res.output


# ----------------------------------------------------------------------------------------- update


def test_tuner_update_continues_from_a_tuner_on_a_changed_family(tiny_settings, tiny_tank_tuner: Path,
                                                                  tank_spec: dict, tmp_path: Path) -> None:
    new = tank_spec
    new["randomize"]["params"]["H0"] = [5.0, 20.0]
    before = (tiny_tank_tuner / "tuner.json").read_bytes()
    out = tmp_path / "updated"
    res = run("tuner", "update", tiny_tank_tuner, "--spec", _spec_file(tmp_path, new), "--out", out, "--episodes", 256)
    assert res.exit_code == 0, res.output
    doc = json.loads((out / "tuner.json").read_text())
    assert doc["training"]["warm_start"] == str(tiny_tank_tuner) and doc["training"]["episodes"] == 256
    assert doc["context"] == [{"name": "H0", "lo": 5.0, "hi": 20.0, "log": False}]
    assert (tiny_tank_tuner / "tuner.json").read_bytes() == before  # --out: the old tuner is left as it was
    res = run("tuner", "query", out, "-p", "H0=4")
    assert res.exit_code == 2 and "error: params.H0: H0 = 4 is outside" in res.stderr


def test_tuner_update_to_another_number_of_varying_parameters_exits_2(tiny_tank_tuner: Path, tank_spec: dict,
                                                                       tmp_path: Path) -> None:
    new = tank_spec
    new["randomize"]["params"]["a"] = [1.8, 2.2]
    res = run("tuner", "update", tiny_tank_tuner, "--spec", _spec_file(tmp_path, new), "--out", tmp_path / "u")
    assert res.exit_code == 2 and "error: spec.randomize: " in res.stderr, res.output


def test_tuner_update_to_other_varying_parameters_of_the_same_number_exits_2_naming_them(
        tiny_tank_tuner: Path, tank_spec: dict, tmp_path: Path) -> None:
    """Regression: update checked only how many parameters vary: H0 swapped for another one was accepted, and the
    policy's H0 input was trained on the other."""
    new = tank_spec
    new["randomize"]["params"] = {"a": [1.8, 2.2]}
    res = run("tuner", "update", tiny_tank_tuner, "--spec", _spec_file(tmp_path, new), "--out", tmp_path / "u")
    assert res.exit_code == 2 and "error: spec.randomize: " in res.stderr and "varies H0, this family a" in res.stderr


def test_tuner_update_with_a_pid_loop_on_a_pi_tuner_exits_2_naming_the_gains(tiny_tank_tuner: Path, tank_spec: dict,
                                                                            tmp_path: Path) -> None:
    """Regression: a PID spec on a PI tuner ended in numpy's broadcast error: the PI box was applied first."""
    new = tank_spec
    new["loops"][0]["type"] = "pid"
    res = run("tuner", "update", tiny_tank_tuner, "--spec", _spec_file(tmp_path, new), "--out", tmp_path / "u")
    assert res.exit_code == 2 and "error: spec.loops: " in res.stderr and "Kd" in res.stderr, res.output


def test_tuner_update_of_a_tuner_kept_without_its_agent_continues_from_its_arrays(
        tiny_settings, tiny_tank_tuner: Path, tank_spec: dict, tmp_path: Path) -> None:
    """Regression: update refused a folder without agent.zip (every shipped tuner), although training continues
    from policy.npz and critic.npz, and the query of one outside its range told the user to run update."""
    bare = tmp_path / "bare"
    shutil.copytree(tiny_tank_tuner, bare)
    (bare / "agent.zip").unlink()
    res = run("tuner", "update", bare, "--spec", _spec_file(tmp_path, tank_spec), "--out", tmp_path / "u",
              "--episodes", 64)
    assert res.exit_code == 0, res.output
    assert json.loads((tmp_path / "u" / "tuner.json").read_text())["training"]["warm_start"] == str(bare)


class _RunsCode:
    def __init__(self, marker: Path) -> None:
        self.marker = marker

    def __reduce__(self):
        return (os.system, (f"touch {shlex.quote(str(self.marker))}",))


def test_tuner_update_with_pickled_code_in_agent_zip_runs_nothing(tiny_tank_tuner: Path, tank_spec: dict,
                                                                   tmp_path: Path) -> None:
    """The agent a tuner folder carries is read as weights only (issue 24): a forged one is refused, nothing runs."""
    import base64

    import cloudpickle

    marker = tmp_path / "ran"
    forged = tmp_path / "forged"
    shutil.copytree(tiny_tank_tuner, forged)
    payload = base64.b64encode(cloudpickle.dumps(_RunsCode(marker))).decode()
    with zipfile.ZipFile(forged / "agent.zip", "w") as z:
        z.writestr("data", json.dumps({"policy_class": {":type:": "<class 'abc.ABCMeta'>", ":serialized:": payload}}))
    res = run("tuner", "update", forged, "--spec", _spec_file(tmp_path, tank_spec), "--out", tmp_path / "u")
    assert not marker.exists()
    assert res.exit_code == 2 and "error: tuner: " in res.stderr and "holds no policy weights" in res.stderr, res.output


# --------------------------------------------------------------------------------------- schedule


def test_tuner_schedule_over_the_tank_level_is_verified_exported_and_compared(tiny_tank_tuner: Path,
                                                                              tmp_path: Path) -> None:
    out = tmp_path / "sched"
    res = run("tuner", "schedule", tiny_tank_tuner, "--var", "H0", "--grid", "2:20:3", "--out", out, "--json",
              "--compare")
    _ok_or_fail(res)
    doc = json.loads(res.stdout)
    assert doc["schedule"]["grid"] == [2.0, 11.0, 20.0] and doc["schedule"]["var"] == "H0"
    points = doc["verification"]["points"]
    assert [(p["value"], p["kind"]) for p in points] == [(2.0, "grid"), (6.5, "midpoint"), (11.0, "grid"),
                                                          (15.5, "midpoint"), (20.0, "grid")]
    assert doc["passed"] == (res.exit_code == 0) == all(p["verdict"] == "pass" for p in points) \
        and doc["verification"]["sweep"]["passed"] or res.exit_code == 3
    assert {"schedule.json", "schedule_gains.json"} <= {p.name for p in out.iterdir()}
    assert (out / "schedule_gains.h").exists() == doc["passed"]  # the C header only for a passed schedule
    assert len(doc["comparison"]["levels"]) == 5 and doc["comparison"]["fixed"]["gains"]
    from gaintune.tuners.schedule import load_schedule

    assert load_schedule(out / "schedule.json").grid == [2.0, 11.0, 20.0]
    res = run("tuner", "schedule", tiny_tank_tuner, "--var", "H0", "--grid", "2,11,20")
    _ok_or_fail(res)
    assert "grid points 3/3" in res.stdout or "FAIL" in res.stdout
    assert "give --out DIR" in res.stderr


@pytest.mark.parametrize("which, args, needle", [
    ("fotd", ["--var", "tau", "--grid", "0.1:0.5:3"], "error: tuner: "),
    ("tank", ["--var", "H0", "--grid", "1:30:3"], "error: grid: H0 = 1 is outside the range"),
    ("tank", ["--var", "a", "--grid", "1.8:2.2:3"], "error: var: 'a' is not a context variable"),
    ("tank", ["--var", "H0", "--grid", "2:20"], "error: grid: "),
])
def test_tuner_schedule_bad_input_exits_2_naming_it(tiny_fotd_tuner: Path, tiny_tank_tuner: Path, which: str,
                                                    args: list[str], needle: str) -> None:
    res = run("tuner", "schedule", tiny_fotd_tuner if which == "fotd" else tiny_tank_tuner, *args)
    assert res.exit_code == 2 and needle in res.stderr, res.output


# ------------------------------------------------------------------------------------ old command


def test_policy_command_is_gone() -> None:
    """One name for one thing: `gaintune policy` (a robust design's gains under a tuner's name) no longer exists."""
    res = run("policy", ".")
    assert res.exit_code == 2 and "No such command 'policy'" in res.output
    for mod in ("gaintune.cli.policy", "gaintune.search.policy", "gaintune.bench.policy"):
        with pytest.raises(ModuleNotFoundError):
            __import__(mod)
    assert "policy" not in cli.BENCH
