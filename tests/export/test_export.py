"""Gain exports: the C header compiled with gcc reproduces the simulator's controller output exactly; the
MATLAB objects are the simulator's discrete law; every file carries the verdict at the dt it is exported for."""

from __future__ import annotations

import ctypes
import json
import shutil
import subprocess

import numpy as np
import pytest
import yaml

from gaintune.export import FORMATS, ExportError, export_gains, loop_coefficients
from gaintune.plants.library import load_model
from gaintune.sim import Simulator
from gaintune.spec import load_spec

needs_gcc = pytest.mark.skipif(shutil.which("gcc") is None, reason="gcc not installed")

LAG_GAINS = {"main": {"Kp": 6.0, "Ki": 3.0, "Kd": 4.0}}
DC_GAINS = {"position": {"Kp": 20.0}, "speed": {"Kp": 0.5, "Ki": 20.0}, "current": {"Kp": 5.0, "Ki": 500.0}}

DRIVER = """#include "gains.h"
void run(int T, const double *r, const double *y, double *u) {
    gt_state s; gt_reset(&s);
    for (int k = 0; k < T; ++k) u[k] = gt_step(&s, r[k], y + k * GT_N_LOOPS);
}
"""

LQ_DRIVER = """#include "gains.h"
void run(int T, const double *r, const double *y, const double *x, double *u) {
    gt_state s; gt_reset(&s);
    for (int k = 0; k < T; ++k) u[k] = gt_step(&s, r[k], y + k * GT_N_LOOPS, x + k * GT_N_STATES);
}
"""


def _compile(tmp_path, header: str, driver: str = DRIVER):
    (tmp_path / "gains.h").write_text(header)
    (tmp_path / "drv.c").write_text(driver)
    so = tmp_path / "drv.so"
    subprocess.run(
        ["gcc", "-O2", "-std=c99", "-Wall", "-Wextra", "-Werror", "-pedantic", "-shared", "-fPIC", "-o", str(so),
         str(tmp_path / "drv.c"), "-lm"],
        check=True, capture_output=True, text=True,
    )
    return ctypes.CDLL(str(so))


def _ptr(a: np.ndarray):
    return a.ctypes.data_as(ctypes.POINTER(ctypes.c_double))


def _c_matches_trace(tmp_path, spec, gains) -> float:
    """Feed the simulator's r/y sequences to the compiled header; return max |u_C - u_sim|."""
    sim = Simulator(spec)
    res = sim.run(sim.layout.from_dict(gains)[None], traces=True)
    names = [lp.name for lp in spec.loops]
    r = np.ascontiguousarray(res.traces[f"sp.{names[0]}"][0])
    y = np.ascontiguousarray(np.stack([res.traces[f"y.{n}"][0] for n in names], axis=1))
    u = np.zeros_like(r)
    lib = _compile(tmp_path, export_gains(spec, gains, "c", verdict="pass"))
    lib.run(ctypes.c_int(r.size), _ptr(r), _ptr(y), _ptr(u))
    return float(np.max(np.abs(u - res.traces["u"][0])))


def _lag_variant(**changes):
    d = load_spec(load_model("lag_n").example_spec()).model_dump()
    d["loops"][0].update(b=0.7, c=0.5)  # 2-DOF weights, derivative partly on the setpoint
    d["actuator"]["limits"] = [-2.0, 2.0]  # saturates: exercises anti-windup
    d["scenarios"][0]["disturbance"] = {"kind": "step", "amplitude": 0.5, "time": 10.0}
    for k, v in changes.items():
        if k == "anti_windup":
            d["loops"][0]["anti_windup"] = v
        else:
            d["actuator"][k] = v
    return load_spec(d)


@needs_gcc
def test_c_header_matches_simulator_pid_clamping(tmp_path) -> None:
    spec = _lag_variant()
    assert _c_matches_trace(tmp_path, spec, LAG_GAINS) < 1e-9


