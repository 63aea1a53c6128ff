"""The water-tank schedule measurement: ``python -m gaintune.tuners.schedule.measure [--grid 2:20:10] [--out DIR]``.

Builds the schedule of the water tank's example spec over ``H0`` with a quick CMA-ES search
per grid point (:func:`~gaintune.tuners.schedule.compare.cma_gains_at`; a trained tuner will
answer these later), fits the midpoints (:func:`~gaintune.tuners.schedule.fit.fit_midpoints`),
verifies it (:func:`~gaintune.tuners.schedule.check.verify_schedule`), designs the best single
fixed PI over the range (:func:`~gaintune.tuners.schedule.compare.best_fixed_pi`), verifies that
at every level too, and compares the two on the level step
(:func:`~gaintune.tuners.schedule.compare.compare_fixed`). With gcc on the PATH, the exported C
header is compiled and fed the sweep's signals. Writes ``schedule_water_tank.json`` and ``.md``.
"""

from __future__ import annotations

import argparse
import ctypes
import json
import shutil
import subprocess
import tempfile
import time
from pathlib import Path
from typing import Any

import numpy as np

from gaintune.export.schedule import schedule_to_c
from gaintune.files import write_atomic
from gaintune.plants.library import load_model
from gaintune.spec import load_spec
from gaintune.tuners.schedule.check import verify_schedule
from gaintune.tuners.schedule.compare import POINT_BUDGET, best_fixed_pi, cma_gains_at, compare_fixed
from gaintune.tuners.schedule.fit import fit_midpoints
from gaintune.tuners.schedule.law import ScheduledPid
from gaintune.tuners.schedule.sweep import ScheduleModel, sweep_levels
from gaintune.tuners.schedule.table import GainSchedule, build_schedule, parse_grid, schedule_table, spec_at

__all__ = ["measure_water_tank", "c_sweep_mismatch", "main"]

_DRIVER = """#include "schedule_gains.h"
void run(int T, const double *r, const double *y, const double *x, double *u) {
    gt_state s; gt_reset(&s, x[0]);
    for (int k = 0; k < T; ++k) u[k] = gt_step(&s, r[k], y[k], x[k]);
}
"""


def c_sweep_mismatch(schedule: GainSchedule, hold: float | None = None) -> float | None:
    """max |u_C - u_Python| over the sweep, the exported header compiled with gcc; None without gcc."""
    if shutil.which("gcc") is None:
        return None
    model = ScheduleModel(schedule)
    k_hold = int(round((hold or model.spec.scenarios[0].resolved_horizon) / model.dt))
    levels = sweep_levels(schedule.grid)
    ref = np.repeat([model.operating(v)[2] for v in levels], k_hold)
    run = model.run(ScheduledPid(model.table), ref, np.repeat(levels, k_hold))
    with tempfile.TemporaryDirectory() as tmp:
        d = Path(tmp)
        (d / "schedule_gains.h").write_text(schedule_to_c(model.table))
        (d / "drv.c").write_text(_DRIVER)
        subprocess.run(["gcc", "-O2", "-std=c99", "-Wall", "-Werror", "-shared", "-fPIC", "-o", str(d / "drv.so"),
                        str(d / "drv.c"), "-lm"], check=True, capture_output=True)
        lib = ctypes.CDLL(str(d / "drv.so"))
        u = np.zeros(run.r.size)
        args = [np.ascontiguousarray(a, dtype=float) for a in (run.r, run.y, run.x)] + [u]
        lib.run(ctypes.c_int(u.size), *(a.ctypes.data_as(ctypes.POINTER(ctypes.c_double)) for a in args))
    return float(np.max(np.abs(u - run.u)))


