"""Admission of one process's writes to the SQLite job database: bounded in time and in waiting threads.

SQLite lets one connection write at a time. When another process holds the write
lock (a standalone worker frozen inside a transaction, an operator's ``sqlite3``
shell), every write of this process waits for it. Requests run in a shared thread
pool, so writes that wait long would hold every thread and reads would queue
behind them. :class:`WriteGate` keeps that from happening:

* the writes of this process go through it one at a time (SQLite serialises them
  anyway), and each write gets at most ``timeout`` seconds in all, waiting included;
* once the write lock is seen held elsewhere (the write in progress has waited
  ``stuck`` seconds, or the last write ran out of time on the lock), a new write is
  refused at once instead of queueing, so at most one thread waits on the lock;
* at most ``max_waiting`` writes queue behind the one in progress.

A refused write raises :class:`gaintune_api.storage_faults.StorageFault` ``database-locked``
(503 with ``Retry-After``). Reads never pass through the gate: in WAL mode they do
not wait for a writer.
"""

from __future__ import annotations

import threading
import time
from collections.abc import Iterator
from contextlib import contextmanager

from gaintune_api.storage_faults import StorageFault, classify

__all__ = ["WriteGate"]


class WriteGate:
    """One process's door to the database write lock.

    Parameters
    ----------
    timeout
        Most seconds one write may take, waiting for the gate and for SQLite's lock included.
    stuck
        A write in progress for longer than this is waiting on a lock held elsewhere
        (a normal write takes milliseconds): later writes are refused at once.
    max_waiting
        Most writes queued behind the one in progress; more are refused at once.
    """

    def __init__(self, timeout: float = 1.5, stuck: float = 0.5, max_waiting: int = 16) -> None:
        self.timeout = timeout
        self.stuck = stuck
        self.max_waiting = max_waiting
        self._gate = threading.Lock()
        self._mu = threading.Lock()
        self._waiting = 0
        self._held_since: float | None = None
        #: The last write ran out of time on the lock; cleared by the next write that does not.
        self._locked = False

    def _refuse(self, why: str) -> StorageFault:
        return StorageFault("database", "locked", why)

    def _admit(self, t0: float) -> None:
        with self._mu:
            held = self._held_since
            if held is not None and (self._locked or t0 - held > self.stuck):
                raise self._refuse(f"another write has waited {t0 - held:.1f} s for the write lock; refused at once")
            if self._waiting >= self.max_waiting:
                raise self._refuse(f"{self._waiting} writes already wait for the write lock; refused at once")
            self._waiting += 1

    @contextmanager
    def enter(self) -> Iterator[float]:
        """Hold the gate for one write; yields the seconds left for it (the SQLite busy timeout to use).

        Raises
        ------
        StorageFault
            ``database-locked``: refused at once, or no turn within ``timeout``.
        """
        t0 = time.monotonic()
        self._admit(t0)
        try:
            got = self._gate.acquire(timeout=self.timeout)
        finally:
            with self._mu:
                self._waiting -= 1
        if not got:
            raise self._refuse(f"no turn to write within {self.timeout:g} s")
        with self._mu:
            self._held_since = time.monotonic()
        locked = False
        try:
            yield max(0.01, self.timeout - (time.monotonic() - t0))
        except BaseException as exc:
            fault = classify(exc, "database")
            locked = fault is not None and fault.kind == "locked"
            raise
        finally:
            with self._mu:
                self._held_since = None
                self._locked = locked
            self._gate.release()
