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
import signal
import socket
import subprocess
import sys
import tempfile
import time
from collections.abc import Callable
from pathlib import Path

import numpy as np

from gaintune.bench.arguments import BenchParser, int_list, int_range, non_negative_int, positive_float, positive_int

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
        {"name": "speed", "type": "pi", "measure": "w", "gains": {"Kp": {"bounds": [0.05, 20]}, "Ki": {"bounds": [0.5, 500]}}},
        {"name": "current", "type": "pi", "measure": "i", "gains": {"Kp": {"bounds": [0.5, 50]}, "Ki": {"bounds": [10, 5000]}}},
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


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def _pct(x: list[float], q: float) -> float:
    return float(np.percentile(np.asarray(x) * 1e3, q)) if x else float("nan")


class _Response:
    __slots__ = ("status_code", "content")

    def __init__(self, status_code: int, content: bytes) -> None:
        self.status_code, self.content = status_code, content

    def json(self):
        return json.loads(self.content)


class RawClient:
    """A minimal HTTP/1.1 keep-alive client for the load phases (``--client raw``, the default).

    The load generator shares the 2 CPUs with the server it measures; httpx spends about
    2.5 ms of CPU per request here, which the server then does not get. This client writes
    the request bytes and reads the status line, headers and ``Content-Length`` (or chunked)
    body on a pool of persistent connections: a fraction of that cost. Same interface as
    ``httpx.AsyncClient.request`` for what :func:`_load` uses.
    """

    def __init__(self, host: str, port: int) -> None:
        self.host, self.port = host, port
        self._idle: list[tuple[asyncio.StreamReader, asyncio.StreamWriter]] = []

    async def request(self, method: str, url: str, json=None) -> _Response:  # noqa: A002 - httpx's name
        import json as _json

        body = b"" if json is None else _json.dumps(json).encode()
        head = (f"{method} {url} HTTP/1.1\r\nHost: {self.host}:{self.port}\r\n"
                + ("Content-Type: application/json\r\n" if json is not None else "")
                + f"Content-Length: {len(body)}\r\n\r\n").encode()
        while True:
            reused = bool(self._idle)
            conn = self._idle.pop() if reused else await asyncio.open_connection(self.host, self.port)
            reader, writer = conn
            try:
                writer.write(head + body)
                line = await reader.readline()
            except (ConnectionError, OSError):
                line = b""
            if line:
                break
            writer.close()
            if not reused:  # a fresh connection closed at once: a real error
                raise ConnectionError("server closed the connection without a response")
            # the server closed an idle keep-alive connection (uvicorn: after 5 s): retry on a new one
        status = int(line.split(b" ", 2)[1])
        length, chunked, close = None, False, False
        while True:
            line = await reader.readline()
            if line in (b"\r\n", b"\n", b""):
                break
            k, _, v = line.partition(b":")
            k = k.strip().lower()
            if k == b"content-length":
                length = int(v)
            elif k == b"transfer-encoding" and b"chunked" in v.lower():
                chunked = True
            elif k == b"connection" and b"close" in v.lower():
                close = True
        if chunked:
            parts = []
            while True:
                size = int((await reader.readline()).split(b";")[0], 16)
                if size == 0:
                    await reader.readline()
                    break
                parts.append(await reader.readexactly(size))
                await reader.readline()
            content = b"".join(parts)
        else:
            content = await reader.readexactly(length or 0)
        if close:
            writer.close()
        else:
            self._idle.append(conn)
        return _Response(status, content)

    async def aclose(self) -> None:
        for _, w in self._idle:
            w.close()
        self._idle.clear()


async def _load(client, make_request, n: int, seconds: float, concurrency: int) -> dict:
    """Fire up to n requests (or for `seconds`) with `concurrency` in flight; latency per request."""
    lat: list[float] = []
    errors: dict[int, int] = {}
    counter = iter(range(n))
    t_end = time.perf_counter() + seconds

    async def one_worker():
        for i in counter:
            if time.perf_counter() > t_end:
                return
            method, url, body = make_request(i)
            t0 = time.perf_counter()
            r = await client.request(method, url, json=body)
            lat.append(time.perf_counter() - t0)
            if r.status_code >= 300:
                errors[r.status_code] = errors.get(r.status_code, 0) + 1

    t0 = time.perf_counter()
    await asyncio.gather(*(one_worker() for _ in range(concurrency)))
    wall = time.perf_counter() - t0
    return {"requests": len(lat), "seconds": round(wall, 2), "rps": round(len(lat) / wall, 1),
            "p50_ms": round(_pct(lat, 50), 2), "p95_ms": round(_pct(lat, 95), 2), "p99_ms": round(_pct(lat, 99), 2),
            "errors": errors}


