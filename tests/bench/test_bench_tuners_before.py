"""``gaintune bench tuners --before DIR``: alternated rounds of two checkouts and the answers compared."""

from __future__ import annotations

import json
import sys
from pathlib import Path

import numpy as np
import pytest

from gaintune.bench import tuners as TB
from gaintune.bench import tuners_before as TBB
from gaintune.bench.tuners_refs import held_out_plants

HERE = Path(TBB.__file__).resolve().parents[2]


def test_rounds_alternate_the_trees_and_the_summary_compares_times_and_answers(monkeypatch, tmp_path) -> None:
    calls = []

    def fake_round(tree, name, repeats, plants):
        calls.append(tree)
        slow = tree != HERE
        answers = [[{"loop0": {"Kp": 1.0}}, 2.0 if (slow and i == 0) else 1.0, "pass"] for i in range(len(plants))]
        return {"cpu_ms": [10.0 + i + (5.0 if slow else 0.0) for i in range(len(plants))], "answers": answers}

    monkeypatch.setattr(TBB, "_round", fake_round)
    r = TBB.measure_before(tmp_path, "fotd_pi_ms1.4", held_out_plants(4), rounds=2, repeats=3)
    assert calls == [HERE, tmp_path.resolve(), HERE, tmp_path.resolve()]  # after, before, after, before
    s = r["summary"]
    assert s["after"]["p50"] == pytest.approx(11.5) and s["before"]["p50"] == pytest.approx(16.5)
    assert s["ratio"]["p50"] == pytest.approx(11.5 / 16.5)
    assert s["identical"] == 3 and s["same_verdict"] == 4 and s["max_rel_cost_diff"] == pytest.approx(0.5)
    r.update(name="fotd_pi_ms1.4", plants=4, repeats=3, n_rounds=2, loadavg="[0.5]",
             commits={"after": "a", "before": "b"})
    text = TBB.render_before(r, "gaintune bench tuners --before X")
    assert "| after / before, p50 / p95 | 0.697 /" in text and "| answers identical to the last bit" in text


def test_a_failing_round_is_reported_not_raised(monkeypatch, tmp_path) -> None:
    monkeypatch.setattr(TBB, "_round", lambda tree, name, repeats, plants: {"error": "ImportError: no module"})
    r = TBB.measure_before(tmp_path, "fotd_pi_ms1.4", held_out_plants(2), rounds=1, repeats=1)
    assert len(r["errors"]) == 2 and r["summary"]["after"]["p50"] is None and "ratio" not in r["summary"]


def test_the_child_round_times_and_answers_every_plant(monkeypatch, capsys) -> None:
    """The code each round runs, here in-process on this tree (numba's kernel: no ahead-of-time build)."""
    monkeypatch.setenv("GAINTUNE_KERNEL_AOT", "0")
    plants = held_out_plants(2)
    monkeypatch.setattr(sys, "argv", ["-c", "fotd_pi_ms1.4", "2", json.dumps(plants)])
    exec(compile(TBB.CHILD, "<child>", "exec"), {})
    out = json.loads(capsys.readouterr().out.strip().splitlines()[-1])
    assert len(out["cpu_ms"]) == 2 and np.all(np.array(out["cpu_ms"]) > 0)
    assert [a[2] for a in out["answers"]] == ["pass", "pass"]


def test_before_that_is_no_checkout_exits_2_naming_the_option(tmp_path, capsys) -> None:
    with pytest.raises(SystemExit) as exc:
        TB.main(["--before", str(tmp_path), "--out", str(tmp_path / "out")])
    assert exc.value.code == 2 and "--before" in capsys.readouterr().err


def test_the_child_sets_the_collector_threshold_the_gaintune_command_sets() -> None:
    from gaintune.cli.entry import GC_THRESHOLD0

    assert f"gc.set_threshold({GC_THRESHOLD0:_}," in TBB.CHILD


def test_the_child_sets_the_malloc_thresholds_the_gaintune_command_sets() -> None:
    from gaintune.cli.entry import MMAP_THRESHOLD, TRIM_THRESHOLD

    assert MMAP_THRESHOLD == 32 << 20 and TRIM_THRESHOLD == 64 << 20
    assert "mallopt(-3, 32 << 20)" in TBB.CHILD and "mallopt(-1, 64 << 20)" in TBB.CHILD