@needs_gcc
def test_c_header_matches_simulator_back_calculation_and_rate_limit(tmp_path) -> None:
    spec = _lag_variant(anti_windup="back_calculation", rate_limit=5.0)
    assert _c_matches_trace(tmp_path, spec, LAG_GAINS) < 1e-9


@needs_gcc
def test_c_header_matches_simulator_dc_motor_cascade(tmp_path) -> None:
    spec = load_spec(load_model("dc_motor").example_spec())
    sim = Simulator(spec)
    res = sim.run(sim.layout.from_dict(DC_GAINS)[None])
    assert res.metrics["sat_frac"][0] > 0  # the voltage limit is hit: saturation is exercised
    assert _c_matches_trace(tmp_path, spec, DC_GAINS) < 1e-9


@needs_gcc
def test_c_header_matches_simulator_on_a_biproper_plant(tmp_path) -> None:
    """3(s+10)/(s+2) without a delay: the simulator's feedthrough timing leaves the controller law unchanged."""
    spec = load_spec({"plant": {"tf": {"num": "3*(s+10)", "den": "s+2"}}, "loops": [{"type": "pi"}],
                      "scenario": {"dt": 0.01, "horizon": 3.0}})
    assert _c_matches_trace(tmp_path, spec, {"loop0": {"Kp": 0.1, "Ki": 2.0}}) < 1e-9


@needs_gcc
def test_c_header_ideal_form_matches(tmp_path) -> None:
    d = load_spec(load_model("lag_n").example_spec()).model_dump()
    d["loops"][0].update(form="ideal", gains={}, filter={"N": 8.0, "Tf": None})
    spec = load_spec(d)
    gains = {"main": {"Kp": 2.0, "Ti": 2.5, "Td": 0.6}}
    assert _c_matches_trace(tmp_path, spec, gains) < 1e-9
    c = loop_coefficients(spec, gains)[0]
    assert c["Ki"] == pytest.approx(0.8) and c["Kd"] == pytest.approx(1.2) and c["Tf"] == pytest.approx(0.6 / 8)


@needs_gcc
def test_c_header_lqr_matches_simulator(tmp_path) -> None:
    from scipy.linalg import expm

    dt = 0.01
    A = np.array([[0.0, 1.0], [2.0, -0.5]])
    B = np.array([[0.0], [1.0]])
    spec = load_spec({
        "plant": {"ss": {"A": A.tolist(), "B": B.tolist(), "C": [[1.0, 0.0]], "states": ["p", "v"], "outputs": ["p"]}},
        "loops": [{"type": "lqr"}],
        "actuator": {"limits": [-5, 5]},
        "scenario": {"dt": dt, "horizon": 4.0, "reference": {"time": 0.2, "amplitude": 0.5}},
    })
    gains = {"loop0": {"q_p": 10.0, "q_v": 0.5, "r": 0.2}}
    sim = Simulator(spec)
    res = sim.run(sim.layout.from_dict(gains)[None], traces=True)
    u_sim = res.traces["u"][0]
    # states from the exact ZOH discretisation driven by the simulated u
    M = expm(np.block([[A, B], [np.zeros((1, 3))]]) * dt)
    Ad, Bd = M[:2, :2], M[:2, 2:]
    x = np.zeros((u_sim.size, 2))
    for k in range(1, u_sim.size):
        x[k] = Ad @ x[k - 1] + Bd[:, 0] * u_sim[k - 1]
    r = np.ascontiguousarray(res.traces["sp.loop0"][0])
    y = np.ascontiguousarray(res.traces["y.loop0"][0][:, None])
    u = np.zeros_like(r)
    header = export_gains(spec, gains, "c")
    assert "GT_K[2]" in header
    lib = _compile(tmp_path, header, LQ_DRIVER)
    lib.run(ctypes.c_int(r.size), _ptr(r), _ptr(y), _ptr(np.ascontiguousarray(x)), _ptr(u))
    assert np.max(np.abs(u - u_sim)) < 1e-9


