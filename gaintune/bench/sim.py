"""Benchmark: closed-loop simulations per second of the compiled kernel, against a plain NumPy loop.

Run::

    gaintune bench sim              # or: python -m gaintune.bench.sim [--json] [--batch 1 4096]

Cases (each 2,000 time steps):

* ``lag3_pid``: 1/(s+1)^3, PID with derivative filter (N = 10), actuator
  saturation [-1.5, 1.5] (active: the first move is Kp > 1.5) and clamping
  anti-windup, dt = 0.01 over 20 s. The reference case of the issue.
* ``dc_motor``: the 3-loop position -> speed -> current cascade of
  ``models/dc_motor.yaml`` (its ``example``), dt = 1 ms over 2 s.
* ``water_tank``: the nonlinear tank of ``models/water_tank.yaml`` (casadi tape, RK4),
  PI level control, dt = 0.1 s over 200 s.
* ``wood_berry``: the 2 x 2 Wood-Berry column with delays (``models/wood_berry.yaml``, its
  ``example``: two PI loops, the step on xD) on the MIMO simulator (:mod:`gaintune.sim.mimo`),
  dt = 0.1 min over 200 min, around Luyben's BLT gains. It has no prebuilt-argument path and no
  NumPy baseline: its ``kernel`` figures are those of the full ``Simulator.run``.
* ``quadruple_tank``: the nonlinear quadruple tank (``models/quadruple_tank.yaml``, casadi tapes,
  RK4) on the MIMO simulator, Johansson's PI on both loops, the step on y1, dt = 0.5 s over
  1,000 s; timed as ``wood_berry``.
* ``robot_arm6``: the nonlinear six-joint arm (``models/robot_arm6.yaml``: 18 states, casadi tapes,
  RK4; 18 loops, 54 gains, position -> velocity -> current PID per joint), the 0.1 rad step on the
  shoulder, dt = 1 ms over 2 s, on the MIMO simulator as ``wood_berry``.
* ``quadrotor_ode``: the nonlinear quadrotor (``models/quadrotor_ode.yaml``: 12 states, casadi
  tapes, RK4; 12 loops, 24 gains, hand-set cascades), the 1 m step in x, dt = 5 ms over 8 s (1,600
  steps), as ``wood_berry``.

Each batch holds distinct gain sets (nominal gains times a seeded log-uniform
factor in [0.74, 1.35]). Reported per case and batch size:

* ``kernel``: the compiled kernel alone on prebuilt arrays (simulations/s, ms per simulation);
* ``run``: the full :meth:`gaintune.sim.Simulator.run` (array assembly and
  Python overhead included) and the overhead share;
* ``numpy``: :func:`numpy_rollout`, a plain NumPy loop over time steps batched
  over candidates computing the same law and streaming metrics; the ratio
  numpy time / kernel time is measured in the same run, with the kernel and
  NumPy repetitions interleaved (the machine is shared and noisy);
* peak memory: each (case, implementation, batch) runs once more in a fresh
  subprocess. After imports and a B = 1 warm-up, the kernel's peak-RSS mark is
  reset (``/proc/self/clear_refs``) and the first run at batch B is made;
  the reported figure is ``VmHWM - VmRSS(before)``: everything the batch
  allocates (draw/plant/controller arrays, chunk state, outputs), numba's
  allocations included (tracemalloc would miss those). Without
  ``clear_refs`` the ``ru_maxrss`` delta is used instead (a lower bound).

Times are medians over interleaved repetitions, each repetition at least
``--min-time`` seconds of back-to-back calls.
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import subprocess
import sys
import time
from collections.abc import Callable
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

import numpy as np

from gaintune.bench.arguments import MAX_BATCH, BenchParser, fail, int_range, positive_float, positive_int
from gaintune.bench.numpy_rollout import numpy_rollout, prepare_numpy

if TYPE_CHECKING:  # pragma: no cover
    from gaintune.spec import Gains

__all__ = ["CASES", "MIMO_CASES", "main", "numpy_rollout", "make_case", "run_benchmark"]

LAG3_SPEC: dict[str, Any] = {
    "name": "lag3_pid",
    "plant": {"tf": {"num": [1.0], "den": "(s+1)^3"}},
    "loops": [{"name": "main", "type": "pid", "anti_windup": "clamping", "filter": {"N": 10}}],
    "actuator": {"limits": [-1.5, 1.5]},
    "scenario": {"dt": 0.01, "horizon": 20.0, "reference": {"kind": "step", "amplitude": 1.0}},
}

#: Nominal gains of each case (``{loop: {gain: value}}``).
NOMINAL_GAINS: dict[str, Gains] = {
    "lag3_pid": {"main": {"Kp": 2.0, "Ki": 1.0, "Kd": 1.0}},
    "dc_motor": {"position": {"Kp": 20.0}, "speed": {"Kp": 0.5, "Ki": 0.5}, "current": {"Kp": 5.0, "Ki": 2000.0}},
    "water_tank": {"level": {"Kp": 1.0, "Ki": 0.05}},
    "wood_berry": {"xD": {"Kp": 0.375, "Ki": 0.375 / 8.29}, "xB": {"Kp": -0.075, "Ki": -0.075 / 23.6}},
    "quadruple_tank": {"y1": {"Kp": 3.0, "Ki": 3.0 / 30}, "y2": {"Kp": 2.7, "Ki": 2.7 / 40}},
    "robot_arm6": {name: gains for k in range(1, 7) for name, gains in (
        (f"q{k}", {"Kp": 10.0, "Ki": 1.0, "Kd": 1e-3}),
        (f"w{k}", {"Kp": 14.0 if k <= 3 else 0.85, "Ki": 140.0 if k <= 3 else 8.5, "Kd": 1e-3}),
        (f"i{k}", {"Kp": 5.0, "Ki": 1000.0, "Kd": 1e-5}))},
    "quadrotor_ode": {**{name: gains for axis in (("x", "vx", "theta", "q"), ("y", "vy", "phi", "p"))
                         for name, gains in zip(axis, ({"Kp": 1.0}, {"Kp": 0.2, "Ki": 0.05, "Kd": 0.01}, {"Kp": 6.0},
                                                       {"Kp": 0.1, "Ki": 0.2, "Kd": 0.002}), strict=True)},
                      "z": {"Kp": 1.5}, "vz": {"Kp": 5.0, "Ki": 1.0, "Kd": 0.01}, "psi": {"Kp": 5.0},
                      "r": {"Kp": 0.2, "Ki": 0.2, "Kd": 0.001}},
}
#: The MIMO cases (gaintune.sim.mimo): timed through Simulator.run only.
MIMO_CASES = ("wood_berry", "quadruple_tank", "robot_arm6", "quadrotor_ode")
#: The single-input cases, with the NumPy baseline.
CASES = tuple(k for k in NOMINAL_GAINS if k not in MIMO_CASES)


def case_spec(name: str) -> dict[str, Any]:
    if name == "lag3_pid":
        return json.loads(json.dumps(LAG3_SPEC))
    from gaintune.plants.library import load_model

    spec = load_model(name).example_spec()
    if name == "wood_berry":  # one scenario (the step on xD) of 2,000 steps, as the other cases
        spec["scenarios"] = [{**spec["scenarios"][0], "horizon": 200.0}]
    if name == "quadruple_tank":
        spec["scenarios"] = [{**spec["scenarios"][0], "horizon": 1000.0}]
    if name == "robot_arm6":  # the step on the shoulder (q2), 2,000 steps of 1 ms
        spec["scenarios"] = [{**spec["scenarios"][1], "horizon": 2.0}]
    return spec


@dataclass
class Case:
    name: str
    sim: Any  # gaintune.sim.Simulator
    full: np.ndarray  # (B, n_gains)


def make_case(name: str, batch: int, seed: int = 0) -> Case:
    """The simulator of case ``name`` and ``batch`` distinct gain sets around its nominal gains."""
    from gaintune.sim import Simulator
    from gaintune.spec import load_spec

    sim = Simulator(load_spec(case_spec(name)))
    nominal = sim.layout.from_dict(NOMINAL_GAINS[name])
    rng = np.random.default_rng(seed)
    spread = np.exp(rng.uniform(-0.3, 0.3, (batch, nominal.size)))
    spread[0] = 1.0
    return Case(name, sim, nominal[None, :] * spread)


# ------------------------------------------------------------------ timing


def _per_call(fn: Callable[[], Any], min_time: float, clock: Callable[[], float] = time.perf_counter) -> float:
    """Seconds per call of ``fn``, calling it back to back for at least ``min_time`` seconds of ``clock``."""
    n = 0
    t0 = clock()
    while True:
        fn()
        n += 1
        el = clock() - t0
        if not el < min_time:  # not `el >= min_time`: a NaN limit must end the loop too
            return el / n


def time_case(
    name: str, batch: int, repeat: int = 5, min_time: float = 0.3, numpy_baseline: bool = True
) -> dict[str, Any]:
    """Interleaved timings of kernel-only, full ``Simulator.run`` and the NumPy loop for one case and batch."""
    from gaintune.sim.kernel import METRICS, run_kernel

    if name in MIMO_CASES:
        return _time_mimo(name, batch, repeat, min_time)
    case = make_case(name, batch)
    sim, full = case.sim, case.full
    args = sim.kernel_args(full)  # prebuilt once: the timed kernel calls skip the array assembly
    out_k = run_kernel(args)
    prep = prepare_numpy(sim, full) if numpy_baseline else None
    if numpy_baseline:
        m_np, _ = numpy_rollout(sim, full, prepared=prep)
        iae_k = out_k[METRICS.index("iae")]
        ok = np.isfinite(iae_k) & np.isfinite(m_np["iae"])
        rel = np.abs(iae_k[ok] - m_np["iae"][ok]) / np.maximum(np.abs(iae_k[ok]), 1e-12)
        agree = float(np.max(rel)) if ok.any() else np.nan
    else:
        agree = np.nan
    tk, tr, tn = [], [], []
    for _ in range(repeat):
        tk.append(_per_call(lambda: run_kernel(args), min_time))
        tr.append(_per_call(lambda: sim.run(full), min_time))
        if numpy_baseline:
            tn.append(_per_call(lambda: numpy_rollout(sim, full, prepared=prep), min_time))
    k, r = float(np.median(tk)), float(np.median(tr))
    n = float(np.median(tn)) if tn else np.nan
    return {
        "case": name, "batch": batch, "steps": sim.spec.scenarios[0].n_steps,
        "kernel_s": k, "run_s": r, "numpy_s": n,
        "kernel_sims_per_s": batch / k, "run_sims_per_s": batch / r, "numpy_sims_per_s": batch / n,
        "kernel_ms_per_sim": 1e3 * k / batch, "run_ms_per_sim": 1e3 * r / batch,
        "overhead_frac": (r - k) / r, "speedup_vs_numpy": n / k, "numpy_iae_max_rel_diff": agree,
        "diverged": int(np.sum(out_k[METRICS.index("diverged")] != 0)),
    }


def _time_mimo(name: str, batch: int, repeat: int, min_time: float) -> dict[str, Any]:
    """Timings of a MIMO case: the full ``Simulator.run`` (no prebuilt-argument path, no NumPy baseline)."""
    case = make_case(name, batch)
    sim, full = case.sim, case.full
    diverged = int(np.sum(sim.run(full).metrics["diverged"]))
    r = float(np.median([_per_call(lambda: sim.run(full), min_time) for _ in range(repeat)]))
    nan = float("nan")
    return {
        "case": name, "batch": batch, "steps": sim.spec.scenarios[0].n_steps,
        "kernel_s": r, "run_s": r, "numpy_s": nan,
        "kernel_sims_per_s": batch / r, "run_sims_per_s": batch / r, "numpy_sims_per_s": nan,
        "kernel_ms_per_sim": 1e3 * r / batch, "run_ms_per_sim": 1e3 * r / batch,
        "overhead_frac": nan, "speedup_vs_numpy": nan, "numpy_iae_max_rel_diff": nan, "diverged": diverged,
    }


# ------------------------------------------------------------------ memory


def _rss_kb(field: str) -> int | None:
    try:
        with open("/proc/self/status") as fh:
            for line in fh:
                if line.startswith(field + ":"):
                    return int(line.split()[1])
    except OSError:
        return None
    return None


def _memory_worker(name: str, impl: str, batch: int) -> dict[str, Any]:
    """Run in a fresh process: peak RSS above the pre-run level of one batch run."""
    import gc

    # warm up on a small batch that takes the same path (single lane, one serial chunk, or the
    # kernel threads over chunk ranges), so that loading the variant or starting the threads is not
    # counted; a small one, so its freed memory cannot
    # hide the measured run's peak
    from gaintune.sim.kernel import CHUNK

    warm = make_case(name, min(batch, CHUNK + 1))
    if impl == "kernel":
        warm.sim.run(warm.full)
    else:
        numpy_rollout(warm.sim, warm.full)
    case = make_case(name, batch)
    del warm
    gc.collect()
    before = _rss_kb("VmRSS")
    method = "VmHWM after clear_refs"
    try:
        with open("/proc/self/clear_refs", "w") as fh:
            fh.write("5")
    except OSError:
        method = "ru_maxrss delta (lower bound)"
        before = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    if impl == "kernel":
        case.sim.run(case.full)
    else:
        numpy_rollout(case.sim, case.full)
    peak = _rss_kb("VmHWM") if method.startswith("VmHWM") else resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    high = _rss_kb("VmHWM") or resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    return {"case": name, "impl": impl, "batch": batch, "peak_delta_mb": max((peak or 0) - (before or 0), 0) / 1024.0,
            "peak_rss_mb": high / 1024.0, "method": method}


def measure_memory(name: str, impl: str, batch: int) -> dict[str, Any]:
    cmd = [sys.executable, "-m", "gaintune.bench.sim", "--_memory", name, impl, str(batch)]
    res = subprocess.run(cmd, capture_output=True, text=True, check=True)
    return json.loads(res.stdout.strip().splitlines()[-1])


# ------------------------------------------------------------------ report


def run_benchmark(cases=CASES + MIMO_CASES, batches=(1, 4096), repeat: int = 5, min_time: float = 0.3,
                  memory: bool = True, numpy_baseline: bool = True) -> dict[str, Any]:
    import numba

    rows = []
    for name in cases:
        for B in batches:
            row = time_case(name, B, repeat=repeat, min_time=min_time, numpy_baseline=numpy_baseline)
            if memory:
                mk = measure_memory(name, "kernel", B)
                row["kernel_peak_mb"] = mk["peak_delta_mb"]
                row["memory_method"] = mk["method"]
                with_numpy = numpy_baseline and name not in MIMO_CASES
                row["numpy_peak_mb"] = measure_memory(name, "numpy", B)["peak_delta_mb"] if with_numpy else np.nan
            rows.append(row)
    return {
        "machine": {"cpus": os.cpu_count(),
                    "numba_threads": numba.config.NUMBA_NUM_THREADS,  # type: ignore[attr-defined]  # not in numba's stubs
                    "python": sys.version.split()[0],
                    "numpy": np.__version__, "numba": numba.__version__},
        "rows": rows,
    }


def markdown(result: dict[str, Any]) -> str:
    m = result["machine"]
    lines = [
        f"{m['cpus']} CPUs, {m['numba_threads']} numba threads, Python {m['python']}, NumPy {m['numpy']}, "
        f"numba {m['numba']}",
        "",
        "| case | batch | steps | kernel sims/s | kernel ms/sim | Simulator.run sims/s | run overhead | NumPy sims/s "
        "| kernel vs NumPy | peak mem kernel (MB) | peak mem NumPy (MB) |",
        "|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|",
    ]
    for r in result["rows"]:
        lines.append(
            f"| {r['case']} | {r['batch']} | {r['steps']} | {r['kernel_sims_per_s']:,.0f} | "
            f"{r['kernel_ms_per_sim']:.4f} | "
            f"{r['run_sims_per_s']:,.0f} | {100 * r['overhead_frac']:.0f} % | {r['numpy_sims_per_s']:,.1f} | "
            f"{r['speedup_vs_numpy']:,.0f}x | {r.get('kernel_peak_mb', float('nan')):.2f} | "
            f"{r.get('numpy_peak_mb', float('nan')):.2f} |"
        )
    meth = {r.get("memory_method") for r in result["rows"]} - {None}
    if meth:
        lines += ["", "Peak memory: RSS high-water mark above the pre-run level of one batch run in a fresh process "
                      f"({', '.join(sorted(str(x) for x in meth))})."]
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    ap = BenchParser(prog="gaintune bench sim", description="Closed-loop simulations per second: kernel vs NumPy.")
    ap.add_argument("--case", nargs="+", choices=CASES + MIMO_CASES, default=list(CASES + MIMO_CASES))
    ap.add_argument("--batch", nargs="+", type=int_range(1, MAX_BATCH), default=[1, 4096],
                    help=f"batch sizes, 1 .. {MAX_BATCH:,} (default 1 4096)")
    ap.add_argument("--repeat", type=positive_int, default=5, help="interleaved repetitions (median reported)")
    ap.add_argument("--min-time", type=positive_float, default=0.3, help="seconds of back-to-back calls per repetition")
    ap.add_argument("--no-memory", action="store_true", help="skip the subprocess peak-memory runs")
    ap.add_argument("--no-numpy", action="store_true", help="skip the NumPy baseline")
    ap.add_argument("--json", action="store_true", help="print JSON instead of a Markdown table")
    ap.add_argument("--_memory", nargs=3, help=argparse.SUPPRESS)
    a = ap.parse_args(argv)
    if a._memory:
        name, impl, B = a._memory
        print(json.dumps(_memory_worker(name, impl, int(B))))
        return 0
    try:
        res = run_benchmark(a.case, a.batch, a.repeat, a.min_time, memory=not a.no_memory,
                            numpy_baseline=not a.no_numpy)
    except MemoryError:  # within MAX_BATCH, but more than this machine holds
        fail("--batch", f"out of memory at batch {max(a.batch):,}; give a smaller --batch")
    print(json.dumps(res, indent=2, default=float) if a.json else markdown(res))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
