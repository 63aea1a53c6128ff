"""Integration tests against real uvicorn processes on 127.0.0.1: a tiny job end to end, worker crash, server kill -9.

These run the real RL search (``gaintune.search.tune``) in worker processes.
"""

from __future__ import annotations

import os
import signal
import socket
import sqlite3
import subprocess
import sys
import time
from pathlib import Path

import httpx
import pytest

pytest.importorskip("gaintune.search", reason="needs gaintune.search.tune")
from gaintune.search import tune  # noqa: E402,F401 - after the skip on purpose; only its import matters

REPO = Path(__file__).resolve().parents[2]

TINY = {
    "name": "tiny",
    "plant": {"tf": {"num": [1], "den": "(s+1)^3"}},
    "loops": [{"type": "pi"}],
    "scenario": {"dt": 0.05, "horizon": 15.0},
    "search": {"budget": 200, "n_envs": 16, "seed": 1},
}


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


class Server:
    """A real server process (``python -m gaintune_api`` or ``uvicorn gaintune_api.main:app``), own data folder."""

    def __init__(self, tmp: Path, *, use_uvicorn: bool = False, **env: str) -> None:
        self.tmp = tmp
        self.port = free_port()
        self.url = f"http://127.0.0.1:{self.port}"
        self.db = tmp / "jobs.db"
        e = dict(os.environ)
        e.update(GAINTUNE_DB_PATH=str(self.db), GAINTUNE_DATA_DIR=str(tmp / "data"), GAINTUNE_WARMUP="false",
                 GAINTUNE_HEARTBEAT_INTERVAL="0.25", PYTHONPATH=str(REPO))
        e.update(env)
        self.env = e
        if use_uvicorn:
            cmd = [sys.executable, "-m", "uvicorn", "gaintune_api.main:app", "--host", "127.0.0.1",
                   "--port", str(self.port)]
        else:
            cmd = [sys.executable, "-m", "gaintune_api", "--host", "127.0.0.1", "--port", str(self.port),
                   "--workers", e.get("GAINTUNE_WORKERS", "1"), "--log-level", "warning"]
        self.log = open(tmp / f"server-{self.port}.log", "w")
        self.proc = subprocess.Popen(cmd, cwd=tmp, env=e, stdout=self.log, stderr=subprocess.STDOUT)
        self.client = httpx.Client(base_url=self.url, timeout=30)

    def wait_ready(self, timeout: float = 60) -> None:
        t0 = time.monotonic()
        while time.monotonic() - t0 < timeout:
            assert self.proc.poll() is None, self.logs()
            try:
                if self.client.get("/readyz").status_code == 200:
                    return
            except httpx.TransportError:
                pass
            time.sleep(0.2)
        raise AssertionError("server not ready:\n" + self.logs())

    def logs(self) -> str:
        self.log.flush()
        return (self.tmp / f"server-{self.port}.log").read_text()[-4000:]

    def wait_job(self, job_id: str, statuses: set[str], timeout: float = 90, cond=None) -> dict:
        t0 = time.monotonic()
        while time.monotonic() - t0 < timeout:
            j = self.client.get(f"/v1/jobs/{job_id}").json()
            if j["status"] in statuses and (cond is None or cond(j)):
                return j
            time.sleep(0.2)
        raise AssertionError(f"job {job_id} is {j['status']} ({j.get('error')}):\n{self.logs()}")

    def worker_pid(self, job_id: str) -> int:
        with sqlite3.connect(self.db) as c:
            return c.execute("SELECT worker_pid FROM jobs WHERE id=?", (job_id,)).fetchone()[0]

    def wait(self, cond, timeout: float = 60, what: str = "condition", poll: float = 0.1):
        """Poll ``cond()`` until it returns something truthy (bounded); returns that value."""
        t0 = time.monotonic()
        while time.monotonic() - t0 < timeout:
            assert self.proc.poll() is None, self.logs()
            v = cond()
            if v:
                return v
            time.sleep(poll)
        raise AssertionError(f"timed out waiting for {what}:\n{self.logs()}")

    def sql(self, query: str, *args):
        """One row of a read-only query on the server's database."""
        with sqlite3.connect(f"file:{self.db}?mode=ro", uri=True, timeout=30) as c:
            return c.execute(query, args).fetchone()

    def metric(self, name: str) -> float:
        for line in self.client.get("/metrics").text.splitlines():
            if line.startswith(name + " "):
                return float(line.split()[1])
        raise AssertionError(f"no metric {name}")

    def worker_pids(self) -> list[int]:
        """The server's job worker processes (children named ``gaintune-worker``)."""
        return children_named(self.proc.pid, "gaintune-worker")

    def stop(self, sig=signal.SIGTERM) -> None:
        if self.proc.poll() is None:
            self.proc.send_signal(sig)
            try:
                self.proc.wait(15)
            except subprocess.TimeoutExpired:
                self.proc.kill()
                self.proc.wait(5)
        self.client.close()
        self.log.close()


def children_named(parent: int, comm: str) -> list[int]:
    """Live (not zombie) child processes of ``parent`` whose ``/proc/<pid>/comm`` is ``comm``."""
    out = []
    for d in Path("/proc").iterdir():
        if not d.name.isdigit():
            continue
        try:
            stat = (d / "stat").read_text()
        except OSError:
            continue
        name = stat[stat.index("(") + 1: stat.rindex(")")]
        fields = stat[stat.rindex(")") + 2:].split()
        if name == comm and int(fields[1]) == parent and fields[0] != "Z":
            out.append(int(d.name))
    return sorted(out)


