"""Benchmark: a chaos campaign against real API servers on 127.0.0.1, driven over HTTP only.

Run ``gaintune bench chaos`` (or ``python -m gaintune.bench.chaos``; ``--help`` for the options). The servers
run as subprocesses (``python -m gaintune_api``; ``python -m gaintune_api.worker`` for standalone workers); this
module never imports ``api``. Workers are the server's child processes named ``gaintune-worker``. Phases:

1. campaign: ``--jobs`` small jobs (each with an Idempotency-Key) on 2 workers; ``--worker-kills`` SIGKILLs of
   a worker while every worker is mid-job, ``--server-kills`` SIGKILLs of the server (restarted on the same
   database; every key re-submitted). Every job must succeed exactly once, with a consistent result and an
   agent matching its recorded digest.
2. frozen: SIGSTOP an idle supervised worker: /readyz must be 503 while it is stopped; it must be killed.
3. stale: a standalone worker frozen mid-job past its lease resumes after a second worker finished the job:
   the finished job's agent and result must not change.
4. storage: each storage fault, every endpoint: every 5xx must name its cause; /readyz must be 503.
5. connections: after each error (a genuine 500 from a row corrupted with ``sqlite3``, 503, 507, 404, 409,
   422) the next request goes on the same keep-alive socket and must succeed (or the error carried
   ``Connection: close``).
6. lock: a frozen worker holds the database write lock while writes queue: GET p95 (target 100 ms), how long a
   write takes to be refused (target 2 s, 503 with Retry-After), and when the holder's lease is enforced
   (:mod:`gaintune.bench.chaos_durable`).
7. diskfull: the database fills as jobs finish: finished jobs lost or recomputed, unrelated jobs disturbed.

``--phases`` runs a subset (e.g. ``--phases lock,diskfull``). ``--db-url postgresql://...`` runs the campaign
on that PostgreSQL store with ``--servers`` API servers (default 2) sharing it (:mod:`gaintune.bench.chaos_multi`)
and the lock phase with a frozen row-lock holder (:mod:`gaintune.bench.chaos_pglock`); the other phases fault the
SQLite file and run on SQLite only.

Fault injection: SIGKILL/SIGSTOP, the tests-only hooks ``GAINTUNE_TEST_HOLD_FILE`` (pauses a job after its
first progress report: freezes land mid-job) and ``GAINTUNE_TEST_STORAGE_FAULT_FILE``, and the corrupted row.
"""

from __future__ import annotations

import argparse
import json
import os
import random
import signal
import sys
import tempfile
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

from gaintune.bench.arguments import (
    BenchParser,
    budget_int,
    fail,
    float_range,
    int_range,
    non_negative_int,
    positive_int,
)
from gaintune.bench.chaos_durable import TERMINAL, diskfull, lock
from gaintune.bench.chaos_procs import (
    Server,
    _agent_ok,
    _kill_events,
    _n_done,
    _proc_state,
    _serving,
    _tally_jobs,
    _wait,
    _Worker,
    job_spec,
)
from gaintune.bench.chaos_storage import storage_and_connections

__all__ = ["main", "job_spec", "PHASES"]

PHASES = ("campaign", "frozen", "stale", "storage", "lock", "diskfull")
#: Targets of the timed figures of the lock phase: (key in its output, most allowed, what).
TIMED = (("get_ms_p95", 100.0, "GET p95 (ms) while a frozen worker holds the database write lock"),
         ("refusal_s_max", 2.0, "longest wait (s) before a write is refused while the lock is held"))

# ------------------------------------------------------------------------ 1. campaign


