"""Issue 24 (defects 7, 9, 12): a full disk at a job's finish, a frozen worker holding the database write lock,
and a cancel racing the end of a search. In-process (TestClient, workers run with ``run_job``) plus real helper
processes where the defect needs one: a process that holds the SQLite write lock, SIGSTOPped.

Durations are controlled, never guessed: faults come from the tests-only fault file (``db:full@finish=N`` fails
exactly the next N finishing COMMITs), lease expiry from a supervisor clock the test sets, and waits poll an
observable condition with a generous backstop.
"""

from __future__ import annotations

import hashlib
import logging
import multiprocessing as mp
import os
import shutil
import sqlite3
import subprocess
import sys
import textwrap
import threading
import time
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import pytest
from fastapi.testclient import TestClient
from test_api_routes import GOOD, SPEC, make_fake_tune, settings_for

from gaintune_api import supervisor as supervisor_mod
from gaintune_api.job_store import JobStore, claim_tag, loads
from gaintune_api.main import create_app
from gaintune_api.storage_faults import FaultInjector, StorageFault, wal_write_lock_holder
from gaintune_api.supervisor import Supervisor, pid_alive, pid_stopped
from gaintune_api.worker import run_job

BACKSTOP = 60.0  # generous bound of every wait: only a hang reaches it


def wait_until(cond, timeout: float = BACKSTOP, what: str = "condition"):
    t0 = time.monotonic()
    while time.monotonic() - t0 < timeout:
        v = cond()
        if v:
            return v
        time.sleep(0.02)
    raise AssertionError(f"timed out waiting for {what}")


def _spec_json() -> str:
    from gaintune.spec import TuningSpec

    return TuningSpec.model_validate(SPEC).model_dump_json()


def _new_job(store: JobStore, name: str = "x") -> str:
    row, _ = store.create("anonymous", _spec_json(), "h", name, idem_key=None, max_queue=99)
    return row.id


