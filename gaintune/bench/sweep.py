"""``gaintune bench sweep``: fleet sweeps, local processes against Ray, scaling, worker and driver kills, a projection.

One run prints (and writes ``sweep.json`` / ``sweep.md`` to ``--out``):

(a) the same ``--problems``-item sweep (PI on FOTD valves, a grid of gain, time constant and dead
    time, ``--budget`` simulations each) on the local backend (2 worker processes) and on Ray (a
    local cluster of 2 CPUs, started before the clock, as a ``--address`` cluster would be), side
    by side, with Ray's overhead as a share of the wall time, and whether both gave the same
    answers;
(b) the local sweep on 1 worker against 2 (the speed-up);
(c) a Ray worker killed mid-sweep (SIGKILL of a worker process running an item once half the
    items are done): the sweep completes; items lost (no record) and items run to completion
    twice are counted from the workers' ledger;
(d) the driver killed (SIGKILL once half the items are recorded) and the sweep run again with the
    same folder: finished items run again (must be 0), and the in-flight ones that did;
(e) a projection for 10,000 loops on a 32-node x 16-core cluster from the measured per-item cost
    and Ray's per-item overhead (docs/scale.md explains the model).

The machine is shared: the load average before and after is printed beside the figures.
"""

from __future__ import annotations

import math
import os
import signal
import statistics
import subprocess
import sys
import tempfile
import textwrap
import time
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import yaml

from gaintune.bench.arguments import BenchParser, add_out_argument, budget_int, int_range, resolve_out
from gaintune.bench.compare import md_table, write_outputs
from gaintune.spec.settings import SearchSpec

__all__ = ["main", "fleet_doc", "projection", "noop", "ray_task_overhead"]

#: The valve every item varies (PI on K exp(-L s)/(T s + 1)).
VALVE: dict[str, Any] = {
    "name": "valve",
    "plant": {"tf": {"num": ["K"], "den": "T*s + 1"}, "delay": "L", "params": {"K": 1.0, "T": 5.0, "L": 1.0}},
    "loops": [{"name": "flow", "type": "pi", "gains": {"Kp": {"bounds": [0.01, 20]}, "Ki": {"bounds": [0.001, 20]}}}],
    "actuator": {"limits": [-100, 100]},
    "scenario": {"dt": 0.05, "horizon": 40.0, "reference": {"kind": "step", "amplitude": 1.0, "time": 1.0}},
    "requirements": {"gm_min_db": 6, "pm_min_deg": 45, "ms_max": 1.6},
    "search": {"seed": 0},
}

#: Simulations per item: what a spec that names no budget gets, so an item is a typical search.
DEFAULT_BUDGET: int = SearchSpec.model_fields["budget"].default


def fleet_doc(n: int, budget: int) -> dict[str, Any]:
    """A fleet of ``n`` distinct valves: cases over gain, time constant and dead time."""
    gains, taus, delays = [0.5, 1.0, 1.5, 2.0, 3.0], [2.0, 4.0, 6.0, 8.0, 10.0, 12.0], [0.5, 1.0, 1.5, 2.0]
    combos = [(k, t, d) for d in delays for t in taus for k in gains][:n]
    cases = [{"plant.params.K": k, "plant.params.T": t, "plant.params.L": d} for k, t, d in combos]
    return {"name": f"bench_valves_{n}", "base": VALVE, "overrides": {"search.budget": budget}, "cases": cases}


def _answers(out: Path) -> dict[str, tuple]:
    """key -> (status, verdict, cost, gains, wall s, CPU s) of the sweep folder ``out``."""
    from gaintune.sweep.store import SqliteStore

    store = SqliteStore(out / "sweep.db")
    try:
        return {r["key"]: (r["status"], r["verdict"], r["cost"], r["gains"], r["wall_s"], r["cpu_s"])
                for r in store.records()}
    finally:
        store.close()


def _median(out: Path, column: int) -> float:
    return statistics.median(v[column] for v in _answers(out).values() if v[column] is not None)


