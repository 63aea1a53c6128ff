"""Benchmark: REST API latency and throughput against a real uvicorn server on 127.0.0.1.

Run::

    gaintune bench api             # or: python -m gaintune.bench.api [--requests 500] [--concurrency 8] [--json]
                                   #     [--compute-processes N]  (0: no process pool, the old mode)
                                   #     [--sweep 1,2,4,8,16]  (extra verify_distinct runs at these concurrencies)
                                   #     [--phases verify,simulate,jobs] [--simulate-scenarios 1,16]

Phases (each bounded by ``--requests`` requests or ``--seconds`` seconds):

1. ``verify_distinct``: ``POST /v1/verify`` on a 2-loop DC-motor cascade (speed PI
   outside, current PI inside; inline state-space spec), every request with
   different gains (seeded log-uniform factors in [0.8, 1.25] on nominal
   gains), so each one is a full verification (no cache hit).
2. ``verify_repeat``: the same request over and over (served from the
   server's verification LRU cache after the first).
3. ``simulate``: ``POST /v1/simulate`` on 1/(s+1)^3 with ``--simulate-scenarios``
   scenarios of 2,000 steps (about 100 KB of traces each), ``--simulate-requests``
   requests at ``--simulate-concurrency`` (1), with the compute pool's respawns and
   thread fallbacks during each phase (from ``/metrics``).
4. ``get_job_idle``: ``GET /v1/jobs/{id}`` with no job running.
5. ``get_job_2_jobs``: the same while 2 tuning jobs run in the 2 worker
   processes (both CPUs busy with the RL search); then both jobs are cancelled
   and the time until they report ``cancelled`` is printed.

Targets (issue): verify p95 <= 50 ms and >= 200 requests/s; GET stays low while jobs run;
no compute pool respawns, and simulate p50 with 16 scenarios <= 2 x the p50 with 1.
"""

from __future__ import annotations

import argparse
import asyncio
import json
import os
import re
import tempfile
import time
from collections.abc import Callable
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from gaintune.bench.api_load import (
    LoadClient,
    RawClient,
    Request,
    free_port,
    run_load,
    start_server,
    stop_server,
    wait_ready,
)
from gaintune.bench.arguments import BenchParser, int_list, int_range, non_negative_int, positive_float, positive_int

if TYPE_CHECKING:  # pragma: no cover
    import httpx

__all__ = ["main", "CASCADE_SPEC", "NOMINAL_GAINS", "simulate_spec"]

R, Lm, J, b, Kt = 1.0, 0.01, 0.01, 0.001, 0.5

#: DC motor (states current i, speed w), speed PI -> current PI.
CASCADE_SPEC = {
    "name": "dc_motor_speed_cascade",
    "plant": {
        "ss": {
            "A": [[-R / Lm, -Kt / Lm], [Kt / J, -b / J]],
            "B": [[1.0 / Lm], [0.0]],
            "C": [[1.0, 0.0], [0.0, 1.0]],
            "states": ["i", "w"],
            "outputs": ["i", "w"],
        }
    },
    "loops": [
        {"name": "speed", "type": "pi", "measure": "w",
         "gains": {"Kp": {"bounds": [0.05, 20]}, "Ki": {"bounds": [0.5, 500]}}},
        {"name": "current", "type": "pi", "measure": "i",
         "gains": {"Kp": {"bounds": [0.5, 50]}, "Ki": {"bounds": [10, 5000]}}},
    ],
    "scenario": {"dt": 1e-3, "horizon": 0.5},
}
NOMINAL_GAINS = {"speed": {"Kp": 2.0, "Ki": 40.0}, "current": {"Kp": 10.0, "Ki": 1000.0}}
#: Most requests in flight: each holds a socket (a file descriptor) and the server has 2 job workers.
MAX_CONCURRENCY = 1000
#: Gains of the ``/v1/simulate`` phases (on :func:`simulate_spec`).
SIMULATE_GAINS = {"loop0": {"Kp": 1.14, "Ki": 0.454}}
#: The server's default ``max_scenarios``.
MAX_SIMULATE_SCENARIOS = 16
#: The benchmark's phases, in the order they run.
PHASES = ("verify", "simulate", "jobs")


