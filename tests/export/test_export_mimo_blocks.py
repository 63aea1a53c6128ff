"""Exports of tuned static blocks: the C header with the tuned decoupler and the reference feedforward,
compiled with gcc, reproduces the MIMO simulator's actuator traces; the payload and the MATLAB file
carry the tuned W, FF and the tuned entries; a gain set round-trips through the payload."""

from __future__ import annotations

import ctypes
import json
import shutil
import subprocess
from typing import Any

import numpy as np
import pytest

from gaintune.export import export_gains
from gaintune.plants.library import load_model
from gaintune.sim import Simulator
from gaintune.spec import load_spec

needs_gcc = pytest.mark.skipif(shutil.which("gcc") is None, reason="gcc not installed")

DRIVER = """#include "gains.h"
void run(int T, const double *r, const double *y, double *u) {
    gt_state s; gt_reset(&s);
    for (int k = 0; k < T; ++k) gt_step(&s, r + k * GT_N_CHAINS, y + k * GT_N_OUTPUTS, u + k * GT_N_INPUTS);
}
"""
TOL = 1e-9

#: Wood-Berry with a static decoupler whose off-diagonal entries are tuned, and a feedforward from
#: the xD reference to the steam flow S.
GAINS = {"xD": {"Kp": 0.6, "Ki": 0.08}, "xB": {"Kp": -0.12, "Ki": -0.01},
         "decoupler": {"d_R_S": 1.2, "d_S_R": 0.25}, "feedforward": {"ff_xD_S": 0.05}}


def _spec(anti_windup: str | None = None, **changes: Any):
    d = load_model("wood_berry").example_spec()
    for lp in d["loops"] if anti_windup else []:
        lp["anti_windup"] = anti_windup
    d["scenarios"] = [{**sc, "horizon": 60.0} for sc in d["scenarios"]]
    d["decoupler"] = {"inputs": ["R", "S"], "matrix": [[1.0, {"bounds": [0.2, 3.0]}], [{"bounds": [0.05, 1.0]}, 1.0]]}
    d["feedforward"] = [{"loop": "xD", "input": "S", "gain": {"value": 0.05, "bounds": [0.001, 1.0]}}]
    d.update(changes)
    return load_spec(d)


def _c_vs_sim(tmp_path, spec, gains) -> float:
    """Every scenario's simulated references and outputs fed to the compiled header; max |u_C - u_sim|."""
    sim = Simulator(spec)
    (tmp_path / "gains.h").write_text(export_gains(spec, gains, "c", verdict="pass"))
    (tmp_path / "drv.c").write_text(DRIVER)
    so = tmp_path / "drv.so"
    subprocess.run(["gcc", "-O2", "-std=c99", "-Wall", "-Wextra", "-Werror", "-pedantic", "-shared", "-fPIC", "-o",
                    str(so), str(tmp_path / "drv.c"), "-lm"], check=True, capture_output=True, text=True)
    lib = ctypes.CDLL(str(so))
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
        ptr = ctypes.POINTER(ctypes.c_double)
        lib.run(ctypes.c_int(T), r.ctypes.data_as(ptr), np.ascontiguousarray(y).ctypes.data_as(ptr),
                u.ctypes.data_as(ptr))
        u_sim = np.stack([res.traces[f"u.{n}"][0] for n in mimo.input_names], axis=1)
        assert np.all(np.isfinite(u_sim)) and np.ptp(u_sim) > 0
        worst = max(worst, float(np.max(np.abs(u - u_sim))))
    return worst


@needs_gcc
def test_c_header_with_tuned_decoupler_and_feedforward_matches_the_simulator(tmp_path) -> None:
    spec = _spec()
    text = export_gains(spec, GAINS, "c", verdict="pass")
    assert "#define GT_DECOUPLER_D_R_S 1.2" in text and "#define GT_FEEDFORWARD_FF_XD_S 0.05" in text
    assert "static const double GT_FF[GT_N_INPUTS][GT_N_CHAINS]" in text
    assert _c_vs_sim(tmp_path, spec, GAINS) <= TOL


