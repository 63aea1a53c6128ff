"""Starts, watches and restarts the job worker processes; recovers jobs of dead or frozen workers.

Every second (and once at start-up) the supervisor:

1. probes that the database accepts a write. While it does not, nothing is
   written and no lease runs out: a job's lease is counted from its last
   heartbeat or from the moment the database became writable again, whichever
   is later, so a storage outage never makes live work look abandoned. One
   exception: when the write lock is held by a job worker on this host (found in
   ``/proc/locks``; SQLite only), that worker's own lease is not extended. It cannot write, so
   it is frozen or stalled; once its lease runs out it is killed, whether it is
   ours or a standalone worker, which frees the lock, and its job is recovered;
2. kills our workers whose job ignores a cancel or wall-time limit for
   ``2 * cancel_grace`` seconds;
3. recovers every ``running`` job whose worker process (on this host) is gone, or whose lease
   expired (no heartbeat for ``heartbeat_timeout``), according to
   ``Settings.recover``; a worker of ours that still runs the attempt whose
   lease expired is frozen or stalled and is killed. Before any kill for a job
   the worker is stopped and the attempt it publishes (shared memory) is
   compared with the job's: a worker that has moved on to another job is
   resumed, untouched;
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
import signal
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

from gaintune_api.job_rows import HOST
from gaintune_api.job_store import JobRow, JobStore, claim_tag
from gaintune_api.settings import Settings
from gaintune_api.storage_faults import StorageFault, wal_write_lock_holder
from gaintune_api.stores import Store
from gaintune_api.worker import PROCESS_NAME

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


def _pid(p: mp.process.BaseProcess) -> int:
    """The pid of a started worker process (multiprocessing types it Optional: None only before ``start()``)."""
    assert p.pid is not None, "worker process not started"
    return p.pid


def _is_worker(pid: int) -> bool:
    """Whether ``pid`` is a job worker (it names itself ``gaintune-worker``; Linux)."""
    try:
        return Path(f"/proc/{pid}/comm").read_text().strip() == PROCESS_NAME
    except OSError:
        return False


def _on_this_host(job: JobRow) -> bool:
    """Whether ``job``'s worker pid is a pid of this machine (None: a row written before hosts were recorded)."""
    return job.worker_host is None or job.worker_host == HOST


def _until(cond: Callable[[], bool], timeout: float) -> bool:
    """Poll ``cond`` every millisecond for at most ``timeout`` seconds."""
    end = time.monotonic() + timeout
    while not cond():
        if time.monotonic() > end:
            return False
        time.sleep(0.001)
    return True