def _term_with_parent() -> Callable[[], None] | None:
    """A ``preexec_fn`` that has Linux send the child SIGTERM when this process dies (None elsewhere).

    The ``finally`` of :func:`_run` stops the server on every exception, but not when this
    process is SIGKILLed (``timeout -s KILL``, the OOM killer): the server and its job workers
    were left running. SIGTERM lets the server stop its workers itself. libc is loaded here,
    in the parent: the child between fork and exec only calls it.
    """
    if not sys.platform.startswith("linux"):
        return None
    try:
        import ctypes

        prctl = ctypes.CDLL("libc.so.6", use_errno=True).prctl
    except OSError:  # pragma: no cover - no glibc
        return None
    return lambda: prctl(1, signal.SIGTERM, 0, 0, 0)  # PR_SET_PDEATHSIG


def _start_server(tmp: Path, port: int, workers: int, compute_processes: int | None = None) -> subprocess.Popen:
    env = dict(os.environ, GAINTUNE_DB_PATH=str(tmp / "jobs.db"), GAINTUNE_DATA_DIR=str(tmp / "data"))
    if compute_processes is not None:
        env["GAINTUNE_COMPUTE_PROCESSES"] = str(compute_processes)
    cmd = [sys.executable, "-m", "gaintune_api", "--host", "127.0.0.1", "--port", str(port), "--workers", str(workers),
           "--log-level", "warning"]
    with open(tmp / "server.log", "w") as log:  # the child keeps its own copy of the descriptor
        return subprocess.Popen(cmd, cwd=tmp, env=env, stdout=log, stderr=subprocess.STDOUT,
                                preexec_fn=_term_with_parent())


def _stop_server(proc: subprocess.Popen) -> None:
    """SIGTERM, then SIGKILL after 15 s: the server must never outlive the benchmark."""
    if proc.poll() is not None:
        return
    proc.send_signal(signal.SIGTERM)
    try:
        proc.wait(15)
    except subprocess.TimeoutExpired:
        proc.kill()
        proc.wait()


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


async def _wait_ready(c, proc: subprocess.Popen, tmp: Path) -> float:
    """Seconds until ``/readyz`` says ready (SystemExit when the server exits or takes over 120 s)."""
    import httpx

    t0 = time.perf_counter()
    while True:
        if proc.poll() is not None:
            raise SystemExit("server exited:\n" + (tmp / "server.log").read_text()[-3000:])
        try:
            if (await c.get("/readyz")).status_code == 200:
                return round(time.perf_counter() - t0, 1)
        except httpx.TransportError:
            pass
        if time.perf_counter() - t0 > 120:
            raise SystemExit("server not ready after 120 s")
        await asyncio.sleep(0.2)


async def _verify_phases(c, lc, args, out: dict) -> None:
    """``verify_distinct`` (every request a cache miss), ``verify_repeat`` (cached) and the ``--sweep``."""
    rng = np.random.default_rng(0)
    n_factors = args.requests + 64 + len(args.sweep) * args.sweep_requests
    factors = np.exp(rng.uniform(np.log(0.8), np.log(1.25), size=(n_factors, 4)))

    def distinct(i):
        f = factors[i]
        g = {"speed": {"Kp": 2.0 * f[0], "Ki": 40.0 * f[1]}, "current": {"Kp": 10.0 * f[2], "Ki": 1000.0 * f[3]}}
        return "POST", "/v1/verify", {"spec": CASCADE_SPEC, "gains": g}

    def repeat(i):
        return "POST", "/v1/verify", {"spec": CASCADE_SPEC, "gains": NOMINAL_GAINS}

    await _load(c, lambda i: distinct(args.requests + (i % 64)), 16, 30, args.concurrency)  # warm-up (httpx)
    out["verify_distinct"] = await _load(lc, distinct, args.requests, args.seconds, args.concurrency)
    out["verify_repeat"] = await _load(lc, repeat, args.requests, args.seconds, args.concurrency)
    sweep = {}
    for k, conc in enumerate(args.sweep):
        # fresh gains for every sweep point: every request is still a cache miss
        base = args.requests + 64 + k * args.sweep_requests
        sweep[str(conc)] = await _load(lc, lambda i, b=base: distinct(b + i), args.sweep_requests, args.seconds, conc)
    if sweep:
        out["verify_distinct_sweep"] = sweep


def simulate_spec(n_scenarios: int) -> dict:
    """1/(s+1)^3 with a PI and ``n_scenarios`` scenarios of 2,000 steps (reference steps at different times):
    each scenario adds about 100 KB of traces to the ``/v1/simulate`` answer."""
    scenarios = [{"name": f"step{i}", "dt": 0.01, "horizon": 20.0, "reference": {"kind": "step", "time": 0.25 * i}}
                 for i in range(n_scenarios)]
    return {"name": f"simulate_{n_scenarios}", "plant": {"tf": {"num": [1], "den": "(s+1)^3"}},
            "loops": [{"type": "pi"}], "scenarios": scenarios}