@needs_gcc
def test_c_header_feedforward_with_saturation_and_back_calculation_matches_the_simulator(tmp_path) -> None:
    """A feedforward on an input its loop drives directly (no decoupler), saturated, back-calculation:
    the loop's integrator tracks the applied value less the feedforward, in the header as in the kernel."""
    spec = _spec("back_calculation", decoupler=None,
                 actuators={"R": {"limits": [-0.4, 0.4]}, "S": {"limits": [-0.3, 0.3]}},
                 feedforward=[{"loop": "xB", "input": "S", "gain": -0.2}, {"loop": "xD", "input": "R", "gain": 0.3}])
    gains = {k: v for k, v in GAINS.items() if k in ("xD", "xB")}
    assert _c_vs_sim(tmp_path, spec, gains) <= TOL


@needs_gcc
def test_c_header_clamp_ignoring_feedforward_saturation_follows_the_fixed_kernel(tmp_path) -> None:
    """Clamping loops driving inputs directly, a feedforward that saturates R on the xD step (issue 28): the
    header holds the integrator when the input saturates on the loop's output plus the feedforward, as the
    kernel now does (the old header, judging the loop's own limits only, is off by far more than TOL)."""
    spec = _spec("clamping", decoupler=None,
                 actuators={"R": {"limits": [-0.4, 0.4]}, "S": {"limits": [-0.3, 0.3]}},
                 feedforward=[{"loop": "xB", "input": "S", "gain": -0.2}, {"loop": "xD", "input": "R", "gain": 0.3}])
    gains = {k: v for k, v in GAINS.items() if k in ("xD", "xB")}
    assert "hold = ts != tot" in export_gains(spec, gains, "c", verdict="pass")
    assert _c_vs_sim(tmp_path, spec, gains) <= TOL


def test_payload_and_matlab_carry_the_tuned_w_and_feedforward() -> None:
    spec = _spec()
    p = json.loads(export_gains(spec, GAINS, "json", verdict="pass"))
    assert p["decoupler"] == {"inputs": ["R", "S"], "matrix": [[1.0, 1.2], [0.25, 1.0]]}
    assert p["W"] == [[1.0, 1.2], [0.25, 1.0], [0.0, 0.0]]
    assert p["FF"] == [[0.0, 0.0], [0.05, 0.0], [0.0, 0.0]]  # inputs R, S, F x chains xD, xB
    assert p["feedforward"] == [{"loop": "xD", "input": "S", "input_index": 1, "chain": 0, "gain": 0.05}]
    assert p["blocks"] == {"decoupler": {"d_R_S": 1.2, "d_S_R": 0.25}, "feedforward": {"ff_xD_S": 0.05}}
    m = export_gains(spec, GAINS, "matlab", verdict="pass")
    for line in ("W = [1.0 1.2; 0.25 1.0; 0.0 0.0];  % u = W*v (the decoupler)",
                 "FF = [0.0 0.0; 0.05 0.0; 0.0 0.0];",
                 "gt_decoupler = struct('d_R_S', 1.2, 'd_S_R', 0.25);",
                 "gt_feedforward = struct('ff_xD_S', 0.05);"):
        assert line in m, line
    assert "ARCHITECTURE = {" in export_gains(spec, GAINS, "python", verdict="pass")


def test_exported_gain_set_round_trips_through_the_payload() -> None:
    """The payload's loop gains and tuned entries, read back as a gain set, give the same full vector."""
    spec = _spec()
    p = json.loads(export_gains(spec, GAINS, "json", verdict="pass"))
    back = {lp["name"]: lp["gains"] for lp in p["loops"]} | p["blocks"]
    sim = Simulator(spec)
    np.testing.assert_array_equal(sim.layout.from_dict(back), sim.layout.from_dict(GAINS))


def test_export_without_blocks_has_no_feedforward_table() -> None:
    spec = _spec(decoupler=None, feedforward=None)
    gains = {k: v for k, v in GAINS.items() if k in ("xD", "xB")}
    text = export_gains(spec, gains, "c", verdict="pass")
    assert "GT_FF" not in text and "s->ff" not in text and "GT_DECOUPLER" not in text
    p = json.loads(export_gains(spec, gains, "json", verdict="pass"))
    assert "FF" not in p and "blocks" not in p and p["decoupler"] is None