def campaign(
    root: Path, n_jobs: int, worker_kills: int, server_kills: int, budget: int, log: Callable[[str], None]
) -> dict[str, Any]:
    """Submit ``n_jobs`` jobs, kill workers and the server meanwhile; count lost, duplicated, stuck, corrupt jobs."""
    with _serving(root, 2, GAINTUNE_MAX_ATTEMPTS="50", GAINTUNE_RECOVER="requeue") as srv:
        keys = [f"chaos-{i}" for i in range(n_jobs)]
        ids: dict[str, set[str]] = {k: set() for k in keys}

        def submit_all() -> None:
            for i, k in enumerate(keys):
                r = srv.client.post("/v1/tune", json=job_spec(i, budget), headers={"Idempotency-Key": k})
                if r.status_code == 202:
                    ids[k].add(r.json()["id"])

        submit_all()
        t0 = time.monotonic()
        kills = _kill_during_campaign(srv, _kill_events(worker_kills, server_kills), n_jobs, submit_all, log, t0)
        stuck_timeout = False
        try:
            _wait(lambda: all(srv.job(next(iter(v)))["status"] in TERMINAL for v in ids.values() if v), 900,
                  "all jobs to finish", 0.5)
        except TimeoutError:
            stuck_timeout = True
        out = _tally_jobs(srv, ids, budget)
        total = srv.client.get("/v1/jobs", params={"limit": 1}).json()["total"]
        out["duplicated"] += max(0, total - n_jobs)
        attempts = out.pop("attempts")
        return {"jobs": n_jobs, "worker_kills": kills["worker"], "server_kills": kills["server"],
                "lost": out["lost"], "duplicated": out["duplicated"], "stuck": out["stuck"],
                "corrupt": out["corrupt"], "failed": out["failed"],
                "jobs_in_store": total, "max_attempts_seen": max(attempts or [0]),
                "jobs_retried": sum(a > 1 for a in attempts), "seconds": round(time.monotonic() - t0, 1),
                "timed_out": stuck_timeout}


def _all_busy(srv: Server) -> bool:
    """Every worker is mid-search (a kill surely hits a running job)."""
    running = srv.client.get("/v1/jobs", params={"status": "running", "limit": 200}).json()["items"]
    return len(running) == srv.workers and all(j["progress"] for j in running) \
        and len(srv.worker_pids()) == srv.workers


def _kill_during_campaign(
    srv: Server, events: list[str], n_jobs: int, submit_all: Callable[[], None], log: Callable[[str], None],
    t0: float,
) -> dict[str, int]:
    """Run the kill ``events`` spread over the campaign; returns the kills done of each kind."""
    rng = random.Random(14)
    done_kills = {"worker": 0, "server": 0}
    for k, ev in enumerate(events):
        # Spread the kills over the campaign (event k once k/E of the first N - 2*workers jobs are done),
        # each at a moment when every worker is mid-job.
        target = k * max(0, n_jobs - 2 * srv.workers) // max(1, len(events))
        if not _kill_once(srv, ev, target, rng, submit_all):
            log(f"  campaign: {ev} kill skipped: the workers were never both mid-job again")
            continue
        done_kills[ev] += 1
        log(f"  campaign: {ev} kill {done_kills[ev]} at {time.monotonic() - t0:.0f} s ({_n_done(srv)} jobs done)")
    return done_kills


def _kill_once(srv: Server, ev: str, target: int, rng: random.Random, submit_all: Callable[[], None]) -> bool:
    """Once ``target`` jobs are done and every worker is mid-job, SIGKILL a worker or the server (restarted).

    Returns False when the workers were never all mid-job again (no kill).
    """
    try:
        _wait(lambda: _n_done(srv) >= target and _all_busy(srv), 120, "both workers to be mid-job", 0.1)
    except TimeoutError:
        return False
    if ev == "worker":
        pid = rng.choice(srv.worker_pids())
        os.kill(pid, signal.SIGKILL)
        _wait(lambda: pid not in srv.worker_pids() and len(srv.worker_pids()) == srv.workers, 60,
              "the killed worker to be replaced")
    else:
        srv.kill()
        srv.start()
        srv.wait_ready()
        submit_all()  # clients retry after a crash: idempotency keys must not duplicate jobs
    return True


# ------------------------------------------------------------------------ 2-3. freezes


def _freeze_outside_tx(srv: Server, pid: int) -> None:
    """SIGSTOP ``pid`` when it holds no database write lock (/readyz's write probe still succeeds)."""
    for _ in range(50):
        os.kill(pid, signal.SIGSTOP)
        _wait(lambda: _proc_state(pid) in ("T", "t"), 10, "the worker to stop", 0.01)
        if srv.client.get("/readyz").json().get("database_writable"):
            return
        os.kill(pid, signal.SIGCONT)
        _wait(lambda: _proc_state(pid) not in ("T", "t"), 10, "the worker to resume", 0.01)
    raise RuntimeError("could not stop the worker outside a write transaction")


