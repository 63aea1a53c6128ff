"""Gain-schedule exports: the C header compiled with gcc reproduces the Python scheduled law on the nonlinear sweep;
the lookup is exact at the breakpoints, linear between and clamped outside; MATLAB and JSON carry the same tables."""

from __future__ import annotations

import ctypes
import json
import re
import shutil
import subprocess
from dataclasses import replace

import numpy as np
import pytest

from gaintune.classical.tuning import tune_classical
from gaintune.export.common import ExportError
from gaintune.export.schedule import (
    SCHEDULE_SUFFIX,
    ScheduleTable,
    render_schedule,
    schedule_to_c,
    schedule_to_json,
    schedule_to_matlab,
    write_schedule_exports,
)
from gaintune.plants import build_plant
from gaintune.plants.library import load_model
from gaintune.spec import load_spec
from gaintune.tuners.schedule import ScheduledPid, ScheduleModel, build_schedule, interp, schedule_table
from gaintune.tuners.schedule.sweep import sweep_levels

needs_gcc = pytest.mark.skipif(shutil.which("gcc") is None, reason="gcc not installed")

DRIVER = """#include "schedule_gains.h"
void run(int T, const double *r, const double *y, const double *x, double *u) {
    gt_state s; gt_reset(&s, x[0]);
    for (int k = 0; k < T; ++k) u[k] = gt_step(&s, r[k], y[k], x[k]);
}
void gains(int n, const double *x, double *kp, double *ki, double *kd) {
    for (int k = 0; k < n; ++k) gt_sched_gains(x[k], kp + k, ki + k, kd + k);
}
"""


def _compile(tmp_path, header: str):
    (tmp_path / "schedule_gains.h").write_text(header)
    (tmp_path / "drv.c").write_text(DRIVER)
    so = tmp_path / "drv.so"
    subprocess.run(
        ["gcc", "-O2", "-std=c99", "-Wall", "-Wextra", "-Werror", "-pedantic", "-shared", "-fPIC", "-o", str(so),
         str(tmp_path / "drv.c"), "-lm"],
        check=True, capture_output=True, text=True,
    )
    return ctypes.CDLL(str(so))


def _ptr(a: np.ndarray):
    return a.ctypes.data_as(ctypes.POINTER(ctypes.c_double))


def _c_run(lib, r: np.ndarray, y: np.ndarray, x: np.ndarray) -> np.ndarray:
    r, y, x = (np.ascontiguousarray(a, dtype=float) for a in (r, y, x))
    u = np.zeros_like(r)
    lib.run(ctypes.c_int(r.size), _ptr(r), _ptr(y), _ptr(x), _ptr(u))
    return u


@pytest.fixture(scope="module")
def tank_schedule():
    spec = load_spec(load_model("water_tank").example_spec())

    def imc_x8(s):  # the IMC rule with 8 times its loop gain: the pump saturates on the sweep's steps
        return {lp: {g: 8.0 * v for g, v in gs.items()} for lp, gs in tune_classical(s, build_plant(s.plant),
                                                                                   "imc").gains.items()}

    return build_schedule(spec, "H0", [2.0, 8.0, 14.0, 20.0], imc_x8, method="imc x 8")


def _synthetic(**changes) -> ScheduleTable:
    """A PID table with every feature on: 2-DOF weights, derivative filter, back-calculation, limits, rate limit."""
    t = ScheduleTable(name="synthetic", var="speed", loop="main", measure="y", type="pid", grid=(0.0, 1.0, 3.0),
                      kp=(2.0, 1.0, 0.5), ki=(1.0, 0.6, 0.2), kd=(0.3, 0.2, 0.05), i0=(0.1, 0.5, 0.9), dt=0.01,
                      b=0.7, c=0.4, aw="back_calculation", N=8.0, lo=-1.0, hi=1.5, rate_limit=20.0,
                      schedule_on="parameter", verdict="pass")
    return replace(t, **changes)


# ------------------------------------------------------------------------------------------------- C


@needs_gcc
def test_schedule_c_header_matches_the_python_law_on_the_nonlinear_sweep(tank_schedule, tmp_path) -> None:
    """The sweep's own r, y, x sequences fed to the compiled header give the Python law's u to 1e-9."""
    model = ScheduleModel(tank_schedule)
    levels = sweep_levels(tank_schedule.grid)
    k_hold = 1500
    ref = np.repeat([model.operating(v)[2] for v in levels], k_hold)
    run = model.run(ScheduledPid(model.table), ref, np.repeat(levels, k_hold))
    assert run.stop_time is None and np.any(run.u == 0.0)  # the pump stops going down: clamping exercised
    lib = _compile(tmp_path, schedule_to_c(replace(model.table, verdict="pass")))
    assert np.max(np.abs(_c_run(lib, run.r, run.y, run.x) - run.u)) < 1e-9


@needs_gcc
@pytest.mark.parametrize("changes", [{}, {"Tf": 0.05, "tracking_time": 0.4}, {"aw": "clamping", "rate_limit": None},
                                     {"aw": "none", "type": "pi", "kd": (0.0, 0.0, 0.0)}])
