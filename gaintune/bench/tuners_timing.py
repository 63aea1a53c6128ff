"""Answer times of a trained tuner for ``gaintune bench tuners``: in-process percentiles and fresh processes.

A fresh process runs ``gaintune tuner query NAME -p K=.. -p T=.. -p L=.. --json`` as a user types it
(the installed ``gaintune`` script, in an empty working folder), after a warm-up run that fills
numba's cache and the OS file cache, and with gaintune's bytecode compiled as an installation has
it (:func:`gaintune.bench.startup.compile_bytecode`). A second child imports the CLI the way the
script does, runs the same query in-process and prints whether ``torch`` is in ``sys.modules``
afterwards: answering a query must not pay for the learner's import. It reports ``numba`` too: with the
single-lane kernel compiled ahead of time (:mod:`gaintune.sim.kernel_aot`, built before the warm-up as a
first `gaintune tuner query` builds it) a query does not import numba either.
"""

from __future__ import annotations

import json
import os
import re
import shutil
import subprocess
import sys
import tempfile
import time
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np

__all__ = ["TORCH_PROBE", "FLOOR", "query_argv", "percentiles", "in_process_timing", "fresh_process_timing"]

#: A child that runs one CLI command in-process (``sys.argv[1:]``) and reports whether torch was imported.
TORCH_PROBE = """
import sys
from typer.main import get_command
from gaintune.cli import app
try:
    get_command(app).main(args=sys.argv[1:], prog_name="gaintune", standalone_mode=False)
except SystemExit:
    pass
except Exception as exc:
    print(f"probe: the command raised {type(exc).__name__}: {exc}", file=sys.stderr)
print()
print("torch_imported=" + str("torch" in sys.modules))
print("numba_imported=" + str("numba" in sys.modules))
"""

#: The numeric libraries every answer runs on (the policy and the arrays, the discretisation and the
#: verification's linear algebra; the simulator's kernel is a compiled module that needs numpy only): a fresh
#: process that only imports them is the floor under a fresh query on this machine, timed beside it.
FLOOR = "import numpy, scipy.linalg"

#: A fresh process that does not answer within this many seconds counts as failed.
TIMEOUT_S = 600.0


def query_argv(name: str, values: Mapping[str, float]) -> list[str]:
    """The arguments of ``gaintune tuner query NAME -p K=.. -p T=.. -p L=.. --json`` (values as exact reprs)."""
    argv = ["tuner", "query", name]
    for p in ("K", "T", "L"):
        argv += ["-p", f"{p}={float(values[p])!r}"]
    return [*argv, "--json"]


def percentiles(values: Sequence[float]) -> dict[str, float | None]:
    """``{"p50", "p95", "max", "n"}`` of ``values`` (None when empty)."""
    v = np.asarray([x for x in values if x is not None], dtype=float)
    if v.size == 0:
        return {"p50": None, "p95": None, "max": None, "n": 0}
    return {"p50": float(np.percentile(v, 50)), "p95": float(np.percentile(v, 95)), "max": float(v.max()),
            "n": int(v.size)}


def in_process_timing(rows: Sequence[Mapping[str, Any]], modes: Sequence[str]) -> dict[str, Any]:
    """Per mode: percentiles of the answers' ``policy_ms``, ``elapsed_ms`` (wall) and ``cpu_ms`` (process CPU
    time) over the plants, each plant's time the median of its repeated runs (``repeats``; the first run's
    alone as ``first_elapsed_ms`` and ``first_cpu_ms``), and how many plants' repeats gave the same gains."""
    out: dict[str, Any] = {}
    for mode in modes:
        answers = [r[mode] for r in rows if mode in r and r[mode].get("elapsed_ms") is not None]
        out[mode] = {k: percentiles([a.get(k) for a in answers])
                     for k in ("policy_ms", "elapsed_ms", "cpu_ms", "first_elapsed_ms", "first_cpu_ms")}
        repeats = {int(a.get("repeats", 1)) for a in answers}
        out[mode]["repeats"] = max(repeats) if repeats else 1
        if any("same_answer" in a for a in answers):
            out[mode]["same_answer"] = f"{sum(bool(a.get('same_answer')) for a in answers)} / {len(answers)}"
    return out


def _gaintune_command() -> list[str]:
    """The installed ``gaintune`` script of this interpreter (else the one on PATH, else ``python -m``)."""
    script = Path(sys.executable).with_name("gaintune")
    if script.exists():
        return [str(script)]
    found = shutil.which("gaintune")
    return [found] if found else [sys.executable, "-m", "gaintune"]


def _children_cpu_s() -> float | None:
    """User + system CPU seconds of this process's waited-for children so far (None where unknown)."""
    try:
        import resource
    except ImportError:  # pragma: no cover - not a Unix
        return None
    r = resource.getrusage(resource.RUSAGE_CHILDREN)
    return r.ru_utime + r.ru_stime


