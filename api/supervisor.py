"""Starts, watches and restarts the job worker processes; recovers jobs of dead or frozen workers.

Every second (and once at start-up) the supervisor:

1. probes that the database accepts a write. While it does not, nothing is
   written and no lease runs out: a job's lease is counted from its last
   heartbeat or from the moment the database became writable again, whichever
   is later, so a storage outage never makes live work look abandoned;
2. kills our workers whose job ignores a cancel or wall-time limit for
   ``2 * cancel_grace`` seconds;
3. recovers every ``running`` job whose worker process is gone, or whose lease
   expired (no heartbeat for ``heartbeat_timeout``), according to
   ``Settings.recover``; a worker of ours that holds an expired lease is
   frozen or stalled and is killed;
4. kills workers whose pulse (a shared-memory heartbeat beaten by a thread of
   the worker) is older than ``heartbeat_timeout`` — frozen, e.g. SIGSTOP — and
5. restarts dead workers. Steps 4-5 run even when steps 1-3 fail, so a storage
   fault never leaves the server without workers.
"""

from __future__ import annotations

import asyncio
import logging
import multiprocessing as mp
import os
import time
from typing import Any

from gaintune_api.settings import Settings
from gaintune_api.storage_faults import StorageFault
from gaintune_api.job_store import JobStore

__all__ = ["Supervisor", "pid_alive", "pid_stopped"]

log = logging.getLogger("gaintune.supervisor")


def pid_alive(pid: int | None) -> bool:
    """Whether process ``pid`` exists and is not a zombie."""
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


def pid_stopped(pid: int | None) -> bool:
    """Whether process ``pid`` is stopped (SIGSTOP, traced): frozen now, whatever its last pulse says (Linux)."""
    if not pid:
        return False
    try:
        with open(f"/proc/{pid}/stat") as f:
            return f.read().rsplit(")", 1)[1].split()[0] in ("T", "t")
    except OSError:
        return False


