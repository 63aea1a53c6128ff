"""``gaintune bench tuners``: held-out plants, the per-plant reference and its cache, the rules, the tuner rows.

The real trained tuner is run by the benchmark only; here a fake tuner that answers AMIGO's gains
exercises the tuner rows, so the expected ratios are known exactly. No timing is asserted.
"""

from __future__ import annotations

import json
import math
import sys
from types import SimpleNamespace

import pytest

from gaintune.bench import tuners as TB
from gaintune.bench import tuners_refs as R
from gaintune.bench.tuners_timing import fresh_process_timing, in_process_timing, query_argv

PLANT = {"K": 2.0, "T": 10.0, "L": 1.0}  # L/T = 0.1: AMIGO passes, SIMC (tau_c = L) exceeds Ms 1.4


def _case(values=PLANT, ctype="pi"):
    return R.make_case(0, values, ctype, 1.4)


def _rules(case):
    return {name: R.judge(case, R.rule_gains(name, case)[0], None) for name in R.RULES}


def test_held_out_plants_are_deterministic_and_in_range() -> None:
    plants = R.held_out_plants(300)
    assert plants == R.held_out_plants(300) and R.held_out_plants(7) == plants[:7]
    assert R.held_out_plants(7, seed=1) != plants[:7]
    for p in plants:
        assert 0.05 <= p["L"] / p["T"] <= 10 and 1 <= p["T"] <= 100 and 0.5 <= p["K"] <= 5
    ratios = sorted(p["L"] / p["T"] for p in plants)
    assert ratios[0] < 0.1 and ratios[-1] > 5  # log-uniform: both ends of the range are drawn


def test_query_argv_gives_the_plant_values_exactly() -> None:
    plant = R.held_out_plants(1)[0]
    argv = query_argv("fotd_pi_ms1.4", plant)
    assert argv[:3] == ["tuner", "query", "fotd_pi_ms1.4"] and argv[-1] == "--json"
    given = dict(a.split("=") for a in argv[4:-1:2])
    assert {k: float(v) for k, v in given.items()} == plant


def test_reference_of_one_plant_passes_and_no_passing_rule_beats_it(tmp_path) -> None:
    case = _case()
    rules = _rules(case)
    ref = R.reference_for_plant(case, rules, tmp_path)
    assert ref["source"] == "migo" and not ref["cached"]
    assert R.judge(case, ref["gains"], ref["cost"])["verdict"] == "pass"
    passing = [r for r in rules.values() if r["verdict"] == "pass"]
    assert passing, rules  # the comparison below must compare something
    for r in passing:
        assert ref["cost"] <= r["cost"]


def test_cached_reference_whose_cost_no_longer_scores_is_recomputed(tmp_path) -> None:
    case = _case()
    first = R.reference_for_plant(case, {}, tmp_path)
    assert R.reference_for_plant(case, {}, tmp_path)["cached"]
    path = tmp_path / R.CACHE_FILE
    data = json.loads(path.read_text())
    data[first["key"]]["cost"] *= 1.1  # a cost function changed since the entry was written
    path.write_text(json.dumps(data))
    logged: list[str] = []
    again = R.reference_for_plant(case, {}, tmp_path, log=logged.append)
    assert not again["cached"] and again["cost"] == pytest.approx(first["cost"], rel=1e-9)
    assert json.loads(path.read_text())[first["key"]]["cost"] == pytest.approx(first["cost"], rel=1e-9)
    assert logged and "recomputing" in logged[0]


class AmigoTuner:
    """A fake tuner answering AMIGO's gains; with ``refine`` it misreports its cost (the bench must notice)."""

    def query(self, values, refine=0):
        case = R.make_case(0, values, "pi", 1.4)
        gains = R.rule_gains("amigo", case)[0]
        cost = R.score(case.ev, gains)
        return SimpleNamespace(gains=gains, verdict="pass", cost=cost * (2.0 if refine else 1.0),
                               policy_ms=0.1, elapsed_ms=5.0 + refine, n_sims=min(refine, 4))