def _phase_list(text: str) -> list[str]:
    """Type of ``--phases``: comma-separated names from :data:`PHASES`, at least one."""
    names = [x.strip() for x in text.split(",") if x.strip()]
    unknown = [x for x in names if x not in PHASES]
    if unknown or not names:
        raise argparse.ArgumentTypeError(f"comma-separated names from {','.join(PHASES)}; got {text!r}")
    return names


def _in_process_verify_ms(n: int = 20) -> float:
    """Median time of one direct verify() call with distinct gains: the compute floor of a verify request."""
    from gaintune.spec import load_spec
    from gaintune.verification import verify

    spec = load_spec(CASCADE_SPEC)
    verify(spec, NOMINAL_GAINS)
    rng = np.random.default_rng(1)
    ts = []
    for _ in range(n):
        f = np.exp(rng.uniform(np.log(0.8), np.log(1.25), 4))
        g = {"speed": {"Kp": 2.0 * f[0], "Ki": 40.0 * f[1]}, "current": {"Kp": 10.0 * f[2], "Ki": 1000.0 * f[3]}}
        t0 = time.perf_counter()
        verify(spec, g)
        ts.append(time.perf_counter() - t0)
    return round(float(np.median(ts)) * 1e3, 2)


async def _verify_phases(
    c: httpx.AsyncClient, lc: LoadClient, args: argparse.Namespace, out: dict[str, Any]
) -> None:
    """``verify_distinct`` (every request a cache miss), ``verify_repeat`` (cached) and the ``--sweep``."""
    rng = np.random.default_rng(0)
    n_factors = args.requests + 64 + len(args.sweep) * args.sweep_requests
    factors = np.exp(rng.uniform(np.log(0.8), np.log(1.25), size=(n_factors, 4)))

    def distinct(i: int) -> Request:
        f = factors[i]
        g = {"speed": {"Kp": 2.0 * f[0], "Ki": 40.0 * f[1]}, "current": {"Kp": 10.0 * f[2], "Ki": 1000.0 * f[3]}}
        return "POST", "/v1/verify", {"spec": CASCADE_SPEC, "gains": g}

    def repeat(i: int) -> Request:
        return "POST", "/v1/verify", {"spec": CASCADE_SPEC, "gains": NOMINAL_GAINS}

    def distinct_from(base: int) -> Callable[[int], Request]:
        return lambda i: distinct(base + i)

    await run_load(c, lambda i: distinct(args.requests + (i % 64)), 16, 30, args.concurrency)  # warm-up (httpx)
    out["verify_distinct"] = await run_load(lc, distinct, args.requests, args.seconds, args.concurrency)
    out["verify_repeat"] = await run_load(lc, repeat, args.requests, args.seconds, args.concurrency)
    sweep: dict[str, dict[str, Any]] = {}
    for k, conc in enumerate(args.sweep):
        # fresh gains for every sweep point: every request is still a cache miss
        base = args.requests + 64 + k * args.sweep_requests
        sweep[str(conc)] = await run_load(lc, distinct_from(base), args.sweep_requests, args.seconds, conc)
    if sweep:
        out["verify_distinct_sweep"] = sweep


def simulate_spec(n_scenarios: int) -> dict[str, Any]:
    """1/(s+1)^3 with a PI and ``n_scenarios`` scenarios of 2,000 steps (reference steps at different times).

    Each scenario adds about 100 KB of traces to the ``/v1/simulate`` answer.
    """
    scenarios = [{"name": f"step{i}", "dt": 0.01, "horizon": 20.0, "reference": {"kind": "step", "time": 0.25 * i}}
                 for i in range(n_scenarios)]
    return {"name": f"simulate_{n_scenarios}", "plant": {"tf": {"num": [1], "den": "(s+1)^3"}},
            "loops": [{"type": "pi"}], "scenarios": scenarios}


def _always(request: Request) -> Callable[[int], Request]:
    """A request maker of :func:`run_load` that sends ``request`` every time."""
    return lambda i: request