def noop() -> None:
    """A task that does nothing: what Ray costs per task, whatever the task."""


def ray_task_overhead(ray: Any, n: int = 400) -> float:
    """Ray's wall seconds per task x the cluster's CPUs, over ``n`` tasks that do nothing (workers warm)."""
    task = ray.remote(noop).options(num_cpus=1)
    ray.get([task.remote() for _ in range(8)])  # the workers are up
    t0 = time.perf_counter()
    ray.get([task.remote() for _ in range(n)])
    return (time.perf_counter() - t0) * float(ray.cluster_resources().get("CPU", 1.0)) / n


def _timed(fleet: Path, out: Path, **options: Any) -> float:
    from gaintune.sweep import SweepOptions, run_sweep

    t0 = time.perf_counter()
    run_sweep(fleet, out, SweepOptions(**options))
    return time.perf_counter() - t0


def local_vs_ray(fleet: Path, tmp: Path, address: str | None) -> dict[str, Any]:
    """(a) and (b): local on 2 and 1 workers, Ray on a 2-CPU cluster started before the clock."""
    from gaintune.sweep.backends import connect, import_ray

    res: dict[str, Any] = {"local_2_s": _timed(fleet, tmp / "local2", workers=2)}
    ray = import_ray()
    t0 = time.perf_counter()
    connect(ray, address, 2)
    res["ray_start_s"] = time.perf_counter() - t0
    try:
        res["ray_cpus"] = ray.cluster_resources().get("CPU")
        res["ray_2_s"] = _timed(fleet, tmp / "ray2", backend="ray")
        res["ray_task_overhead_s"] = ray_task_overhead(ray)
    finally:
        ray.shutdown()
    res["local_1_s"] = _timed(fleet, tmp / "local1", workers=1)
    a, b = _answers(tmp / "local2"), _answers(tmp / "ray2")
    res["identical"] = {k: v[:4] for k, v in a.items()} == {k: v[:4] for k, v in b.items()}
    res["item_s_median"] = _median(tmp / "local1", 4)  # one worker: items one after another
    for name in ("local2", "ray2", "local1"):  # CPU seconds: the steady figure on a shared machine
        res[f"item_cpu_s_{name}"] = _median(tmp / name, 5)
    res["ray_overhead_of_ray_wall"] = (res["ray_2_s"] - res["local_2_s"]) / res["ray_2_s"]
    res["ray_overhead_of_local_wall"] = (res["ray_2_s"] - res["local_2_s"]) / res["local_2_s"]
    res["speedup_1_to_2"] = res["local_1_s"] / res["local_2_s"]
    return res


def _kill_running_worker(ledger: Path, n: int, deadline: float) -> int | None:
    """Once half the items are done, SIGKILL a worker holding a started, unfinished item; its pid."""
    from gaintune.sweep.worker import ledger_lines

    while time.monotonic() < deadline:
        lines = ledger_lines(ledger)
        done = {key for what, key, _ in lines if what == "done"}
        running = [pid for what, key, pid in lines if what == "start" and key not in done]
        if len(done) >= n // 2 and running:
            os.kill(running[-1], signal.SIGKILL)
            return running[-1]
        time.sleep(0.02)
    return None


def ray_worker_kill(fleet: Path, tmp: Path, n: int, address: str | None) -> dict[str, Any]:
    """(c): a Ray worker killed mid-sweep; lost and twice-finished items from the ledger and the store."""
    import threading

    from gaintune.sweep import SweepOptions, run_sweep
    from gaintune.sweep.worker import Hook, ledger_lines

    ledger = tmp / "ray_kill.ledger"
    killed: list[int | None] = []
    t = threading.Thread(target=lambda: killed.append(_kill_running_worker(ledger, n, time.monotonic() + 900)))
    t.start()
    report = run_sweep(fleet, tmp / "ray_kill", SweepOptions(backend="ray", address=address, workers=2,
                                                              hook=Hook(ledger=str(ledger))))
    t.join()
    lines = ledger_lines(ledger)
    done = [key for what, key, _ in lines if what == "done"]
    answers = _answers(tmp / "ray_kill")
    return {"killed_pid": killed[0], "items": n, "recorded": sum(v[0] == "done" for v in answers.values()),
            "lost": n - sum(v[0] == "done" for v in answers.values()), "finished_twice": len(done) - len(set(done)),
            "attempts": sum(1 for what, *_ in lines if what == "start"), "refused": report.refused}


