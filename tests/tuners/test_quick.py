"""``gaintune tune --quick``: model, tuner choice, the answer on the true plant, refusals, outputs, exit codes.

The ready-made tuners are trained by their owner; here a tiny FOTD PI tuner (512 episodes) is trained
once into a temporary folder and passed as ``tuners_dir`` / ``--tuners``. Its answers are far from
optimal, so the tests check what the quick path guarantees (a verified answer on the true plant, never
worse than a rule that passes, the refusals and outputs), not the tuner's quality. No timing is asserted.
"""

from __future__ import annotations

import copy
import json
import shutil
from pathlib import Path

import pytest
import yaml
from typer.testing import CliRunner

from gaintune import cli
from gaintune.errors import SpecError
from gaintune.plants import build_plant
from gaintune.spec import load_spec
from gaintune.tuners.families import FAMILIES
from gaintune.tuners.quick import quick_tune
from gaintune.tuners.quick_model import (
    SOTD_MIN_RATIO,
    TunerInfo,
    available_tuners,
    choose_tuner,
    loop_model,
    tuner_params,
)
from gaintune.tuners.tuner import Tuner

runner = CliRunner()

#: The thermal FOTD 2 e^{-10s}/(60s+1), PI, unit load step at the input, Ms <= 1.4.
FOTD = {
    "name": "thermal_pi",
    "plant": {"tf": {"num": [2], "den": [60, 1]}, "delay": 10},
    "loops": [{"name": "main", "type": "pi"}],
    "scenarios": [{"name": "load", "reference": {"kind": "none"},
                   "disturbance": {"kind": "step", "entry": "input", "amplitude": 1.0}}],
    "objective": {"measure": "iae", "effort_weight": 0.0},
    "requirements": {"gm_min_db": None, "pm_min_deg": None, "ms_max": 1.4},
}


def _spec(**changes):
    d = copy.deepcopy(FOTD)
    for k, v in changes.items():
        d[k] = v
    return load_spec(d)


@pytest.fixture(scope="session")
def tuners_dir(tmp_path_factory, tiny_fotd_tuner: Path) -> Path:
    """A folder holding one tiny trained FOTD PI tuner (Ms <= 1.4), as the shipped folder holds several."""
    root = tmp_path_factory.mktemp("tuners")
    shutil.copytree(tiny_fotd_tuner, root / "fotd_pi_ms1.4")
    return root


@pytest.fixture(scope="module")
def fotd_answer(tuners_dir):
    return quick_tune(_spec(), tuners_dir=tuners_dir)


# ------------------------------------------------------------------ model and tuner choice


def test_loop_model_names_the_family_of_the_path() -> None:
    def model(num, den, delay=0.0, sotd=True):
        spec = _spec(plant={"tf": {"num": num, "den": den}, "delay": delay})
        from gaintune.classical.timescale import resolve_scenarios

        plant = build_plant(spec.plant)
        return loop_model(resolve_scenarios(spec, plant), plant, sotd=sotd)

    fotd = model([2], [60, 1], 10)
    assert fotd.family == "fotd" and fotd.params["K"] == pytest.approx(2) and fotd.params["T"] == pytest.approx(60)
    assert fotd.params["L"] > 10  # the delay plus half a sample, as the rules see it
    lag3 = model([1], "(s+1)^3")  # half rule: T1 = 1, T2 = 1.5: clearly second order
    assert lag3.family == "sotd" and lag3.params["T2"] >= SOTD_MIN_RATIO * lag3.params["T1"]
    assert model([1], "(s+1)^3", sotd=False).family == "fotd"
    integ = model([1], "s*(0.5*s+1)", 1.0)
    assert integ.family == "ipd" and integ.params["T"] == pytest.approx(0.5)
    reverse = model([-2], [60, 1], 10)
    assert reverse.params["K"] == pytest.approx(2) and reverse.sign == -1


