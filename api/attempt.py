"""The monitor of one running job attempt: heartbeats, cancel, wall-time limit, lost claims.

While :func:`gaintune_api.worker.run_job` runs the search, :meth:`Attempt.watch` runs on a thread
beside it. Every ``heartbeat_interval`` seconds it writes the progress the search reported and a
heartbeat, fenced by the attempt's claim, and reads the job's cancel flag. A cancel request, the
wall-time limit or a lost claim sets the ``cancel`` event that :func:`gaintune.search.tune` checks
(and the progress callback returns False). If the search has not returned ``cancel_grace`` seconds
later, the monitor writes the final state itself and the worker exits hard; its supervisor starts a
new one.
"""

from __future__ import annotations

import logging
import os
import threading
import time
from pathlib import Path
from typing import Any

from gaintune_api.job_store import JobRow
from gaintune_api.settings import Settings
from gaintune_api.storage_faults import StorageFault
from gaintune_api.stores import Store

__all__ = ["Attempt", "final_status", "hold_while_exists"]

log = logging.getLogger("gaintune.worker")


class Attempt:
    """What the search thread and its monitor thread share while one claimed job runs.

    The monitor (:meth:`watch`, on its own thread) heartbeats the progress the search reports
    (:meth:`on_progress`) and sets ``cancel`` on a cancel request, at the wall-time limit or when
    the claim is lost; ``reason`` says which. When the search ignores ``cancel`` for
    ``cancel_grace`` s, the monitor writes the final state itself (:meth:`_give_up`).
    """

    def __init__(self, store: Store, job: JobRow, claim: str, settings: Settings, hard_exit: bool) -> None:
        self.store, self.job, self.claim, self.settings, self.hard_exit = store, job, claim, settings, hard_exit
        self.cancel = threading.Event()
        self.done = threading.Event()  # the search has returned
        self.progress: dict[str, Any] | None = None
        self.reason: str | None = None  # "lost", "cancelled" or "wall_time", once stopped
        self.since = 0.0  # monotonic time of the stop
        self.t0 = time.monotonic()
        self._outage: StorageFault | None = None

    def stop(self, reason: str) -> None:
        """Ask the search to stop (the first reason wins)."""
        if not self.cancel.is_set():
            self.reason, self.since = reason, time.monotonic()
            self.cancel.set()

    def on_progress(self, p: Any) -> bool:
        """The search's progress callback: keep ``p`` for the next heartbeat; False asks the search to stop."""
        self.progress = p.model_dump() if hasattr(p, "model_dump") else dict(p)
        if self.settings.test_hold_file is not None:  # tests only; None (off) unless GAINTUNE_TEST_HOLD_FILE is set
            hold_while_exists(self.settings.test_hold_file, self.cancel)
        return not self.cancel.is_set()

    def watch(self) -> None:
        """Monitor loop: heartbeat and check every ``heartbeat_interval`` until the search returns."""
        while not self.done.wait(self.settings.heartbeat_interval):
            beat = self._beat()
            if beat is None:
                continue
            self._check(*beat)
            if self._overdue():
                self._give_up()
                return

    def _beat(self) -> tuple[bool, bool] | None:
        """Write a heartbeat: (still owned, cancel requested), or None when it could not be written."""
        job_id = self.job.id
        try:
            beat = self.store.heartbeat(job_id, self.claim, self.progress)
        except StorageFault as fault:  # the supervisor extends leases while the database cannot be written
            if self._outage is None:
                log.warning("job %s: heartbeat not written (%s); the search goes on, retrying", job_id, fault)
            self._outage = fault
            return None
        except Exception:  # DB busy for 30 s: try again next tick
            log.exception("heartbeat failed for job %s", job_id)
            return None
        if self._outage is not None:
            log.info("job %s: heartbeats written again", job_id)
            self._outage = None
        return beat

    def _check(self, owned: bool, cancel_requested: bool) -> None:
        """Stop the search for a lost claim, a cancel request or the wall-time limit."""
        if not owned:
            self.stop("lost")
        elif cancel_requested:
            self.stop("cancelled")
        elif time.monotonic() - self.t0 > self.settings.job_wall_time:
            self.stop("wall_time")

    def _overdue(self) -> bool:
        """Whether the search has ignored the stop for longer than ``cancel_grace``."""
        return (self.cancel.is_set() and time.monotonic() - self.since > self.settings.cancel_grace
                and not self.done.is_set())

    def _give_up(self) -> None:
        """Write the final state without the search's result, then exit the worker (``hard_exit``)."""
        job_id = self.job.id
        status, err = final_status(self.reason, self.settings)
        if self.reason != "lost":
            try:
                self.store.finish(job_id, self.claim, status, error=f"{err}; the search did not stop within "
                                  f"{self.settings.cancel_grace:g} s and its worker was restarted")
            except Exception:  # noqa: BLE001 - the supervisor's deadline check finishes it instead
                log.exception("job %s: final state not written", job_id)
        log.warning("job %s did not stop within the grace period: exiting worker", job_id)
        if self.hard_exit:
            os._exit(70)


def hold_while_exists(path: Path, cancel: threading.Event, poll: float = 0.05) -> None:
    """Test hook (``Settings.test_hold_file``): pause the search while *path* exists.

    Integration tests kill a worker or its server "during a job"; a small job can finish before the test
    even sees it running, so they hold it here, after its first progress report, instead of sleeping and
    hoping. The monitor thread keeps heartbeating (the job stays ``running`` with progress); a cancel, a
    wall-time stop or a lost claim ends the hold at once.
    """
    while not cancel.is_set() and path.exists():
        cancel.wait(poll)


def final_status(reason: str | None, settings: Settings) -> tuple[str, str]:
    """The final status and error text of an attempt stopped for ``reason`` ("cancelled", "wall_time", "lost")."""
    if reason == "cancelled":
        return "cancelled", "cancelled on request"
    if reason == "wall_time":
        return "failed", f"exceeded the per-job wall-time limit of {settings.job_wall_time:g} s"
    return "failed", "worker lost the job"