@pytest.mark.parametrize("fmt", FORMATS)
def test_every_format_renders_and_carries_the_verdict(fmt) -> None:
    spec = load_spec(load_model("dc_motor").example_spec())
    text = export_gains(spec, DC_GAINS, fmt, verdict="fail")
    assert "20.0" in text or "20" in text
    if fmt == "json":
        doc = json.loads(text)
        assert doc["verdict"] == "fail" and doc["accepted"] is False and doc["gains"] == DC_GAINS
        assert [lp["name"] for lp in doc["loops"]] == ["position", "speed", "current"]
    elif fmt == "yaml":
        assert text.startswith("# verification: FAILED")
        assert yaml.safe_load(text)["gains"] == DC_GAINS
    elif fmt == "c":
        assert "#define GT_VERIFIED 0" in text and "FAILED" in text
    elif fmt == "matlab":
        assert "C_speed = pid(Kp_speed, Ki_speed, Kd_speed, Tf_speed, Ts, 'IFormula', 'BackwardEuler', 'DFormula', 'BackwardEuler');" in text
        assert "Cstd_current = pidstd(" in text and "FAILED" in text
    else:
        ns: dict = {}
        exec(compile(text, "gains.py", "exec"), ns)  # noqa: S102 - our own generated module
        assert ns["GAINS"] == DC_GAINS and ns["ACCEPTED"] is False


def test_lq_export_gives_K_in_matlab_and_json() -> None:
    spec = load_spec({"plant": {"ss": {"A": [[0, 1], [2, -0.5]], "B": [[0], [1]], "C": [[1, 0]]}}, "loops": [{"type": "lqi"}]})
    gains = {"loop0": {"q_x0": 10.0, "q_x1": 0.5, "q_int": 5.0, "r": 0.2}}
    doc = json.loads(export_gains(spec, gains, "json"))
    assert len(doc["loops"][0]["K"]) == 2 and doc["loops"][0]["Kint"] > 0
    assert "K_loop0 = [" in export_gains(spec, gains, "matlab")


def test_bad_format_and_dt_raise_export_error() -> None:
    spec = load_spec(load_model("lag_n").example_spec())
    with pytest.raises(ExportError, match="format"):
        export_gains(spec, LAG_GAINS, "xml")
    with pytest.raises(ExportError, match="dt"):
        export_gains(spec, LAG_GAINS, "c", dt=0.0)


def test_custom_dt_changes_the_coefficients() -> None:
    spec = load_spec(load_model("lag_n").example_spec())
    assert "#define GT_DT 0.001" in export_gains(spec, LAG_GAINS, "c", dt=0.001)


# ----------------------------------------------------- verdict at the export dt
#
# The DC-motor cascade below passes verification at the model's dt = 1 ms, but the ~300 rad/s current
# loop cannot take the dt/2 sampling delay of a 10 ms (or 50 ms) controller: unstable. Before the fix,
# `gaintune export --dt 0.01` still wrote GT_VERIFIED 1 / PASS for it.

FLIP_GAINS = {"position": {"Kp": 10.0}, "speed": {"Kp": 1.2, "Ki": 14.4}, "current": {"Kp": 3.0, "Ki": 300.0}}


def _verified_result(spec, gains, verdict: str | None = None):
    """A TuneResult holding ``gains`` and their verification (``verdict`` overrides the stored verdict)."""
    from gaintune.search.result import Provenance, TuneResult
    from gaintune.verification import verify

    rep = verify(spec, gains)
    if verdict is not None:
        rep = rep.model_copy(update={"verdict": verdict})
    return TuneResult(spec=spec.model_dump(mode="json"), algo="manual", gains=gains, cost=1.0, verification=rep,
                      provenance=Provenance(spec_hash=spec.content_hash(), seed=0, versions={}))


@pytest.fixture(scope="module")
def motor_spec():
    return load_spec(load_model("dc_motor").example_spec())


@pytest.fixture(scope="module")
def flip_result(motor_spec):
    res = _verified_result(motor_spec, FLIP_GAINS)
    assert res.verdict == "pass"  # at the spec's dt = 1 ms
    return res


@pytest.fixture
def flip_file(flip_result, tmp_path):
    p = tmp_path / "result.json"
    p.write_text(flip_result.model_dump_json())
    return p