def frozen(root: Path, rounds: int, log: Callable) -> dict:
    """Freeze an idle supervised worker; count /readyz 200s while it is stopped and workers never killed."""
    with _serving(root, 2, GAINTUNE_HEARTBEAT_TIMEOUT="3", GAINTUNE_WORKER_LIVENESS_TIMEOUT="1") as srv:
        polls = ready_while_frozen = never_killed = 0
        kill_s = []
        for r in range(rounds):
            pid = srv.worker_pids()[r % srv.workers]
            _freeze_outside_tx(srv, pid)
            t0 = time.monotonic()
            while _proc_state(pid) in ("T", "t") and time.monotonic() - t0 < 60:
                code = srv.client.get("/readyz").status_code
                if _proc_state(pid) in ("T", "t"):  # still frozen after the answer: the answer counts
                    polls += 1
                    ready_while_frozen += code == 200
                time.sleep(0.05)
            if _proc_state(pid) in ("T", "t"):
                never_killed += 1
                os.kill(pid, signal.SIGKILL)
            else:
                kill_s.append(round(time.monotonic() - t0, 1))
            srv.wait_ready()
            log(f"  frozen: round {r + 1}: worker {pid} killed after {kill_s[-1] if kill_s else '?'} s")
        return {"rounds": rounds, "readyz_polls_while_frozen": polls, "readyz_ready_while_frozen": ready_while_frozen,
                "frozen_workers_never_killed": never_killed, "killed_after_s": kill_s}



def stale(root: Path, rounds: int, budget: int, log: Callable) -> dict:
    """Frozen standalone worker resumes after its job was finished elsewhere: count changed artefacts/results."""
    hold = root / "hold"
    out = {"rounds": rounds, "stale_attempts_resumed": 0, "finished_jobs_changed": 0}
    with _serving(root, 0, GAINTUNE_HEARTBEAT_TIMEOUT="2", GAINTUNE_TEST_HOLD_FILE=str(hold)) as srv:
        victim = _Worker(srv, 0)
        try:
            for r in range(rounds):
                changed = _stale_round(srv, victim, hold, r, budget)
                out["stale_attempts_resumed"] += 1
                out["finished_jobs_changed"] += changed
                log(f"  stale: round {r + 1}: finished job {'CHANGED' if changed else 'unchanged'}")
        finally:
            victim.stop()
    return out


def _stale_round(srv: Server, victim: _Worker, hold: Path, r: int, budget: int) -> bool:
    """One freeze-recover-finish-resume round; True when the finished job's agent or result changed."""
    hold.touch()
    job = srv.submit(job_spec(100 + r, budget))
    _wait(lambda: (lambda j: j["status"] == "running" and j["progress"])(srv.job(job)), 300, "the job to run")
    _freeze_outside_tx(srv, victim.proc.pid)
    _wait(lambda: srv.job(job)["status"] == "queued", 60, "the lease to expire and the job to be re-queued")
    helper = _Worker(srv, r + 1)
    try:
        _wait(lambda: (lambda j: j["status"] == "running" and j["attempts"] == 2 and j["progress"])(srv.job(job)),
              300, "the second attempt to run")
        hold.unlink()
        done = _wait(lambda: (lambda j: j if j["status"] in ("succeeded", "failed") else None)(srv.job(job)), 300,
                     "the second attempt to finish")
        ok, digest = _agent_ok(srv, job)
    finally:
        helper.stop()  # the next round's job must go to the victim
    before = len(victim.text())
    os.kill(victim.proc.pid, signal.SIGCONT)
    _wait(lambda: "lost its claim" in victim.text()[before:] or "no longer owns" in victim.text()[before:],
          120, "the resumed worker to drop its stale attempt")
    ok2, digest2 = _agent_ok(srv, job)
    after = srv.job(job)
    return not (ok and ok2 and digest == digest2 and after["result"] == done["result"]
                and after["status"] == done["status"] == "succeeded")


# ------------------------------------------------------------------------ main