DRIVER = textwrap.dedent("""
    import os, signal, sys
    from gaintune.sweep import SweepOptions, run_sweep
    from gaintune.sweep.worker import Hook

    fleet, out, ledger, after = sys.argv[1], sys.argv[2], sys.argv[3], int(sys.argv[4])

    def on_record(rec, report):
        if report.ran >= after:
            os.kill(os.getpid(), signal.SIGKILL)

    run_sweep(fleet, out, SweepOptions(workers=2, hook=Hook(ledger=ledger)), on_record=on_record)
""")


def driver_kill(fleet: Path, tmp: Path, n: int) -> dict[str, Any]:
    """(d): the driver SIGKILLed after half the items, then the sweep run again on the same folder."""
    from gaintune.sweep import SweepOptions, run_sweep
    from gaintune.sweep.store import SqliteStore
    from gaintune.sweep.worker import Hook, ledger_lines

    out = tmp / "driver_kill"
    with open(tmp / "driver.log", "w") as log:
        rc = subprocess.run([sys.executable, "-c", DRIVER, str(fleet), str(out), str(tmp / "d1.ledger"), str(n // 2)],
                            stdout=log, stderr=subprocess.STDOUT, timeout=1800).returncode
    store = SqliteStore(out / "sweep.db")
    finished = store.finished_keys()
    store.close()
    t0 = time.perf_counter()
    report = run_sweep(fleet, out, SweepOptions(workers=2, hook=Hook(ledger=str(tmp / "d2.ledger"))))
    restart_s = time.perf_counter() - t0
    second = [key for what, key, _ in ledger_lines(tmp / "d2.ledger") if what == "start"]
    first_started = {key for what, key, _ in ledger_lines(tmp / "d1.ledger") if what == "start"}
    return {"driver_rc": rc, "finished_at_kill": len(finished), "skipped": report.skipped, "ran_after": report.ran,
            "finished_rerun": len(set(second) & finished),
            "inflight_rerun": len((set(second) & first_started) - finished), "restart_s": restart_s,
            "complete": len(_answers(out)) == n}


def projection(item_s: float, overhead_s: float, loops: int = 10_000, nodes: int = 32, cores: int = 16,
               start_s: float = 0.0) -> dict[str, Any]:
    """Wall time of ``loops`` items on ``nodes`` x ``cores`` CPUs: waves of items, each item its own cost plus
    Ray's per-item overhead, after the workers' start-up.

    Parameters
    ----------
    item_s
        One item's wall time on a core of its own (measured: an item's median CPU seconds; the items
        are single-threaded).
    overhead_s
        Ray's cost per task in CPU seconds (measured: empty tasks on the same cluster).
    start_s
        Fixed cost of a sweep: the cluster connection and a worker's start with its imports (measured:
        the Ray cluster's start, and the 1-worker sweep's wall time less its items').
    """
    cpus = nodes * cores
    waves = math.ceil(loops / cpus)
    wall = start_s + waves * (item_s + max(overhead_s, 0.0))
    return {"loops": loops, "nodes": nodes, "cores": cores, "waves": waves, "item_s": item_s,
            "overhead_s": overhead_s, "start_s": start_s, "wall_s": wall, "serial_s": loops * item_s}


def _markdown(res: dict[str, Any]) -> str:
    a, c, d, p = res["a"], res["c"], res["d"], res["e"]
    rows = [
        ["(a) local, 2 workers", a["local_2_s"], "-"],
        ["(a) ray, 2 CPUs (cluster up)", a["ray_2_s"], f"overhead {100 * a['ray_overhead_of_ray_wall']:.1f} % of "
                                                       f"Ray's wall time ({100 * a['ray_overhead_of_local_wall']:.1f}"
                                                       " % of local's); same answers: " + str(a["identical"])],
        ["(a) ray cluster start (not in the row above)", a["ray_start_s"], "-"],
        ["(a) item CPU s, median: local 2 / ray 2 / local 1", None,
         f"{a['item_cpu_s_local2']:.2f} / {a['item_cpu_s_ray2']:.2f} / {a['item_cpu_s_local1']:.2f}; Ray per task "
         f"(empty tasks): {1e3 * a['ray_task_overhead_s']:.1f} ms of a CPU"],
        ["(b) local, 1 worker", a["local_1_s"], f"speed-up 1 -> 2 workers: {a['speedup_1_to_2']:.2f}x"],
        ["(c) ray, a worker killed mid-sweep", None, f"lost {c['lost']}, finished twice {c['finished_twice']}, "
                                                     f"{c['attempts']} attempts for {c['items']} items"],
        ["(d) driver killed, restarted", d["restart_s"], f"finished at the kill {d['finished_at_kill']}, rerun of "
                                                         f"those {d['finished_rerun']}, in-flight rerun "
                                                         f"{d['inflight_rerun']}, complete {d['complete']}"],
        ["(e) projection: 10,000 loops, 32 x 16 cores", p["wall_s"],
         f"{p['waves']} waves x ({p['item_s']:.2f} s + {p['overhead_s']:.3f} s) + {p['start_s']:.1f} s start"],
    ]
    head = (f"{res['problems']} problems, budget {res['budget']}; load average {res['load_before']} -> "
            f"{res['load_after']}\n\n")
    return head + md_table(["figure", "wall s", "notes"], rows) + "\n"


def _write_fleet(folder: Path, n: int, budget: int, name: str) -> Path:
    path = folder / name
    path.write_text(yaml.safe_dump(fleet_doc(n, budget), sort_keys=False))
    return path


def main(argv: Sequence[str] | None = None) -> int:
    """``gaintune bench sweep``: see the module docstring."""
    ap = BenchParser(prog="gaintune bench sweep", description=(__doc__ or "").splitlines()[0])
    ap.add_argument("--problems", type=int_range(4, 120), default=40, help="items of the timed sweep (default 40)")
    ap.add_argument("--budget", type=budget_int, default=DEFAULT_BUDGET,
                    help=f"simulations per item (default {DEFAULT_BUDGET}, a spec's own default)")
    ap.add_argument("--kill-problems", type=int_range(4, 120), default=12,
                    help="items of the kill sweeps (c) and (d) (default 12)")
    ap.add_argument("--address", help="a running Ray cluster for (a) and (c) (default: a local one of 2 CPUs)")
    add_out_argument(ap)
    args = ap.parse_args(argv)
    out = resolve_out(args.out)
    from gaintune.sim.precompile import missing, precompile

    precompile(missing())  # once here, not in every worker
    load0 = os.getloadavg()
    with tempfile.TemporaryDirectory() as tmp_name:
        tmp = Path(tmp_name)
        fleet = _write_fleet(tmp, args.problems, args.budget, "fleet.yaml")
        small = _write_fleet(tmp, args.kill_problems, args.budget, "small.yaml")
        a = local_vs_ray(fleet, tmp, args.address)
        c = ray_worker_kill(small, tmp, args.kill_problems, args.address)
        d = driver_kill(small, tmp, args.kill_problems)
    # a core of its own per item: its CPU seconds; a worker's start: the 1-worker sweep less its items
    start = max(a["local_1_s"] - args.problems * a["item_s_median"], 0.0)
    res = {"problems": args.problems, "budget": args.budget, "a": a, "c": c, "d": d,
           "e": projection(a["item_cpu_s_local1"], a["ray_task_overhead_s"], start_s=start + a["ray_start_s"]),
           "load_before": [round(x, 2) for x in load0], "load_after": [round(x, 2) for x in os.getloadavg()]}
    md = _markdown(res)
    print(md)
    write_outputs(res, out, "sweep", md)
    return 0