class Supervisor:
    """N worker processes (spawn context) for one server.

    Parameters
    ----------
    settings
        Service settings (``workers``, ``heartbeat_timeout``, ``worker_liveness_timeout``, ...).
    store
        The job store.
    """

    def __init__(self, settings: Settings, store: JobStore) -> None:
        self.settings = settings
        self.store = store
        self.ctx = mp.get_context("spawn")
        self.procs: list[mp.process.BaseProcess | None] = [None] * settings.workers
        self.pulses: list[Any] = [None] * settings.workers
        self.restarts = 0
        self.frozen_kills = 0
        #: The database fault seen by the last probe (None: writable).
        self.db_fault: StorageFault | None = None
        #: Leases are counted from no earlier than this (the database's last return to writable).
        self.db_ok_since = time.time()
        self._logged_tick: str | None = None

    # ------------------------------------------------------------- workers
    def _spawn(self, i: int) -> None:
        from gaintune_api.worker import worker_main

        pulse = self.ctx.Value("d", 0.0, lock=False)  # 0.0: not beating yet (starting)
        p = self.ctx.Process(
            target=worker_main,
            args=(self.settings.model_dump(mode="json"), i, os.getpid(), pulse),
            name=f"gaintune-worker-{i}",
            daemon=False,
        )
        p.start()
        self.procs[i] = p
        self.pulses[i] = pulse
        log.info("started worker %d (pid %s)", i, p.pid)

    def worker_state(self, i: int) -> str:
        """``alive``, ``starting`` (no pulse yet), ``unresponsive`` (stopped, or pulse older than
        ``worker_liveness_timeout``) or ``dead``."""
        p = self.procs[i]
        if p is None or not p.is_alive():
            return "dead"
        if pid_stopped(p.pid):
            return "unresponsive"
        beat = self.pulses[i].value if self.pulses[i] is not None else 0.0
        if beat <= 0.0:
            return "starting"
        return "unresponsive" if time.time() - beat > self.settings.worker_liveness_timeout else "alive"

    @property
    def alive(self) -> int:
        """Workers whose process exists and whose pulse is fresh (a frozen process does not count)."""
        return sum(1 for i in range(len(self.procs)) if self.worker_state(i) == "alive")

    @property
    def unresponsive(self) -> int:
        """Worker processes that exist but have not beaten their pulse for ``worker_liveness_timeout``."""
        return sum(1 for i in range(len(self.procs)) if self.worker_state(i) == "unresponsive")

    def _kill(self, p: mp.process.BaseProcess, why: str) -> None:
        log.warning("killing worker pid %s: %s", p.pid, why)
        p.kill()  # SIGKILL also ends a stopped (SIGSTOP) process
        p.join(5)

    def kill_frozen(self) -> None:
        """Kill workers whose pulse is older than ``heartbeat_timeout`` (frozen); :meth:`respawn` replaces them."""
        now = time.time()
        for i, p in enumerate(self.procs):
            if p is None or not p.is_alive() or self.pulses[i] is None:
                continue
            beat = self.pulses[i].value
            if beat > 0.0 and now - beat > self.settings.heartbeat_timeout:
                self.frozen_kills += 1
                self._kill(p, f"no pulse for {now - beat:.1f} s (frozen)")

    # ------------------------------------------------------------ recovery
    def probe_db(self) -> StorageFault | None:
        """Check that the database accepts a write; track outages for the lease clock. Returns the fault or None."""
        try:
            self.store.probe_write()
        except StorageFault as fault:
            if self.db_fault is None:
                log.warning("the job database cannot be written (%s): leases are extended until it can", fault)
            self.db_fault = fault
            return fault
        if self.db_fault is not None:
            log.warning("the job database accepts writes again; leases restart now")
            self.db_ok_since = time.time()
            self.db_fault = None
        return None

    def recover(self, reason: str) -> list[str]:
        """Recover running jobs whose worker is gone (``reason``) or whose lease expired. Returns the ids changed."""
        now = time.time()
        timeout = self.settings.heartbeat_timeout
        ours = {p.pid: p for p in self.procs if p is not None and p.is_alive()}
        dead: list[str] = []
        expired: list[tuple[str, int | None]] = []
        for j in self.store.running():
            if not pid_alive(j.worker_pid):
                dead.append(j.id)
            elif max(j.heartbeat_at or 0.0, self.db_ok_since) < now - timeout:
                expired.append((j.id, j.worker_pid))
        changed = self._recover(dead, reason) if dead else []
        if expired:
            changed += self._recover([j for j, _ in expired], f"its lease expired (no heartbeat for {timeout:g} s)")
            for _, pid in expired:
                if pid in ours:  # frozen or stalled past its lease: it must not resume
                    self._kill(ours[pid], "its job's lease expired")
        return changed

    def _recover(self, ids: list[str], reason: str) -> list[str]:
        changed = self.store.recover(ids, self.settings.recover, reason, self.settings.max_attempts)
        for job_id, status, error in changed:
            # Say what happened: a job that ran out of attempts is failed, not re-queued.
            log.warning("recovered job %s: %s (%s)", job_id, "re-queued" if status == "queued" else status, error)
        return [job_id for job_id, _, _ in changed]

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
                self._kill(p, f"job {j.id} did not stop")
                status = "cancelled" if late_cancel else "failed"
                err = "cancelled on request (worker killed)" if late_cancel else (
                    f"exceeded the per-job wall-time limit of {s.job_wall_time:g} s (worker killed)")
                self.store.finish(j.id, None, status, error=err)

    # ------------------------------------------------------------- lifecycle
    def start(self) -> None:
        """Recover jobs left running by a previous server, then start the workers (even if recovery must wait)."""
        try:
            self.recover("the server restarted while the job was running")
        except StorageFault as fault:
            log.warning("start-up recovery postponed: %s", fault)
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
        """One supervision pass over the jobs (skipped while the database cannot be written)."""
        if self.probe_db() is not None:
            return
        self._enforce_deadlines()
        self.recover("its worker process died")

    async def tick(self) -> None:
        """One supervision round: job checks in a thread, then worker kills and restarts whatever the checks did."""
        try:
            await asyncio.to_thread(self.check_jobs)
            self._logged_tick = None
        except Exception as exc:  # noqa: BLE001 - keep supervising; log each distinct failure once
            key = f"{type(exc).__name__}: {exc}"
            if key != self._logged_tick:
                if isinstance(exc, StorageFault):
                    log.warning("supervisor tick: %s", exc)
                else:
                    log.exception("supervisor tick failed")
                self._logged_tick = key
        try:
            self.kill_frozen()
            self.respawn()
        except Exception:  # noqa: BLE001
            log.exception("restarting workers failed")

    async def watch(self, period: float = 1.0) -> None:
        """Supervise forever, one :meth:`tick` every ``period`` seconds."""
        while True:
            await asyncio.sleep(period)
            await self.tick()

    def stop(self, timeout: float = 5.0) -> None:
        """Terminate the workers (SIGTERM, then SIGKILL after ``timeout``)."""
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