class Supervisor:
    """N worker processes (spawn context) for one server.

    Parameters
    ----------
    settings
        Service settings (``workers``, ``heartbeat_timeout``, ``worker_liveness_timeout``, ...).
    store
        The job store.
    """

    def __init__(self, settings: Settings, store: Store) -> None:
        self.settings = settings
        self.store = store
        self.ctx = mp.get_context("spawn")
        self.procs: list[mp.process.BaseProcess | None] = [None] * settings.workers
        self.pulses: list[Any] = [None] * settings.workers
        #: pid -> shared Value('q'): the claim_tag of the attempt that worker runs (0: idle).
        self.holding: dict[int, Any] = {}
        self.restarts = 0
        self.frozen_kills = 0
        #: The database fault seen by the last probe (None: writable).
        self.db_fault: StorageFault | None = None
        #: Leases are counted from no earlier than this (the database's last return to writable).
        self.db_ok_since = time.time()
        self._logged_tick: str | None = None
        #: (pid, since): the process seen holding the database write lock, and since when.
        self._lock_seen: tuple[int, float] | None = None

    # ------------------------------------------------------------- workers
    def _spawn(self, i: int) -> None:
        from gaintune_api.worker import worker_main

        pulse = self.ctx.Value("d", 0.0, lock=False)  # 0.0: not beating yet (starting)
        holding = self.ctx.Value("q", 0, lock=False)  # an aligned 8-byte store: read whole or not at all
        p = self.ctx.Process(
            target=worker_main,
            args=(self.settings.model_dump(mode="json"), i, os.getpid(), pulse, holding),
            name=f"gaintune-worker-{i}",
            daemon=False,
        )
        p.start()
        self.procs[i] = p
        self.pulses[i] = pulse
        self.holding[_pid(p)] = holding
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
        self.holding.pop(_pid(p), None)

    def kill_if_holding(self, p: mp.process.BaseProcess, job: JobRow, why: str) -> bool:
        """Kill our worker ``p`` for ``job`` only if it still runs that attempt; True when killed.

        The worker is stopped (SIGSTOP) while the attempt it publishes is compared with the job's
        claim, so it cannot move on to another job between the check and the kill. A worker that
        runs another attempt now (it gave up on this one, e.g. after its final write failed) is
        resumed untouched: killing it would throw away an unrelated job.
        """
        pid = _pid(p)
        holding = self.holding.get(pid)
        if holding is None or not job.claim:
            log.warning("worker pid %s not killed for job %s: what it runs is unknown", p.pid, job.id)
            return False
        stopped_before = pid_stopped(pid)
        if not stopped_before:
            try:
                os.kill(pid, signal.SIGSTOP)
            except ProcessLookupError:
                return False
            _until(lambda: pid_stopped(pid) or not pid_alive(pid), 2.0)
        if holding.value == claim_tag(job.claim):
            self._kill(p, why)
            return True
        if not stopped_before:
            os.kill(pid, signal.SIGCONT)
        log.warning("worker pid %s not killed for job %s (attempt %d): it runs another job now", p.pid, job.id,
                    job.attempts)
        return False

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
                log.warning("the job database cannot be written (%s): leases are extended until it can%s", fault,
                            " (except the lease of a worker holding the lock)" if fault.kind == "locked" else "")
            self.db_fault = fault
            return fault
        if self.db_fault is not None:
            log.warning("the job database accepts writes again; leases restart now")
            self.db_ok_since = time.time()
            self.db_fault = None
        return None

    def _current_job(self, pid: int, jobs: list[JobRow]) -> JobRow | None:
        """The job worker ``pid`` runs now, among the running ``jobs`` that name it (a worker runs one
        at a time: the one it published, else the one it claimed last)."""
        holding = self.holding.get(pid)
        if holding is not None:
            return next((j for j in jobs if claim_tag(j.claim) == holding.value), None)
        return max(jobs, key=lambda j: j.started_at or 0.0, default=None)

    def fence_lock_holder(self) -> bool:
        """While the database is locked: kill the job worker holding its write lock once it is past its lease.

        The holder is found in ``/proc/locks`` (a worker on this host); its lease is read, not written
        (WAL readers do not wait for the lock), and it is not extended by the outage the holder causes.
        A worker that holds no job is killed once it has held the lock for ``heartbeat_timeout``.
        Any other process (an operator's ``sqlite3`` shell) is only named in the log.

        Returns
        -------
        bool
            True when a worker was killed (the lock is free; its job was recovered if the database let us).
        """
        if not isinstance(self.store, JobStore):  # PostgreSQL: row locks, and a stuck session is closed by the server
            return False
        pid = wal_write_lock_holder(self.store.path)
        if pid is None or pid == os.getpid():
            self._lock_seen = None
            return False
        now = time.time()
        if self._lock_seen is None or self._lock_seen[0] != pid:
            self._lock_seen = (pid, now)
            log.warning("the job database's write lock is held by pid %s", pid)
        timeout = self.settings.heartbeat_timeout
        jobs = [j for j in self.store.running() if j.worker_pid == pid and _on_this_host(j)]
        job = self._current_job(pid, jobs)
        if job is not None:
            late = max(job.heartbeat_at or 0.0, self.db_ok_since) < now - timeout
            why = f"it holds the database write lock past the lease of job {job.id} (attempt {job.attempts})"
        else:
            late = _is_worker(pid) and now - self._lock_seen[1] > timeout
            why = f"it has held the database write lock for {now - self._lock_seen[1]:.0f} s"
        if not late:
            return False
        ours = {p.pid: p for p in self.procs if p is not None}
        if pid in ours:
            self._kill(ours[pid], why)
        else:
            log.warning("killing worker pid %s: %s", pid, why)
            try:
                os.kill(pid, signal.SIGKILL)
            except ProcessLookupError:
                pass
            _until(lambda: not pid_alive(pid), 5.0)
        self._lock_seen = None
        if job is not None:
            reason = (f"its lease expired while its worker (pid {pid}) held the database write lock; "
                      "the worker was killed")
            end = time.monotonic() + self.store.gate.timeout
            while True:  # other writes of this server may be trying the freed lock too: take a turn
                try:
                    self._recover([job.id], reason)
                    break
                except StorageFault:
                    if time.monotonic() > end:  # the next pass finds the worker dead and recovers the job
                        break
                    time.sleep(0.05)
        return True

    def recover(self, reason: str) -> list[str]:
        """Recover running jobs whose worker is gone (``reason``) or whose lease expired. Returns the ids changed."""
        now = time.time()
        timeout = self.settings.heartbeat_timeout
        ours = {p.pid: p for p in self.procs if p is not None and p.is_alive()}
        dead: list[str] = []
        expired: list[JobRow] = []
        for j in self.store.running():
            if _on_this_host(j) and not pid_alive(j.worker_pid):  # another host's pid says nothing here
                dead.append(j.id)
            elif max(j.heartbeat_at or 0.0, self.db_ok_since) < now - timeout:
                expired.append(j)
        changed = self._recover(dead, reason) if dead else []
        if expired:
            recovered = set(self._recover([j.id for j in expired],
                                          f"its lease expired (no heartbeat for {timeout:g} s)"))
            changed += list(recovered)
            for j in expired:
                p = ours.get(j.worker_pid) if _on_this_host(j) else None
                if p is not None and j.id in recovered:  # frozen or stalled past its lease: it must not resume
                    self.kill_if_holding(p, j, f"the lease of job {j.id} (attempt {j.attempts}) expired")
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
            p = ours.get(j.worker_pid) if _on_this_host(j) else None
            if p is None:
                continue
            late_cancel = j.cancel_requested_at is not None and now - j.cancel_requested_at > 2 * s.cancel_grace
            late_wall = j.started_at is not None and now - j.started_at > s.job_wall_time + 2 * s.cancel_grace
            if late_cancel or late_wall:
                self.kill_if_holding(p, j, f"job {j.id} did not stop")
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
                self.holding.pop(_pid(p), None)
                self.restarts += 1
                self._spawn(i)

    def check_jobs(self) -> None:
        """One supervision pass over the jobs (skipped while the database cannot be written, after
        fencing a worker that holds its write lock past its lease)."""
        fault = self.probe_db()
        if fault is not None and fault.kind == "locked" and self.fence_lock_holder():
            fault = self.probe_db()
        if fault is not None:
            return
        self._lock_seen = None
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
        except Exception:  # noqa: BLE001 - keep supervising; the next tick tries again
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