def _cli(*args: str):
    from typer.testing import CliRunner

    from gaintune import cli

    return CliRunner().invoke(cli.app, list(args))


def test_flip_case_verdict_really_depends_on_dt(motor_spec) -> None:
    """The premise of the tests below: the same gains pass at 1 ms and are unstable at 10 ms and 50 ms."""
    from gaintune.export import spec_at_dt, verified_dt
    from gaintune.verification import verify

    assert verified_dt(motor_spec) == 0.001
    assert verify(motor_spec, FLIP_GAINS).verdict == "pass"
    for dt in (0.01, 0.05):
        rep = verify(spec_at_dt(motor_spec, dt), FLIP_GAINS)
        assert rep.verdict == "fail" and not rep.stability.stable
        assert rep.reasons[0].startswith("closed loop unstable")
        assert rep.dt == pytest.approx(dt) and rep.sampled  # the sampled loop at the new dt


def test_verdict_at_dt_reuses_the_stored_verdict_only_at_the_verified_dt(motor_spec, flip_result, monkeypatch) -> None:
    import gaintune.verification as gv
    from gaintune.export import verdict_at_dt

    stored = flip_result.verification.model_copy(update={"verdict": "fail", "reasons": ["stored sentinel"]})
    real = gv.verify
    calls = []

    def counting(spec, gains, **kw):
        calls.append(max(sc.dt for sc in spec.scenarios))
        return real(spec, gains, **kw)

    monkeypatch.setattr(gv, "verify", counting)
    verdict, report = verdict_at_dt(motor_spec, FLIP_GAINS, 0.001, stored=stored)
    # same dt: the stored verdict (as JSON), no re-verification
    assert (verdict, report) == ("fail", json.loads(stored.model_dump_json())) and calls == []
    as_json = json.loads(stored.model_dump_json())
    assert verdict_at_dt(motor_spec, FLIP_GAINS, 0.001, stored=as_json)[1] is as_json and calls == []  # a dict as it is
    verdict, report = verdict_at_dt(motor_spec, FLIP_GAINS, 0.01, stored=stored)
    assert calls == [0.01] and verdict == "fail" and "unstable" in report["reasons"][0]
    assert report["dt"] == pytest.approx(0.01)
    verdict, _ = verdict_at_dt(motor_spec, FLIP_GAINS, None, stored=None)  # nothing stored: verified at the spec's dt
    assert verdict == "pass" and calls == [0.01, 0.001]


def test_export_at_coarser_dt_reverifies_and_refuses_unstable(flip_file, flip_result, tmp_path) -> None:
    out = tmp_path / "gains.h"
    res = _cli("export", str(flip_file), "--format", "c", "--dt", "0.01", "-o", str(out))
    assert res.exit_code == 3, res.output
    assert not out.exists() and res.stdout == ""
    msg = res.stderr
    assert "dt = 0.01 s" in msg and "FAILED" in msg and "closed loop unstable" in msg
    assert "verified at dt = 0.001 s" in msg and "Re-tune at dt = 0.01 s" in msg and "--allow-unverified" in msg
    # the library renders the verdict at the exported dt, never the stored PASS
    from gaintune.export import export_result

    header = export_result(flip_result, "c", dt=0.01)
    assert "#define GT_DT 0.01\n" in header and "#define GT_VERIFIED 0\n" in header
    assert '#define GT_VERDICT "fail"' in header and "#define GT_VERIFIED_DT 0.01 " in header
    assert "FAILED at dt = 0.01 s - closed loop unstable" in header and "PASS" not in header


