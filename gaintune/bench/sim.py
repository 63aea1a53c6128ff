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

if TYPE_CHECKING:  # pragma: no cover
    from gaintune.spec import Gains

__all__ = ["CASES", "main", "numpy_rollout", "make_case", "run_benchmark"]

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
}
CASES = tuple(NOMINAL_GAINS)


def _water_tank_numpy(params: dict[str, float]) -> tuple[Callable, Callable]:
    A, a, b = params["A"], params["a"], params["b"]

    def rhs(x: np.ndarray, u: np.ndarray) -> np.ndarray:
        return ((b * u - a * np.sqrt(np.maximum(x[0], 0.0))) / A)[None, :]

    return rhs, lambda x: x[:1]


#: Hand-written NumPy right-hand sides (and output maps) of nonlinear benchmark plants.
NUMPY_PLANTS: dict[str, Callable[[dict[str, float]], tuple[Callable, Callable]]] = {"water_tank": _water_tank_numpy}


def case_spec(name: str) -> dict[str, Any]:
    if name == "lag3_pid":
        return json.loads(json.dumps(LAG3_SPEC))
    from gaintune.plants.library import load_model

    return load_model(name).example_spec()


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


# ------------------------------------------------------------ NumPy baseline


# One loop over time steps, as the numba kernel is one function (gaintune/sim/kernel/drivers.py): it is the
# baseline the kernel is timed against, and a call per stage and step would slow that baseline.
def numpy_rollout(  # noqa: C901  # the NumPy mirror of the kernel's time step, kept in one loop (see above)
    sim: Any, full: np.ndarray, scenario: int = 0, traces: bool = False, prepared: dict | None = None
) -> tuple[dict[str, np.ndarray], dict[str, np.ndarray]]:
    """The closed loop as a plain NumPy loop over time steps, batched over the candidates.

    Implements the same discrete-time law as the kernel (see
    :mod:`gaintune.controllers.pid`: backward-Euler PID, 2-DOF weights,
    derivative filter, output limits, anti-windup, rate limit, cascades) and
    the same streaming metrics, for the nominal plant. Supported: LTI plants
    without delay, or nonlinear plants with a hand-written right-hand side in
    :data:`NUMPY_PLANTS` (RK4); no noise, disturbance, safety monitor or LQ
    loops. It is the benchmark's baseline and a second implementation the
    tests compare the kernel against.

    Returns
    -------
    metrics : dict of (B,) arrays (iae, ise, itae, effort, tv, peak_u, sat_frac,
        overshoot, rise_time, settling_time, y_final, diverged)
    traces : dict with ``u`` (B, T) and ``y.<loop>`` (B, T) when ``traces``
    """
    p = prepared if prepared is not None else prepare_numpy(sim, full, scenario)
    T, dt, L, B = p["T"], p["dt"], p["L"], p["B"]
    kp, ki, al, be, bw, cw, kb, lo, hi = (p[k] for k in ("kp", "ki", "al", "be", "bw", "cw", "kb", "lo", "hi"))
    aw, meas, r, rate, u_lo, u_hi, u_op = p["aw"], p["meas"], p["r"], p["rate"], p["u_lo"], p["u_hi"], p["u_op"]
    x = p["x0"].copy()
    integ = p["I0"].copy()
    D = np.zeros((L, B))
    edp = np.zeros((L, B))
    awe = np.zeros((L, B))
    uprev = np.full(B, u_op)
    y0 = None
    iae, ise, itae, effort, tv, peak_u, sat, peak = (np.zeros(B) for _ in range(8))
    t10, t90, last = (np.full(B, -1.0) for _ in range(3))
    target, k_step = p["target"], p["k_step"]
    tr_u = np.zeros((T, B) if traces else (0, B))
    tr_y = np.zeros((L, T, B) if traces else (L, 0, B))
    rhs, out = p["rhs"], p["out"]
    monitor, tripped = p["monitor"], np.zeros(B, dtype=bool)
    Ad, G0, Cm = p["Ad"], p["G0"], p["Cm"]
    with np.errstate(all="ignore"):
        for k in range(T):
            t = k * dt
            Y = Cm @ x if rhs is None else out(x)
            sp = r[k]
            if monitor:  # safety monitor, hold action: the actuator goes to the safe value for good
                tripped |= (np.abs(sp - Y[meas[0]]) > p["max_err"]) | np.any(np.abs(Y) > p["max_out"], axis=0)
                tripped |= np.any(np.abs(x) > p["xb"], axis=0)
            for li in range(L):
                y = Y[meas[li]]
                e = sp - y
                ed = cw[li] * sp - y
                if k == 0:
                    edp[li] = ed
                D[li] = al[li] * D[li] + be[li] * (ed - edp[li])
                edp[li] = ed
                pt = kp[li] * (bw[li] * sp - y)
                it = integ[li] + ki[li] * dt * e
                if aw[li] == 2:
                    it = it + kb[li] * dt * awe[li]
                vu = pt + it + D[li]
                vs = np.clip(vu, lo[li], hi[li])
                if aw[li] == 1:
                    hold = (vs != vu) & (e * (vu - vs) * ki[li] > 0)
                    it = np.where(hold, integ[li], it)
                    vu = pt + it + D[li]
                    vs = np.clip(vu, lo[li], hi[li])
                integ[li] = it
                awe[li] = vs - vu
                sp = vs
            u = sp
            if np.isfinite(rate):
                u = np.clip(u, uprev - rate * dt, uprev + rate * dt)
            if monitor:
                u = np.where(tripped, p["u_safe"], u)
            if aw[L - 1] == 2:
                awe[L - 1] += u - sp
            # streaming metrics on the outer loop's output
            yo = Y[meas[0]]
            e0 = r[k] - yo
            ae = np.abs(e0)
            du = u - u_op
            iae += ae * dt
            ise += e0 * e0 * dt
            itae += t * ae * dt
            effort += du * du * dt
            tv += np.abs(u - uprev)
            np.maximum(peak_u, np.abs(du), out=peak_u)
            sat += (u <= u_lo) | (u >= u_hi)
            if k == 0:
                y0 = yo.copy()
                span = target - y0
                inv = np.where(span != 0, 1.0 / np.where(span != 0, span, 1.0), 0.0)
            dev = (yo - y0) * inv
            if k >= k_step:
                np.maximum(peak, dev, out=peak)
                t10 = np.where((t10 < 0) & (dev >= 0.1), t, t10)
                t90 = np.where((t90 < 0) & (dev >= 0.9), t, t90)
                last = np.where(np.abs(dev - 1.0) >= 0.02, k, last)
            uprev = u
            if traces:
                tr_u[k] = u
                for li in range(L):
                    tr_y[li, k] = Y[meas[li]]
            # plant update over the sample (ZOH)
            if rhs is None:
                x = Ad @ x + G0 * u
            else:
                k1 = rhs(x, u)
                k2 = rhs(x + 0.5 * dt * k1, u)
                k3 = rhs(x + 0.5 * dt * k2, u)
                k4 = rhs(x + dt * k3, u)
                x = x + dt / 6.0 * (k1 + 2.0 * k2 + 2.0 * k3 + k4)
        y_fin = Y[meas[0]]
        div = ~np.all(np.isfinite(x) & (np.abs(x) <= p["bound"]), axis=0)
    settle = np.where(last < T - 1, np.where(last >= 0, (last + 1) * dt - k_step * dt, 0.0), np.nan)
    m = {
        "iae": iae, "ise": ise, "itae": itae, "effort": effort, "tv": tv, "peak_u": peak_u, "sat_frac": sat / T,
        "overshoot": np.maximum(0.0, peak - 1.0) * 100.0,
        "rise_time": np.where((t10 >= 0) & (t90 >= 0), t90 - t10, np.nan),
        "settling_time": settle, "y_final": y_fin, "diverged": div, "tripped": tripped,
    }
    for key in ("iae", "ise", "itae", "effort", "tv", "peak_u"):
        m[key] = np.where(div, np.inf, m[key])
    tr = {}
    if traces:
        tr["u"] = tr_u.T
        for li, lp in enumerate(sim.spec.loops):
            tr[f"y.{lp.name}"] = tr_y[li].T
    return m, tr