def test_fake_tuner_rows_give_amigos_ratios_and_flag_a_misreported_cost(tmp_path) -> None:
    plants = R.held_out_plants(2)
    result = TB.measure(plants, tmp_path, tuner_name="fake", refine=10, tuner_factory=lambda name: AmigoTuner())
    assert result["methods"] == ["amigo", "simc", "tuner", "refine"]
    for row in result["rows"]:
        for mode in ("tuner", "refine"):
            assert row[mode]["ratio"] == pytest.approx(row["amigo"]["ratio"], rel=1e-12)
            assert row[mode]["verdict"] == row["amigo"]["verdict"]
    s = result["summary"]
    amigo_passes = sum(r["amigo"]["verdict"] == "pass" for r in result["rows"])
    # equal cost is not a win: every plant where AMIGO passes is an exception, with the reason
    vs_amigo = s["tuner"]["beats"]["amigo"]
    assert vs_amigo["wins"] == 0 and len(vs_amigo["exceptions"]) == vs_amigo["rule_passes"] == amigo_passes
    assert s["tuner"]["cost_agrees"] == 2 and s["refine"]["cost_agrees"] == 0
    assert s["refine"]["max_sims"] == 4 and s["tuner"]["median_ratio"] == pytest.approx(s["amigo"]["median_ratio"])
    timing = result["timing"]["in_process"]
    assert timing["tuner"]["elapsed_ms"]["p50"] == 5.0 and timing["refine"]["elapsed_ms"]["p50"] == 15.0
    text = TB.render(result, "gaintune bench tuners --plants 2")
    assert "| tuner + refine |" in text and "## Plants where the tuner does not beat a passing rule" in text
    refine_row = next(line for line in text.splitlines() if line.startswith("| tuner + refine |"))
    assert "| 0/2 | 2/2 |" in refine_row  # its costs disagree with the bench's, its verdicts agree


class SlowOnceTuner(AmigoTuner):
    """AMIGO's gains, answered in 5 ms except every third call, which another process held up to 40 ms."""

    def __init__(self) -> None:
        self.calls = 0

    def query(self, values, refine=0):
        self.calls += 1
        a = super().query(values, refine)
        a.elapsed_ms = 40.0 if self.calls % 3 == 1 else 5.0
        return a


def test_each_plants_zero_shot_time_is_the_median_of_its_repeated_runs(tmp_path) -> None:
    """A shared machine's interruption of one run must not set the plant's figure: the same query runs
    TIMING_REPEATS times, the median is its time, and the first run's figures are kept beside it."""
    tuner = SlowOnceTuner()
    row = TB.tuner_answer(tuner, R.make_case(0, R.held_out_plants(1)[0], "pi", 1.4), None, 0, 3)
    assert tuner.calls == 3 and row["elapsed_ms"] == 5.0 and row["first_elapsed_ms"] == 40.0
    assert row["repeats"] == 3 and row["same_answer"] is True
    timing = in_process_timing([{"tuner": row}], ["tuner"])["tuner"]
    assert timing["elapsed_ms"]["p50"] == 5.0 and timing["first_elapsed_ms"]["p50"] == 40.0
    assert timing["repeats"] == 3 and timing["same_answer"] == "1 / 1"


def test_tuner_that_raises_on_a_plant_gives_an_error_row_not_a_crash(tmp_path) -> None:
    class Broken:
        def query(self, values, refine=0):
            raise RuntimeError("policy file truncated")

    result = TB.measure(R.held_out_plants(1), tmp_path, tuner_name="broken", tuner_factory=lambda name: Broken())
    row = result["rows"][0]["tuner"]
    assert row["verdict"] == "error" and "policy file truncated" in row["error"]
    assert result["summary"]["tuner"]["errors"] == 1 and result["summary"]["tuner"]["pass"] == 0


def test_rules_only_runs_end_to_end_on_3_plants(tmp_path, capsys) -> None:
    assert TB.main(["--rules-only", "--plants", "3", "--out", str(tmp_path)]) == 0
    text = capsys.readouterr().out
    assert text.startswith("# gaintune bench tuners --rules-only --plants 3 --out ")
    assert "| AMIGO |" in text and "| SIMC |" in text and "rules only (no tuner measured)" in text
    raw = json.loads((tmp_path / "tuners.json").read_text())
    assert len(raw["rows"]) == 3 and raw["methods"] == ["amigo", "simc"] and raw["timing"] == {}
    assert raw["reference"]["pass"] == 3 and raw["reference"]["computed"] == 3
    assert all(math.isfinite(r["reference"]["cost"]) for r in raw["rows"])
    assert (tmp_path / "tuners.md").read_text().startswith("# gaintune bench tuners")