def _run(argv: list[str], cwd: str, env: Mapping[str, str] | None = None) -> dict[str, Any]:
    """One fresh process: wall time, its CPU time (user + system; None where unknown), exit code (None on
    timeout), stdout and the last stderr line. ``env``: variables set on top of this process's."""
    t0, c0 = time.perf_counter(), _children_cpu_s()
    try:
        p = subprocess.run(argv, capture_output=True, text=True, cwd=cwd, timeout=TIMEOUT_S, check=False,
                           env=None if env is None else {**os.environ, **env})
    except subprocess.TimeoutExpired:
        return {"wall_s": time.perf_counter() - t0, "cpu_s": None, "code": None, "stdout": "",
                "error": f"timeout {TIMEOUT_S:g} s"}
    wall, c1 = time.perf_counter() - t0, _children_cpu_s()
    lines = [x for x in p.stderr.splitlines() if x.strip()]
    return {"wall_s": wall, "cpu_s": None if c0 is None or c1 is None else c1 - c0, "code": p.returncode,
            "stdout": p.stdout, "error": lines[-1] if lines else ""}


def _is_json(text: str) -> bool:
    try:
        json.loads(text)
    except ValueError:
        return False
    return True


def _time_figures(runs: Sequence[Mapping[str, Any]]) -> dict[str, Any]:
    """Wall and CPU times of the runs that exited 0: the lists, their medians and their maxima."""
    ok = [d for d in runs if d["code"] == 0]
    walls = [d["wall_s"] for d in ok]
    cpus = [d["cpu_s"] for d in ok if d["cpu_s"] is not None]
    return {"wall_s": walls, "median_s": float(np.median(walls)) if walls else None,
            "max_s": max(walls) if walls else None, "cpu_s": cpus,
            "cpu_median_s": float(np.median(cpus)) if cpus else None, "cpu_max_s": max(cpus) if cpus else None}


def fresh_process_timing(name: str, plants: Sequence[Mapping[str, float]], runs: int) -> dict[str, Any]:
    """``runs`` fresh ``gaintune tuner query`` processes (plants in turn), each followed by the same query on
    numba's JIT kernel (``GAINTUNE_KERNEL_AOT=0``, its cache warm: the query before the ahead-of-time module)
    and by a fresh process that only imports the numeric libraries (:data:`FLOOR`), and the torch probe.

    Returns the wall times of the queries that exited 0, their median and max, the same of their CPU times
    (user + system: on a shared machine the load inflates the wall time far more), how many printed valid
    JSON, the failures (exit code and last stderr line), ``floor`` (the same figures of the import-only
    processes, interleaved with the queries so that both see the same load), ``jit`` (the same of the JIT
    queries), ``torch_imported`` and ``numba_imported`` (None when the probe printed no answer) and
    ``aot_kernel`` ("built", or why the build failed).
    """
    from gaintune.bench.startup import compile_bytecode
    from gaintune.sim.kernel_aot import SWITCH, aot_missing
    from gaintune.sim.precompile import build_single

    compile_bytecode()
    aot = "built"
    if aot_missing():  # what a fresh install's first query builds
        try:
            build_single()
        except Exception as exc:  # noqa: BLE001 - reported: the queries then run numba's JIT variant
            aot = f"failed: {type(exc).__name__}: {exc}"
    exe = _gaintune_command()
    jit_env = {SWITCH: "0"}
    with tempfile.TemporaryDirectory() as tmp:  # an empty working folder: no local package shadows the install
        warm = _run([*exe, *query_argv(name, plants[0])], tmp)  # fills numba's cache and the OS file cache
        _run([*exe, *query_argv(name, plants[0])], tmp, jit_env)
        done, jit, floor = [], [], []
        for i in range(runs):
            argv = [*exe, *query_argv(name, plants[i % len(plants)])]
            done.append(_run(argv, tmp))
            jit.append(_run(argv, tmp, jit_env))
            floor.append(_run([sys.executable, "-c", FLOOR], tmp))
        probe = _run([sys.executable, "-c", TORCH_PROBE, *query_argv(name, plants[0])], tmp)
    ok = [d for d in done if d["code"] == 0]
    m = re.search(r"^torch_imported=(True|False)$", probe["stdout"], re.M)
    nb = re.search(r"^numba_imported=(True|False)$", probe["stdout"], re.M)
    return {
        "command": " ".join(["gaintune", *query_argv(name, plants[0])]),
        "runs": runs, "ok": len(ok), "json_ok": sum(_is_json(d["stdout"]) for d in ok), **_time_figures(done),
        "floor": {"command": f'python -c "{FLOOR}"', **_time_figures(floor)},
        "jit": {"command": f"{SWITCH}=0 gaintune {' '.join(query_argv(name, plants[0]))}", **_time_figures(jit)},
        "warm_up": {"code": warm["code"], "wall_s": warm["wall_s"]},
        "failures": [{"code": d["code"], "error": d["error"]} for d in done if d["code"] != 0],
        "torch_imported": None if m is None else m.group(1) == "True",
        "numba_imported": None if nb is None else nb.group(1) == "True", "aot_kernel": aot,
        "probe_error": probe["error"] if m is None or probe["code"] != 0 else "",
    }