def test_choose_tuner_takes_the_nearest_ms_limit_at_or_below_the_specs() -> None:
    tuners = [TunerInfo(f"fotd_pi_ms{m:g}", Path("."), "fotd", "pi", m) for m in (1.4, 2.0)]
    tuners.append(TunerInfo("fotd_pid_ms1.4", Path("."), "fotd", "pid", 1.4))
    assert choose_tuner(tuners, "fotd", "pi", 1.4).ms_max == 1.4
    assert choose_tuner(tuners, "fotd", "pi", 1.7).ms_max == 1.4
    assert choose_tuner(tuners, "fotd", "pi", 2.5).ms_max == 2.0
    assert choose_tuner(tuners, "fotd", "pi", 1.2).ms_max == 1.4  # none at or below: the lowest
    assert choose_tuner(tuners, "fotd", "pi", None).ms_max == 1.4
    assert choose_tuner(tuners, "fotd", "pid", 2.0).name == "fotd_pid_ms1.4"
    assert choose_tuner(tuners, "ipd", "pi", 1.4) is None


def test_available_tuners_reads_the_problem_of_each_folder(tuners_dir, tmp_path) -> None:
    (tmp_path / "broken").mkdir()
    (tmp_path / "broken" / "tuner.json").write_text("{not json")
    assert available_tuners(tmp_path) == []
    assert [(t.name, t.family, t.ctype, t.ms_max) for t in available_tuners(tuners_dir)] == [
        ("fotd_pi_ms1.4", "fotd", "pi", 1.4)]


def test_a_shape_outside_the_training_range_is_moved_to_its_edge(tuners_dir) -> None:
    tuner = Tuner.load(tuners_dir / "fotd_pi_ms1.4")
    from gaintune.tuners.quick_model import LoopModel

    fam = FAMILIES["fotd"]
    inside = LoopModel("fotd", {"K": 2.0, "T": 60.0, "L": 10.0}, None)  # type: ignore[arg-type]
    assert tuner_params(inside, tuner.problem) == (inside.params, None)
    fast = LoopModel("fotd", {"K": 2.0, "T": 60.0, "L": 0.01}, None)  # type: ignore[arg-type]  # L/T = 1.7e-4
    params, note = tuner_params(fast, tuner.problem)
    lo = tuner.problem.variables[0].lo
    assert fam.shape_of(params)["tau"] == pytest.approx(lo) and "outside the tuner's training range" in note
    assert params["K"] == 2.0 and fam.time_scale(params) == pytest.approx(60.01)  # gain and time scale kept
    tuner.context(params)  # the tuner takes it


# ------------------------------------------------------------------ the answer


def test_quick_on_a_fotd_spec_passes_and_is_not_worse_than_amigo(fotd_answer) -> None:
    q = fotd_answer
    assert q.verdict == "pass" and q.result.accepted_gains == q.result.gains
    assert q.tuner.name == "fotd_pi_ms1.4" and q.model.family == "fotd" and q.notes == []
    assert q.result.algo == "quick" and q.result.settle is not None
    rows = {r["method"]: r for r in q.comparison}
    assert set(rows) == {"quick", "amigo", "simc"}
    assert rows["amigo"]["verdict"] == "pass"  # AMIGO passes Ms <= 1.4 here: the comparison means something
    assert q.result.cost <= rows["amigo"]["cost"]
    for r in rows.values():
        if r["verdict"] == "pass":
            assert q.result.cost <= r["cost"] * (1 + 1e-9), r


def test_compare_search_adds_the_searched_answer_to_the_comparison(tuners_dir) -> None:
    q = quick_tune(_spec(), tuners_dir=tuners_dir, refine=0, compare_search=400)
    row = q.comparison[-1]
    assert row["method"] == "search" and row["verdict"] in ("pass", "fail") and "budget 400" in row["note"]
    assert row["ratio"] == pytest.approx(row["cost"] / q.result.cost)
    assert q.result.gains == quick_tune(_spec(), tuners_dir=tuners_dir, refine=0).result.gains  # answer unchanged