def test_missing_tuner_core_exits_2_with_a_message_before_any_work(tmp_path, capsys, monkeypatch) -> None:
    monkeypatch.setitem(sys.modules, "gaintune.tuners.tuner", None)  # import fails, on any tree
    with pytest.raises(SystemExit) as info:
        TB.main(["--plants", "1", "--out", str(tmp_path)])
    err = capsys.readouterr().err
    assert info.value.code == 2 and "Traceback" not in err
    assert err.startswith("error: --tuner: the trained-tuner core") and "--rules-only" in err
    assert not (tmp_path / R.CACHE_FILE).exists()


@pytest.mark.parametrize("args, option", [(["--plants", "0"], "--plants"), (["--ctype", "pd"], "--ctype"),
                                          (["--refine", "-3"], "--refine"), (["--fresh-runs", "x"], "--fresh-runs"),
                                          (["--rules-only", "--tuner", "x"], "--tuner"),
                                          (["--algo-compare", "--algo-episodes", "10"], "--algo-episodes"),
                                          (["--algo-compare", "--algo-family", "sopdt"], "--algo-family")])
def test_bench_tuners_bad_argument_exits_2_naming_it(args, option, tmp_path, capsys) -> None:
    with pytest.raises(SystemExit) as info:
        TB.main([*args, "--out", str(tmp_path)])
    assert info.value.code == 2 and capsys.readouterr().err.startswith(f"error: {option}:")


def test_fresh_process_timing_reports_a_failing_query_instead_of_raising() -> None:
    fresh = fresh_process_timing("no_such_tuner_for_this_test", R.held_out_plants(1), 1)
    assert fresh["runs"] == 1 and fresh["ok"] == 0 and fresh["median_s"] is None
    assert fresh["failures"][0]["code"] not in (0, None) and fresh["failures"][0]["error"]
    assert fresh["torch_imported"] in (True, False)  # the probe answers even when the command fails
    assert fresh["numba_imported"] in (True, False) and fresh["aot_kernel"] == "built"
    floor = fresh["floor"]  # the import-only process beside each query runs whatever the query did
    assert "scipy.linalg" in floor["command"] and len(floor["wall_s"]) == 1 and floor["median_s"] > 0


def test_timing_table_gives_the_import_floor_and_the_query_minus_it() -> None:
    fresh = {"command": "gaintune tuner query x", "runs": 3, "ok": 3, "json_ok": 3, "median_s": 0.9, "max_s": 1.0,
             "cpu_median_s": 0.85, "cpu_max_s": 0.95, "failures": [], "torch_imported": False,
             "floor": {"command": 'python -c "import numpy"', "median_s": 0.6, "max_s": 0.7, "cpu_median_s": 0.55,
                       "cpu_max_s": 0.65}}
    rows = {r[0]: r[1] for r in TB._floor_rows(fresh)}
    assert any("numeric libraries alone" in k and v == "0.6 / 0.7" for k, v in rows.items()), rows
    assert [v for k, v in rows.items() if k.startswith("fresh query minus")] == ["0.3"]
    assert TB._floor_rows({k: v for k, v in fresh.items() if k != "floor"}) == []  # older results: no rows


def test_update_render_of_a_shipped_only_run_lists_the_two_runs_and_says_the_critic_came_with_the_folder() -> None:
    from gaintune.bench.tuners_update import render_update

    curve = [{"episodes": 0, "sims": 0, "median_ratio": 1.05}, {"episodes": 256, "sims": 300, "median_ratio": 1.008}]
    run = {"sims_to_target": 300, "wall_s": 10.0, "validation_median": 1.004, "validation_worst": 1.01, "curve": curve}
    r = {"base": "fotd_pi_ms1.4", "lag": 0.2, "target": 1.01, "episodes": 1024, "seed": 0, "base_has_critic": True,
         "cold": {**run, "sims_to_target": 1500}, "update": run, "ratio_update": 5.0, "ratio": 5.0}
    md = render_update(r, "gaintune bench tuners --update --shipped-only")
    assert "actor and critic arrays" in md and "cold / update simulations: **5.0x**" in md
    assert "update_with_agent" not in md and "a curve point every 256 episodes (the training chunk)" in md
    finer = render_update({**r, "curve_every": 64, "chunk": 256}, "gaintune bench tuners")
    assert "a curve point every 64 episodes, training chunks of 256 episodes" in finer