async def _pool_counts(c: httpx.AsyncClient, tmp: Path) -> dict[str, int | None]:
    """The compute pool's respawns and thread fallbacks so far, from ``/metrics``. A server without those
    series (older code): respawns from its log's "compute worker N died" warnings, fallbacks unknown (None)."""
    text = (await c.get("/metrics")).text
    counts: dict[str, int | None] = {}
    series = (("respawns", "gaintune_compute_restarts_total"), ("fallbacks", "gaintune_compute_fallbacks_total"))
    for key, name in series:
        m = re.search(rf"^{name} (\S+)$", text, re.M)
        counts[key] = int(float(m.group(1))) if m else None
    if counts["respawns"] is None:
        counts["respawns"] = len(re.findall(r"compute worker \d+ died", (tmp / "server.log").read_text()))
    return counts


async def _simulate_phases(
    c: httpx.AsyncClient, lc: LoadClient, args: argparse.Namespace, tmp: Path, out: dict[str, Any]
) -> None:
    """``POST /v1/simulate`` with each ``--simulate-scenarios`` count, the same request over and over
    (simulate has no cache), at ``--simulate-concurrency``; with the answer's size and the pool's
    respawns and thread fallbacks during the phase."""
    res: dict[str, dict[str, Any]] = {}
    for n in args.simulate_scenarios:
        body = {"spec": simulate_spec(n), "gains": SIMULATE_GAINS}
        before = await _pool_counts(c, tmp)
        r = await lc.request("POST", "/v1/simulate", json=body)  # also warms the spec's caches in a worker
        if r.status_code != 200:
            raise SystemExit(f"/v1/simulate with {n} scenarios answered {r.status_code}: {r.content[:500]!r}")
        phase = await run_load(lc, _always(("POST", "/v1/simulate", body)), args.simulate_requests,
                               args.seconds, args.simulate_concurrency)
        after = await _pool_counts(c, tmp)
        phase["answer_kb"] = round(len(r.content) / 1024, 1)
        for k in ("respawns", "fallbacks"):
            a, b = after[k], before[k]
            phase[k] = None if a is None or b is None else a - b
        res[str(n)] = phase
    out["simulate"] = res
    out["simulate_concurrency"] = args.simulate_concurrency


async def _job_phases(
    c: httpx.AsyncClient, lc: LoadClient, args: argparse.Namespace, out: dict[str, Any]
) -> None:
    """GET a job with none running, then while 2 tuning jobs run; then cancel both and time it."""
    tune_spec = {**CASCADE_SPEC, "search": {"budget": 100_000, "n_envs": 32}}
    idle = (await c.post("/v1/tune", json={**tune_spec, "name": "probe"})).json()["id"]
    await c.delete(f"/v1/jobs/{idle}")
    out["get_job_idle"] = await run_load(lc, lambda i: ("GET", f"/v1/jobs/{idle}", None), args.requests,
                                         args.seconds, args.concurrency)
    jobs = [(await c.post("/v1/tune", json={**tune_spec, "name": f"load{k}"})).json()["id"] for k in range(2)]
    t0 = time.perf_counter()
    started = True
    while True:
        st = [(await c.get(f"/v1/jobs/{j}")).json() for j in jobs]
        if all(s["status"] == "running" and s["progress"] for s in st):
            break
        if time.perf_counter() - t0 > args.job_start_timeout:
            # e.g. a cold numba cache: report the other phases rather than nothing
            out["jobs_error"] = (
                f"jobs reported no progress within {args.job_start_timeout} s: {[s['status'] for s in st]}"
            )
            started = False
            break
        await asyncio.sleep(0.2)
    out["jobs_start_s"] = round(time.perf_counter() - t0, 1)
    if started:
        out["get_job_2_jobs"] = await run_load(lc, lambda i: ("GET", f"/v1/jobs/{jobs[i % 2]}", None),
                                               args.requests, args.seconds, args.concurrency)
        out["sims_while_measuring"] = [(await c.get(f"/v1/jobs/{j}")).json()["progress"]["sims"] for j in jobs]
    t0 = time.perf_counter()
    for j in jobs:
        await c.delete(f"/v1/jobs/{j}")
    while True:
        states = [(await c.get(f"/v1/jobs/{j}")).json()["status"] for j in jobs]
        if "running" not in states or time.perf_counter() - t0 > 60:
            break
        await asyncio.sleep(0.05)
    out["cancelled_states"] = states
    out["cancel_s"] = round(time.perf_counter() - t0, 2)


