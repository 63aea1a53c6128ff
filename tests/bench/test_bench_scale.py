"""gaintune bench scale: the curve read at budgets, the table, and a bad problem name refused."""

from __future__ import annotations

import pytest

from gaintune.bench import scale


def test_curve_is_the_best_cost_within_each_budget() -> None:
    pts = [(100, 5.0), (300, 3.0), (900, 2.5)]
    assert scale.curve_at(pts, [50, 100, 500, 1000]) == [None, 5.0, 3.0, 2.5]


def test_unknown_problem_exits_2_naming_the_option(capsys: pytest.CaptureFixture[str]) -> None:
    with pytest.raises(SystemExit) as e:
        scale.main(["--problems", "no_such_model", "--budgets", "20"])
    assert e.value.code == 2 and "--problems" in capsys.readouterr().err


def test_table_shows_ratios_to_the_best_run_and_errors() -> None:
    result = {"budgets": [10, 20], "load_average": [1.0, 1.0, 1.0], "cpus": 2,
              "problems": {"p": {"n_loops": 2, "n_gains": 4, "best": 2.0}},
              "rows": [{"problem": "p", "method": "rl", "seed": 0, "at": [None, 4.0], "cost": 4.0, "wall_time": 1.0,
                        "setup_sims": 30, "stable": True},
                       {"problem": "p", "method": "cmaes", "seed": 0, "at": [2.0, 2.0], "cost": 2.0,
                        "wall_time": 1.0, "error": ""}]}
    md = scale.render_markdown(result, "gaintune bench scale")
    assert "| rl | 0 | - | 2.0000 | 2.0000 | 30 | yes | - | 1.0 |" in md and "| cmaes | 0 | 1.0000 | 1.0000 |" in md
    assert "p: 2 loops, 4 tuned gains" in md and "load average" in md