def test_update_curve_every_reaches_the_training_settings(monkeypatch, tmp_path) -> None:
    import gaintune.bench.tuners as TB

    seen = {}

    def fake_measure(base, episodes, with_agent=True, curve_every=256):
        seen.update(base=base, episodes=episodes, curve_every=curve_every)
        raise SystemExit(0)

    import gaintune.bench.tuners_update as TU

    monkeypatch.setattr(TU, "measure_update", fake_measure)
    with pytest.raises(SystemExit):
        TB.main(["--update", "--shipped-only", "--update-curve-every", "32", "--out", str(tmp_path)])
    assert seen == {"base": "fotd_pi_ms1.4", "episodes": 8192, "curve_every": 32}


def test_update_runs_train_in_chunks_of_256_whatever_the_curve(monkeypatch) -> None:
    """The curve's resolution is a measurement: both runs get the same chunk (noise schedule, checkpoints)."""
    import gaintune.bench.tuners_update as U
    import gaintune.tuners.train as T

    seen = []

    def fake_train(problem, out, settings, warm_start=None, resume=True):
        seen.append((settings.chunk, settings.curve_every))
        raise SystemExit(0)

    monkeypatch.setattr(T, "train", fake_train)
    with pytest.raises(SystemExit):
        U.measure_update(episodes=1024, with_agent=False, curve_every=64)
    assert seen == [(U.CHUNK, 64)] and U.CHUNK == 256


def test_algo_compare_render_gives_each_learners_held_out_ratios() -> None:
    from gaintune.bench.tuners_algo import render_algo_compare

    row = {"median_ratio": 1.0034, "worst_ratio": 1.0387, "passed": 16, "n": 16, "sims": 5388, "wall_s": 373.0}
    r = {"family": "fotd", "ctype": "pi", "ms_max": 1.4, "episodes": 4096, "contexts": 16, "seed": 0,
         "td3": row, "ppo": {**row, "median_ratio": 1.2363, "worst_ratio": 2.3129}}
    md = render_algo_compare(r, "gaintune bench tuners --algo-compare")
    assert "| td3 | 1.0034 | 1.0387 | 16/16 |" in md and "| ppo | 1.2363 | 2.3129 | 16/16 |" in md


def test_a_shipped_only_update_run_does_not_overwrite_the_full_runs_results(monkeypatch, tmp_path) -> None:
    """--shipped-only measures the cold start and the shipped tuner's update only: it writes tuners_update_shipped.*,
    and the full run's tuners_update.* (with the agent's update and tune --warm-start) stays."""
    import gaintune.bench.tuners as TB

    def fake_measure(base, episodes, with_agent=True, curve_every=256):
        return {"base": base, "episodes": episodes, "seed": 0, "lag": 0.2, "ms_max": 1.4, "curve_every": curve_every,
                "chunk": 256, "cold": {"sims_to_target": 10, "wall_s": 1.0, "validation": {"median_ratio": 1.0,
                                       "worst_ratio": 1.0}, "curve": []},
                "update": {"sims_to_target": 1, "wall_s": 1.0, "validation": {"median_ratio": 1.0, "worst_ratio": 1.0},
                           "curve": []}, "ratio_update": 10.0, "ratio": 10.0}

    import gaintune.bench.tuners_update as TU

    monkeypatch.setattr(TU, "measure_update", fake_measure)
    monkeypatch.setattr(TU, "render_update", lambda r, command: "# rendered\n")
    (tmp_path / "tuners_update.md").write_text("the full run\n")
    assert TB.main(["--update", "--shipped-only", "--out", str(tmp_path)]) == 0
    assert (tmp_path / "tuners_update.md").read_text() == "the full run\n"
    assert (tmp_path / "tuners_update_shipped.md").read_text() == "# rendered\n"