def test_schedule_c_header_matches_the_python_law_pid_features(tmp_path, changes) -> None:
    t = _synthetic(**changes)
    rng = np.random.default_rng(3)
    n = 3000
    x = np.clip(np.cumsum(rng.normal(0.0, 0.05, n)) + 1.0, -1.0, 4.0)  # wanders below, across and above the grid
    r = np.repeat(rng.uniform(-1.0, 2.0, n // 100), 100)
    y = np.cumsum(rng.normal(0.0, 0.02, n))
    law = ScheduledPid(t)
    law.reset(x[0])
    u_py = np.array([law.step(r[k], y[k], x[k]) for k in range(n)])
    assert np.any(u_py == t.hi) or np.any(u_py == t.lo)  # saturation exercised
    lib = _compile(tmp_path, schedule_to_c(t))
    assert np.max(np.abs(_c_run(lib, r, y, x) - u_py)) < 1e-9


@needs_gcc
def test_schedule_c_lookup_is_exact_at_breakpoints_linear_between_clamped_outside(tmp_path) -> None:
    t = _synthetic()
    lib = _compile(tmp_path, schedule_to_c(t))
    x = np.array([-2.0, 0.0, 0.25, 1.0, 2.0, 2.999, 3.0, 7.0, np.nan])
    kp, ki, kd = np.zeros_like(x), np.zeros_like(x), np.zeros_like(x)
    lib.gains(ctypes.c_int(x.size), _ptr(x), _ptr(kp), _ptr(ki), _ptr(kd))
    assert kp.tolist() == [interp(t.grid, t.kp, v) for v in x]  # bit for bit the Python lookup
    assert kp[1] == 2.0 and kp[3] == 1.0 and kp[6] == 0.5  # exact at the breakpoints
    assert kp[0] == 2.0 and kp[7] == 0.5 and kp[8] == 2.0  # clamped; NaN takes the first entry
    assert kp[2] == pytest.approx(1.75) and kp[4] == pytest.approx(0.75)
    assert ki.tolist() == [interp(t.grid, t.ki, v) for v in x] and kd.tolist() == [interp(t.grid, t.kd, v) for v in x]


@needs_gcc
def test_schedule_c_header_with_hostile_names_compiles(tmp_path) -> None:
    t = _synthetic(name="tank */ #define X ??/", loop="lo\nop */", var="H0 */ int x;", verdict="fail",
                   reasons=("Ms */ too ??= high",))
    text = schedule_to_c(t)
    _compile(tmp_path, text)
    assert "#define GT_VERIFIED 0" in text


def test_schedule_c_header_claims_verified_only_for_a_pass() -> None:
    assert "#define GT_VERIFIED 1" in schedule_to_c(_synthetic())
    assert "#define GT_VERIFIED 0" in schedule_to_c(_synthetic(verdict=None))
    with pytest.raises(ExportError) as exc:
        schedule_to_c(_synthetic(), prefix="1bad")
    assert exc.value.field == "prefix"


# --------------------------------------------------------------------------------------- MATLAB, JSON


def _m_vector(text: str, name: str) -> list[float]:
    m = re.search(rf"^sched\.{name} = \[([^\]]*)\];", text, re.M)
    assert m, name
    return [float(v) for v in m.group(1).split()]


def test_schedule_matlab_has_the_breakpoints_tables_and_a_clamped_lookup() -> None:
    t = _synthetic()
    text = schedule_to_matlab(t)
    assert _m_vector(text, "breakpoints") == list(t.grid)
    assert _m_vector(text, "Kp") == list(t.kp) and _m_vector(text, "Ki") == list(t.ki)
    assert _m_vector(text, "Kd") == list(t.kd) and _m_vector(text, "i0") == list(t.i0)
    assert "interp1(sched.breakpoints, tab, min(max(x, sched.breakpoints(1)), sched.breakpoints(end)), 'linear')" \
        in text
    assert "Ts = 0.01;" in text and "accepted = true;" in text


def test_schedule_json_export_carries_the_tables_and_the_verdict(tank_schedule) -> None:
    t = schedule_table(tank_schedule, verdict="fail", reasons=["H0 = 5 (midpoint): Ms too high"])
    d = json.loads(schedule_to_json(t))
    assert d["breakpoints"] == list(t.grid) and d["tables"]["Kp"] == list(t.kp) and d["tables"]["i0"] == list(t.i0)
    assert d["verdict"] == "fail" and not d["accepted"] and d["reasons"] == ["H0 = 5 (midpoint): Ms too high"]
    assert d["schedule_on"] == "measurement" and d["actuator"]["limits"] == [0.0, 10.0] and d["dt"] == 0.1


def test_write_schedule_exports_withholds_c_and_matlab_unless_passed(tmp_path) -> None:
    written = write_schedule_exports(_synthetic(), tmp_path)
    assert sorted(p.name for p in written) == sorted(SCHEDULE_SUFFIX.values())
    failed = write_schedule_exports(_synthetic(verdict="fail", reasons=("midpoint fails",)), tmp_path)
    assert [p.name for p in failed] == ["schedule_gains.json"]
    assert sorted(failed.withheld) == ["schedule_gains.h", "schedule_gains.m"]
    assert not (tmp_path / "schedule_gains.h").exists() and failed.reason == "midpoint fails"
    with pytest.raises(ExportError) as exc:
        render_schedule(_synthetic(), "yaml")
    assert exc.value.field == "format"


@pytest.mark.parametrize(("changes", "field"), [({"grid": (0.0, 0.0, 1.0)}, "grid"), ({"grid": (1.0,)}, "grid"),
                                                ({"kp": (1.0, 2.0)}, "kp"), ({"ki": (1.0, float("nan"), 1.0)}, "ki"),
                                                ({"type": "lqr"}, "type"), ({"dt": 0.0}, "dt"),
                                                ({"lo": 2.0}, "lo")])
def test_schedule_table_refuses_bad_data_naming_the_field(changes, field) -> None:
    with pytest.raises(ExportError) as exc:
        _synthetic(**changes)
    assert exc.value.field == field
