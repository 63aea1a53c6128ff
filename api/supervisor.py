"""Starts, watches and restarts the job worker processes; recovers jobs of dead workers.

Recovery rule (at start-up and every second while serving): a ``running`` job
whose worker process is gone, or whose heartbeat is older than
``heartbeat_timeout``, is re-queued or failed according to
``Settings.recover``. A job cancelled or past its wall-time limit whose worker
does not stop within ``2 * cancel_grace`` seconds gets its worker killed.
"""

from __future__ import annotations

import asyncio
import logging
import multiprocessing as mp
import os
import time

from api.settings import Settings
from api.store import JobStore

__all__ = ["Supervisor", "pid_alive"]

log = logging.getLogger("gaintune.supervisor")


def pid_alive(pid: int | None) -> bool:
    if not pid:
        return False
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True
    # A zombie child of ours is dead for our purposes.
    try:
        with open(f"/proc/{pid}/stat") as f:
            return f.read().rsplit(")", 1)[1].split()[0] != "Z"
    except OSError:
        return True


class Supervisor:
    """N worker processes (spawn context) for one server."""

    def __init__(self, settings: Settings, store: JobStore) -> None:
        self.settings = settings
        self.store = store
        self.ctx = mp.get_context("spawn")
        self.procs: list[mp.process.BaseProcess | None] = [None] * settings.workers
        self.restarts = 0
        self._task: asyncio.Task | None = None

    # ------------------------------------------------------------- workers
    def _spawn(self, i: int) -> None:
        from api.worker import worker_main

        p = self.ctx.Process(
            target=worker_main,
            args=(self.settings.model_dump(mode="json"), i, os.getpid()),
            name=f"gaintune-worker-{i}",
            daemon=False,
        )
        p.start()
        self.procs[i] = p
        log.info("started worker %d (pid %s)", i, p.pid)

    @property
    def alive(self) -> int:
        return sum(1 for p in self.procs if p is not None and p.is_alive())

    # ------------------------------------------------------------ recovery
    def recover(self, reason: str) -> list[str]:
        """Recover running jobs whose worker is gone or silent."""
        now = time.time()
        dead = [
            j.id
            for j in self.store.running()
            if not pid_alive(j.worker_pid) or (j.heartbeat_at or 0) < now - self.settings.heartbeat_timeout
        ]
        if not dead:
            return []
        changed = self.store.recover(dead, self.settings.recover, reason, self.settings.max_attempts)
        if changed:
            log.warning("recovered %d job(s) (%s, policy %s): %s", len(changed), reason, self.settings.recover, changed)
        return changed

    def _enforce_deadlines(self) -> None:
        """Kill our workers whose job ignores a cancel or wall-time limit (backup for the worker's own timer)."""
        now = time.time()
        s = self.settings
        ours = {p.pid: p for p in self.procs if p is not None and p.is_alive()}
        for j in self.store.running():
            p = ours.get(j.worker_pid)
            if p is None:
                continue
            late_cancel = j.cancel_requested_at is not None and now - j.cancel_requested_at > 2 * s.cancel_grace
            late_wall = j.started_at is not None and now - j.started_at > s.job_wall_time + 2 * s.cancel_grace
            if late_cancel or late_wall:
                log.warning("killing worker pid %s: job %s did not stop", p.pid, j.id)
                p.kill()
                p.join(5)
                status = "cancelled" if late_cancel else "failed"
                err = "cancelled on request (worker killed)" if late_cancel else (
                    f"exceeded the per-job wall-time limit of {s.job_wall_time:g} s (worker killed)")
                self.store.finish(j.id, None, status, error=err)

    # ------------------------------------------------------------- lifecycle
    def start(self) -> None:
        self.recover("the server restarted while the job was running")
        for i in range(len(self.procs)):
            self._spawn(i)

    def respawn(self) -> None:
        """Restart dead workers (called from the thread that started them: PDEATHSIG is per thread)."""
        for i, p in enumerate(self.procs):
            if p is not None and not p.is_alive():
                log.warning("worker %d (pid %s) exited with %s; restarting", i, p.pid, p.exitcode)
                p.join(0)
                self.restarts += 1
                self._spawn(i)

    def check_jobs(self) -> None:
        self._enforce_deadlines()
        self.recover("its worker process died")

    async def watch(self, period: float = 1.0) -> None:
        while True:
            await asyncio.sleep(period)
            try:
                await asyncio.to_thread(self.check_jobs)
                self.respawn()
            except Exception:  # noqa: BLE001 - keep supervising
                log.exception("supervisor tick failed")

    def stop(self, timeout: float = 5.0) -> None:
        for p in self.procs:
            if p is not None and p.is_alive():
                p.terminate()
        deadline = time.monotonic() + timeout
        for p in self.procs:
            if p is not None:
                p.join(max(0.0, deadline - time.monotonic()))
                if p.is_alive():
                    p.kill()
                    p.join(1)
