"""Issue 14 chaos suite: real servers (``python -m gaintune_api``) and workers on 127.0.0.1, faults injected for real.

* freeze (SIGSTOP) and resume a worker: a stale attempt never changes a finished job (defect 1); a frozen
  supervised worker makes /readyz not ready and is killed and replaced (defect 6);
* storage faults: read-only data directory (defect 2), read-only or full database (defects 4, 5, 6), by the
  tests-only ``GAINTUNE_TEST_STORAGE_FAULT_FILE`` (deterministic, effective as root) and, where the runner
  may mount, a real small tmpfs that fills up and is remounted read-only;
* a 500 and a 503, then the next request on the same keep-alive connection (defect 3);
* SIGKILL of workers and of the server during jobs (``slow``: the default run covers both in
  test_api_server.py).

Durations are controlled, never guessed: jobs pause after their first progress report while the hold file
exists (``GAINTUNE_TEST_HOLD_FILE``), and every wait polls an observable condition with a generous bound.
"""

from __future__ import annotations

import hashlib
import os
import shutil
import signal
import sqlite3
import subprocess
import sys
import time
from pathlib import Path

import httpx
import pytest
from test_api_server import TINY, Server, pid_gone

FAST = dict(GAINTUNE_COMPUTE_PROCESSES="0", GAINTUNE_POLL_INTERVAL="0.1")


def state(pid: int) -> str:
    try:
        return Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0]
    except OSError:
        return "gone"


def freeze(srv: Server, pid: int) -> None:
    """SIGSTOP ``pid`` at a moment it holds no database write lock.

    A process stopped inside a write transaction would stall every writer until it is killed; that is
    real (the supervisor's pulse check kills its own frozen workers for that reason too), but these tests
    freeze a worker to make it *stale*, so they retry until the stop lands outside a transaction.
    """
    for _ in range(50):
        os.kill(pid, signal.SIGSTOP)
        srv.wait(lambda: state(pid) in ("T", "t"), 10, "the worker to stop", poll=0.01)
        try:
            c = sqlite3.connect(srv.db, timeout=0.5, isolation_level=None)
            try:
                c.execute("BEGIN IMMEDIATE")
                c.execute("ROLLBACK")
                return
            finally:
                c.close()
        except sqlite3.OperationalError:
            os.kill(pid, signal.SIGCONT)
            srv.wait(lambda: state(pid) not in ("T", "t"), 10, "the worker to resume", poll=0.01)
    raise AssertionError("could not stop the worker outside a write transaction")


class Worker:
    """A standalone worker (``python -m gaintune_api.worker``) on a server's database, which neither supervises
    nor kills it."""

    def __init__(self, srv: Server, index: int) -> None:
        self.path = srv.tmp / f"worker-{index}.log"
        self.log = open(self.path, "w")
        self.proc = subprocess.Popen([sys.executable, "-m", "gaintune_api.worker", "--index", str(index)], cwd=srv.tmp,
                                     env=srv.env, stdout=self.log, stderr=subprocess.STDOUT)
        self.pid = self.proc.pid

    def text(self) -> str:
        self.log.flush()
        return self.path.read_text()

    def stop(self) -> None:
        if self.proc.poll() is None:
            os.kill(self.pid, signal.SIGCONT)
            self.proc.kill()
            self.proc.wait(10)
        self.log.close()


def agent_digest(srv: Server, job_id: str) -> tuple[str, str]:
    """(sha256 of the served agent, the Repr-Digest the server sends for it)."""
    r = srv.client.get(f"/v1/jobs/{job_id}/agent")
    assert r.status_code == 200, r.text
    return hashlib.sha256(r.content).hexdigest(), r.headers["repr-digest"]


def repr_digest(hexdigest: str) -> str:
    import base64

    return f"sha-256=:{base64.b64encode(bytes.fromhex(hexdigest)).decode()}:"


# --------------------------------------------------------------------------- defect 1


