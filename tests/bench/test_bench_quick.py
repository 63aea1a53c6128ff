"""``gaintune bench quick``: the SISO problems, one measured row, refusals as rows, the summary, bad arguments.

The ready-made tuners are measured by the benchmark itself; here an empty tuner folder makes the
quick path start from the rules alone (the path a loop without a tuner takes), which is enough to
exercise the rows. The suite's cached references are copied from bench/results, so nothing is
recomputed. No timing is asserted.
"""

from __future__ import annotations

import shutil

import pytest

from gaintune.bench import quick as BQ

REPO_CACHE = "bench/results/reference_standard.json"


@pytest.fixture(scope="module")
def measured(tmp_path_factory, repo_root):
    out = tmp_path_factory.mktemp("out")
    shutil.copy(repo_root / REPO_CACHE, out / "reference_standard.json")
    empty = tmp_path_factory.mktemp("no_tuners")
    problems = BQ.siso_problems(["std_fotd1_pi", "std_unstable_pi"])
    return BQ.measure(problems, out, empty, refine=0)


def test_siso_problems_are_the_single_loop_problems_of_the_standard_suite() -> None:
    names = [p.name for p in BQ.siso_problems()]
    assert "std_fotd1_pi" in names and "std_lag3_pi_track" in names and len(names) == len(set(names))
    assert all(len(p.spec["loops"]) == 1 for p in BQ.siso_problems())


def test_a_problem_row_holds_the_ratio_the_verdict_and_the_rules(measured) -> None:
    row = measured["rows"][0]
    assert row["problem"] == "std_fotd1_pi" and row["reference_passes"]
    assert row["verdict"] == "pass" and row["tuner"] == "-" and row["source"] in ("amigo", "simc")
    assert row["ratio"] == pytest.approx(row["cost"] / row["reference"])
    assert row["ratio"] >= 1 - 1e-3  # the reference is the constrained optimum
    assert row["amigo"]["verdict"] == "pass" and row["ratio"] <= row["amigo"]["ratio"]
    assert row["tuner_ratio"] is None  # no tuner asked
    assert any("no ready-made tuner" in n for n in row["notes"])


def test_a_problem_without_a_model_is_answered_from_the_search_box(measured) -> None:
    row = measured["rows"][1]
    assert row["problem"] == "std_unstable_pi" and not row.get("refused")
    assert row["source"].startswith("search box") and row["verdict"] == "pass" and "unstable" in row["model"]


def test_summary_counts_every_answered_problem(measured) -> None:
    s = measured["summary"]
    assert s["problems"] == 2 and s["answered"] == 2 and s["refused"] == 0
    assert s["reference_passes"] == 2 and s["passed_where_reference_passes"] == 2
    assert s["amigo"]["quick_not_worse_where_rule_passes"] == s["amigo"]["rule_passes"] == 1
    md = BQ.render({**measured, "loadavg": "-"}, "gaintune bench quick")
    assert "| std_unstable_pi |" in md and "2 / 2" in md


def test_summary_of_no_answer_has_no_figures() -> None:
    s = BQ.summarize([{"problem": "p", "reference_passes": True, "refused": "plant: x", "wall_s": 0.0}])
    assert s["ratio"]["median"] is None and s["wall_s"]["median"] is None and s["passed_where_reference_passes"] == 0


@pytest.mark.parametrize("argv, option", [
    (["--tuners", "no/such/folder"], "--tuners"),
    (["--problems", "nope"], "--problems"),
    (["--refine", "-1"], "--refine"),
])
def test_bad_arguments_exit_2_naming_the_option(argv, option, capsys) -> None:
    with pytest.raises(SystemExit) as e:
        BQ.main(argv)
    assert e.value.code == 2
    assert f"error: {option}:" in capsys.readouterr().err
