"""Processes of the chaos benchmark: a real API server and standalone workers on 127.0.0.1, over HTTP only.

Used by :mod:`gaintune.bench.chaos`. The server runs as ``python -m gaintune_api`` and standalone workers as
``python -m gaintune_api.worker``; nothing here imports the API package.
"""

from __future__ import annotations

import hashlib
import os
import signal
import socket
import subprocess
import sys
import time
from base64 import b64encode
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any

__all__ = ["WORKER_NAME", "TERMINAL", "Server", "job_spec"]


WORKER_NAME = "gaintune-worker"
TERMINAL = ("succeeded", "failed", "cancelled")


def job_spec(i: int, budget: int) -> dict[str, Any]:
    """A small tuning job (3rd-order lag, PI loop); ``i`` picks the seed."""
    return {"name": f"chaos-{i}", "plant": {"tf": {"num": [1], "den": "(s+1)^3"}}, "loops": [{"type": "pi"}],
            "scenario": {"dt": 0.05, "horizon": 15.0}, "search": {"budget": budget, "n_envs": 16, "seed": i + 1}}


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def _proc_state(pid: int) -> str:
    try:
        return Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0]
    except OSError:
        return "gone"


def _children(parent: int, comm: str = WORKER_NAME) -> list[int]:
    out = []
    for d in Path("/proc").iterdir():
        if d.name.isdigit():
            try:
                stat = (d / "stat").read_text()
            except OSError:
                continue
            fields = stat[stat.rindex(")") + 2:].split()
            if stat[stat.index("(") + 1: stat.rindex(")")] == comm and int(fields[1]) == parent and fields[0] != "Z":
                out.append(int(d.name))
    return sorted(out)


def _wait(cond: Callable[[], Any], timeout: float, what: str, poll: float = 0.1) -> Any:
    t0 = time.monotonic()
    while time.monotonic() - t0 < timeout:
        v = cond()
        if v:
            return v
        time.sleep(poll)
    raise TimeoutError(f"timed out after {timeout:g} s waiting for {what}")


class Server:
    """``python -m gaintune_api`` on a free port with its own data folder (restartable on the same database)."""

    def __init__(self, root: Path, workers: int, **env: str) -> None:
        import httpx

        root.mkdir(parents=True, exist_ok=True)
        self.root, self.workers = root, workers
        self.db = root / "jobs.db"
        # ``env`` overrides the defaults (GAINTUNE_DB_URL and a shared GAINTUNE_DATA_DIR: servers on one store).
        self.env = {**os.environ, "GAINTUNE_DB_PATH": str(self.db), "GAINTUNE_DATA_DIR": str(root / "data"),
                    "GAINTUNE_WARMUP": "false", "GAINTUNE_COMPUTE_PROCESSES": "0",
                    "GAINTUNE_HEARTBEAT_INTERVAL": "0.25", "GAINTUNE_POLL_INTERVAL": "0.1", **env}
        self.port = _free_port()
        self.url = f"http://127.0.0.1:{self.port}"
        key = self.env.get("GAINTUNE_API_KEYS", "").split(",")[0].strip()
        self.client = httpx.Client(base_url=self.url, timeout=60, headers={"X-API-Key": key} if key else None)
        self.proc: subprocess.Popen | None = None
        self.log = root / "server.log"

    def start(self) -> None:
        """Start the server process (output appended to ``server.log``); see :meth:`wait_ready`."""
        cmd = [sys.executable, "-m", "gaintune_api", "--host", "127.0.0.1", "--port", str(self.port),
               "--workers", str(self.workers), "--log-level", "warning"]
        self.proc = subprocess.Popen(cmd, cwd=self.root, env=self.env, stdout=open(self.log, "a"),
                                     stderr=subprocess.STDOUT)

    def ready(self) -> bool:
        """``/readyz`` answers 200 (RuntimeError with the log's tail when the server has exited)."""
        import httpx

        assert self.proc is not None
        if self.proc.poll() is not None:
            raise RuntimeError("server exited:\n" + self.log.read_text()[-3000:])
        try:
            return self.client.get("/readyz").status_code == 200
        except httpx.TransportError:
            return False

    def wait_ready(self, timeout: float = 180) -> None:
        """Wait until :meth:`ready` (TimeoutError after ``timeout`` s)."""
        _wait(self.ready, timeout, "the server to be ready", 0.2)

    def worker_pids(self) -> list[int]:
        """Live job workers: the server's child processes named :data:`WORKER_NAME`."""
        return _children(self.proc.pid) if self.proc else []

    def job(self, job_id: str) -> dict[str, Any]:
        """``GET /v1/jobs/{job_id}`` as a dict."""
        return self.client.get(f"/v1/jobs/{job_id}").json()

    def submit(self, spec: dict[str, Any]) -> str:
        """``POST /v1/tune``: the new job's id.

        A refused job raises naming the status and the body (a 422 problem body read as a job was a
        bare ``KeyError: 'id'``).
        """
        r = self.client.post("/v1/tune", json=spec)
        if r.status_code != 202:
            raise RuntimeError(f"POST /v1/tune answered {r.status_code}, not 202: {r.text[:500]}")
        return r.json()["id"]

    def kill(self) -> None:
        """SIGKILL the server; wait until its workers are gone (they die with it)."""
        assert self.proc is not None
        workers = self.worker_pids()
        self.proc.kill()
        self.proc.wait(30)
        _wait(lambda: all(_proc_state(p) in ("gone", "Z") for p in workers), 30, "the workers to die with the server")

    def stop(self) -> None:
        """Resume any stopped worker, SIGTERM the server (SIGKILL after 20 s) and close the client."""
        if self.proc is not None and self.proc.poll() is None:
            for pid in self.worker_pids():
                try:
                    os.kill(pid, signal.SIGCONT)
                except ProcessLookupError:
                    pass
            self.proc.terminate()
            try:
                self.proc.wait(20)
            except subprocess.TimeoutExpired:
                self.proc.kill()
                self.proc.wait(5)
        self.client.close()


