"""The chaos campaign with several API servers on one PostgreSQL job store (``gaintune bench chaos --db-url``).

``--servers`` servers (default 2), each with ``workers`` job workers, share one PostgreSQL database and one
data folder (as servers on several hosts share a database and a network file system). Jobs are submitted
through the servers in turn; ``worker_kills`` SIGKILLs of a worker (a random server's) land while every
worker is mid-job, and ``server_kills`` SIGKILLs of a server (in turn) are each followed by its restart and
by every key re-submitted through another server: idempotency must hold across servers. The other servers'
supervisors recover a killed server's jobs (its workers die with it) without waiting for its restart.

Each run uses a fresh random API key, so its jobs are the only ones its owner sees in a shared database.
"""

from __future__ import annotations

import os
import random
import secrets
import signal
import time
from collections.abc import Callable, Iterator
from contextlib import ExitStack, contextmanager
from pathlib import Path
from typing import Any

from gaintune.bench.chaos_procs import TERMINAL, Server, _kill_events, _n_done, _tally_jobs, _wait, job_spec

__all__ = ["campaign_multi"]


@contextmanager
def _servers(root: Path, db_url: str, n: int, workers: int, **env: str) -> Iterator[list[Server]]:
    """``n`` started, ready servers on the database ``db_url`` sharing ``root/data``; stopped on exit."""
    shared = {"GAINTUNE_DB_URL": db_url, "GAINTUNE_DATA_DIR": str(root / "data"),
              "GAINTUNE_API_KEYS": secrets.token_hex(16), **env}
    with ExitStack() as stack:
        servers = []
        for i in range(n):
            srv = Server(root / f"server-{i}", workers, **shared)
            stack.callback(srv.stop)
            srv.start()
            servers.append(srv)
        for srv in servers:
            srv.wait_ready()
        yield servers


def _all_busy(servers: list[Server]) -> bool:
    """Every worker of every server is mid-search (a kill surely hits a running job)."""
    running = servers[0].client.get("/v1/jobs", params={"status": "running", "limit": 200}).json()["items"]
    n = sum(s.workers for s in servers)
    return len(running) == n and all(j["progress"] for j in running) \
        and all(len(s.worker_pids()) == s.workers for s in servers)


def _kill(servers: list[Server], ev: str, k: int, rng: random.Random,
          submit_all: Callable[[list[Server]], None]) -> None:
    """SIGKILL a random server's worker (``ev == "worker"``), or server ``k % n``, restarted and re-submitted to."""
    if ev == "worker":
        srv = rng.choice([s for s in servers if s.workers])
        pid = rng.choice(srv.worker_pids())
        os.kill(pid, signal.SIGKILL)
        _wait(lambda: pid not in srv.worker_pids() and len(srv.worker_pids()) == srv.workers, 60,
              "the killed worker to be replaced")
        return
    victim = servers[k % len(servers)]
    victim.kill()
    submit_all([s for s in servers if s is not victim])  # clients fail over to the others while it is down
    victim.start()
    victim.wait_ready()
    submit_all([victim])  # and retry on the restarted one: idempotency keys must not duplicate jobs


def _kills(servers: list[Server], events: list[str], n_jobs: int, submit_all: Callable[[list[Server]], None],
           log: Callable[[str], None], t0: float) -> dict[str, int]:
    """Run the kill ``events`` spread over the campaign, each while every worker is mid-job."""
    rng = random.Random(14)
    done = {"worker": 0, "server": 0}
    n_workers = sum(s.workers for s in servers)
    for k, ev in enumerate(events):
        target = k * max(0, n_jobs - 2 * n_workers) // max(1, len(events))
        def ready(t: int = target) -> bool:
            return _n_done(servers[0]) >= t and _all_busy(servers)

        try:
            _wait(ready, 120, "every worker to be mid-job", 0.1)
        except TimeoutError:
            log(f"  campaign: {ev} kill skipped: the workers were never all mid-job again")
            continue
        _kill(servers, ev, done["server"], rng, submit_all)
        done[ev] += 1
        log(f"  campaign: {ev} kill {done[ev]} at {time.monotonic() - t0:.0f} s ({_n_done(servers[0])} jobs done)")
    return done


def campaign_multi(root: Path, db_url: str, n_jobs: int, worker_kills: int, server_kills: int, budget: int,
                   log: Callable[[str], None], servers: int = 2, workers: int = 1) -> dict[str, Any]:
    """Submit ``n_jobs`` jobs to ``servers`` servers on one PostgreSQL store, kill workers and servers meanwhile.

    Returns
    -------
    dict
        The campaign's counts (target 0: ``lost``, ``duplicated``, ``stuck``, ``corrupt``), the kills done,
        the attempts seen and the jobs each server's workers finished.
    """
    with _servers(root, db_url, servers, workers, GAINTUNE_MAX_ATTEMPTS="50", GAINTUNE_RECOVER="requeue") as srvs:
        keys = [f"chaos-{i}" for i in range(n_jobs)]
        ids: dict[str, set[str]] = {k: set() for k in keys}

        def submit_all(via: list[Server]) -> None:
            for i, k in enumerate(keys):
                srv = via[i % len(via)]
                r = srv.client.post("/v1/tune", json=job_spec(i, budget), headers={"Idempotency-Key": k})
                if r.status_code == 202:
                    ids[k].add(r.json()["id"])

        submit_all(srvs)
        t0 = time.monotonic()
        kills = _kills(srvs, _kill_events(worker_kills, server_kills), n_jobs, submit_all, log, t0)
        timed_out = False
        try:
            _wait(lambda: all(srvs[0].job(next(iter(v)))["status"] in TERMINAL for v in ids.values() if v), 900,
                  "all jobs to finish", 0.5)
        except TimeoutError:
            timed_out = True
        out = _tally_jobs(srvs[0], ids, budget)
        total = srvs[0].client.get("/v1/jobs", params={"limit": 1}).json()["total"]
        attempts = out.pop("attempts")
        return {"jobs": n_jobs, "servers": servers, "workers_per_server": workers, "store": "postgresql",
                "worker_kills": kills["worker"], "server_kills": kills["server"], "lost": out["lost"],
                "duplicated": out["duplicated"] + max(0, total - n_jobs), "stuck": out["stuck"],
                "corrupt": out["corrupt"], "failed": out["failed"], "jobs_in_store": total,
                "max_attempts_seen": max(attempts or [0]), "jobs_retried": sum(a > 1 for a in attempts),
                "seconds": round(time.monotonic() - t0, 1), "timed_out": timed_out}