def test_export_allow_unverified_marks_failed_at_new_dt(flip_file, tmp_path) -> None:
    res = _cli("export", str(flip_file), "--format", "c", "--dt", "0.05", "--allow-unverified")
    assert res.exit_code == 0, res.output
    h = res.stdout
    assert "#define GT_DT 0.05\n" in h and "#define GT_VERIFIED 0\n" in h and '#define GT_VERDICT "fail"' in h
    assert "#define GT_VERIFIED_DT 0.05 " in h and '#define GT_VERDICT_REASON "closed loop unstable' in h
    assert "verification: FAILED at dt = 0.05 s" in h
    assert "re-verified at dt = 0.05 s" in res.stderr
    doc = json.loads(_cli("export", str(flip_file), "--dt", "0.01", "--force").stdout)  # --force: hidden old name
    assert doc["verdict"] == "fail" and doc["accepted"] is False
    assert doc["dt"] == 0.01 and doc["verified_dt"] == 0.01 and doc["reasons"][0].startswith("closed loop unstable")
    for fmt, mark in (("yaml", "# verification: FAILED at dt = 0.01 s"), ("matlab", "verdict = 'fail';"),
                      ("python", "ACCEPTED = False")):
        text = _cli("export", str(flip_file), "--format", fmt, "--dt", "0.01", "--allow-unverified").stdout
        assert mark in text and "closed loop unstable" in text, fmt
    helptext = _cli("export", "--help").output
    assert "--allow-unverified" in helptext and "--force" not in helptext


def test_export_at_the_verified_dt_verifies_again_and_passes(flip_file) -> None:
    """The stored verdict is never the authority: the gains are verified again at the verified dt too."""
    res = _cli("export", str(flip_file), "--format", "c")
    assert res.exit_code == 0, res.output
    assert "#define GT_DT 0.001\n" in res.stdout and "#define GT_VERIFIED 1\n" in res.stdout
    assert "#define GT_VERIFIED_DT 0.001 " in res.stdout and "verification: PASS at dt = 0.001 s" in res.stdout
    assert "re-verified at dt = 0.001 s: PASS" in res.stderr


def test_export_at_finer_dt_reverifies_and_passes(flip_file) -> None:
    res = _cli("export", str(flip_file), "--format", "json", "--dt", "0.0005")
    assert res.exit_code == 0, res.output
    doc = json.loads(res.stdout)
    assert doc["verdict"] == "pass" and doc["accepted"] is True and doc["dt"] == doc["verified_dt"] == 0.0005
    assert "re-verified at dt = 0.0005 s" in res.stderr and "PASS" in res.stderr


def test_export_gains_never_claims_a_verdict_from_another_dt(motor_spec) -> None:
    """The low-level renderer: a verdict obtained at 1 ms is not written as the verdict of a 10 ms file."""
    h = export_gains(motor_spec, FLIP_GAINS, "c", verdict="pass", dt=0.01)
    assert "#define GT_VERIFIED 0\n" in h and '#define GT_VERDICT "unverified"' in h
    assert "#define GT_VERIFIED_DT 0.001 " in h and "NOT verified at dt = 0.01 s" in h
    doc = json.loads(export_gains(motor_spec, FLIP_GAINS, "json", verdict="pass", dt=0.01))
    assert doc["verdict"] == "unverified" and doc["accepted"] is False and doc["verified_dt"] == 0.001
    doc = json.loads(export_gains(motor_spec, FLIP_GAINS, "json", verdict="pass"))  # default dt: the verified one
    assert doc["verdict"] == "pass" and doc["accepted"] is True and doc["dt"] == doc["verified_dt"] == 0.001


def test_export_dt_out_of_range_raises_input_error_naming_dt(motor_spec, flip_file) -> None:
    from gaintune.errors import GaintuneError
    from gaintune.export import spec_at_dt
    from gaintune.spec import MAX_STEPS

    with pytest.raises(ExportError, match="steps") as exc:
        spec_at_dt(motor_spec, 2.0 / (MAX_STEPS + 10))
    assert isinstance(exc.value, GaintuneError) and exc.value.field == "dt" and "export at dt >=" in exc.value.message
    with pytest.raises(ExportError, match="fewer than 2 samples") as exc:
        spec_at_dt(motor_spec, 1.5)  # horizon 2 s
    assert exc.value.field == "dt" and "export at dt <= 1 s" in exc.value.message
    assert spec_at_dt(motor_spec, 0.001) is motor_spec
    copy = spec_at_dt(motor_spec, 0.004)
    assert copy.scenarios[0].dt == 0.004 and copy.scenarios[0].horizon == motor_spec.scenarios[0].horizon
    res = _cli("export", str(flip_file), "--format", "c", "--dt", "1e-7")
    assert res.exit_code == 2 and res.stderr.startswith("error: dt: ") and "steps" in res.stderr
    res = _cli("export", str(flip_file), "--format", "c", "--dt", "0")
    assert res.exit_code == 2 and "error: dt: sample time must be > 0" in res.stderr