async def _run(args: argparse.Namespace) -> dict[str, Any]:
    import httpx

    tmp = Path(tempfile.mkdtemp(prefix="gaintune-bench-api-"))
    port = free_port()
    load0 = [round(x, 2) for x in os.getloadavg()]
    in_process = _in_process_verify_ms()
    out: dict[str, Any] = {
        "url": f"http://127.0.0.1:{port}", "cpus": os.cpu_count(), "concurrency": args.concurrency,
        "client": args.client, "phases": args.phases, "loadavg_start": load0, "verify_in_process_ms": in_process,
        "compute_processes": "default" if args.compute_processes is None else args.compute_processes,
    }
    proc = start_server(tmp, port, workers=2, compute_processes=args.compute_processes)
    try:  # nothing between the start and this try may raise: the finally stops the server
        limits = httpx.Limits(max_connections=args.concurrency * 2)
        async with httpx.AsyncClient(base_url=out["url"], timeout=60, limits=limits) as c:
            out["startup_s"] = await wait_ready(c, proc, tmp)
            r = await c.post("/v1/verify", json={"spec": CASCADE_SPEC, "gains": NOMINAL_GAINS})
            r.raise_for_status()
            out["verdict_nominal"] = r.json()["verdict"]
            lc: LoadClient = c if args.client == "httpx" else RawClient("127.0.0.1", port)  # the load phases' client
            try:
                if "verify" in args.phases:
                    await _verify_phases(c, lc, args, out)
                if "simulate" in args.phases:
                    await _simulate_phases(c, lc, args, tmp, out)
                if "jobs" in args.phases:
                    await _job_phases(c, lc, args, out)
            finally:
                if isinstance(lc, RawClient):
                    await lc.aclose()
    finally:
        stop_server(proc)
    return out


def _print_table(out: dict[str, Any]) -> None:
    """The phases measured, as a Markdown table, and the targets they are held to."""
    print("| phase | requests | req/s | p50 ms | p95 ms | p99 ms | errors | pool respawns / thread fallbacks |")
    print("|---|---:|---:|---:|---:|---:|---|---|")
    rows = [(k, out.get(k)) for k in ("verify_distinct", "verify_repeat")]
    rows += [(f"verify_distinct, concurrency {c}", r) for c, r in out.get("verify_distinct_sweep", {}).items()]
    rows += [(f"simulate, {n} scenario(s), {r['answer_kb']} KB answer, concurrency {out['simulate_concurrency']}", r)
             for n, r in out.get("simulate", {}).items()]
    rows += [(k, out.get(k)) for k in ("get_job_idle", "get_job_2_jobs")]
    for name, r in rows:
        if r is None:
            print(f"| {name} | - | - | - | - | - | not measured | - |")
            continue
        pool = "-" if "respawns" not in r else f"{r['respawns']} / {'?' if r['fallbacks'] is None else r['fallbacks']}"
        print(f"| {name} | {r['requests']} | {r['rps']} | {r['p50_ms']} | {r['p95_ms']} | {r['p99_ms']} | "
              f"{r['errors'] or '-'} | {pool} |")
    if "jobs_error" in out:
        print(f"get_job_2_jobs not measured: {out['jobs_error']}")
    elif "cancel_s" in out:
        print(f"2 jobs ran {out.get('sims_while_measuring')} simulations by the end of the GET phase "
              f"(first progress {out['jobs_start_s']} s after submission); "
              f"both cancelled within {out['cancel_s']} s of DELETE")
    vd = out.get("verify_distinct")
    if vd is not None:
        print(f"targets: verify p95 <= 50 ms: {'met' if vd['p95_ms'] <= 50 else 'MISSED'} ({vd['p95_ms']} ms, distinct "
              f"gains); >= 200 req/s: {'met' if vd['rps'] >= 200 else 'MISSED'} ({vd['rps']} req/s, distinct gains)")
    sim = out.get("simulate", {})
    if sim:
        respawns = sum(r["respawns"] for r in sim.values())
        print(f"targets: no compute pool respawns in the simulate phases: {'met' if respawns == 0 else 'MISSED'} "
              f"({respawns})", end="")
        if "1" in sim and "16" in sim:
            one, many = sim["1"]["p50_ms"], sim["16"]["p50_ms"]
            print(f"; simulate p50 with 16 scenarios <= 2 x with 1: {'met' if many <= 2 * one else 'MISSED'} "
                  f"({many} ms vs {one} ms, {many / one:.1f} x)", end="")
        print()


