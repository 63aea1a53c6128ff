"""Chaos benchmark phases of issue 24: a frozen worker holding the database write lock, and a full database at a
job's finish. Used by :mod:`gaintune.bench.chaos` (``--phases lock,diskfull``); real servers over HTTP only.

* lock: a process named like a worker claims a queued job, opens a write transaction (``BEGIN IMMEDIATE``) and
  stops itself (SIGSTOP). While it holds the lock, ``--writers`` threads keep writes coming (each cancels a
  queued job, or with ``--write post`` submits one; ``--write-pause`` s between a writer's answer and its next
  write) and a reader times ``GET /v1/jobs/{id}``. Measured: GET p50/p95/max, how long a write takes to be
  refused (and with what), and when the supervisor kills the frozen holder, compared with the end of its lease.
  A job whose supervised worker was merely blocked must go on (attempt 1).
* diskfull: two jobs end their search while every finishing COMMIT fails with SQLITE_FULL (the tests-only
  fault ``db:full@finish``: the files are already renamed into place when the COMMIT fails), then the whole
  database is full for longer than a lease, then space is back. A third job, queued meanwhile, is taken by
  a worker. Counted: finished jobs lost or recomputed (attempts > 1), and the third job disturbed (re-run or
  its worker killed).
"""

from __future__ import annotations

import functools
import statistics
import sys
import threading
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

from gaintune.bench.chaos_procs import TERMINAL, Server, _proc_state, _serving, _wait, job_spec

__all__ = ["lock", "diskfull"]

# A stand-in for a worker frozen inside a write: it claims the job as a worker does (same columns), then
# takes the write lock and stops itself. It names itself like a worker (what the supervisor checks).
_HOLDER = """
import ctypes, os, signal, sqlite3, sys, time, uuid
ctypes.CDLL("libc.so.6").prctl(15, b"gaintune-worker", 0, 0, 0)
db, job = sys.argv[1], sys.argv[2]
c = sqlite3.connect(db, isolation_level=None, timeout=30)
now = time.time()
c.execute("BEGIN IMMEDIATE")
c.execute("UPDATE jobs SET status='running', claim=?, worker_pid=?, started_at=?, heartbeat_at=?, updated_at=?,"
          " attempts=attempts+1 WHERE id=? AND status='queued'", (uuid.uuid4().hex, os.getpid(), now, now, now, job))
c.execute("COMMIT")
c.execute("BEGIN IMMEDIATE")
c.execute("UPDATE jobs SET updated_at=? WHERE id=?", (time.time(), job))
print(now, flush=True)
os.kill(os.getpid(), signal.SIGSTOP)
"""




def _restarts(srv: Server) -> int:
    text = srv.client.get("/metrics").text
    return next((int(float(ln.split()[-1])) for ln in text.splitlines()
                 if ln.startswith("gaintune_worker_restarts_total")), -1)


def _pct(xs: list[float], q: float) -> float:
    if not xs:
        return float("nan")
    if len(xs) == 1:
        return xs[0]
    return statistics.quantiles(xs, n=100, method="inclusive")[int(q) - 1]


def _hammer(srv: Server, writers: int, pause: float, queued: str | None, stop: threading.Event,
            out: list) -> list[threading.Thread]:
    """``writers`` threads, each keeping one write in flight until ``stop``: (seconds, status, cause, Retry-After,
    end time). The write cancels job ``queued`` (a write transaction and little else), or with ``queued`` None
    submits a job (``POST /v1/tune``: the spec is fully validated first, milliseconds of CPU per request).
    Each writer waits ``pause`` seconds after an answer before its next write (0: back to back)."""
    import httpx

    def run(i: int) -> None:
        with httpx.Client(base_url=srv.url, timeout=120) as c:
            while not stop.is_set():
                t0 = time.perf_counter()
                r = c.delete(f"/v1/jobs/{queued}") if queued else c.post("/v1/tune", json=job_spec(500 + i, 50))
                cause = r.json().get("cause") if r.status_code >= 500 else None
                out.append((time.perf_counter() - t0, r.status_code, cause, r.headers.get("retry-after"), time.time()))
                stop.wait(pause)

    ths = [threading.Thread(target=run, args=(i,), daemon=True) for i in range(writers)]
    for t in ths:
        t.start()
    return ths