def test_mixed_dt_spec_is_reverified_at_the_largest_dt(motor_spec, monkeypatch) -> None:
    """Scenarios at 1 ms and 2 ms: the stored verdict's nonlinear check ran partly at 1 ms, so a 2 ms export re-verifies."""
    import gaintune.verification as gv
    from gaintune.export import verdict_at_dt

    d = motor_spec.model_dump()
    d["scenarios"].append({**d["scenarios"][0], "name": "coarse", "dt": 0.002})
    spec = load_spec(d)
    calls = []
    real = gv.verify
    monkeypatch.setattr(gv, "verify", lambda s, g, **kw: calls.append([sc.dt for sc in s.scenarios]) or real(s, g, **kw))
    verdict, _ = verdict_at_dt(spec, FLIP_GAINS, 0.002, stored={"verdict": "pass", "robust": None})
    assert calls == [[0.002, 0.002]] and verdict in ("pass", "fail")


def test_write_exports_withholds_c_and_matlab_for_failing_gains(motor_spec, flip_result, tmp_path, monkeypatch) -> None:
    from io import StringIO

    from rich.console import Console

    from gaintune import cli
    from gaintune.export import write_exports

    bad = _verified_result(motor_spec, {"position": {"Kp": 20.0}, "speed": {"Kp": 0.5, "Ki": 20.0},
                                        "current": {"Kp": 5.0, "Ki": 500.0}})
    assert bad.verdict == "fail"
    out = tmp_path / "bad"
    out.mkdir()
    (out / "gains.h").write_text("/* stale header from an earlier, passing run */")
    paths = write_exports(bad, out, formats=("json", "yaml", "c", "matlab", "python"))
    assert sorted(p.name for p in paths) == ["gains.json", "gains.yaml"]
    assert sorted(p.name for p in out.iterdir()) == ["gains.json", "gains.yaml"]  # stale gains.h removed too
    assert paths.withheld == ["gains.h", "gains.m", "gains.py"] and [p.name for p in paths.removed] == ["gains.h"]
    assert paths.verdict == "fail" and paths.reason == bad.verification.reasons[0]
    assert json.loads((out / "gains.json").read_text())["accepted"] is False
    assert yaml.safe_load((out / "gains.yaml").read_text())["accepted"] is False
    # passing gains: everything is written
    good = write_exports(flip_result, tmp_path / "good")
    assert sorted(p.name for p in good) == ["gains.h", "gains.json", "gains.m", "gains.yaml"] and good.withheld == []
    assert "#define GT_VERIFIED 1\n" in (tmp_path / "good" / "gains.h").read_text()
    # passing at 1 ms but written for a 10 ms controller: withheld as well
    coarse = write_exports(flip_result, tmp_path / "coarse", dt=0.01)
    assert sorted(p.name for p in coarse) == ["gains.json", "gains.yaml"] and "unstable" in coarse.reason
    # the CLI's out-dir writer says what it withheld and why
    import gaintune.report as report_mod

    monkeypatch.setattr(report_mod, "render_report", lambda result, path: path.write_text("<html></html>") or path)
    buf = StringIO()
    cli._write_outputs(bad, tmp_path / "cli", console=Console(file=buf, width=400))
    text = buf.getvalue()
    assert "not written: gains.h, gains.m" in text and "verdict fail" in text and bad.verification.reasons[0] in text
    assert not (tmp_path / "cli" / "gains.h").exists() and (tmp_path / "cli" / "gains.json").exists()


