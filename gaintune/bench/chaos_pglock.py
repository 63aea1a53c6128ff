"""Chaos phase ``lock`` on a PostgreSQL store (``gaintune bench chaos --db-url URL --phases lock``).

A process that claimed a job like a worker freezes (SIGSTOP) inside a write transaction of that job, holding
its row lock, while the server's own worker is mid-job. Meanwhile the bench submits jobs and reads jobs over
HTTP. Measured: GET and POST latencies and refusals while the lock is held (other rows: target 0 refused),
when PostgreSQL closes the frozen session (``db_idle_timeout``), when the supervisor re-queues the frozen
process's job (its lease, ``--lease``), and whether that job then succeeds once and the blocked worker's job
goes on (attempt 1). On SQLite the same freeze holds the whole file's write lock until the holder is killed.
"""

from __future__ import annotations

import os
import signal
import statistics
import subprocess
import sys
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

from gaintune.bench.chaos_procs import TERMINAL, Server, _proc_state, _wait, job_spec

__all__ = ["pg_lock"]

# A worker frozen mid-write: it claims the queued job through the real store, opens a write of it and stops.
_HOLDER = """
import os, signal, sys, time
from gaintune_api.job_store_pg import PgJobStore
store = PgJobStore(sys.argv[1], idle_timeout=float(sys.argv[2]))
job = store.claim(os.getpid())
try:
    with store._tx() as c:
        c.execute("UPDATE jobs SET updated_at=%s WHERE id=%s", (time.time(), job.id))
        pid = c.execute("SELECT pg_backend_pid() AS p").fetchone()["p"]
        print(job.id, pid, time.time(), flush=True)
        os.kill(os.getpid(), signal.SIGSTOP)
except Exception as exc:  # resumed: the server closed the session meanwhile, nothing was written
    print("resumed:", type(exc).__name__, flush=True)
"""


def _session_open(db_url: str, backend: int) -> bool:
    import psycopg

    with psycopg.connect(db_url, autocommit=True) as c:
        row = c.execute("SELECT COUNT(*) FROM pg_stat_activity WHERE pid=%s", (backend,)).fetchone()
        return bool(row and row[0])


def _pct(xs: list[float], q: int) -> float:
    return round(1000 * statistics.quantiles(xs, n=100)[q - 1], 1) if len(xs) > 1 else round(1000 * sum(xs), 1)


def _while_frozen(srv: Server, db_url: str, victim: str, backend: int, frozen_at: float) -> dict[str, Any]:
    """GETs and POSTs until the frozen process's job is recovered; the session's close and the re-queue times."""
    gets: list[float] = []
    posts: list[float] = []
    refused = 0
    closed_at = requeued = None
    i = 0
    while requeued is None and time.time() - frozen_at < 300:
        t = time.monotonic()
        job = srv.job(victim)
        gets.append(time.monotonic() - t)
        t = time.monotonic()
        r = srv.client.post("/v1/tune", json=job_spec(600 + i, 50))
        posts.append(time.monotonic() - t)
        refused += r.status_code != 202
        i += 1
        if closed_at is None and not _session_open(db_url, backend):
            closed_at = time.time()
        if job["status"] != "running" or job["attempts"] > 1:
            requeued = time.time()
        time.sleep(0.05)
    return {"get_ms_p50": _pct(gets, 50), "get_ms_p95": _pct(gets, 95), "post_ms_p95": _pct(posts, 95),
            "posts": len(posts), "posts_refused": refused,
            "session_closed_s": None if closed_at is None else round(closed_at - frozen_at, 2),
            "job_requeued_s": None if requeued is None else round(requeued - frozen_at, 2)}


def pg_lock(root: Path, db_url: str, lease: float, idle: float, budget: int, log: Callable[[str], None]) -> dict:
    """Freeze a row-lock holder on the PostgreSQL store; measure the service meanwhile and its recovery."""
    import secrets

    hold = root / "hold"
    root.mkdir(parents=True, exist_ok=True)
    hold.touch()
    srv = Server(root, 1, GAINTUNE_DB_URL=db_url, GAINTUNE_HEARTBEAT_TIMEOUT=f"{lease:g}",
                 GAINTUNE_DB_IDLE_TIMEOUT=f"{idle:g}", GAINTUNE_TEST_HOLD_FILE=str(hold), GAINTUNE_MAX_QUEUE="100000",
                 GAINTUNE_API_KEYS=secrets.token_hex(16))
    holder = None
    try:
        srv.start()
        srv.wait_ready()
        busy = srv.submit(job_spec(500, budget))  # the supervised worker's job: held mid-run by the hold file
        _wait(lambda: srv.job(busy)["progress"], 300, "the supervised worker's job to run")
        victim = srv.submit(job_spec(501, budget))
        holder = subprocess.Popen([sys.executable, "-c", _HOLDER, db_url, f"{idle:g}"], stdout=subprocess.PIPE,
                                  text=True, env=srv.env)
        assert holder.stdout is not None  # stdout=PIPE
        job_id, backend, _ = holder.stdout.readline().split()
        assert job_id == victim, "the holder claimed another job"
        _wait(lambda: _proc_state(holder.pid) in ("T", "t"), 30, "the lock holder to freeze", 0.01)
        frozen_at = time.time()
        out = _while_frozen(srv, db_url, victim, int(backend), frozen_at)
        hold.unlink()
        done = _wait(lambda: (lambda j: j if j["status"] in TERMINAL else None)(srv.job(victim)), 600,
                     "the frozen process's job to finish")
        still = _wait(lambda: (lambda j: j if j["status"] in TERMINAL else None)(srv.job(busy)), 600,
                      "the blocked job to finish")
        os.kill(holder.pid, signal.SIGCONT)  # the frozen process resumes: its session is gone, it writes nothing
        holder.wait(30)
        after = srv.job(victim)
    finally:
        if holder is not None and holder.poll() is None:
            holder.kill()
        srv.stop()
    out.update({"lease_s": lease, "idle_timeout_s": idle, "held_job_final": done["status"],
                "held_job_attempts": done["attempts"], "held_job_changed_by_resumed_holder": int(after != done),
                "blocked_job_final": still["status"], "blocked_job_attempts": still["attempts"]})
    log(f"  lock (PostgreSQL): {out['posts']} POSTs, {out['posts_refused']} refused, GET p95 {out['get_ms_p95']} ms; "
        f"frozen session closed after {out['session_closed_s']} s, its job re-queued after {out['job_requeued_s']} s")
    return out