def _time_reads(srv: Server, job: str, holder: int, give_up: float, reads: list[float]) -> float:
    """Time ``GET /v1/jobs/{job}`` while process ``holder`` is stopped; returns the last time it was seen stopped."""
    import httpx

    last_locked = time.time()
    with httpx.Client(base_url=srv.url, timeout=120) as c:
        while _proc_state(holder) in ("T", "t") and time.time() < give_up:
            last_locked = time.time()
            t0 = time.perf_counter()
            r = c.get(f"/v1/jobs/{job}")
            dt = time.perf_counter() - t0
            if _proc_state(holder) in ("T", "t") and r.status_code == 200:  # answered while locked
                reads.append(dt)
            time.sleep(0.02)
    return last_locked


def _timings(reads: list[float], writes: list[tuple], since: float, until: float) -> dict:
    """GET latencies and write refusals answered while the lock was held (reads timed from ``since``)."""
    writes = [w for w in writes if w[4] <= until]
    refused = [w for w in writes if w[1] >= 500]
    times = [w[0] for w in refused]
    return {
        "reads_while_locked": len(reads), "get_ms_p50": round(1000 * _pct(reads, 50), 1),
        "get_ms_p95": round(1000 * _pct(reads, 95), 1), "get_ms_max": round(1000 * max(reads or [float("nan")]), 1),
        "writes_refused": len(refused), "writes_accepted_while_locked": len(writes) - len(refused),
        "writes_per_s": round(sum(w[4] >= since for w in writes) / max(1e-9, until - since), 1),
        "refusal_s_p50": round(_pct(times, 50), 3), "refusal_s_p95": round(_pct(times, 95), 3),
        "refusal_s_max": round(max(times or [float("nan")]), 3),
        "refusal_statuses": sorted({(w[1], w[2]) for w in refused}, key=str),
        "refusals_without_retry_after": sum(1 for w in refused if not w[3]),
    }


def lock(root: Path, writers: int, write: str, pause: float, lease: float, budget: int, log: Callable) -> dict:
    """Freeze a lock-holding 'worker'; time reads and refused writes; see when its lease is enforced."""
    import subprocess

    hold = root / "hold"
    hold.parent.mkdir(parents=True, exist_ok=True)
    hold.touch()
    with _serving(root, 1, GAINTUNE_HEARTBEAT_TIMEOUT=f"{lease:g}", GAINTUNE_TEST_HOLD_FILE=str(hold),
                  GAINTUNE_MAX_QUEUE="100000") as srv:
        busy = srv.submit(job_spec(400, budget))  # the supervised worker's job: blocked by the lock, not frozen
        _wait(lambda: srv.job(busy)["progress"], 300, "the supervised worker's job to run")
        victim = srv.submit(job_spec(401, budget))
        target = srv.submit(job_spec(499, 50)) if write == "delete" else None  # never cancelled while locked
        holder = subprocess.Popen([sys.executable, "-c", _HOLDER, str(srv.db), victim], stdout=subprocess.PIPE,
                                  text=True)
        assert holder.stdout is not None  # stdout=PIPE
        claimed_at = float(holder.stdout.readline())
        _wait(lambda: _proc_state(holder.pid) in ("T", "t"), 30, "the lock holder to freeze", 0.01)
        lease_end = claimed_at + lease
        stop = threading.Event()
        writes: list[tuple[Any, ...]] = []
        reads: list[float] = []
        ths = _hammer(srv, writers, pause, target, stop, writes)
        time.sleep(0.5)  # let the writers fill the queue before the first timed read
        reads_from = time.time()
        last_locked = _time_reads(srv, busy, holder.pid, lease_end + 120, reads)
        killed_at = time.time()
        frozen_left = _proc_state(holder.pid) in ("T", "t")
        stop.set()
        for t in ths:
            t.join(150)
        holder.kill()
        holder.wait(30)
        recovered = _wait(lambda: (lambda j: j if j["status"] != "running" else None)(srv.job(victim)), 60,
                          "the frozen holder's job to be recovered")
        still = srv.job(busy)
        hold.unlink()
        done = _wait(lambda: (lambda j: j if j["status"] in TERMINAL else None)(srv.job(busy)), 300,
                     "the blocked job to finish")
        restarts = _restarts(srv)
    out = {"writers": writers, "write": write, "write_pause_s": pause,
           **_timings(reads, writes, reads_from, last_locked),
           "lease_s": lease, "holder_killed_s_after_lease_end": round(killed_at - lease_end, 2),
        "holder_never_killed": int(frozen_left), "holder_job_after": f"{recovered['status']}: {recovered['error']}",
        "blocked_job_status_during": still["status"], "blocked_job_attempts": done["attempts"],
        "blocked_job_final": done["status"], "worker_restarts": restarts}
    log(f"  lock: GET p95 {out['get_ms_p95']} ms over {len(reads)} reads; {out['writes_refused']} writes refused, "
        f"p95 {out['refusal_s_p95']} s; holder killed {out['holder_killed_s_after_lease_end']} s after its lease")
    return out