def test_quick_gains_verify_on_the_true_plant(fotd_answer) -> None:
    from gaintune.verification import verify

    rep = verify(_spec(), fotd_answer.result.gains)
    assert rep.verdict == "pass" and rep.requirements[0].value <= 1.4


def test_quick_without_refinement_answers_the_settled_candidate(tuners_dir) -> None:
    q = quick_tune(_spec(), tuners_dir=tuners_dir, refine=0)
    assert q.verdict == "pass" and q.refine_sims == 0 and not q.refined
    assert q.result.gains_source in ("policy", "start")


def test_quick_of_a_reverse_acting_loop_answers_negative_gains(tuners_dir) -> None:
    q = quick_tune(_spec(plant={"tf": {"num": [-2], "den": [60, 1]}, "delay": 10}), tuners_dir=tuners_dir)
    assert q.verdict == "pass" and all(v < 0 for v in q.result.gains["main"].values())


def test_quick_with_other_requirements_says_the_tuner_answer_is_the_start(tuners_dir) -> None:
    q = quick_tune(_spec(requirements={"gm_min_db": 6, "pm_min_deg": 45, "ms_max": 1.7}), tuners_dir=tuners_dir)
    assert q.verdict == "pass" and q.tuner.name == "fotd_pi_ms1.4"
    assert any("Ms <= 1.7, GM >= 6 dB, PM >= 45 deg" in n and "start" in n for n in q.notes), q.notes


def test_quick_without_a_tuner_of_the_family_starts_from_the_rules(tuners_dir) -> None:
    d = copy.deepcopy(FOTD)
    d["loops"][0]["type"] = "pid"
    q = quick_tune(load_spec(d), tuners_dir=tuners_dir)
    assert q.tuner is None and q.source in ("amigo", "simc") and q.verdict == "pass"
    assert "no ready-made tuner for a FOTD PID loop" in q.notes[0]


def test_quick_of_a_plant_beyond_the_tuners_gain_range_starts_from_the_rules_and_says_why(tuners_dir) -> None:
    """The tuner's refusal (params.K, outside GAIN_RANGE) ended --quick with exit 2 naming a field the spec
    does not have; the quick answer starts from the rules instead, and says so."""
    d = copy.deepcopy(FOTD)
    d["plant"]["tf"]["num"] = [2e12]
    d["safety"] = {"divergence_bound": 1e20}  # its signals are that large
    q = quick_tune(load_spec(d), tuners_dir=tuners_dir)
    assert q.tuner is None and q.source in ("amigo", "simc") and q.verdict == "pass"
    assert "does not answer for this model (the plant's gain K = 2e+12 is outside" in q.notes[0]


# ------------------------------------------------------------------ refusals


def test_quick_refuses_a_multi_loop_spec_naming_loops(tuners_dir) -> None:
    from gaintune.plants.library import load_model

    with pytest.raises(SpecError) as e:
        quick_tune(load_spec(load_model("dc_motor").example_spec()), tuners_dir=tuners_dir)
    assert e.value.field == "loops" and "gaintune tune SPEC (without --quick)" in e.value.message


def test_quick_refuses_a_p_loop_naming_its_type(tuners_dir) -> None:
    d = copy.deepcopy(FOTD)
    d["loops"][0]["type"] = "p"
    with pytest.raises(SpecError) as e:
        quick_tune(load_spec(d), tuners_dir=tuners_dir)
    assert e.value.field == "loops[0].type" and "PI and PID" in e.value.message


def test_quick_on_an_unstable_plant_answers_from_the_search_box_start(tuners_dir) -> None:
    """Issue 27 asks for an instant answer for any SISO loop: a path without a FOTD model (unstable here) was
    refused; it now starts from the search box's start, is settled and verified like every answer."""
    q = quick_tune(_spec(plant={"tf": {"num": [1], "den": [1, -1]}, "delay": 0.1}), tuners_dir=tuners_dir)
    assert q.model.family == "none" and "unstable" in q.model.text()
    assert q.source.startswith("search box") and q.result.verdict == "pass"
    assert any("search box" in n for n in q.notes)