async def _pool_counts(c, tmp: Path) -> dict[str, int | None]:
    """The compute pool's respawns and thread fallbacks so far, from ``/metrics``. A server without those
    series (older code): respawns from its log's "compute worker N died" warnings, fallbacks unknown (None)."""
    text = (await c.get("/metrics")).text
    counts: dict[str, int | None] = {}
    for key, name in (("respawns", "gaintune_compute_restarts_total"), ("fallbacks", "gaintune_compute_fallbacks_total")):
        m = re.search(rf"^{name} (\S+)$", text, re.M)
        counts[key] = int(float(m.group(1))) if m else None
    if counts["respawns"] is None:
        counts["respawns"] = len(re.findall(r"compute worker \d+ died", (tmp / "server.log").read_text()))
    return counts


async def _simulate_phases(c, lc, args, tmp: Path, out: dict) -> None:
    """``POST /v1/simulate`` with each ``--simulate-scenarios`` count, the same request over and over
    (simulate has no cache), at ``--simulate-concurrency``; with the answer's size and the pool's
    respawns and thread fallbacks during the phase."""
    res = {}
    for n in args.simulate_scenarios:
        body = {"spec": simulate_spec(n), "gains": SIMULATE_GAINS}
        before = await _pool_counts(c, tmp)
        r = await lc.request("POST", "/v1/simulate", json=body)  # also warms the spec's caches in a worker
        if r.status_code != 200:
            raise SystemExit(f"/v1/simulate with {n} scenarios answered {r.status_code}: {r.content[:500]!r}")
        phase = await _load(lc, lambda i, b=body: ("POST", "/v1/simulate", b), args.simulate_requests, args.seconds,
                            args.simulate_concurrency)
        after = await _pool_counts(c, tmp)
        phase["answer_kb"] = round(len(r.content) / 1024, 1)
        for k in ("respawns", "fallbacks"):
            phase[k] = None if after[k] is None or before[k] is None else after[k] - before[k]
        res[str(n)] = phase
    out["simulate"] = res
    out["simulate_concurrency"] = args.simulate_concurrency


async def _job_phases(c, lc, args, out: dict) -> None:
    """GET a job with none running, then while 2 tuning jobs run; then cancel both and time it."""
    tune_spec = {**CASCADE_SPEC, "search": {"budget": 100_000, "n_envs": 32}}
    idle = (await c.post("/v1/tune", json={**tune_spec, "name": "probe"})).json()["id"]
    await c.delete(f"/v1/jobs/{idle}")
    out["get_job_idle"] = await _load(lc, lambda i: ("GET", f"/v1/jobs/{idle}", None), args.requests,
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
            out["jobs_error"] = f"jobs reported no progress within {args.job_start_timeout} s: {[s['status'] for s in st]}"
            started = False
            break
        await asyncio.sleep(0.2)
    out["jobs_start_s"] = round(time.perf_counter() - t0, 1)
    if started:
        out["get_job_2_jobs"] = await _load(lc, lambda i: ("GET", f"/v1/jobs/{jobs[i % 2]}", None), args.requests,
                                            args.seconds, args.concurrency)
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


async def _run(args) -> dict:
    import httpx

    tmp = Path(tempfile.mkdtemp(prefix="gaintune-bench-api-"))
    port = _free_port()
    load0 = [round(x, 2) for x in os.getloadavg()]
    in_process = _in_process_verify_ms()
    out: dict = {"url": f"http://127.0.0.1:{port}", "cpus": os.cpu_count(), "concurrency": args.concurrency,
                 "client": args.client, "phases": args.phases,
                 "loadavg_start": load0, "verify_in_process_ms": in_process,
                 "compute_processes": "default" if args.compute_processes is None else args.compute_processes}
    proc = _start_server(tmp, port, workers=2, compute_processes=args.compute_processes)
    try:  # nothing between the start and this try may raise: the finally stops the server
        limits = httpx.Limits(max_connections=args.concurrency * 2)
        async with httpx.AsyncClient(base_url=out["url"], timeout=60, limits=limits) as c:
            out["startup_s"] = await _wait_ready(c, proc, tmp)
            r = await c.post("/v1/verify", json={"spec": CASCADE_SPEC, "gains": NOMINAL_GAINS})
            r.raise_for_status()
            out["verdict_nominal"] = r.json()["verdict"]
            lc = c if args.client == "httpx" else RawClient("127.0.0.1", port)  # the load phases' client
            try:
                if "verify" in args.phases:
                    await _verify_phases(c, lc, args, out)
                if "simulate" in args.phases:
                    await _simulate_phases(c, lc, args, tmp, out)
                if "jobs" in args.phases:
                    await _job_phases(c, lc, args, out)
            finally:
                if lc is not c:
                    await lc.aclose()
    finally:
        _stop_server(proc)
    return out


def _print_table(out: dict) -> None:
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
              f"(first progress {out['jobs_start_s']} s after submission); both cancelled within {out['cancel_s']} s of DELETE")
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
                    help=f"/v1/simulate phases with these scenario counts, 1 .. {MAX_SIMULATE_SCENARIOS} (default 1,16)")
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