def test_stale_worker_overwrote_finished_job_artifacts_after_resume(tmp_path):
    """Freeze a worker mid-job past its lease; the job is re-queued and finished by another worker; when the
    frozen worker resumes, it stops and discards its attempt: the served agent and result do not change."""
    hold = tmp_path / "hold"
    hold.touch()
    # the lease (5 s) outlasts freeze()'s retries on a loaded machine: a worker resumed by a retry after its lease
    # expired could claim the re-queued job again (seen once at load 4: attempt 2 ran on the frozen worker)
    srv = Server(tmp_path, GAINTUNE_WORKERS="0", GAINTUNE_HEARTBEAT_TIMEOUT="5", GAINTUNE_TEST_HOLD_FILE=str(hold),
                 **FAST)
    w1 = w2 = None
    try:
        srv.wait_ready()
        w1 = Worker(srv, 1)
        job = srv.client.post("/v1/tune", json=TINY).json()["id"]
        srv.wait_job(job, {"running"}, cond=lambda j: j["progress"] is not None)
        assert srv.worker_pid(job) == w1.pid
        freeze(srv, w1.pid)
        j = srv.wait_job(job, {"queued"}, timeout=30)  # lease expired: recovered; w1 is not ours to kill
        assert "lease expired" in j["error"], j
        w2 = Worker(srv, 2)
        srv.wait_job(job, {"running"}, cond=lambda j: j["attempts"] == 2 and j["progress"] is not None)
        assert srv.worker_pid(job) == w2.pid
        hold.unlink()
        done = srv.wait_job(job, {"succeeded", "failed"})
        assert done["status"] == "succeeded" and done["attempts"] == 2, done
        digest, header = agent_digest(srv, job)
        assert header == repr_digest(digest)
        os.kill(w1.pid, signal.SIGCONT)  # the stale attempt resumes
        srv.wait(lambda: "lost its claim" in w1.text() or "no longer owns" in w1.text(), 60,
                 "the resumed worker to find out it lost the job")
        assert agent_digest(srv, job) == (digest, header)
        after = srv.client.get(f"/v1/jobs/{job}").json()
        assert after["result"] == done["result"] and after["attempts"] == 2 and after["status"] == "succeeded"
        staged = srv.tmp / "data" / "jobs" / job / ".attempts"
        assert not staged.exists() or not any(p.name.startswith("1-") for p in staged.iterdir())
    finally:
        for w in (w1, w2):
            if w is not None:
                w.stop()
        srv.stop()


# --------------------------------------------------------------------------- defect 6 (frozen)


def test_readyz_counted_frozen_worker_alive_and_it_was_never_killed(tmp_path):
    hold = tmp_path / "hold"
    hold.touch()
    srv = Server(tmp_path, GAINTUNE_WORKERS="2", GAINTUNE_HEARTBEAT_TIMEOUT="4", GAINTUNE_WORKER_LIVENESS_TIMEOUT="1",
                 GAINTUNE_TEST_HOLD_FILE=str(hold), **FAST)
    try:
        srv.wait_ready()
        assert len(srv.worker_pids()) == 2
        job = srv.client.post("/v1/tune", json=TINY).json()["id"]
        srv.wait_job(job, {"running"}, cond=lambda j: j["progress"] is not None)
        pid = srv.worker_pid(job)
        freeze(srv, pid)
        r = srv.wait(lambda: (lambda r: r if r.status_code == 503 else None)(srv.client.get("/readyz")), 30,
                     "/readyz to see the frozen worker")
        body = r.json()
        assert body["workers_alive"] == 1 and body["workers_unresponsive"] == 1, body
        assert any("unresponsive" in x for x in body["reasons"]), body
        assert pid_gone(pid, 30), "the frozen worker was not killed"
        srv.wait_job(job, {"running"}, cond=lambda j: j["attempts"] == 2 and j["progress"] is not None)
        assert srv.worker_pid(job) != pid
        hold.unlink()
        done = srv.wait_job(job, {"succeeded", "failed"})
        assert done["status"] == "succeeded" and done["attempts"] == 2, done
        digest, header = agent_digest(srv, job)
        assert header == repr_digest(digest)
        srv.wait_ready(60)  # the replacement worker beats its pulse
        ready = srv.client.get("/readyz").json()
        assert ready["workers_alive"] == 2 and ready["workers_unresponsive"] == 0
        assert srv.metric("gaintune_worker_restarts_total") >= 1
    finally:
        srv.stop()


# --------------------------------------------------------------------------- defects 2, 4, 5, 6 (storage)