def _lag_2dof_spec():
    d = load_spec(load_model("lag_n").example_spec()).model_dump()
    d["loops"][0].update(b=0.7, c=0.5)
    d["actuator"]["limits"] = None  # linear: the transfer functions are the whole law
    d["scenarios"][0]["reference"]["time"] = 1.0  # r[-1] = r[0] = 0: lfilter's zero initial state is the simulator's
    return load_spec(d)


def _tf_of(text: str, name: str):
    import re

    m = re.search(rf"^{name} = tf\(\[([^\]]*)\], \[([^\]]*)\], Ts\);", text, re.M)
    assert m, f"{name} not found"
    return [float(x) for x in m.group(1).split()], [float(x) for x in m.group(2).split()]


def test_matlab_export_is_discrete_with_ts() -> None:
    from scipy.signal import lfilter

    spec = _lag_2dof_spec()
    sim = Simulator(spec)
    res = sim.run(sim.layout.from_dict(LAG_GAINS)[None], traces=True)
    dt = spec.scenarios[0].dt
    text = export_gains(spec, LAG_GAINS, "matlab", verdict="pass")
    forms = "'IFormula', 'BackwardEuler', 'DFormula', 'BackwardEuler'"
    assert f"Ts = {dt!r};" in text and f"verified_Ts = {dt!r};" in text and "verdict = 'pass';" in text
    assert f"C_main = pid2(Kp_main, Ki_main, Kd_main, Tf_main, 0.7, 0.5, Ts, {forms});" in text
    assert f"Cfb_main = pid(Kp_main, Ki_main, Kd_main, Tf_main, Ts, {forms});" in text
    assert f"Ts, {forms});  % ideal form" in text and "gt_main = struct('Kp', 6.0" in text
    assert "pid(Kp_main, Ki_main, Kd_main, Tf_main);" not in text  # no continuous-time object left
    # the emitted discrete transfer functions reproduce the simulator's controller output exactly
    r, y, u = res.traces["sp.main"][0], res.traces["y.main"][0], res.traces["u"][0]
    (ny, dy), (nr, dr) = _tf_of(text, "Cy_main"), _tf_of(text, "Cr_main")
    assert len(ny) == len(dy) == 3  # PID: (z - 1)((Tf + Ts) z - Tf)
    u_tf = lfilter(nr, dr, r) - lfilter(ny, dy, y)
    assert np.max(np.abs(u_tf - u)) < 1e-9 * max(1.0, np.max(np.abs(u)))
    # 1-DOF loops (b = 1, no derivative) use pid; a PID with the default c = 0 (derivative on y) needs pid2
    motor = export_gains(load_spec(load_model("dc_motor").example_spec()), DC_GAINS, "matlab")
    assert f"C_current = pid(Kp_current, Ki_current, Kd_current, Tf_current, Ts, {forms});" in motor
    assert "= pid2(" not in motor
    lag = export_gains(load_spec(load_model("lag_n").example_spec()), LAG_GAINS, "matlab")
    assert f"C_main = pid2(Kp_main, Ki_main, Kd_main, Tf_main, 1.0, 0.0, Ts, {forms});" in lag


def test_stored_verdict_of_another_spec_content_was_reused_at_export():
    """Regression: a stored report vouched for the verdict whatever spec it was computed on. A result
    written before a requirement or default changed (e.g. the noise-sensitivity limit) must be re-verified."""
    from gaintune.export.verdict import stored_verdict_holds, verified_dt
    from gaintune.spec import load_spec

    spec = load_spec({"plant": {"tf": {"num": [1], "den": "(s+1)^3"}}, "loops": [{"type": "pi"}],
                      "scenario": {"dt": 0.05, "horizon": 10}})
    dt = verified_dt(spec)
    assert stored_verdict_holds(spec, dt, {"verdict": "pass", "spec_hash": spec.content_hash()})
    assert not stored_verdict_holds(spec, dt, {"verdict": "pass", "spec_hash": "0" * 64})
    assert not stored_verdict_holds(spec, dt, {"verdict": "pass"})  # no hash: not vouched for