def pid_gone(pid: int, timeout: float = 10) -> bool:
    t0 = time.monotonic()
    while time.monotonic() - t0 < timeout:
        try:
            os.kill(pid, 0)
        except ProcessLookupError:
            return True
        try:  # a zombie (not yet reaped by anyone) is gone as well
            if Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0] == "Z":
                return True
        except OSError:
            return True
        time.sleep(0.1)
    return False


def test_real_server_tiny_job_end_to_end_and_worker_crash(tmp_path):
    hold = tmp_path / "hold"  # GAINTUNE_TEST_HOLD_FILE (gaintune_api.attempt.hold_while_exists); absent: the tiny job
    srv = Server(tmp_path, use_uvicorn=True, GAINTUNE_WORKERS="1", GAINTUNE_RECOVER="fail",
                 GAINTUNE_TEST_HOLD_FILE=str(hold))
    try:
        srv.wait_ready()
        c = srv.client
        r = c.post("/v1/tune", json=TINY, headers={"Idempotency-Key": "tiny-1"})
        assert r.status_code == 202, r.text
        loc = r.headers["location"]
        assert c.post("/v1/tune", json=TINY, headers={"Idempotency-Key": "tiny-1"}).headers["location"] == loc
        job_id = r.json()["id"]
        # the server stays responsive while the job runs
        assert c.post("/v1/verify", json={"spec": TINY, "gains": {"loop0": {"Kp": 1.0, "Ki": 0.4}}}).status_code == 200
        j = srv.wait_job(job_id, {"succeeded", "failed", "cancelled"})
        assert j["status"] == "succeeded", j
        res = j["result"]
        assert res["sims"] <= 200 and res["curve"] and res["provenance"]["spec_hash"] == j["spec_hash"]
        assert res["verification"]["verdict"] in ("pass", "fail")
        assert (res["accepted_gains"] is not None) == (res["verdict"] == "pass")
        agent = c.get(f"{loc}/agent")
        assert agent.status_code == 200 and agent.content[:2] == b"PK"
        try:
            import gaintune.export  # noqa: F401 - installed? (the route needs it)

            exp = c.get(f"{loc}/export", params={"format": "json", "allow_unverified": "true"})
            assert exp.status_code == 200 and "loop0" in exp.text
        except ImportError:
            pass
        try:
            import gaintune.report  # noqa: F401 - installed? (the route needs it)

            rep = c.get(f"{loc}/report")
            assert rep.status_code == 200 and "<html" in rep.text.lower()
        except ImportError:
            pass
        assert 'gaintune_jobs{state="succeeded"} 1' in c.get("/metrics").text

        # kill -9 a worker during a job: the job is failed (GAINTUNE_RECOVER=fail) and the worker restarted.
        # The hold file pauses the job after its first progress report, so it is provably still running
        # when it is killed (a large budget alone is only "probably long enough").
        hold.touch()
        long = {**TINY, "name": "long", "search": {**TINY["search"], "budget": 50_000}}
        job2 = c.post("/v1/tune", json=long).json()["id"]
        srv.wait_job(job2, {"running"}, cond=lambda j: j["progress"] is not None)
        pid = srv.worker_pid(job2)
        os.kill(pid, signal.SIGKILL)
        j2 = srv.wait_job(job2, {"failed", "queued"}, timeout=20)
        assert j2["status"] == "failed" and "interrupted" in j2["error"], j2
        srv.wait_ready(30)
        assert "gaintune_worker_restarts_total 1" in c.get("/metrics").text
    finally:
        srv.stop()


def test_sigkill_server_during_job_then_restart_requeues_and_finishes(tmp_path):
    job_spec = {**TINY, "name": "durable", "search": {**TINY["search"], "budget": 300}}
    # The 300-simulation job takes ~2 s on a fast machine: without control it can succeed before this test sees
    # it running. While the hold file exists, workers pause a job after its first progress report (test hook
    # GAINTUNE_TEST_HOLD_FILE, see gaintune_api.attempt.hold_while_exists), so the server is killed while the job is
    # provably mid-run, and after the restart it cannot finish (nor can "waiting" start, with one worker)
    # before the checks below; deleting the file lets it finish.
    hold = tmp_path / "hold"
    hold.touch()
    env = dict(GAINTUNE_WORKERS="1", GAINTUNE_RECOVER="requeue", GAINTUNE_TEST_HOLD_FILE=str(hold))
    srv = Server(tmp_path, **env)
    try:
        srv.wait_ready()
        job_id = srv.client.post("/v1/tune", json=job_spec).json()["id"]
        waiting = srv.client.post("/v1/tune", json={**job_spec, "name": "waiting"}).json()["id"]
        srv.wait_job(job_id, {"running"}, cond=lambda j: j["progress"] is not None)
        worker = srv.worker_pid(job_id)
    finally:
        srv.stop(signal.SIGKILL)
    assert pid_gone(worker), "the worker outlived its server"

    srv2 = Server(tmp_path, **env)
    try:
        srv2.wait_ready()
        c = srv2.client
        j = c.get(f"/v1/jobs/{job_id}").json()
        assert j["status"] in ("queued", "running") and "re-queued" in (j["error"] or "re-queued"), j
        assert c.get(f"/v1/jobs/{waiting}").json()["status"] in ("queued", "running")
        assert c.delete(f"/v1/jobs/{waiting}").status_code in (200, 202)
        hold.unlink()  # let the re-queued job run to the end
        j = srv2.wait_job(job_id, {"succeeded", "failed"})
        assert j["status"] == "succeeded" and j["attempts"] == 2, j
        assert j["result"]["sims"] <= 300
    finally:
        srv2.stop()