def test_storage_faults_crash_loop_generic_500_and_no_restarts(tmp_path):
    """Read-only data dir: the job fails once with the real cause, no worker restarts. Read-only database: 503
    naming it; a finished result is kept and written afterwards (1 attempt); dead workers are restarted
    meanwhile. Full database: 507. /readyz is not ready during each fault."""
    hold, faults = tmp_path / "hold", tmp_path / "faults"
    srv = Server(tmp_path, GAINTUNE_WORKERS="2", GAINTUNE_HEARTBEAT_TIMEOUT="3", GAINTUNE_TEST_HOLD_FILE=str(hold),
                 GAINTUNE_TEST_STORAGE_FAULT_FILE=str(faults), **FAST)
    c = srv.client
    try:
        srv.wait_ready()
        # -- read-only data directory (defect 2)
        faults.write_text("data:readonly")
        r = c.get("/readyz")
        assert r.status_code == 503 and r.json()["data_dir_writable"] is False
        assert any(x.startswith("data-dir-read-only") for x in r.json()["reasons"])
        r = c.post("/v1/tune", json=TINY)  # refused at once, naming the fault (nothing stored)
        assert r.status_code == 503 and r.json()["cause"] == "data-dir-read-only", r.text
        assert int(r.headers["retry-after"]) > 0
        assert c.get("/v1/jobs").json()["total"] == 0
        assert srv.metric("gaintune_worker_restarts_total") == 0
        faults.unlink()
        srv.wait_ready()

        # -- read-only database while a job finishes (defects 4, 5, 6)
        hold.touch()
        job = c.post("/v1/tune", json={**TINY, "name": "outage"}).json()["id"]
        srv.wait_job(job, {"running"}, cond=lambda j: j["progress"] is not None)
        runner = srv.worker_pid(job)
        faults.write_text("db:readonly")
        r = c.post("/v1/tune", json=TINY)
        assert r.status_code == 503 and r.json()["cause"] == "database-read-only", r.text
        assert int(r.headers["retry-after"]) > 0 and r.headers.get("connection") != "close"
        ready = c.get("/readyz")
        assert ready.status_code == 503 and ready.json()["database_writable"] is False
        hold.unlink()  # the search ends; its result cannot be written
        srv.wait(lambda: "result kept" in srv.logs(), 60, "the worker to keep its unwritten result")
        # the outage outlasts the lease (3 s) ...
        srv.wait(lambda: time.time() - srv.sql("SELECT heartbeat_at FROM jobs WHERE id=?", job)[0] > 4, 30,
                 "the outage to outlast the lease")
        other = next(p for p in srv.worker_pids() if p != runner)
        os.kill(other, signal.SIGKILL)  # ... and a worker dies during it
        srv.wait(lambda: srv.metric("gaintune_worker_restarts_total") == 1
                 and c.get("/readyz").json()["workers_alive"] == 2, 60, "the dead worker to be restarted")
        assert c.get(f"/v1/jobs/{job}").json()["status"] == "running"  # not recovered during the outage
        faults.unlink()
        j = srv.wait_job(job, {"succeeded", "failed", "queued"})
        assert j["status"] == "succeeded" and j["attempts"] == 1, j  # written, not recomputed
        assert srv.worker_pid(job) == runner

        # -- full database (defect 4)
        faults.write_text("db:full")
        r = c.post("/v1/tune", json=TINY)
        assert r.status_code == 507 and r.json()["cause"] == "database-full" and "retry-after" in r.headers
        faults.unlink()
        srv.wait_ready()
        assert "Traceback" not in (srv.tmp / f"server-{srv.port}.log").read_text()
    finally:
        srv.stop()


# --------------------------------------------------------------------------- defect 3


def test_connection_dropped_after_500_without_connection_close(tmp_path):
    faults = tmp_path / "faults"
    srv = Server(tmp_path, GAINTUNE_WORKERS="0", GAINTUNE_TEST_STORAGE_FAULT_FILE=str(faults), **FAST)
    try:
        srv.wait_ready()
        c = srv.client
        job = c.post("/v1/tune", json=TINY).json()["id"]
        with sqlite3.connect(srv.db) as db:  # a corrupt row: a genuine unhandled error (500) on read
            db.execute("UPDATE jobs SET result='{not json' WHERE id=?", (job,))
        with httpx.Client(base_url=srv.url, timeout=30) as client:
            ports = set()
            for fault in ("", "db:readonly", "db:full", "", "db:readonly", ""):
                faults.write_text(fault)
                bad = client.get(f"/v1/jobs/{job}") if not fault else client.post("/v1/tune", json=TINY)
                assert bad.status_code in ((500,) if not fault else (503, 507)), bad.text
                assert bad.headers["content-type"] == "application/problem+json"
                ports.add(bad.extensions["network_stream"].get_extra_info("client_addr"))
                nxt = client.get("/healthz")  # the next request on the same keep-alive connection
                assert nxt.status_code == 200
                ports.add(nxt.extensions["network_stream"].get_extra_info("client_addr"))
                assert client.get("/v1/jobs/nope").status_code == 404
                assert client.get("/healthz").status_code == 200
            assert len(ports) == 1, f"the connection was not reused: {ports}"
    finally:
        srv.stop()


# --------------------------------------------------------------------------- real tmpfs


def _mount(*args: str) -> bool:
    if shutil.which("mount") is None:
        return False
    return subprocess.run(["mount", *args], capture_output=True).returncode == 0


