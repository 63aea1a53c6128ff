"""The gaintune CLI: commands, exit codes (0 ok, 2 bad input, 3 verification failed), outputs, no tracebacks."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest
import yaml
from typer.testing import CliRunner

from gaintune import cli
from gaintune.plants.library import load_model
from gaintune.report import result_from_gains
from gaintune.search.result import Progress, TuneResult
from gaintune.spec import load_spec

runner = CliRunner()
AMIGO = {"main": {"Kp": 0.6485, "Ki": 0.3957, "Kd": 0.3751}}
TOO_HOT = {"main": {"Kp": 20.0, "Ki": 10.0, "Kd": 0.01}}


@pytest.fixture(scope="module")
def spec_file(tmp_path_factory) -> Path:
    p = tmp_path_factory.mktemp("spec") / "lag.yaml"
    p.write_text(yaml.safe_dump(load_model("lag_n").example_spec(), sort_keys=False))
    return p


@pytest.fixture(scope="module")
def good_result() -> TuneResult:
    return result_from_gains(load_spec(load_model("lag_n").example_spec()), AMIGO, algo="ppo")


@pytest.fixture(scope="module")
def result_file(good_result, tmp_path_factory) -> Path:
    p = tmp_path_factory.mktemp("res") / "result.json"
    p.write_text(good_result.model_dump_json())
    return p


def run(*args: str):
    return runner.invoke(cli.app, list(args))


def _no_traceback(res) -> None:
    assert "Traceback" not in res.output
    assert res.exception is None or isinstance(res.exception, SystemExit)


# ------------------------------------------------------------------ help


def test_help_documents_exit_codes() -> None:
    res = run("--help")
    assert res.exit_code == 0
    for cmd in ("tune", "demo", "verify", "simulate", "report", "plants", "export", "serve", "bench"):
        assert cmd in res.output
    assert "Exit codes" in res.output and "2 invalid input" in res.output and "3 verification failed" in res.output


def test_python_dash_m_works() -> None:
    p = subprocess.run([sys.executable, "-m", "gaintune", "--help"], capture_output=True, text=True, timeout=120)
    assert p.returncode == 0 and "Exit codes" in p.stdout


# --------------------------------------------------------------- verify


def test_verify_pass_prints_table(spec_file: Path) -> None:
    res = run("verify", str(spec_file), "--gains", json.dumps(AMIGO))
    assert res.exit_code == 0, res.output
    assert "verification of 'lag_n': PASS" in res.output and "requirements:" in res.output


def test_verify_fail_exits_3(spec_file: Path, tmp_path: Path) -> None:
    g = tmp_path / "g.yaml"
    g.write_text(yaml.safe_dump(TOO_HOT))
    res = run("verify", str(spec_file), "--gains", str(g))
    assert res.exit_code == 3
    assert "FAIL" in res.output


def test_verify_accepts_a_result_file_as_gains(spec_file: Path, result_file: Path) -> None:
    res = run("verify", str(spec_file), "--gains", str(result_file), "--json", "--no-robust")
    assert res.exit_code == 0
    assert json.loads(res.stdout)["verdict"] == "pass"


@pytest.mark.parametrize(
    ("spec_text", "gains", "expect"),
    [
        ("plant: {tf: {num: [1], den: [1, 1]}}\nloops: [{type: pidd}]\n", "{}", "error: loops.0.type: Input should be"),
        ("plant: {tf: {num: [1], den: [1, 1]}\nloops: [", "{}", "error: spec: not valid JSON/YAML"),
        ("- just\n- a list\n", "{}", "error: spec: must be a mapping"),
        ("plant: {tf: {num: [1], den: [1, 1]}}\nloops: [{type: pi}]\nscenario: {dt: -1}\n", "{}", "error: scenarios.0: dt must be > 0"),
        (None, '{"main": {"Kp": -1, "Ki": 1, "Kd": 1}}', "error: gains.main.Kp: must be > 0"),
        (None, '{"main": {"Kp": 1', "error: gains: not valid JSON/YAML"),
        (None, '{"nope": {"Kp": 1}}', "error: gains: unknown loop(s) ['nope']"),
        (None, "missing-gains.yaml", "error: gains: file not found"),
    ],
)
def test_bad_input_exits_2_naming_the_field(spec_file: Path, tmp_path: Path, spec_text, gains, expect) -> None:
    path = spec_file
    if spec_text is not None:
        path = tmp_path / "bad.yaml"
        path.write_text(spec_text)
    res = run("verify", str(path), "--gains", gains)
    assert res.exit_code == 2, res.output
    assert expect in res.stderr, res.stderr
    _no_traceback(res)


def test_missing_spec_file_exits_2(tmp_path: Path) -> None:
    res = run("simulate", str(tmp_path / "nope.yaml"), "--gains", "{}")
    assert res.exit_code == 2 and "error: spec: file not found" in res.stderr
    _no_traceback(res)


# ------------------------------------------------------------- simulate


def test_simulate_table_json_and_plot(spec_file: Path, tmp_path: Path) -> None:
    res = run("simulate", str(spec_file), "--gains", json.dumps(AMIGO))
    assert res.exit_code == 0 and "iae" in res.output and "overshoot" in res.output
    png = tmp_path / "sim.png"
    res = run("simulate", str(spec_file), "--gains", json.dumps(AMIGO), "--json", "--traces", "--plot", str(png))
    assert res.exit_code == 0, res.output
    doc = json.loads(res.stdout)
    assert doc["step"]["metrics"]["iae"] > 0 and len(doc["step"]["traces"]["u"]) == len(doc["step"]["t"])
    assert png.stat().st_size > 5000


# --------------------------------------------------------------- plants


def test_plants_list_and_show() -> None:
    res = run("plants")
    assert res.exit_code == 0 and "dc_motor" in res.output and "lag_n" in res.output
    res = run("plants", "show", "dc_motor")
    assert res.exit_code == 0
    assert "rad/s" in res.output and "position" in res.output and "Example spec" in res.output
    res = run("plants", "show", "warp_drive")
    assert res.exit_code == 2 and "error: plant.model.name: unknown model 'warp_drive'" in res.stderr


def test_plants_show_spec_prints_only_the_example_spec_which_loads(tmp_path: Path) -> None:
    res = run("plants", "show", "dc_motor", "--spec")
    assert res.exit_code == 0, res.output
    spec = load_spec(yaml.safe_load(res.stdout))
    assert spec.plant.model is not None and len(spec.loops) == 3


def test_tuning_a_plant_model_file_says_it_is_one_and_what_to_run_instead(repo_root: Path) -> None:
    # it gave six unknown-key errors (title, parameters, input, ...), none saying what the file is
    res = run("tune", str(repo_root / "models" / "dc_motor.yaml"), "--quick")
    assert res.exit_code == 2
    assert res.stderr.count("error:") == 1, res.stderr
    assert "error: spec: this is a plant model file" in res.stderr
    assert "gaintune plants show dc_motor --spec > spec.yaml" in res.stderr


# ------------------------------------------------------- export, report


@pytest.mark.parametrize("fmt", ["json", "yaml", "c", "matlab", "python"])
def test_export_formats(result_file: Path, tmp_path: Path, fmt: str) -> None:
    res = run("export", str(result_file), "--format", fmt)
    assert res.exit_code == 0, res.output
    assert "0.6485" in res.stdout
    out = tmp_path / f"g.{fmt}"
    res = run("export", str(result_file), "--format", fmt, "--dt", "0.005", "-o", str(out))
    assert res.exit_code == 0 and out.exists()


def test_export_refuses_failed_gains_unless_forced(tmp_path: Path) -> None:
    bad = result_from_gains(load_spec(load_model("lag_n").example_spec()), TOO_HOT, algo="ppo")
    assert bad.verdict == "fail"
    p = tmp_path / "bad.json"
    p.write_text(bad.model_dump_json())
    res = run("export", str(p), "--format", "c")
    assert res.exit_code == 3 and "FAILED" in res.stderr
    res = run("export", str(p), "--format", "c", "--force")
    assert res.exit_code == 0 and "#define GT_VERIFIED 0" in res.stdout


def test_export_bad_format_and_bad_result(result_file: Path, tmp_path: Path) -> None:
    res = run("export", str(result_file), "--format", "xml")
    assert res.exit_code == 2 and "error: format: unknown format 'xml'" in res.stderr
    junk = tmp_path / "junk.json"
    junk.write_text('{"algo": 3}')
    res = run("export", str(junk))
    assert res.exit_code == 2 and "error: " in res.stderr
    _no_traceback(res)


def test_report_command(result_file: Path, tmp_path: Path) -> None:
    out = tmp_path / "r.html"
    res = run("report", str(result_file), "-o", str(out))
    assert res.exit_code == 0, res.output
    assert out.read_text().count('<section id="') == 7


# ----------------------------------------------------------- tune, demo


@pytest.fixture
def fake_tune(monkeypatch, good_result):
    calls = {}

    def tune(spec, *, progress=None, out_dir=None, verify=True, baselines=False, cancel=None, warm_start=None, command=""):
        calls.update(spec=spec, out_dir=out_dir, baselines=baselines, command=command, progress=progress)
        if progress is not None:
            for s in (50, 100, 200):
                progress(Progress(sims=s, budget=spec.search.budget, best_cost=3.0 - s / 100, eta=1.0))
        return good_result.model_copy(deep=True)

    monkeypatch.setattr(cli, "_get_tune", lambda: tune)
    return calls


def test_tune_overrides_and_writes_everything(spec_file: Path, tmp_path: Path, fake_tune) -> None:
    out = tmp_path / "out"
    res = run("tune", str(spec_file), "--out", str(out), "--algo", "sac", "--budget", "200", "--seed", "7", "--workers", "4")
    assert res.exit_code == 0, res.output
    spec = fake_tune["spec"]
    assert (spec.search.algo, spec.search.budget, spec.search.seed, spec.search.n_envs) == ("sac", 200, 7, 4)
    assert fake_tune["out_dir"] == str(out)
    assert fake_tune["command"] == f"gaintune tune {spec_file} --algo sac --budget 200 --seed 7 --workers 4"
    for name in ("result.json", "report.html", "gains.json", "gains.yaml", "gains.h", "gains.m"):
        assert (out / name).stat().st_size > 0, name
    assert "Accepted gains" in res.output and "verdict: PASS" in res.output and "Margins" in res.output
    TuneResult.model_validate_json((out / "result.json").read_text())


def test_tune_json_is_pure_json(spec_file: Path, fake_tune) -> None:
    res = run("tune", str(spec_file), "--json")
    assert res.exit_code == 0
    assert fake_tune["progress"] is None
    assert json.loads(res.stdout)["gains"]["main"]["Kp"] == pytest.approx(0.6485)


def test_tune_bad_override_exits_2(spec_file: Path, fake_tune) -> None:
    res = run("tune", str(spec_file), "--algo", "dqn")
    assert res.exit_code == 2 and "error: search.algo: Input should be" in res.stderr
    res = run("tune", str(spec_file), "--budget", "3")
    assert res.exit_code == 2 and "search.budget" in res.stderr


def test_tune_failed_verification_exits_3(spec_file: Path, monkeypatch, good_result) -> None:
    failed = good_result.verification.model_copy(update={"verdict": "fail", "reasons": ["ms_max: too high"]})
    bad = good_result.model_copy(update={"verification": failed})
    monkeypatch.setattr(cli, "_get_tune", lambda: (lambda spec, **kw: bad))
    res = run("tune", str(spec_file))
    assert res.exit_code == 3
    assert "FAILED" in res.output and "Accepted gains" not in res.output and "ms_max: too high" in res.output


def test_demo_uses_lag_n(tmp_path: Path, fake_tune) -> None:
    res = run("demo", "--out", str(tmp_path / "demo"), "--budget", "300")
    assert res.exit_code == 0, res.output
    assert fake_tune["spec"].plant.model.name == "lag_n" and fake_tune["spec"].search.budget == 300
    assert (tmp_path / "demo" / "report.html").exists() and (tmp_path / "demo" / "gains.h").exists()


def test_tune_for_real_with_a_tiny_budget(spec_file: Path) -> None:
    """Integration with the real RL search (tiny budget); the verdict may be either."""
    res = run("tune", str(spec_file), "--budget", "200", "--workers", "8", "--json")
    assert res.exit_code in (0, 3), res.output
    doc = json.loads(res.stdout)
    assert doc["verification"]["verdict"] in ("pass", "fail") and doc["sims"] <= 400


def test_tune_warm_start_continues_a_saved_agent_and_refuses_a_mismatched_one(spec_file: Path, tmp_path: Path) -> None:
    """Learning on from the CLI: ``--warm-start agent.zip``; a wrong file or layout exits 2 naming warm_start."""
    first = run("tune", str(spec_file), "--budget", "200", "--workers", "8", "--out", str(tmp_path / "a"), "--json")
    assert first.exit_code in (0, 3), first.output
    agent = tmp_path / "a" / "agent.zip"
    res = run("tune", str(spec_file), "--budget", "200", "--workers", "8", "--warm-start", str(agent), "--json")
    assert res.exit_code in (0, 3), res.output
    doc = json.loads(res.stdout)
    assert doc["rl_sims"] > 0 and f"--warm-start {agent}" in doc["provenance"]["command"] and doc["warm_start"] == str(agent)
    res = run("tune", str(spec_file), "--budget", "10", "--warm-start", str(agent), "--json")  # learning off
    doc = json.loads(res.stdout)
    assert doc["rl_sims"] == 0 and doc["verification"]["verdict"] in ("pass", "fail")
    assert f"saved policy of {agent} as it is (learning off)" in doc["diagnosis"]["hints"][0]
    pi = tmp_path / "pi.yaml"
    data = load_model("lag_n").example_spec()
    pi.write_text(yaml.safe_dump({**data, "loops": [{"name": "main", "type": "pi"}]}, sort_keys=False))
    junk = tmp_path / "junk.zip"
    junk.write_text("not an agent")
    for spec, path, needle in [(pi, agent, "trained on 3 tuned gains"), (spec_file, junk, "is not an agent saved by gaintune"),
                               (spec_file, tmp_path / "none.zip", "no saved agent at")]:
        res = run("tune", str(spec), "--budget", "200", "--warm-start", str(path), "--json")
        _no_traceback(res)
        assert res.exit_code == 2 and "error: warm_start: " in res.stderr and needle in res.stderr, res.output


# ----------------------------------------------------------- bench, serve


def test_bench_missing_module_is_a_clear_message(monkeypatch) -> None:
    import importlib

    real = importlib.import_module

    def fake(name, *a, **k):
        if name == "gaintune.bench.api":
            raise ModuleNotFoundError("No module named 'gaintune.bench.api'")
        return real(name, *a, **k)

    monkeypatch.setattr(cli.importlib, "import_module", fake)
    res = run("bench", "api")
    assert res.exit_code == 1 and "benchmark 'api' is not available" in res.stderr


def test_bench_passes_arguments_through(monkeypatch) -> None:
    import types

    seen = {}
    mod = types.SimpleNamespace(main=lambda argv: seen.setdefault("argv", argv) and 0)
    monkeypatch.setattr(cli.importlib, "import_module", lambda name: mod)
    res = run("bench", "sim", "--batch", "64", "--json")
    assert res.exit_code == 0 and seen["argv"] == ["--batch", "64", "--json"]


def test_serve_calls_api(monkeypatch) -> None:
    import types

    seen = {}
    fake = types.ModuleType("gaintune_api.main")
    fake.serve = lambda host, port, workers: seen.update(host=host, port=port, workers=workers)
    monkeypatch.setitem(sys.modules, "gaintune_api.main", fake)
    res = run("serve", "--host", "0.0.0.0", "--port", "9000", "--workers", "3")
    assert res.exit_code == 0 and seen == {"host": "0.0.0.0", "port": 9000, "workers": 3}


def test_export_and_report_of_gains_edited_in_result_json_reverify_not_stamp_pass(result_file: Path, tmp_path: Path) -> None:
    """Bug (fuzzing): editing result.json's gains kept its stored PASS: a C header said GT_VERIFIED 1 for unstable gains."""
    doc = json.loads(result_file.read_text())
    doc["gains"]["main"] = {"Kp": 50.0, "Ki": 5000.0, "Kd": 0.01}
    edited = tmp_path / "edited.json"
    edited.write_text(json.dumps(doc))
    res = run("export", str(edited), "--format", "c", "-o", str(tmp_path / "g.h"))
    _no_traceback(res)
    assert res.exit_code == 3 and not (tmp_path / "g.h").exists(), res.output
    assert "verification was for other gains" in res.stderr and "FAILED" in res.stderr
    res = run("report", str(edited), "-o", str(tmp_path / "r.html"))
    assert res.exit_code == 0, res.output
    html = (tmp_path / "r.html").read_text()
    assert 'class="verdict fail">FAILED<' in html and "verification was for other gains" in html


