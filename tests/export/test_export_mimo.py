"""MIMO exports: the C header of the whole architecture, compiled with gcc, reproduces the MIMO simulator's
actuator traces; the MATLAB file and the payload carry every loop and the wiring; the verdict gate holds."""

from __future__ import annotations

import ctypes
import json
import shutil
import subprocess

import numpy as np
import pytest
from typer.testing import CliRunner

from gaintune import cli
from gaintune.export import export_gains, write_exports
from gaintune.plants.library import load_model
from gaintune.sim import Simulator
from gaintune.spec import load_spec

needs_gcc = pytest.mark.skipif(shutil.which("gcc") is None, reason="gcc not installed")

#: Luyben's BLT tuning of the Wood-Berry column (Ki = Kc/Ti).
BLT = {"xD": {"Kp": 0.375, "Ki": 0.375 / 8.29}, "xB": {"Kp": -0.075, "Ki": -0.075 / 23.6}}

DRIVER = """#include "gains.h"
void run(int T, const double *r, const double *y, double *u) {
    gt_state s; gt_reset(&s);
    for (int k = 0; k < T; ++k) gt_step(&s, r + k * GT_N_CHAINS, y + k * GT_N_OUTPUTS, u + k * GT_N_INPUTS);
}
"""

#: Largest |u_C - u_sim| accepted: the header runs the kernel's arithmetic, step for step.
TOL = 1e-9


def _wood_berry(**changes) -> dict:
    d = load_model("wood_berry").example_spec()
    d["scenarios"].append({"name": "feed", "dt": 0.1, "horizon": 150.0,
                           "disturbance": {"kind": "step", "amplitude": 0.3, "time": 20.0, "entry": "input",
                                           "input": "F"}})
    d.update(changes)
    return d


def _compile(tmp_path, header: str):
    tmp_path.mkdir(parents=True, exist_ok=True)
    (tmp_path / "gains.h").write_text(header)
    (tmp_path / "drv.c").write_text(DRIVER)
    so = tmp_path / "drv.so"
    subprocess.run(["gcc", "-O2", "-std=c99", "-Wall", "-Wextra", "-Werror", "-pedantic", "-shared", "-fPIC", "-o",
                    str(so), str(tmp_path / "drv.c"), "-lm"], check=True, capture_output=True, text=True)
    return ctypes.CDLL(str(so))


def _ptr(a: np.ndarray):
    return a.ctypes.data_as(ctypes.POINTER(ctypes.c_double))


def _c_vs_sim(tmp_path, spec, gains) -> float:
    """Feed every scenario's simulated references and outputs to the compiled header; max |u_C - u_sim| over all."""
    sim = Simulator(spec)
    lib = _compile(tmp_path, export_gains(spec, gains, "c", verdict="pass"))
    arch, mimo = sim.arch, sim.mimo
    names = [spec.loop_names[i] for i in arch.order]
    chains = [names[p] for p in arch.roots]
    worst = 0.0
    for k in range(len(spec.scenarios)):
        res = sim.run(sim.layout.from_dict(gains)[None], scenario=k, traces=True)
        T = res.t.size
        r = np.ascontiguousarray(np.stack([res.traces[f"sp.{c}"][0] for c in chains], axis=1))
        y = np.zeros((T, len(mimo.outputs)))
        for pos, nm in enumerate(names):
            y[:, arch.meas[pos]] = res.traces[f"y.{nm}"][0]
        u = np.zeros((T, len(mimo.inputs)))
        lib.run(ctypes.c_int(T), _ptr(r), _ptr(np.ascontiguousarray(y)), _ptr(u))
        u_sim = np.stack([res.traces[f"u.{n}"][0] for n in mimo.input_names], axis=1)
        assert np.all(np.isfinite(u_sim)) and np.ptp(u_sim) > 0  # the loops really act
        worst = max(worst, float(np.max(np.abs(u - u_sim))))
    return worst


@needs_gcc
def test_c_header_matches_mimo_simulator_wood_berry_blt(tmp_path) -> None:
    spec = load_spec(_wood_berry())
    assert _c_vs_sim(tmp_path, spec, BLT) <= TOL


@needs_gcc
def test_c_header_matches_with_limits_rate_limits_decoupler_and_back_calculation(tmp_path) -> None:
    """Saturation (clamping and back-calculation), rate limits and a static decoupler: every branch of the step."""
    d = _wood_berry(actuators={"R": {"limits": [-0.4, 0.4], "rate_limit": 0.05}, "S": {"limits": [-0.3, 0.3]}})
    d["loops"][1]["anti_windup"] = "back_calculation"
    gains = {"xD": {"Kp": 0.6, "Ki": 0.08}, "xB": {"Kp": -0.12, "Ki": -0.01}}
    assert _c_vs_sim(tmp_path / "sat", load_spec(d), gains) <= TOL
    d["decoupler"] = {"inputs": ["R", "S"], "matrix": [[1.0, 18.9 / 12.8 * 0.5], [6.6 / 19.4 * 0.5, 1.0]]}
    assert _c_vs_sim(tmp_path / "dec", load_spec(d), gains) <= TOL