def _logged(srv: Server, text: str) -> int:
    return srv.log.read_text(errors="replace").count(text)


def diskfull(root: Path, rounds: int, lease: float, budget: int, log: Callable[[str], None]) -> dict[str, Any]:
    """Finishing COMMITs fail with SQLITE_FULL, then the whole database is full past a lease: count the damage."""
    hold, faults = root / "hold", root / "faults"
    out: dict[str, Any] = {"rounds": rounds, "finished_jobs": 0, "lost": 0, "recomputed": 0,
                           "unrelated_disturbed": 0, "worker_restarts": 0, "attempts": []}
    root.mkdir(parents=True, exist_ok=True)
    with _serving(root, 2, GAINTUNE_HEARTBEAT_TIMEOUT=f"{lease:g}", GAINTUNE_TEST_HOLD_FILE=str(hold),
                  GAINTUNE_TEST_STORAGE_FAULT_FILE=str(faults), GAINTUNE_LOG_LEVEL="warning") as srv:
        for r in range(rounds):
            ends, mid, last = _diskfull_round(srv, hold, faults, r, lease, budget)
            for j in ends:
                out["finished_jobs"] += 1
                out["lost"] += j["status"] != "succeeded"
                out["recomputed"] += j["attempts"] > 1
                out["attempts"].append(j["attempts"])
            out["unrelated_disturbed"] += mid["attempts"] > 1 or last["attempts"] > 1 or last["status"] != "succeeded"
            log(f"  diskfull: round {r + 1}: finished jobs {[(j['status'], j['attempts']) for j in ends]}, "
                f"unrelated job {last['status']} after {last['attempts']} attempt(s)")
        out["worker_restarts"] = _restarts(srv)
    return out


def _job_when(srv: Server, job_id: str, ok: Callable[[dict[str, Any]], bool]) -> dict[str, Any] | None:
    """Job ``job_id`` when ``ok(job)``, else None (a condition for :func:`_wait`)."""
    j = srv.job(job_id)
    return j if ok(j) else None


def _diskfull_round(
    srv: Server, hold: Path, faults: Path, r: int, lease: float, budget: int
) -> tuple[list[dict[str, Any]], dict[str, Any], dict[str, Any]]:
    """One round: 2 jobs whose finishing writes fail, then a full database while a third job waits.

    Returns the 2 finished jobs, the third job past a lease after it started, and the third job at its end.
    """
    hold.touch()
    a, b = srv.submit(job_spec(600 + 3 * r, budget)), srv.submit(job_spec(601 + 3 * r, budget))
    _wait(lambda: all(srv.job(j)["progress"] for j in (a, b)), 300, "both jobs to run")
    kept = _logged(srv, "result kept")
    faults.write_text("db:full@finish")  # the disk fills as the searches end
    hold.unlink()
    _wait(lambda: _logged(srv, "result kept") >= kept + 2 or any(
        srv.job(j)["status"] != "running" for j in (a, b)), 300, "both finishing writes to fail")
    hold.touch()
    c = srv.submit(job_spec(602 + 3 * r, budget))  # unrelated: queued while the disk is full
    faults.write_text("db:full")  # the whole database is full for longer than a lease
    time.sleep(2 * lease)
    faults.unlink()

    def written_or_rerun(x: dict[str, Any]) -> bool:
        return x["status"] in TERMINAL or x["attempts"] > 1

    ends = [_wait(functools.partial(_job_when, srv, j, written_or_rerun), 300,
                  "the finished jobs to be written (or re-run)") for j in (a, b)]
    _wait(lambda: srv.job(c)["status"] == "running" and srv.job(c)["progress"], 300, "the third job to run")
    time.sleep(lease + 1)  # past the lease the finished jobs' attempts held: nothing may happen to it
    mid = srv.job(c)
    hold.unlink()
    last = _wait(lambda: _job_when(srv, c, lambda x: x["status"] in TERMINAL), 300, "the third job to finish")
    return ends, mid, last