def prepare_numpy(sim: Any, full: np.ndarray, scenario: int = 0) -> dict[str, Any]:
    """Arrays for :func:`numpy_rollout` (built once, outside the timed loop)."""
    spec = sim.spec
    sc = spec.scenarios[scenario]
    full = np.atleast_2d(np.asarray(full, dtype=float))
    B = full.shape[0]
    a = sim.kernel_args(full, scenario=scenario)  # the kernel's own arguments (nominal draws)
    if a.sf:
        raise NotImplementedError("numpy_rollout: LQ loops are not supported")
    if np.any(a.dsteps != 0) or (sim.plant.kind == "lti" and np.any(a.G1 != 0)):
        raise NotImplementedError("numpy_rollout: plant delays are not supported")
    if sc.noise_std > 0 or sc.disturbance.kind != "none":
        raise NotImplementedError("numpy_rollout: noise and disturbances are not supported")
    sf = spec.safety
    if sf.action != "hold":
        raise NotImplementedError("numpy_rollout: only the 'hold' safety action is supported")
    T, dt = sc.n_steps, sc.dt
    L = len(spec.loops)
    lo, hi = a.u_lo[0], a.u_hi[0]  # nominal draws: the spec's limits
    clo, chi = a.lo.copy(), a.hi.copy()
    clo[L - 1], chi[L - 1] = lo, hi
    k = np.arange(T)
    # reference, shared by the candidates (nominal draws): (T,) + operating point
    k0, k1, off, slope = a.sk0[0, :, 0], a.sk1[0, :, 0], a.soff[0, :, 0], a.sslope[0, :, 0]
    act = (k[:, None] >= k0[None, :]) & (k[:, None] < k1[None, :])
    r = (act * (off[None, :] + slope[None, :] * (k[:, None] - k0[None, :]) * dt)).sum(axis=1) + a.y_op[0, 0]
    y_op = a.y_op[:, 0]
    I0 = np.zeros((L, B))
    for li in range(L):
        I0[li] = y_op[li + 1] if li + 1 < L else a.u_op[0]
    tf = a.tf
    out: dict[str, Any] = dict(
        T=T, dt=dt, L=L, B=B, kp=a.kp, ki=a.ki, al=tf / (tf + dt), be=a.kd / (tf + dt),
        bw=a.bw, cw=a.cw, kb=a.kb, lo=clo, hi=chi, aw=a.aw, meas=np.array(sim.setup.meas),
        r=r, rate=a.rate, u_lo=lo, u_hi=hi, u_op=float(a.u_op[0]),
        target=float(a.target[0]), k_step=int(a.k_step[0]),
        x0=np.repeat(a.x_op[:, :1], B, axis=1), I0=I0, bound=a.div_bound,
        max_err=a.max_err, max_out=a.max_out, xb=a.xbound[:, None],
        monitor=bool(sf.max_abs_error or sf.max_abs_output or sf.state_bounds), u_safe=a.u_safe,
        rhs=None, out=None, Ad=None, G0=None, Cm=None,
    )
    if sim.plant.kind == "lti":
        lin = sim.plant.linearize()
        out.update(Ad=a.Ad[:, :, 0].copy(), G0=a.G0[:, :1].copy(), Cm=lin.C.copy())
    else:
        name = spec.plant.model.name if spec.plant.model is not None else None
        if name not in NUMPY_PLANTS:
            raise NotImplementedError(f"numpy_rollout: no NumPy right-hand side for plant {name!r}")
        out["rhs"], out["out"] = NUMPY_PLANTS[name](sim.plant.params)
    return out


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


def run_benchmark(cases=CASES, batches=(1, 4096), repeat: int = 5, min_time: float = 0.3, memory: bool = True,
                  numpy_baseline: bool = True) -> dict[str, Any]:
    import numba

    rows = []
    for name in cases:
        for B in batches:
            row = time_case(name, B, repeat=repeat, min_time=min_time, numpy_baseline=numpy_baseline)
            if memory:
                mk = measure_memory(name, "kernel", B)
                row["kernel_peak_mb"] = mk["peak_delta_mb"]
                row["memory_method"] = mk["method"]
                row["numpy_peak_mb"] = measure_memory(name, "numpy", B)["peak_delta_mb"] if numpy_baseline else np.nan
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
    ap.add_argument("--case", nargs="+", choices=CASES, default=list(CASES))
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