def measure_water_tank(grid: str = "2:20:10", budget: int = POINT_BUDGET, seed: int = 0) -> dict[str, Any]:
    """Every figure of the measurement (module docstring) as JSON-safe data."""
    from gaintune.verification import verify

    spec = load_spec(load_model("water_tank").example_spec())
    t0 = time.perf_counter()
    raw = build_schedule(spec, "H0", parse_grid(grid), cma_gains_at(budget, seed),
                         method=f"CMA-ES per grid point, {budget} simulations, seed {seed}")
    t_build = time.perf_counter() - t0
    schedule, notes = fit_midpoints(raw)
    t_fit = time.perf_counter() - t0 - t_build
    check = verify_schedule(schedule)
    raw_check = verify_schedule(raw, sweep=False)
    fixed = best_fixed_pi(schedule, seed=seed)
    fixed_ok = [verify(spec_at(schedule.tuning_spec, "H0", v), fixed.gains).verdict for v in fixed.levels]
    comparison = compare_fixed(schedule, fixed.gains)
    return {
        "grid": schedule.grid, "method": schedule.method, "build_wall_s": t_build, "fit_wall_s": t_fit,
        "fit_notes": notes, "fitted": schedule.fitted, "gains": schedule.gains,
        "unfitted_counts": {"grid": raw_check.count("grid"), "midpoint": raw_check.count("midpoint"),
                            "reasons": raw_check.reasons},
        "verification": {"summary": check.summary(), "grid": check.count("grid"),
                         "midpoint": check.count("midpoint"), "reasons": check.reasons,
                         "sweep": check.sweep.model_dump()},
        "fixed": {**fixed.model_dump(), "verified_levels": [fixed_ok.count("pass"), len(fixed_ok)]},
        "comparison": [{**lv.model_dump(), "ratio": lv.ratio, "better": lv.better} for lv in comparison.levels],
        "comparison_step": comparison.step,
        "better_everywhere": comparison.better_everywhere,
        "c_sweep_max_abs_diff": c_sweep_mismatch(schedule),
        "schedule": json.loads(schedule.to_json()),
        "table": schedule_table(schedule, "pass" if check.passed else "fail", check.reasons).to_dict(),
    }


def to_markdown(m: dict[str, Any]) -> str:
    """The measurement's tables."""
    v, f = m["verification"], m["fixed"]
    lines = [
        f"# Water tank gain schedule over H0 = {m['grid'][0]:g} .. {m['grid'][-1]:g} m ({len(m['grid'])} points)",
        "",
        f"Per-point gains: {m['method']} ({m['build_wall_s']:.1f} s). Midpoint fit: "
        f"{'; '.join(m['fit_notes']) or 'none needed'} ({m['fit_wall_s']:.1f} s).",
        f"Before the fit: grid points {m['unfitted_counts']['grid'][0]}/{m['unfitted_counts']['grid'][1]}, "
        f"midpoints {m['unfitted_counts']['midpoint'][0]}/{m['unfitted_counts']['midpoint'][1]} passed.",
        f"Verification: {v['summary']}.",
        f"Best single fixed PI: {f['gains']}, worst cost {f['cost']:.4g}, search {f['wall_time']:.1f} s "
        f"({f['n_sims']} simulations); passes verification at {f['verified_levels'][0]}/{f['verified_levels'][1]} "
        "levels.",
        f"C header on the sweep: max |u_C - u_Python| = {m['c_sweep_max_abs_diff']}.",
        "",
        f"Level step: {m['comparison_step']}.",
        "",
        "| H0 (m) | kind | IAE scheduled | IAE fixed PI | ratio |",
        "|---:|---|---:|---:|---:|",
    ]
    lines += [f"| {c['level']:g} | {c['kind']} | {c['iae_scheduled']:.3f} | {c['iae_fixed']:.3f} | {c['ratio']:.3f} |"
              for c in m["comparison"]]
    lines += ["", f"Scheduled better at every level: {m['better_everywhere']}.", "",
              "Nonlinear sweep (hold {:g} s per level):".format(v["sweep"]["hold"]), "",
              "| from (m) | to (m) | IAE | error at the end |", "|---:|---:|---:|---:|"]
    lines += [f"| {s['level_from']:g} | {s['level']:g} | {s['iae']:.3f} | {s['final_error']:.2e} |"
              for s in v["sweep"]["segments"]]
    return "\n".join(lines) + "\n"


def main(argv: list[str] | None = None) -> None:
    """Run :func:`measure_water_tank` and write its JSON and Markdown into ``--out``."""
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--grid", default="2:20:10")
    ap.add_argument("--budget", type=int, default=POINT_BUDGET)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--out", default="bench/results")
    a = ap.parse_args(argv)
    m = measure_water_tank(a.grid, a.budget, a.seed)
    out = Path(a.out)
    out.mkdir(parents=True, exist_ok=True)
    write_atomic(out / "schedule_water_tank.json", json.dumps(m, indent=2) + "\n")
    text = to_markdown(m)
    write_atomic(out / "schedule_water_tank.md", text)
    print(text)


if __name__ == "__main__":
    main()