@needs_gcc
def test_c_header_matches_a_cascade_in_the_loop_graph(tmp_path) -> None:
    """An outer loop driving another loop's setpoint (PID with a filtered derivative and setpoint weights)."""
    d = _wood_berry()
    d["loops"] = [
        {"name": "outer", "measure": "xD", "drives": "loop:inner", "type": "pid", "b": 0.8, "c": 0.5,
         "output_limits": [-2.0, 2.0]},
        {"name": "inner", "measure": "xB", "drives": "S", "type": "pi"},
    ]
    d["scenarios"] = [{"name": "step", "dt": 0.1, "horizon": 150.0,
                       "reference": {"loop": "outer", "kind": "step", "amplitude": 1.0}}]
    d["requirements"] = {"gm_min_db": None, "pm_min_deg": None, "ms_max": None, "mks_max": None}
    gains = {"outer": {"Kp": 0.3, "Ki": 0.02, "Kd": 0.5}, "inner": {"Kp": -0.1, "Ki": -0.01}}
    spec = load_spec(d)
    text = export_gains(spec, gains, "c", verdict="pass")
    assert "static const int GT_PARENT[2] = {-1, 0};" in text  # inner takes outer's output as its setpoint
    assert _c_vs_sim(tmp_path, spec, gains) <= TOL


def test_matlab_and_payload_carry_every_loop_and_the_wiring() -> None:
    d = _wood_berry(decoupler={"inputs": ["R", "S"], "matrix": [[1.0, 0.7], [0.2, 1.0]]})
    spec = load_spec(d)
    m = export_gains(spec, BLT, "matlab", verdict="pass")
    for line in ("loop_names = {'xD', 'xB'};", "drives = {'R', 'S'};", "measures = {'xD', 'xB'};",
                 "parent = [0 0];", "W = [1.0 0.7; 0.2 1.0; 0.0 0.0];", "input_names = {'R', 'S', 'F'};"):
        assert line in m, line
    assert "gt_xD = struct('Kp', 0.375" in m and "Cy_xB = tf(" in m
    p = json.loads(export_gains(spec, BLT, "json", verdict="pass"))
    assert p["evaluation_order"] == ["xD", "xB"] and p["chains"] == ["xD", "xB"]
    assert [lp["drives"] for lp in p["loops"]] == ["R", "S"] and p["decoupler"]["matrix"] == [[1.0, 0.7], [0.2, 1.0]]
    assert [i["driven_by"] for i in p["inputs"]] == ["xD", "xB", None]
    assert "ARCHITECTURE = {" in export_gains(spec, BLT, "python", verdict="pass")


def _mimo_result(spec, gains):
    from gaintune.search.result import Provenance, TuneResult

    return TuneResult(spec=spec.model_dump(mode="json"), algo="manual", gains=gains, cost=1.0, verification=None,
                      provenance=Provenance(spec_hash=spec.content_hash(), seed=0, versions={}))


def test_unverified_mimo_gains_are_not_written_as_firmware(tmp_path) -> None:
    """Gains the MIMO verdict fails (BLT's input-side Ms 2.47 against the limit 2.1) are not written as
    firmware: gains.h and gains.m are withheld, naming the failed requirement."""
    spec = load_spec(_wood_berry())
    res = _mimo_result(spec, BLT)
    paths = write_exports(res, tmp_path)
    assert sorted(p.name for p in paths) == ["gains.json", "gains.yaml"]
    assert paths.withheld == ["gains.h", "gains.m"] and "mimo_ms_max" in paths.reason
    doc = json.loads((tmp_path / "gains.json").read_text())
    assert doc["accepted"] is False and doc["verdict"] != "pass" and doc["architecture"] == "mimo"
    (tmp_path / "result.json").write_text(res.model_dump_json())
    run = CliRunner().invoke(cli.app, ["export", str(tmp_path / "result.json"), "-f", "c"])
    assert run.exit_code == 3 and "not exporting" in run.output and "Traceback" not in run.output
    run = CliRunner().invoke(cli.app, ["export", str(tmp_path / "result.json"), "-f", "c", "--allow-unverified"])
    assert run.exit_code == 0 and "#define GT_VERIFIED 0" in run.output and "GT_N_CHAINS 2" in run.output


def test_siso_export_unchanged_by_the_mimo_dispatch() -> None:
    spec = load_spec(load_model("dc_motor").example_spec())
    gains = {"position": {"Kp": 20.0}, "speed": {"Kp": 0.5, "Ki": 20.0}, "current": {"Kp": 5.0, "Ki": 500.0}}
    text = export_gains(spec, gains, "c", verdict="pass")
    assert "static inline double gt_step(gt_state *s, double r, const double y[GT_N_LOOPS])" in text
    assert "GT_N_CHAINS" not in text and "ARCHITECTURE" not in export_gains(spec, gains, "python", verdict="pass")


@needs_gcc
def test_c_header_matches_mimo_simulator_quadruple_tank_with_tied_gains(tmp_path) -> None:
    """A state-space plant with named inputs, and one tuned Kp serving both loops (a tie)."""
    d = load_model("quadruple_tank_min").example_spec()
    d["ties"] = [["y1.Kp", "y2.Kp"]]
    spec = load_spec(d)
    gains = {"y1": {"Kp": 3.0, "Ki": 0.1}, "y2": {"Kp": 3.0, "Ki": 0.0675}}
    text = export_gains(spec, gains, "c", verdict="pass")
    assert "#define GT_Y1_KP 3.0" in text and "#define GT_Y2_KP 3.0" in text
    assert _c_vs_sim(tmp_path, spec, gains) <= TOL