def _parser() -> BenchParser:
    """The options of ``gaintune bench chaos``."""
    ap = BenchParser(prog="gaintune bench chaos", description=(__doc__ or "").split("\n\n")[0])
    ap.add_argument("--jobs", type=positive_int, default=40)
    ap.add_argument("--worker-kills", type=non_negative_int, default=10)
    ap.add_argument("--server-kills", type=non_negative_int, default=2)
    ap.add_argument("--budget", type=budget_int, default=1000,
                    help="simulations per job: small, but long enough (a few s) for kills to land mid-job")
    ap.add_argument("--rounds", type=non_negative_int, default=3, help="freeze rounds in the frozen and stale phases")
    ap.add_argument("--phases", default=None,
                    help=f"comma-separated subset of {', '.join(PHASES)} (default: all; with --db-url: campaign,lock)")
    ap.add_argument("--db-url", default=None,
                    help="campaign on this PostgreSQL job store (postgresql://...), with --servers API servers on it")
    ap.add_argument("--servers", type=int_range(1, 8), default=2, help="with --db-url: API servers on the store")
    ap.add_argument("--db-idle-timeout", type=float_range(0.5, 600.0), default=5.0,
                    help="with --db-url, lock phase: db_idle_timeout (s) of the server and the frozen process")
    ap.add_argument("--writers", type=int_range(1, 1000), default=40,
                    help="lock phase: POSTs kept in flight while the write lock is held")
    ap.add_argument("--write", choices=("delete", "post"), default="delete",
                    help="lock phase: the queued writes (delete: cancel a queued job; post: submit a job, whose "
                    "validation costs CPU)")
    ap.add_argument("--write-pause", type=float_range(0.0, 60.0, lo_open=False), default=0.25,
                    help="lock phase: seconds each writer waits after an answer (0: back to back)")
    ap.add_argument("--lease", type=float_range(1.0, 600.0), default=8.0,
                    help="lock and diskfull phases: heartbeat_timeout (s) of their servers")
    ap.add_argument("--json", action="store_true")
    ap.add_argument("--keep", action="store_true", help="keep the temporary folder (logs, databases)")
    return ap


def _run_phases(args: argparse.Namespace, phases: list[str], root: Path, say: Callable[[str], None]) -> dict[str, Any]:
    """Run the chosen phases in ``root``; their outputs keyed by phase (storage also gives ``connections``)."""
    out: dict[str, Any] = {"folder": str(root), "cpus": os.cpu_count(), "loadavg_start": os.getloadavg()}
    say(f"chaos campaign in {root} (phases: {', '.join(phases)})")
    if "campaign" in phases and args.db_url:
        from gaintune.bench.chaos_multi import campaign_multi

        out["campaign"] = campaign_multi(root / "campaign", args.db_url, args.jobs, args.worker_kills,
                                         args.server_kills, args.budget, say, servers=args.servers)
    elif "campaign" in phases:
        out["campaign"] = campaign(root / "campaign", args.jobs, args.worker_kills, args.server_kills, args.budget, say)
    if "frozen" in phases:
        out["frozen"] = frozen(root / "frozen", args.rounds, say)
    if "stale" in phases:
        out["stale"] = stale(root / "stale", args.rounds, args.budget, say)
    if "storage" in phases:
        out["storage"], out["connections"] = storage_and_connections(root / "storage", args.budget, say)
    if "lock" in phases and args.db_url:
        from gaintune.bench.chaos_pglock import pg_lock

        out["lock"] = pg_lock(root / "lock", args.db_url, args.lease, args.db_idle_timeout, args.budget, say)
    elif "lock" in phases:
        out["lock"] = lock(root / "lock", args.writers, args.write, args.write_pause, args.lease, args.budget, say)
    if "diskfull" in phases:
        out["diskfull"] = diskfull(root / "diskfull", max(1, args.rounds), args.lease, args.budget, say)
    return out


def _print_report(out: dict[str, Any], figures: dict[str, int], timed: dict[str, tuple[float, float]]) -> None:
    """The counted and timed figures as a Markdown table, then each phase's output."""
    print("\n| figure | measured |\n|---|---:|")
    for name, v in figures.items():
        print(f"| {name} | {('never' if v == 0 else f'{v} times') if name.startswith('/readyz') else v} |")
    for name, (t, most) in timed.items():
        print(f"| {name} (target <= {most:g}) | {t} |")
    for k in (*PHASES, "connections"):
        if k in out:
            print(f"{k}: {json.dumps(out[k], default=str)}")
    print(f"total {out['seconds']} s")


