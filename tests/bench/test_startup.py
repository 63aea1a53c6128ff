"""``gaintune bench startup``: the side-by-side ``--before`` mode (no timings are asserted)."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

from gaintune.bench import startup


def test_before_without_a_gaintune_package_exits_2(tmp_path: Path, capsys) -> None:
    assert startup.main(["--before", str(tmp_path), "--out", str(tmp_path / "out")]) == 2
    assert "--before" in capsys.readouterr().err


def test_tree_env_makes_that_trees_gaintune_the_one_imported(tmp_path: Path) -> None:
    (tmp_path / "gaintune").mkdir()
    (tmp_path / "gaintune" / "__init__.py").write_text("MARK = 'older checkout'\n")
    out = subprocess.run([sys.executable, "-c", "import gaintune; print(gaintune.MARK)"], capture_output=True,
                         text=True, env=startup._tree_env(tmp_path), check=True, cwd=tmp_path / "gaintune").stdout
    assert out.strip() == "older checkout"


def test_module_commands_run_the_cli_of_the_tree_on_the_path(tmp_path: Path) -> None:
    cmds = startup.commands(tmp_path, module=True)
    assert cmds["gaintune verify (PI loop)"][:3] == [sys.executable, "-m", "gaintune"]
    assert json.loads((tmp_path / "pi.json").read_text()) == startup.SPEC


def test_the_tune_rows_break_the_figure_down(tmp_path: Path) -> None:
    """Beside the 3,000-sim tune: the same without files, a 100-sim tune, and the learner's import."""
    cmds = startup.commands(tmp_path)
    assert "--out" in cmds["gaintune tune (PI loop, 3,000 sims)"]
    assert cmds["gaintune tune (PI loop, 3,000 sims, no --out)"][-2:] == ["tune", str(tmp_path / "pi.json")]
    small = json.loads((tmp_path / "pi_100.json").read_text())
    assert small["search"] == {**startup.SPEC["search"], "budget": 100} and small["plant"] == startup.SPEC["plant"]
    assert str(tmp_path / "pi_100.json") in cmds["gaintune tune (PI loop, 100 sims)"]
    assert cmds["import stable_baselines3"][1:] == ["-c", "import stable_baselines3"]
    assert cmds["PPO alone: 800 updates on idle envs"][1:] == ["-c", startup.LEARNER_FLOOR]


def test_the_learner_floor_row_runs_the_tunes_800_updates() -> None:
    """The floor script trains gaintune's PPO for exactly the PI tune's 800 gradient steps (it asserts so)."""
    subprocess.run([sys.executable, "-c", startup.LEARNER_FLOOR], check=True, timeout=300)


def test_before_and_after_rows_side_by_side(tmp_path: Path, monkeypatch) -> None:
    before = tmp_path / "before"
    (before / "gaintune").mkdir(parents=True)
    (before / "gaintune" / "__init__.py").write_text("")
    py = sys.executable
    monkeypatch.setattr(startup, "commands", lambda folder, module=False: {
        "python -c pass": [py, "-c", "pass"], "import gaintune": [py, "-c", "import gaintune"]})
    assert startup.main(["--repeat", "1", "--before", str(before), "--out", str(tmp_path / "out")]) == 0
    data = json.loads((tmp_path / "out" / "startup.json").read_text())
    assert data["header"][-1] == "after / before"
    assert [r[0] for r in data["rows"]] == ["python -c pass", "import gaintune"]
    assert all(r[1] > 0 and r[2] > 0 and r[4] > 0 for r in data["rows"])


def test_the_verification_row_imports_the_verify_package_of_a_checkout_older_than_the_rename(tmp_path: Path) -> None:
    """``--before`` may name a tree where the package was still ``gaintune.verify``: the row imports that."""
    (tmp_path / "gaintune" / "verify").mkdir(parents=True)
    (tmp_path / "gaintune" / "__init__.py").write_text("")
    (tmp_path / "gaintune" / "verify" / "__init__.py").write_text("print('old verify imported')\n")
    (tmp_path / "files").mkdir()
    cmd = startup.commands(tmp_path / "files")["import gaintune.verification"]
    out = subprocess.run(cmd, capture_output=True, text=True, env=startup._tree_env(tmp_path), check=True,
                         cwd=tmp_path / "files").stdout
    assert out.strip() == "old verify imported"

def test_cold_cache_runs_give_every_cold_run_an_empty_numba_cache(tmp_path: Path, monkeypatch) -> None:
    """``--cold-cache``: each cold run gets a new, empty NUMBA_CACHE_DIR; the warm runs share one filled by a warm-up."""
    log = tmp_path / "log.txt"
    probe = ("import os, sys; d = os.environ['NUMBA_CACHE_DIR']; seen = os.path.exists(d); os.makedirs(d, exist_ok=True); "
             f"open({str(log)!r}, 'a').write(d + ' ' + str(seen) + chr(10))")
    monkeypatch.setattr(startup, "demo_command", lambda folder, module=False: [sys.executable, "-c", probe])
    work = tmp_path / "work"
    work.mkdir()
    runs = startup.cold_cache_runs({"after": None}, {"after": None}, work, 2, module=False)
    lines = [(Path(d).name, seen) for d, seen in (ln.split() for ln in log.read_text().splitlines())]
    warmup, timed = lines[0], lines[1:]
    assert warmup == ("numba-warm-after", "False")
    cold = [ln for ln in timed if ln[0].startswith("numba-cold")]
    assert len(cold) == 2 and len({d for d, _ in cold}) == 2 and all(seen == "False" for _, seen in cold)
    assert [ln for ln in timed if ln not in cold] == [("numba-warm-after", "True")] * 2
    assert all(wall > 0 and cpu >= 0 for v in runs.values() for wall, cpu in v) and len(runs[("after", "cold")]) == 2


def test_cold_cache_table_has_a_cold_and_a_warm_row_with_cpu_seconds(tmp_path: Path, monkeypatch) -> None:
    py = sys.executable
    monkeypatch.setattr(startup, "demo_command", lambda folder, module=False: [py, "-c", "pass"])
    assert startup.main(["--cold-cache", "--repeat", "1", "--out", str(tmp_path / "out")]) == 0
    data = json.loads((tmp_path / "out" / "startup_cold.json").read_text())
    assert data["header"] == ["gaintune demo", "median wall s", "min wall s", "median CPU s"]
    assert [r[0] for r in data["rows"]] == ["cold numba cache", "warm numba cache"]
    assert "--cold-cache" in (tmp_path / "out" / "startup_cold.md").read_text()