@contextmanager
def _serving(root: Path, workers: int, **env: str) -> Iterator[Server]:
    """A started, ready server, stopped on exit (also on errors)."""
    srv = Server(root, workers, **env)
    try:
        srv.start()
        srv.wait_ready()
        yield srv
    finally:
        srv.stop()


def _agent_ok(srv: Server, job_id: str) -> tuple[bool, str | None]:
    """(served agent matches the digest recorded when the job finished, its sha256)."""
    r = srv.client.get(f"/v1/jobs/{job_id}/agent")
    if r.status_code != 200:
        return False, None
    digest = hashlib.sha256(r.content).hexdigest()
    return r.headers.get("repr-digest") == f"sha-256=:{b64encode(bytes.fromhex(digest)).decode()}:", digest




def _kill_events(worker_kills: int, server_kills: int) -> list[str]:
    """The campaign's kills in order: ``"worker"`` and ``"server"``, the server kills spread evenly among the others."""
    events = ["worker"] * worker_kills
    for j in range(server_kills):
        events.insert(round((j + 1) * len(events) / (server_kills + 1)) + j, "server")
    return events


def _n_done(srv: Server) -> int:
    """Jobs in the store that are neither queued nor running."""
    def count(**q: str) -> int:
        return srv.client.get("/v1/jobs", params={"limit": 1, **q}).json()["total"]

    return count() - count(status="queued") - count(status="running")


def _tally_jobs(srv: Server, ids: dict[str, set[str]], budget: int) -> dict[str, Any]:
    """Lost, duplicated, stuck, failed and corrupt jobs among the keys' ``ids``, and every job's attempts."""
    lost = dup = corrupt = stuck = failed = 0
    attempts = []
    for job_ids in ids.values():
        if len(job_ids) == 0:
            lost += 1
            continue
        if len(job_ids) > 1:
            dup += 1
        j = srv.job(next(iter(job_ids)))
        attempts.append(j["attempts"])
        if j["status"] not in TERMINAL:
            stuck += 1
        elif j["status"] != "succeeded":
            failed += 1
        else:
            res = j["result"] or {}
            ok_agent, _ = _agent_ok(srv, j["id"])
            if (res.get("provenance", {}).get("spec_hash") != j["spec_hash"] or not res.get("curve")
                    or not 0 < res.get("sims", 0) <= budget or not ok_agent):
                corrupt += 1
    return {"lost": lost, "duplicated": dup, "stuck": stuck, "corrupt": corrupt, "failed": failed,
            "attempts": attempts}


class _Worker:
    def __init__(self, srv: Server, index: int) -> None:
        self.log = srv.root / f"worker-{index}.log"
        self.proc = subprocess.Popen([sys.executable, "-m", "gaintune_api.worker", "--index", str(index)], cwd=srv.root,
                                     env=srv.env, stdout=open(self.log, "a"), stderr=subprocess.STDOUT)

    def text(self) -> str:
        return self.log.read_text()

    def stop(self) -> None:
        if self.proc.poll() is None:
            os.kill(self.proc.pid, signal.SIGCONT)
            self.proc.kill()
            self.proc.wait(10)