def _sha(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


# ------------------------------------------------------------------ a process holding the write lock

_HOLDER = textwrap.dedent("""
    import ctypes, os, signal, sqlite3, sys
    ctypes.CDLL("libc.so.6").prctl(15, b"gaintune-worker", 0, 0, 0)  # named like a job worker
    db, claim = sys.argv[1], sys.argv[2] == "claim"
    if claim:
        from gaintune_api.job_store import JobStore
        job = JobStore(db).claim(os.getpid())
        print(job.id, flush=True)
    c = sqlite3.connect(db, isolation_level=None)
    c.execute("BEGIN IMMEDIATE")
    print("locked", flush=True)
    os.kill(os.getpid(), signal.SIGSTOP)  # frozen inside its write transaction
    signal.pause()
""")


class LockHolder:
    """A process that (optionally claims the oldest queued job, then) takes the database write lock and freezes."""

    def __init__(self, db: Path, claim: bool = False) -> None:
        self.proc = subprocess.Popen([sys.executable, "-c", _HOLDER, str(db), "claim" if claim else "-"],
                                     stdout=subprocess.PIPE, text=True)
        self.pid = self.proc.pid
        self.job = self.proc.stdout.readline().strip() if claim else None
        assert self.proc.stdout.readline().strip() == "locked"
        wait_until(lambda: pid_stopped(self.pid), what="the lock holder to freeze")
        assert wal_write_lock_holder(db) == self.pid

    def stop(self) -> None:
        if self.proc.poll() is None:
            self.proc.kill()
        self.proc.wait(30)
        self.proc.stdout.close()


# ------------------------------------------------------------------ defect 7: a full disk at finish


def test_full_disk_at_finish_loses_no_result(tmp_path):
    """The disk fills just as the job finishes: its files are renamed into place, then the COMMIT fails with
    SQLITE_FULL (twice). The retry must find the files and write the result: succeeded, attempt 1, agent intact."""
    faults = tmp_path / "faults"
    s = settings_for(tmp_path, test_storage_fault_file=faults, poll_interval=0.01)
    store = JobStore(s.db_path, FaultInjector(faults))
    store.init()
    job_id = _new_job(store)
    other_id = _new_job(store, "other")
    job = store.claim(os.getpid())
    other = store.claim(os.getpid())  # an unrelated running job: must not be touched
    inner = make_fake_tune()
    agent: dict = {}

    def tune_then_disk_full(spec, **kw):
        res = inner(spec, **kw)
        agent["sha"] = _sha(Path(res.agent_path))
        faults.write_text("db:full@finish=2")  # the next two finishing COMMITs fail with SQLITE_FULL
        return res

    assert run_job(store, job, s, tune_then_disk_full, hard_exit=False) == "succeeded"
    assert not faults.read_text().strip()  # both injected failures were used: the commit did fail twice
    done = store.get(job_id)
    assert done.status == "succeeded" and done.attempts == 1 and done.error is None
    result = loads(done.result)
    assert result["gains"] == GOOD
    final = Path(result["agent_path"])
    assert final == s.jobs_dir / job_id / "agent.zip" and _sha(final) == agent["sha"]
    manifest = loads(done.artifacts)
    assert manifest["attempt"] == 1 and manifest["files"]["agent.zip"]["sha256"] == agent["sha"]
    assert not any((s.jobs_dir / job_id / ".attempts").iterdir())  # the staging folder is discarded
    after = store.get(other_id)
    assert after.status == "running" and after.claim == other.claim and after.attempts == 1


def _mount_tmpfs(path: Path, size: str) -> bool:
    if shutil.which("mount") is None:
        return False
    return subprocess.run(["mount", "-t", "tmpfs", "-o", f"size={size}", "tmpfs", str(path)],
                          capture_output=True).returncode == 0


def _fill(path: Path) -> None:
    """Write ``path`` until the disk refuses even one more byte (ENOSPC)."""
    with open(path, "wb", buffering=0) as f:
        for chunk in (1 << 16, 1 << 12, 1):
            try:
                while True:
                    f.write(b"\0" * chunk)
            except OSError:
                pass


def test_full_tmpfs_at_finish_loses_no_result(tmp_path, caplog):
    """The same on a real 8 MiB tmpfs holding the database and the data directory (skipped where the runner
    cannot mount): the disk is filled as the search ends, so the finishing COMMIT really fails with SQLITE_FULL;
    once space is freed the result is written, attempt 1."""
    disk = tmp_path / "disk"
    disk.mkdir()
    if not _mount_tmpfs(disk, "8m"):
        pytest.skip("cannot mount a tmpfs here (needs root with CAP_SYS_ADMIN)")
    try:
        s = settings_for(disk, poll_interval=0.02)
        store = JobStore(s.db_path)
        store.init()
        job_id = _new_job(store)
        job = store.claim(os.getpid())
        inner = make_fake_tune()

        def tune_then_fill(spec, **kw):
            res = inner(spec, **kw)
            _fill(disk / "filler")
            return res

        out: dict = {}
        caplog.set_level(logging.WARNING, logger="gaintune.worker")
        th = threading.Thread(target=lambda: out.setdefault("s", run_job(store, job, s, tune_then_fill,
                                                                         hard_exit=False)), daemon=True)
        th.start()
        wait_until(lambda: any("result kept" in r.getMessage() for r in caplog.records) or not th.is_alive(),
                   what="the finishing write to fail on the full disk")
        assert any("database-full" in r.getMessage() or "is full" in r.getMessage() for r in caplog.records)
        (disk / "filler").unlink()
        th.join(BACKSTOP)
        assert out.get("s") == "succeeded", (out, store.get(job_id).error)
        done = store.get(job_id)
        assert done.status == "succeeded" and done.attempts == 1
        manifest = loads(done.artifacts)
        assert _sha(s.jobs_dir / job_id / "agent.zip") == manifest["files"]["agent.zip"]["sha256"]
    finally:
        subprocess.run(["umount", "-l", str(disk)], capture_output=True)


# ------------------------------------------------------------------ defect 7: the kill of an unrelated job


class Proc:
    """A real process in the supervisor's worker list (its ``pid``/``is_alive``/``kill``/``join``)."""

    def __init__(self) -> None:
        self.p = subprocess.Popen([sys.executable, "-c", "import time; time.sleep(600)"])
        self.pid = self.p.pid

    def is_alive(self) -> bool:
        return self.p.poll() is None

    def kill(self) -> None:
        self.p.kill()

    def join(self, timeout=None) -> None:
        self.p.wait(timeout)


def test_supervisor_kills_worker_only_if_it_still_holds_the_job(tmp_path):
    """Job A's lease names worker W, but W gave up on A (its final write failed) and runs job B now: A is
    recovered and W is left alone (B goes on). A worker that still runs its expired attempt is killed."""
    s = settings_for(tmp_path, heartbeat_timeout=5.0)
    store = JobStore(s.db_path)
    store.init()
    moved_on, stuck = Proc(), Proc()
    try:
        a, b, c = _new_job(store, "a"), _new_job(store, "b"), _new_job(store, "c")
        job_a = store.claim(moved_on.pid)
        job_b = store.claim(moved_on.pid)
        job_c = store.claim(stuck.pid)
        assert (job_a.id, job_b.id, job_c.id) == (a, b, c)
        sup = Supervisor(s, store)
        sup.procs, sup.pulses = [moved_on, stuck], [None, None]
        sup.holding = {moved_on.pid: mp.Value("q", claim_tag(job_b.claim), lock=False),
                       stuck.pid: mp.Value("q", claim_tag(job_c.claim), lock=False)}
        with sqlite3.connect(s.db_path) as db:  # A's and C's leases expired; B heartbeats
            db.execute("UPDATE jobs SET heartbeat_at=? WHERE id IN (?, ?)", (time.time() - 60, a, c))
        sup.db_ok_since = time.time() - 60
        sup.check_jobs()
        assert store.get(a).status == "queued" and "lease expired" in store.get(a).error
        assert store.get(c).status == "queued"
        assert moved_on.is_alive() and not pid_stopped(moved_on.pid), "the worker running job B was killed"
        got_b = store.get(b)
        assert got_b.status == "running" and got_b.claim == job_b.claim
        wait_until(lambda: not stuck.is_alive(), what="the stuck worker to be killed")
    finally:
        for p in (moved_on, stuck):
            if p.is_alive():
                p.kill()
            p.join(30)


# ------------------------------------------------------------------ defect 9: a frozen writer holds the lock


class CountPosts:
    """The app, counting the POST requests it has received (to know that writes are queued, not to time them)."""

    def __init__(self, app) -> None:
        self.app, self.state, self.posts = app, app.state, 0

    async def __call__(self, scope, receive, send) -> None:
        if scope["type"] == "http" and scope["method"] == "POST":
            self.posts += 1
        await self.app(scope, receive, send)


@pytest.fixture
def locked_app(tmp_path):
    """(client, holder, job): an in-process app whose database write lock is held by a frozen process."""
    app = create_app(settings_for(tmp_path))
    with TestClient(CountPosts(app), raise_server_exceptions=False) as c:
        job = c.post("/v1/tune", json=SPEC).json()["id"]
        holder = LockHolder(app.state.settings.db_path)
        try:
            yield c, holder, job
        finally:
            holder.stop()


def test_writes_fail_fast_with_retry_after_when_locked(locked_app):
    c, holder, job = locked_app
    for r in (c.post("/v1/tune", json=SPEC), c.delete(f"/v1/jobs/{job}")):
        assert r.status_code == 503, r.text
        body = r.json()
        assert body["cause"] == "database-locked" and "locked by another writer" in body["detail"]
        assert int(r.headers["retry-after"]) > 0 and r.headers["content-type"] == "application/problem+json"
    ready = c.get("/readyz").json()
    assert ready["database_writable"] is False and any(x.startswith("database-locked") for x in ready["reasons"])
    holder.stop()  # the lock is released: writes work again
    assert c.post("/v1/tune", json=SPEC).status_code == 202


def test_reads_do_not_queue_behind_a_locked_writer(locked_app):
    """60 writes queued against the locked database (more than the request thread pool's 40 threads) while
    a GET is asked: the GET is answered, with the lock still held and writes still being refused."""
    c, holder, job = locked_app
    n = 60
    before = c.app.posts
    with ThreadPoolExecutor(n) as pool:
        writes = [pool.submit(c.post, "/v1/tune", json=SPEC) for _ in range(n)]
        wait_until(lambda: c.app.posts - before == n, what="every write to reach the server")
        got: dict = {}
        reader = threading.Thread(target=lambda: got.setdefault("r", c.get(f"/v1/jobs/{job}")), daemon=True)
        reader.start()
        reader.join(15.0)  # backstop: writes used to hold every thread for 30 s each
        assert not reader.is_alive(), "the read queued behind the blocked writes"
        assert got["r"].status_code == 200 and got["r"].json()["id"] == job
        assert holder.proc.poll() is None and wal_write_lock_holder(c.app.state.settings.db_path) == holder.pid
        codes = {w.result(BACKSTOP).status_code for w in writes}
    assert codes == {503}


class Clock:
    """The supervisor's ``time`` module with a wall clock the test sets (monotonic time and sleep are real)."""

    def __init__(self, now: float) -> None:
        self.now = now
        self.monotonic, self.sleep = time.monotonic, time.sleep

    def time(self) -> float:
        return self.now


def test_lease_expires_on_time_while_db_locked(tmp_path, monkeypatch):
    """A standalone worker freezes inside a write transaction. Every other write waits, so no heartbeat is
    written, but only the lock holder's lease runs on: at its expiry (not before) the supervisor kills it,
    which frees the lock, and recovers its job; a job whose worker was only blocked keeps running."""
    s = settings_for(tmp_path, heartbeat_timeout=10.0)
    store = JobStore(s.db_path)
    store.init()
    blocked_job = _new_job(store, "blocked")
    blocked = store.claim(os.getpid())  # a live worker that the lock merely blocks
    frozen_job = _new_job(store, "frozen")
    holder = LockHolder(s.db_path, claim=True)
    try:
        assert holder.job == frozen_job
        with pytest.raises(StorageFault) as exc:  # the lock is held: every write is refused
            store.heartbeat(blocked_job, blocked.claim, None)
        assert exc.value.cause == "database-locked"
        hb = store.get(frozen_job).heartbeat_at
        clock = Clock(hb + s.heartbeat_timeout - 1.0)
        monkeypatch.setattr(supervisor_mod, "time", clock)
        sup = Supervisor(s, store)
        sup.db_ok_since = hb - 100
        sup.check_jobs()  # 1 s before the holder's lease ends: nothing happens
        assert pid_alive(holder.pid) and store.get(frozen_job).status == "running"
        clock.now = hb + s.heartbeat_timeout + 1.0
        sup.check_jobs()  # 1 s after: the holder is killed and its job recovered
        wait_until(lambda: holder.proc.poll() is not None, what="the frozen lock holder to be killed")
        got = store.get(frozen_job)
        assert got.status == "queued" and "held the database write lock" in got.error, got
        assert wal_write_lock_holder(s.db_path) is None
        still = store.get(blocked_job)
        assert still.status == "running" and still.claim == blocked.claim  # its lease restarts with the database
        store.probe_write()
    finally:
        holder.stop()


# ------------------------------------------------------------------ defect 12: cancel vs finish


def test_cancel_accepted_before_finish_ends_cancelled(tmp_path):
    """The cancel is accepted (202) after the search returned but before its result was committed, and the
    worker never polls the flag in between: the job still ends cancelled (its result kept), as the 202 said."""
    app = create_app(settings_for(tmp_path, heartbeat_interval=3600.0))  # the monitor never polls the flag
    with TestClient(app, raise_server_exceptions=False) as c:
        job_id = c.post("/v1/tune", json=SPEC).json()["id"]
        store, settings = app.state.store, app.state.settings
        job = store.claim(os.getpid())
        inner = make_fake_tune()
        answer: dict = {}

        def tune_then_cancel(spec, **kw):
            res = inner(spec, **kw)  # the search is done ...
            answer["r"] = c.delete(f"/v1/jobs/{job_id}")  # ... and the cancel arrives before the final write
            return res

        assert run_job(store, job, settings, tune_then_cancel, hard_exit=False) == "cancelled"
        assert answer["r"].status_code == 202 and answer["r"].json()["cancel_requested"]
        j = c.get(f"/v1/jobs/{job_id}").json()
        assert j["status"] == "cancelled" and j["cancel_requested"]
        assert "finished before it saw the request" in j["error"]
        assert j["result"]["accepted_gains"] == GOOD and j["result"]["agent_available"]
        assert c.delete(f"/v1/jobs/{job_id}").status_code == 409


def test_chaos_bench_unknown_phase_exits_2_naming_the_option(capsys):
    from gaintune.bench.chaos import main

    with pytest.raises(SystemExit) as exc:
        main(["--phases", "lock,nope"])
    assert exc.value.code == 2
    assert "error: --phases: unknown phase 'nope'" in capsys.readouterr().err