def main(argv: list[str] | None = None) -> int:
    """``gaintune bench api``: parse ``argv``, run the phases on a fresh server, print a table (or ``--json``).

    Returns
    -------
    int
        0; bad arguments exit 2 before a server starts.
    """
    # every argument is checked here, before the server starts (concurrency 0 waited for ever on no requests)
    ap = BenchParser(prog="gaintune bench api", description="REST API latency/throughput on a real server.")
    ap.add_argument("--requests", type=positive_int, default=500, help="requests per phase (upper bound)")
    ap.add_argument("--seconds", type=positive_float, default=20.0, help="seconds per phase (upper bound)")
    ap.add_argument("--concurrency", type=int_range(1, MAX_CONCURRENCY), default=8,
                    help=f"requests in flight in every phase, 1 .. {MAX_CONCURRENCY}")
    ap.add_argument("--sweep", type=int_list(1, MAX_CONCURRENCY), default=[],
                    help="extra verify_distinct runs at these concurrencies, e.g. 1,2,4,8,16")
    ap.add_argument("--sweep-requests", type=positive_int, default=300, help="requests per sweep point (upper bound)")
    ap.add_argument("--phases", type=_phase_list, default=list(PHASES),
                    help=f"which phases run, comma-separated from {','.join(PHASES)} (default: all)")
    ap.add_argument("--simulate-scenarios", type=int_list(1, MAX_SIMULATE_SCENARIOS), default=[1, 16],
                    help=f"/v1/simulate phases with these scenario counts, 1 .. {MAX_SIMULATE_SCENARIOS} "
                         "(default 1,16)")
    ap.add_argument("--simulate-requests", type=positive_int, default=100,
                    help="requests per simulate phase (upper bound)")
    ap.add_argument("--simulate-concurrency", type=int_range(1, MAX_CONCURRENCY), default=1,
                    help="requests in flight in the simulate phases (default 1: latency without queueing)")
    ap.add_argument("--job-start-timeout", type=positive_float, default=300.0,
                    help="seconds to wait for the 2 tuning jobs to report progress (cold numba caches compile first)")
    ap.add_argument("--compute-processes", type=non_negative_int, default=None,
                    help="server's compute_processes (default: the server default; 0: compute in the server process)")
    ap.add_argument("--client", choices=("raw", "httpx"), default="raw",
                    help="load-phase HTTP client: raw (light keep-alive HTTP/1.1, default) or httpx (about 2.5 ms CPU "
                         "per request on the shared CPUs)")
    ap.add_argument("--json", action="store_true", help="print JSON instead of a table")
    args = ap.parse_args(argv)
    out = asyncio.run(_run(args))
    out["loadavg_end"] = [round(x, 2) for x in os.getloadavg()]
    if args.json:
        print(json.dumps(out, indent=2))
        return 0
    print(f"server {out['url']} ({out['cpus']} CPUs, 2 job workers, compute_processes {out['compute_processes']}), "
          f"ready in {out['startup_s']} s; "
          f"concurrency {out['concurrency']}, {out['client']} client; nominal verdict {out['verdict_nominal']}")
    print(f"load average at start {out['loadavg_start']}, at end {out['loadavg_end']}; one verify() in-process "
          f"(no HTTP, distinct gains): {out['verify_in_process_ms']} ms median")
    _print_table(out)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