def main(argv: list[str] | None = None) -> int:
    """Run the campaign and print the figures (``--json``: as JSON). Exit 1 if any figure is off target."""
    # checked before any server starts: a budget the API refuses (422) used to surface as KeyError: 'id'
    args = _parser().parse_args(argv)
    phases = _phases(args)
    root = Path(tempfile.mkdtemp(prefix="gaintune-bench-chaos-"))

    def say(m: str) -> None:
        print(m, file=sys.stderr if args.json else sys.stdout, flush=True)

    t0 = time.monotonic()
    out = _run_phases(args, phases, root, say)
    out["seconds"] = round(time.monotonic() - t0, 1)
    figures = _figures(out)
    sqlite_lock = "lock" in out and "posts_refused" not in out["lock"]  # the timed targets are SQLite's lock phase's
    timed = {what: (out["lock"][key], most) for key, most, what in TIMED if sqlite_lock}
    out["figures"], out["timed"] = figures, {k: v for k, (v, _) in timed.items()}
    if args.json:
        print(json.dumps(out, indent=2, default=str))
    else:
        _print_report(out, figures, timed)
    if not args.keep:
        import shutil

        shutil.rmtree(root, ignore_errors=True)
    off = any(figures.values()) or any(not v <= most for v, most in timed.values())
    return 1 if off else 0


def _phases(args: argparse.Namespace) -> list[str]:
    """The phases to run (exit 2 naming the option when unknown, or not campaign with --db-url)."""
    default = "campaign,lock" if args.db_url else ",".join(PHASES)
    phases = [p.strip() for p in (args.phases or default).split(",") if p.strip()]
    bad = [p for p in phases if p not in PHASES]
    if bad or not phases:
        fail("--phases", f"unknown phase {bad[0]!r}; choose from {', '.join(PHASES)}" if bad else "name a phase")
    if args.db_url and not set(phases) <= {"campaign", "lock"}:
        fail("--phases", "with --db-url only the campaign and lock phases run (the others fault the SQLite file); "
             "drop --db-url for them")
    if args.db_url and not args.db_url.startswith(("postgresql://", "postgres://")):
        fail("--db-url", "must be a PostgreSQL URL: postgresql://user:password@host:port/dbname")
    return phases


def _figures(out: dict[str, Any]) -> dict[str, int]:
    """The counted figures (target 0) of the phases that ran."""
    figures: dict[str, int] = {}
    if "campaign" in out:
        c = out["campaign"]
        on = f", {c['servers']} servers on one PostgreSQL store" if "servers" in c else ""
        figures[f"jobs lost, duplicated or corrupt under {c['worker_kills']} worker kills + {c['server_kills']} "
                f"server kills, {c['jobs']} jobs{on}"] = c["lost"] + c["duplicated"] + c["corrupt"] + c["stuck"]
    if "stale" in out:
        figures["finished-job artefacts changed by a stale attempt"] = out["stale"]["finished_jobs_changed"]
    if "storage" in out:
        figures["storage-fault responses that are 5xx without a named cause"] = out["storage"]["unnamed_5xx"]
    if "storage" in out or "frozen" in out:
        figures["/readyz true while unable to write or with a frozen worker"] = \
            out.get("storage", {}).get("readyz_ready", 0) + out.get("frozen", {}).get("readyz_ready_while_frozen", 0)
    if "connections" in out:
        figures["requests failing on a reused connection after an error"] = out["connections"]["next_request_failures"]
    if "lock" in out and "posts_refused" in out["lock"]:  # PostgreSQL
        k = out["lock"]
        figures["writes to other jobs refused while a frozen process holds a job's row lock"] = k["posts_refused"]
        figures["frozen row-lock holder's job not recovered, run twice, or blocked job re-run"] = \
            int(k["job_requeued_s"] is None) + (k["held_job_final"] != "succeeded") \
            + k["held_job_changed_by_resumed_holder"] + (k["blocked_job_attempts"] != 1)
    elif "lock" in out:
        k = out["lock"]
        figures["writes refused while locked without Retry-After, or accepted"] = \
            k["refusals_without_retry_after"] + k["writes_accepted_while_locked"]
        figures["frozen lock holder never killed, or blocked job re-run"] = \
            k["holder_never_killed"] + (k["blocked_job_attempts"] != 1) + (k["blocked_job_final"] != "succeeded")
    if "diskfull" in out:
        d = out["diskfull"]
        figures[f"jobs lost or recomputed when the database fills at their finish ({d['finished_jobs']} jobs)"] = \
            d["lost"] + d["recomputed"]
        figures["unrelated jobs disturbed (re-run) or workers killed meanwhile"] = \
            d["unrelated_disturbed"] + max(0, d["worker_restarts"])
    return figures


if __name__ == "__main__":
    raise SystemExit(main())