# ------------------------------------------------------------------ CLI


@pytest.fixture(scope="module")
def spec_file(tmp_path_factory) -> Path:
    p = tmp_path_factory.mktemp("spec") / "thermal.yaml"
    p.write_text(yaml.safe_dump(FOTD, sort_keys=False))
    return p


def test_cli_quick_writes_the_outputs_and_export_reads_them(tuners_dir, spec_file, tmp_path) -> None:
    out = tmp_path / "out"
    res = runner.invoke(cli.app, ["tune", str(spec_file), "--quick", "--tuners", str(tuners_dir), "--out", str(out)])
    assert res.exit_code == 0, res.output
    assert "The quick answer beside the rules" in res.output and "verdict: PASS" in res.output
    for f in ("result.json", "report.html", "gains.json", "gains.h", "quick.json"):
        assert (out / f).is_file(), f
    doc = json.loads((out / "quick.json").read_text())
    assert doc["verdict"] == "pass" and doc["tuner"]["name"] == "fotd_pi_ms1.4"
    assert [r["method"] for r in doc["comparison"]] == ["quick", "amigo", "simc"]
    exp = runner.invoke(cli.app, ["export", str(out / "result.json"), "--format", "c"])
    assert exp.exit_code == 0, exp.output
    assert "PASS" in exp.output


def test_cli_quick_json_holds_the_result_and_the_comparison(tuners_dir, spec_file) -> None:
    res = runner.invoke(cli.app, ["tune", str(spec_file), "--quick", "--tuners", str(tuners_dir), "--json",
                                  "--refine", "0"])
    assert res.exit_code == 0, res.output
    doc = json.loads(res.stdout)
    assert doc["algo"] == "quick" and doc["verification"]["verdict"] == "pass"
    assert doc["quick"]["refine_sims"] == 0 and doc["quick"]["model"]["family"] == "fotd"


def test_cli_quick_exits_3_when_the_answer_fails(tuners_dir, tmp_path) -> None:
    d = copy.deepcopy(FOTD)
    d["requirements"]["wc_min"] = 5.0  # 5 rad/s on a loop with 10 s of delay: no PI meets it
    p = tmp_path / "impossible.yaml"
    p.write_text(yaml.safe_dump(d))
    res = runner.invoke(cli.app, ["tune", str(p), "--quick", "--tuners", str(tuners_dir)])
    assert res.exit_code == 3, res.output
    assert "verdict: FAILED" in res.output and "without --quick" in res.output


def test_cli_quick_exits_2_for_a_multi_loop_spec(tuners_dir, tmp_path) -> None:
    from gaintune.plants.library import load_model

    p = tmp_path / "cascade.yaml"
    p.write_text(yaml.safe_dump(load_model("dc_motor").example_spec()))
    res = runner.invoke(cli.app, ["tune", str(p), "--quick", "--tuners", str(tuners_dir)])
    assert res.exit_code == 2 and "error: loops:" in res.output and "Traceback" not in res.output


@pytest.mark.parametrize("args, field", [
    (["--quick", "--budget", "100"], "budget"),
    (["--quick", "--algo", "ppo"], "algo"),
    (["--quick", "--baselines"], "baselines"),
    (["--refine", "10"], "refine"),
    (["--tuners", "."], "tuners"),
    (["--quick", "--tuners", "no/such/folder"], "tuners"),
])
def test_cli_quick_options_that_do_not_fit_exit_2(spec_file, args, field) -> None:
    res = runner.invoke(cli.app, ["tune", str(spec_file), *args])
    assert res.exit_code == 2, res.output
    assert f"error: {field}:" in res.output
