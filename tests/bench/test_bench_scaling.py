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


def test_a_built_in_model_name_is_a_problem_beside_the_suite_ones():
    """``--problems`` takes the suite's problems and built-in model names (the model's example spec) together."""
    suite_p, model_p = scaling.resolve_problems("cascades", ["six_lag_cascade", "quadrotor"])
    assert suite_p.name == "six_lag_cascade" and suite_p.family != scaling.MODEL_FAMILY
    assert model_p.name == "quadrotor" and model_p.family == scaling.MODEL_FAMILY
    assert scaling._n_gains(model_p) == 24 and len(model_p.tuning_spec().loops) == 12


def test_unknown_problem_names_both_the_suite_problems_and_the_models(capsys):
    with pytest.raises(SystemExit) as exc:
        scaling.main(["--problems", "no_such_model", "--budgets", "20"])
    err = capsys.readouterr().err
    assert exc.value.code == 2 and "--problems" in err and "robot_arm6" in err and "six_lag_cascade" in err


def test_a_models_reference_is_the_best_cost_any_run_reached():
    """No reference search on a built-in model: its runs' best answer or curve point is 1.000."""
    refs = {"m": {"cost": None, "basis": "best run"}, "s": {"cost": 2.0, "basis": "reference optimum"}}
    rows = [{"problem": "m", "cost": 5.0, "at": [None, 6.0]}, {"problem": "m", "cost": 8.0, "at": [4.0, 4.0]},
            {"problem": "s", "cost": 3.0, "at": [3.0]}]
    scaling._settle_references(refs, rows)
    assert refs["m"]["cost"] == 4.0 and refs["s"]["cost"] == 2.0
    assert rows[0]["ratio"] == 1.25 and rows[0]["curve_ratio"] == [None, 1.5] and rows[2]["ratio"] == 1.5


def test_table_shows_set_up_sims_verdict_stability_and_load_average():
    rows = [{"problem": "p", "method": "rl", "seed": 0, "ratio": 2.0, "curve_ratio": [None, 2.0], "sims": 40,
             "setup_sims": 30, "wall_time": 1.0, "verdict": "pass", "stable": True, "stability": "verdict"},
            {"problem": "p", "method": "cmaes", "seed": 0, "ratio": 1.0, "curve_ratio": [1.0, 1.0], "sims": 20,
             "setup_sims": 0, "wall_time": 1.0, "verdict": None, "stable": False,
             "stability": "linear check: pade", "check_error": "LinAlgError: Singular matrix"}]
    result = {"methods": ["rl", "cmaes"], "budgets": [10, 20], "load_average": [1.0, 2.0, 3.0], "cpus": 2,
              "references": {"p": {"cost": 2.0, "n_gains": 4, "n_loops": 2, "basis": "best run"}}, "rows": rows}
    md = scaling.render_markdown(result, "gaintune bench scaling --problems p")
    assert "## p: 2 loops, 4 gains, reference 2 (best run)" in md and "load average at the end 1.0 2.0 3.0" in md
    assert "| rl | 0 | 2.0000 | 40 | 30 | 1 | pass | yes |" in md
    assert "| cmaes | 0 | 1.0000 | 20 | 0 | 1 | - | NO (linear check) | LinAlgError: Singular matrix |" in md


def test_answer_check_reads_the_verdict_of_a_loop_graph():
    """The stable column is the MIMO verdict's: P control of 1/(s (s + 1)) through a two-loop cascade x -> v,
    u = kv (kx (r - x) - v), stable for kx, kv > 0 (s^2 + (1 + kv) s + kv kx)."""
    from gaintune.spec import load_spec

    d = {"plant": {"ss": {"A": [[0, 1], [0, -1]], "B": [[0], [1]], "C": [[1, 0], [0, 1]], "outputs": ["x", "v"],
                          "inputs": ["u"]}},
         "loops": [{"name": "x", "measure": "x", "drives": "loop:v", "type": "p", "direction": "direct"},
                   {"name": "v", "measure": "v", "drives": "u", "type": "p", "direction": "direct"}],
         "scenarios": [{"dt": 0.01, "horizon": 5.0}]}
    out = scaling.answer_check(load_spec(d), {"x": {"Kp": 2.0}, "v": {"Kp": 3.0}})
    assert out["stable"] is True and out["stability"] == "verdict" and out["verdict"] in ("pass", "fail")