def test_tune_baselines_prints_a_baselines_table(spec_file: Path, monkeypatch, good_result) -> None:
    """--baselines ran the rules but printed no table in the terminal."""
    with_baselines = good_result.model_copy(update={"baselines": [
        {"method": "simc", "gains": {"main": {"Kp": 0.5, "Ki": 0.3, "Kd": 0.1}}, "cost": 2 * good_result.cost,
         "feasible": True, "n_sims": 1, "reason": None},
        {"method": "zn_step", "gains": None, "cost": None, "feasible": None, "n_sims": 0, "reason": "no rule"}]})
    monkeypatch.setattr(cli, "_get_tune", lambda: (lambda spec, **kw: with_baselines))
    res = run("tune", str(spec_file), "--baselines")
    assert res.exit_code == 0, res.output
    assert "Baselines" in res.output and "simc" in res.output and "zn_step" in res.output and "no rule" in res.output
    assert " 2 " in res.output  # simc's cost is twice this result's


def test_tune_summary_shows_the_ideal_form(spec_file: Path, fake_tune) -> None:
    res = run("tune", str(spec_file))
    assert res.exit_code == 0, res.output
    assert "Ti " in res.output and "Td " in res.output


def test_plants_listing_never_truncates_a_name(monkeypatch) -> None:
    """`gaintune plants` cut 'mass_spring_damper' to 'mass_spring_damp…' at 80 columns."""
    monkeypatch.setenv("COLUMNS", "80")
    res = run("plants")
    assert res.exit_code == 0
    assert "mass_spring_damper" in res.output and "…" not in res.output


def test_plants_listing_of_an_empty_or_a_bad_models_folder_exits_without_a_traceback(tmp_path, monkeypatch):
    """Regression: 'gaintune plants' had no error handler (a bad model file printed a traceback) and took the max
    of an empty list when GAINTUNE_MODELS held no model (ValueError)."""
    monkeypatch.setenv("GAINTUNE_MODELS", str(tmp_path))
    res = CliRunner().invoke(cli.app, ["plants"])
    assert res.exit_code == 0 and "no plant models in" in res.output, res.output
    (tmp_path / "bad.yaml").write_text("- 1\n")
    res = CliRunner().invoke(cli.app, ["plants"])
    assert res.exit_code == 2 and "error: models/bad.yaml:" in res.stderr and "Traceback" not in res.output


def test_an_out_folder_nobody_can_write_is_refused_before_any_work_even_for_root():
    """Regression: os.access says root may write anywhere, so '--out /proc/foo' passed the check and failed at the
    end with a bare '[Errno 2] ...', after a whole training run for 'tuner train'."""
    from gaintune.cli.common import InputError, check_out_dir

    with pytest.raises(InputError) as e:
        check_out_dir(Path("/proc/gaintune-out"))
    assert e.value.field == "out" and "is not writable" in e.value.message