def test_real_full_then_read_only_tmpfs_data_dir(tmp_path):
    """The same faults on a real filesystem: a 2 MiB tmpfs, filled up, then remounted read-only (skipped
    where the runner may not mount)."""
    data = tmp_path / "data"
    data.mkdir()
    if not _mount("-t", "tmpfs", "-o", "size=2m", "tmpfs", str(data)):
        pytest.skip("cannot mount a tmpfs here (needs root with CAP_SYS_ADMIN)")
    srv = None
    try:
        srv = Server(tmp_path, GAINTUNE_WORKERS="1", **FAST)
        srv.wait_ready()
        c = srv.client
        with open(data / "filler", "wb") as f:  # fill the disk (ENOSPC ends the loop)
            try:
                while True:
                    f.write(b"\0" * 65536)
                    f.flush()
            except OSError:
                pass
        r = c.get("/readyz")
        assert r.status_code == 503 and any(x.startswith("data-dir-full") for x in r.json()["reasons"]), r.text
        r = c.post("/v1/tune", json=TINY)
        assert r.status_code == 507 and r.json()["cause"] == "data-dir-full", r.text
        (data / "filler").unlink()
        srv.wait_ready()
        ok = c.post("/v1/tune", json={**TINY, "name": "fits"}).json()["id"]
        assert srv.wait_job(ok, {"failed", "succeeded"})["status"] == "succeeded"
        assert _mount("-o", "remount,ro", str(data))
        r = c.get("/readyz")
        assert r.status_code == 503 and any(x.startswith("data-dir-read-only") for x in r.json()["reasons"]), r.text
        rep = c.get(f"/v1/jobs/{ok}/report")
        assert rep.status_code == 200 and rep.headers["x-report-cache"] == "off (data-dir-read-only)"
        assert agent_digest(srv, ok)[1]
        r = c.post("/v1/tune", json=TINY)
        assert r.status_code == 503 and r.json()["cause"] == "data-dir-read-only", r.text
        assert srv.metric("gaintune_worker_restarts_total") == 0
    finally:
        if srv is not None:
            srv.stop()
        subprocess.run(["umount", "-l", str(data)], capture_output=True)


# --------------------------------------------------------------------------- kills (slow)


@pytest.mark.slow
def test_sigkill_workers_and_server_during_jobs_lose_nothing(tmp_path):
    """4 held jobs on 2 workers; SIGKILL a worker, then the server; restart; every job succeeds exactly once."""
    hold = tmp_path / "hold"
    hold.touch()
    env = dict(GAINTUNE_WORKERS="2", GAINTUNE_MAX_ATTEMPTS="5", GAINTUNE_TEST_HOLD_FILE=str(hold), **FAST)
    srv = Server(tmp_path, **env)
    try:
        srv.wait_ready()
        ids = [srv.client.post("/v1/tune", json={**TINY, "name": f"k{i}"}, headers={"Idempotency-Key": f"k{i}"})
               .json()["id"] for i in range(4)]
        first = srv.wait_job(ids[0], {"running"}, cond=lambda j: j["progress"] is not None)
        os.kill(srv.worker_pid(first["id"]), signal.SIGKILL)
        srv.wait(lambda: sum(srv.client.get(f"/v1/jobs/{i}").json()["status"] == "running" for i in ids) == 2
                 and srv.metric("gaintune_worker_restarts_total") == 1, 60, "a restarted worker to take a job")
    finally:
        srv.stop(signal.SIGKILL)
    srv = Server(tmp_path, **env)
    try:
        srv.wait_ready()
        for i in range(4):  # idempotent replays return the same jobs
            r = srv.client.post("/v1/tune", json={**TINY, "name": f"k{i}"}, headers={"Idempotency-Key": f"k{i}"})
            assert r.json()["id"] == ids[i]
        hold.unlink()
        for i in ids:
            j = srv.wait_job(i, {"succeeded", "failed", "cancelled"}, timeout=180)
            assert j["status"] == "succeeded", j
            assert j["result"]["provenance"]["spec_hash"] == j["spec_hash"]
            digest, header = agent_digest(srv, i)
            assert header == repr_digest(digest)
        assert srv.client.get("/v1/jobs").json()["total"] == 4
    finally:
        srv.stop()


@pytest.mark.slow
def test_chaos_benchmark_small_campaign_meets_every_figure(capsys):
    """``gaintune bench chaos`` end to end, scaled down: exit code 0 means every figure is on target."""
    import json

    from gaintune.bench.chaos import main

    assert main(["--jobs", "8", "--worker-kills", "2", "--server-kills", "1", "--rounds", "1", "--json"]) == 0
    figures = json.loads(capsys.readouterr().out)["figures"]
    assert set(figures.values()) == {0}, figures
