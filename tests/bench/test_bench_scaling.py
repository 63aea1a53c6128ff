"""``gaintune bench scaling``: the anytime curve read at budgets, its table, and bad arguments (no runs)."""

from __future__ import annotations

import pytest

from gaintune.bench import scaling


def test_curve_at_reads_the_best_cost_within_each_budget():
    points = [(100, 5.0), (900, 3.0), (1500, 2.0), (4000, 1.5)]
    assert scaling.curve_at(points, [50, 1000, 2000, 5000]) == [None, 3.0, 2.0, 1.5]


def test_render_markdown_gives_one_curve_row_per_method_with_median_and_worst():
    rows = [
        {"problem": "p", "method": m, "seed": s, "ratio": r, "curve_ratio": [c, r], "sims": 10, "wall_time": 1.0}
        for m, s, c, r in [("rl", 0, 1.5, 1.02), ("rl", 1, 1.7, 1.03), ("cmaes", 0, 1.1, 1.0), ("cmaes", 1, None, 1.0)]
    ]
    result = {"methods": ["rl", "cmaes"], "budgets": [100, 200], "references": {"p": {"cost": 3.0, "n_gains": 12}},
              "rows": rows}
    md = scaling.render_markdown(result)
    assert "## p: 12 gains, reference 3" in md
    assert "| rl | 1.6000 (1.7000) | 1.0250 (1.0300) | 1.0250 (1.0300) |" in md
    assert "| cmaes | 1.1000 |" in md  # one seed reached a feasible cost by 100 simulations


@pytest.mark.parametrize("argv, option", [
    (["--spec", "/nonexistent/spec.yaml"], "--spec"),
    (["--problems", "nope"], "--problems"),
    (["--methods", "nope"], "--methods"),
    (["--budgets", "0"], "--budgets"),
])
def test_bad_arguments_exit_2_naming_the_option(capsys, argv, option):
    with pytest.raises(SystemExit) as exc:
        scaling.main(argv)
    err = capsys.readouterr().err
    assert exc.value.code == 2 and f"error: {option}: " in err and "Traceback" not in err
