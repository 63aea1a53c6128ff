"""The job table's rows, its schema and one write transaction: what :mod:`gaintune_api.job_store` reads and writes.

Kept apart from the store so that each module has one job: this one says what a job row is and how a
transaction commits (or rolls back when the COMMIT itself fails); the store says when each is used.
"""

from __future__ import annotations

import json
import socket
import sqlite3
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

from gaintune_api.storage_faults import FaultInjector

__all__ = ["JobRow", "QueueFull", "IdempotencyConflict", "STATUSES", "TERMINAL", "dumps", "loads", "claim_tag",
           "HOST"]

#: This machine's name, written with a claim beside the worker's pid: a pid is only checked on its own host.
HOST = socket.gethostname()

STATUSES = ("queued", "running", "succeeded", "failed", "cancelled")
TERMINAL = ("succeeded", "failed", "cancelled")

_SCHEMA = """
CREATE TABLE IF NOT EXISTS jobs (
    seq INTEGER PRIMARY KEY AUTOINCREMENT,
    id TEXT NOT NULL UNIQUE,
    owner TEXT NOT NULL,
    idem_key TEXT,
    status TEXT NOT NULL,
    spec TEXT NOT NULL,
    spec_hash TEXT NOT NULL,
    spec_name TEXT NOT NULL,
    created_at REAL NOT NULL,
    updated_at REAL NOT NULL,
    started_at REAL,
    finished_at REAL,
    progress TEXT,
    result TEXT,
    error TEXT,
    cancel_requested_at REAL,
    claim TEXT,
    worker_pid INTEGER,
    heartbeat_at REAL,
    attempts INTEGER NOT NULL DEFAULT 0,
    artifacts TEXT,
    kind TEXT NOT NULL DEFAULT 'tune',
    worker_host TEXT
);
CREATE TABLE IF NOT EXISTS probe (id INTEGER PRIMARY KEY, at REAL NOT NULL);
CREATE UNIQUE INDEX IF NOT EXISTS jobs_idem ON jobs(owner, idem_key) WHERE idem_key IS NOT NULL;
CREATE INDEX IF NOT EXISTS jobs_status ON jobs(status, seq);
CREATE INDEX IF NOT EXISTS jobs_owner ON jobs(owner, seq);
"""


def dumps(obj: Any) -> str:
    """JSON with non-finite floats kept (Infinity/NaN literals): lossless storage of results."""
    return json.dumps(obj, allow_nan=True, separators=(",", ":"))


def loads(text: str | None) -> Any:
    """Parse a JSON column written by :func:`dumps` (None stays None)."""
    return None if text is None else json.loads(text)


def claim_tag(claim: str | None) -> int:
    """A claim token as a positive 60-bit integer (0: none): what a worker publishes in shared memory
    as the attempt it holds, so the supervisor can check it before killing the worker for a lease."""
    return int(claim[:15], 16) if claim else 0


class QueueFull(Exception):
    """The queue holds ``max_queue`` jobs already."""


class IdempotencyConflict(Exception):
    """An Idempotency-Key was reused with a different request body."""


@dataclass(frozen=True)
class JobRow:
    """One row of the ``jobs`` table, as read (JSON columns still text)."""

    id: str
    owner: str
    idem_key: str | None
    status: str
    spec: str
    spec_hash: str
    spec_name: str
    created_at: float
    updated_at: float
    started_at: float | None
    finished_at: float | None
    progress: str | None
    result: str | None
    error: str | None
    cancel_requested_at: float | None
    claim: str | None
    worker_pid: int | None
    heartbeat_at: float | None
    attempts: int
    artifacts: str | None = None
    kind: str = "tune"  # "tune": a search (spec = the TuningSpec); "tuner": a tuner's training (spec = the request)
    #: The host name of the machine whose process ``worker_pid`` runs the attempt (None: written before hosts).
    worker_host: str | None = None

    @classmethod
    def from_row(cls, row: sqlite3.Row | Mapping[str, Any]) -> JobRow:
        """The row selected with :data:`_COLS` (an SQLite row or a PostgreSQL dict row)."""
        return cls(**{k: row[k] for k in cls.__dataclass_fields__})


_COLS = ", ".join(JobRow.__dataclass_fields__)

class _Tx:
    """BEGIN IMMEDIATE ... COMMIT (ROLLBACK on error, also when the COMMIT itself fails).

    ``faults``/``point``: tests only, a fault injected at this COMMIT (``db:full@<point>``).
    """

    def __init__(self, conn: sqlite3.Connection, faults: FaultInjector | None = None, point: str | None = None) -> None:
        self.conn = conn
        self.faults = faults
        self.point = point

    def __enter__(self) -> sqlite3.Connection:
        self.conn.execute("BEGIN IMMEDIATE")
        return self.conn

    def __exit__(self, et, ev, tb) -> None:
        if et is None:
            try:
                if self.faults is not None and self.point:
                    self.faults.check_commit(self.point)
                self.conn.execute("COMMIT")
                return
            except BaseException:
                self._rollback()
                raise
        self._rollback()

    def _rollback(self) -> None:
        try:
            self.conn.execute("ROLLBACK")
        except sqlite3.Error:  # SQLite may have rolled back already (e.g. SQLITE_FULL): keep the original error
            pass


