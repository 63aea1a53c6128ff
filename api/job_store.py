"""Durable job store on SQLite (WAL, synchronous=FULL): jobs, progress and results.

The embedded default, for one machine. :mod:`gaintune_api.job_store_pg` is the same store on
PostgreSQL, for several API servers and workers on several machines (``GAINTUNE_DB_URL``).

Every state change is one short transaction, so a crash (``kill -9``) of the
server or a worker never loses an accepted job or a written result.

Fencing: each attempt at a job gets a fresh random ``claim`` token (its lease
id) and the attempt number. Every write of an attempt (progress, heartbeat,
final result) is conditional on the token, and :meth:`JobStore.finish` runs the
artefact promotion (:mod:`gaintune_api.jobfiles`) inside the same write transaction
after checking the token, so the attempt that owns the job is the only one
whose files are ever renamed into place. A job recovered (re-queued or failed)
after its worker was presumed dead can never be overwritten by that worker, in
the database or on disk, whatever process or machine the worker runs on.

A failed COMMIT of that transaction (the disk filled up) leaves the renamed files
in place and the row ``running``; the worker retries with the same promotion,
which must then be idempotent (the worker caches its manifest).

A running job whose cancel was accepted ends ``cancelled`` whatever its attempt
writes: :meth:`JobStore.finish` reads the flag in the transaction that writes the
final state.

Writes are bounded: each takes at most ``write_timeout`` seconds (1.5 s), waiting
included, and while another process holds the write lock they are refused at once
(:class:`gaintune_api.writegate.WriteGate`). Reads (WAL mode) never wait for a writer.
Storage errors (read-only or full database, I/O errors, a lock held elsewhere) leave
this module as :class:`gaintune_api.storage_faults.StorageFault`, naming the cause.
"""

from __future__ import annotations

import builtins
import os
import sqlite3
import threading
import time
import uuid
from collections.abc import Callable, Iterable
from functools import wraps
from pathlib import Path
from typing import Any, TypeVar

from gaintune_api.job_rows import (
    _COLS,
    _SCHEMA,
    HOST,
    STATUSES,
    TERMINAL,
    IdempotencyConflict,
    JobRow,
    QueueFull,
    _Tx,
    claim_tag,
    dumps,
    loads,
)
from gaintune_api.storage_faults import FaultInjector, classify
from gaintune_api.writegate import WriteGate

__all__ = ["JobRow", "JobStore", "QueueFull", "IdempotencyConflict", "STATUSES", "TERMINAL", "dumps", "loads",
           "claim_tag"]

_F = TypeVar("_F", bound=Callable[..., Any])


def _db(write: bool) -> Callable[[_F], _F]:
    """Run a store method with storage errors named (StorageFault).

    ``write``: through the write gate (bounded wait, SQLite busy timeout set to the time left),
    injected write faults applied first.
    """

    def deco(fn: _F) -> _F:
        @wraps(fn)
        def wrapper(self: JobStore, *args: Any, **kw: Any) -> Any:
            try:
                if not write:
                    return fn(self, *args, **kw)
                with self.gate.enter() as left:
                    self.faults.check("database", self.path)
                    self._conn().execute(f"PRAGMA busy_timeout={max(1, int(left * 1000))}")
                    return fn(self, *args, **kw)
            except sqlite3.Error as exc:
                fault = classify(exc, "database")
                if fault is None:
                    raise
                raise fault from exc

        return wrapper  # type: ignore[return-value]  # functools.wraps keeps fn's signature; mypy cannot see it

    return deco


class JobStore:
    """Jobs in one SQLite file. Safe to use from many threads and processes.

    Parameters
    ----------
    path
        The SQLite file.
    faults
        Tests only: injected storage faults (see :class:`gaintune_api.storage_faults.FaultInjector`).
    write_timeout
        Most seconds a write may wait (for this process's other writes and for the database's
        write lock) before it is refused with StorageFault ``database-locked``.
    """

    #: Which database this store runs on (the supervisor fences SQLite's file lock holder only).
    kind = "sqlite"

    def __init__(self, path: str | Path, faults: FaultInjector | None = None, write_timeout: float = 1.5) -> None:
        self.path = Path(path)
        self.faults = faults or FaultInjector(None)
        self.gate = WriteGate(write_timeout)
        self._local = threading.local()

    # ------------------------------------------------------------ plumbing
    def _conn(self) -> sqlite3.Connection:
        conn = getattr(self._local, "conn", None)
        if conn is None or getattr(self._local, "pid", None) != os.getpid():
            timeout = self.gate.timeout
            conn = sqlite3.connect(self.path, timeout=timeout, isolation_level=None, check_same_thread=False)
            conn.row_factory = sqlite3.Row
            conn.execute(f"PRAGMA busy_timeout={int(timeout * 1000)}")
            conn.execute("PRAGMA synchronous=FULL")
            self._local.conn = conn
            self._local.pid = os.getpid()
        return conn

    def _tx(self, point: str | None = None) -> _Tx:
        return _Tx(self._conn(), self.faults if point else None, point)

    def init(self) -> None:
        """Create the folder, file, schema and WAL mode; add columns newer than the file."""
        try:
            self.faults.check("database", self.path)
            self.path.parent.mkdir(parents=True, exist_ok=True)
        except (OSError, sqlite3.Error) as exc:
            fault = classify(exc, "database")
            if fault is None:
                raise
            raise fault from exc
        self._init_schema()

    @_db(write=True)
    def _init_schema(self) -> None:
        conn = self._conn()
        conn.execute("PRAGMA journal_mode=WAL")
        conn.executescript(_SCHEMA)
        cols = {r[1] for r in conn.execute("PRAGMA table_info(jobs)")}
        if "artifacts" not in cols:  # databases written before artefact manifests
            conn.execute("ALTER TABLE jobs ADD COLUMN artifacts TEXT")
        if "kind" not in cols:  # databases written before tuner-training jobs
            conn.execute("ALTER TABLE jobs ADD COLUMN kind TEXT NOT NULL DEFAULT 'tune'")
        if "worker_host" not in cols:  # databases written before several hosts
            conn.execute("ALTER TABLE jobs ADD COLUMN worker_host TEXT")

    @_db(write=False)
    def ping(self) -> None:
        """Raise StorageFault unless the database can be read."""
        self._conn().execute("SELECT 1").fetchone()

    @_db(write=True)
    def probe_write(self) -> None:
        """Raise StorageFault unless a one-row write commits within the write timeout (readiness check)."""
        with self._tx() as c:
            c.execute("INSERT OR REPLACE INTO probe (id, at) VALUES (1, ?)", (time.time(),))

    # -------------------------------------------------------------- create
    @_db(write=True)
    def create(
        self, owner: str, spec_json: str, spec_hash: str, spec_name: str, *, idem_key: str | None, max_queue: int,
        kind: str = "tune",
    ) -> tuple[JobRow, bool]:
        """Queue a job. Returns (job, created); an existing job for the same idempotency key is returned as is.

        ``kind``: "tune" (``spec_json`` is a TuningSpec) or "tuner" (``spec_json`` is a tuner-training request).
        Raises QueueFull or IdempotencyConflict.
        """
        with self._tx() as c:
            if idem_key is not None:
                row = c.execute(f"SELECT {_COLS} FROM jobs WHERE owner=? AND idem_key=?", (owner, idem_key)).fetchone()
                if row is not None:
                    if row["spec_hash"] != spec_hash or row["kind"] != kind:
                        raise IdempotencyConflict(row["id"])
                    return JobRow.from_row(row), False
            (queued,) = c.execute("SELECT COUNT(*) FROM jobs WHERE status='queued'").fetchone()
            if queued >= max_queue:
                raise QueueFull()
            now = time.time()
            job_id = uuid.uuid4().hex
            c.execute(
                "INSERT INTO jobs (id, owner, idem_key, status, spec, spec_hash, spec_name, created_at, updated_at,"
                " kind) VALUES (?, ?, ?, 'queued', ?, ?, ?, ?, ?, ?)",
                (job_id, owner, idem_key, spec_json, spec_hash, spec_name, now, now, kind),
            )
            row = c.execute(f"SELECT {_COLS} FROM jobs WHERE id=?", (job_id,)).fetchone()
            return JobRow.from_row(row), True

    # --------------------------------------------------------------- read
    @_db(write=False)
    def get(self, job_id: str, owner: str | None = None) -> JobRow | None:
        """The job ``job_id`` (only if ``owner`` owns it, when given), or None."""
        q = f"SELECT {_COLS} FROM jobs WHERE id=?"
        args: tuple = (job_id,)
        if owner is not None:
            q += " AND owner=?"
            args += (owner,)
        row = self._conn().execute(q, args).fetchone()
        return None if row is None else JobRow.from_row(row)

    @_db(write=False)
    def list(self, owner: str, status: str | None, limit: int, offset: int) -> tuple[list[JobRow], int]:
        """One page of ``owner``'s jobs, newest first (optionally one ``status`` only), and their total count."""
        where = "owner=?"
        args: list[Any] = [owner]
        if status is not None:
            where += " AND status=?"
            args.append(status)
        conn = self._conn()
        (total,) = conn.execute(f"SELECT COUNT(*) FROM jobs WHERE {where}", args).fetchone()
        rows = conn.execute(
            f"SELECT {_COLS} FROM jobs WHERE {where} ORDER BY seq DESC LIMIT ? OFFSET ?", [*args, limit, offset]
        ).fetchall()
        return [JobRow.from_row(r) for r in rows], total

    @_db(write=False)
    def counts(self) -> dict[str, int]:
        """The number of jobs in each status (every status listed, 0 included)."""
        out = {s: 0 for s in STATUSES}
        for status, n in self._conn().execute("SELECT status, COUNT(*) FROM jobs GROUP BY status"):
            out[status] = n
        return out

    @_db(write=False)
    def running(self) -> builtins.list[JobRow]:  # builtins: the method list() shadows it here
        """Every running job."""
        rows = self._conn().execute(f"SELECT {_COLS} FROM jobs WHERE status='running'").fetchall()
        return [JobRow.from_row(r) for r in rows]

    # -------------------------------------------------------------- cancel
    @_db(write=True)
    def request_cancel(self, job_id: str, owner: str) -> tuple[JobRow | None, bool]:
        """Queued -> cancelled at once; running -> flagged for its worker. Terminal jobs are left alone.

        Returns
        -------
        (job, accepted)
            The job after the request (None: no such job for ``owner``), and whether it is now
            cancelled or bound to end ``cancelled`` (False for a job that had already finished).
        """
        now = time.time()
        with self._tx() as c:
            c.execute(
                "UPDATE jobs SET status='cancelled', finished_at=?, updated_at=?, cancel_requested_at=?,"
                " error='cancelled before it started' WHERE id=? AND owner=? AND status='queued'",
                (now, now, now, job_id, owner),
            )
            c.execute(
                "UPDATE jobs SET cancel_requested_at=?, updated_at=? WHERE id=? AND owner=? AND status='running'"
                " AND cancel_requested_at IS NULL",
                (now, now, job_id, owner),
            )
            row = c.execute(f"SELECT {_COLS} FROM jobs WHERE id=? AND owner=?", (job_id, owner)).fetchone()
        if row is None:
            return None, False
        job = JobRow.from_row(row)
        return job, job.status == "running" or (job.status == "cancelled" and job.cancel_requested_at == now)

    # -------------------------------------------------------------- worker
    @_db(write=True)
    def claim(self, pid: int, host: str = HOST) -> JobRow | None:
        """Take the oldest queued job (atomically) for worker ``pid`` on ``host``."""
        now = time.time()
        token = uuid.uuid4().hex
        # An idle worker polls often: look first without taking the write lock.
        if self._conn().execute("SELECT 1 FROM jobs WHERE status='queued' LIMIT 1").fetchone() is None:
            return None
        with self._tx() as c:
            row = c.execute("SELECT id FROM jobs WHERE status='queued' ORDER BY seq LIMIT 1").fetchone()
            if row is None:
                return None
            c.execute(
                "UPDATE jobs SET status='running', claim=?, worker_pid=?, worker_host=?, started_at=?, heartbeat_at=?,"
                " updated_at=?, attempts=attempts+1, error=NULL WHERE id=?",
                (token, pid, host, now, now, now, row["id"]),
            )
            row = c.execute(f"SELECT {_COLS} FROM jobs WHERE id=?", (row["id"],)).fetchone()
            return JobRow.from_row(row)

    @_db(write=True)
    def heartbeat(self, job_id: str, claim: str, progress: dict | None) -> tuple[bool, bool]:
        """Record progress. Returns (still_owned, cancel_requested)."""
        now = time.time()
        conn = self._conn()
        if progress is not None:
            cur = conn.execute(
                "UPDATE jobs SET heartbeat_at=?, updated_at=?, progress=? WHERE id=? AND claim=? AND status='running'",
                (now, now, dumps(progress), job_id, claim),
            )
        else:
            cur = conn.execute(
                "UPDATE jobs SET heartbeat_at=? WHERE id=? AND claim=? AND status='running'", (now, job_id, claim)
            )
        if cur.rowcount == 0:
            return False, True
        row = conn.execute("SELECT cancel_requested_at FROM jobs WHERE id=?", (job_id,)).fetchone()
        return True, row is not None and row[0] is not None

    @_db(write=False)
    def owns(self, job_id: str, claim: str) -> bool:
        """Whether the attempt holding ``claim`` still owns the running job (a read: works on a read-only database)."""
        row = self._conn().execute("SELECT 1 FROM jobs WHERE id=? AND claim=? AND status='running'",
                                   (job_id, claim)).fetchone()
        return row is not None

    @_db(write=True)
    def finish(
        self,
        job_id: str,
        claim: str | None,
        status: str,
        *,
        result: dict | None = None,
        error: str | None = None,
        progress: dict | None = None,
        promote: Callable[[], dict | None] | None = None,
    ) -> str | None:
        """Write the final state of a running job, fenced by its claim token.

        A job whose cancel was accepted (``cancel_requested_at`` set) ends ``cancelled`` whatever
        ``status`` says: a search that finished before its worker saw the flag keeps its result and
        files, and ``error`` says so.

        Parameters
        ----------
        job_id, claim
            The job and the claim token of the attempt writing (None: the supervisor, unconditional).
        status
            A terminal status.
        result, error, progress
            The final result, error text and progress (None keeps the stored one, except ``error``).
        promote
            Called inside the write transaction once the claim is verified; it renames the attempt's
            artefacts into place and returns their manifest (stored in ``artifacts``). If it raises,
            nothing is written. If the COMMIT then fails (StorageFault, e.g. the disk is full), the
            files stay renamed: a retry must pass a promotion that is idempotent.

        Returns
        -------
        str or None
            The status written; None when the job is not running under ``claim`` (recovered,
            cancelled or finished by someone else): then nothing was written or promoted.
        """
        assert status in TERMINAL
        with self._tx("finish") as c:
            row = c.execute("SELECT status, claim, cancel_requested_at FROM jobs WHERE id=?", (job_id,)).fetchone()
            if row is None or row["status"] != "running" or (claim is not None and row["claim"] != claim):
                return None
            if row["cancel_requested_at"] is not None and status != "cancelled":
                why = "the search had finished before it saw the request; its result is kept" \
                    if status == "succeeded" else f"the job was ending {status}"
                status, error = "cancelled", f"cancelled on request ({why})" + (f"; {error}" if error else "")
            manifest = promote() if promote is not None else None
            now = time.time()
            c.execute(
                "UPDATE jobs SET status=?, finished_at=?, updated_at=?, result=COALESCE(?, result), error=?,"
                " progress=COALESCE(?, progress), artifacts=COALESCE(?, artifacts), claim=NULL WHERE id=?",
                (status, now, now, None if result is None else dumps(result), error,
                 None if progress is None else dumps(progress), None if manifest is None else dumps(manifest), job_id),
            )
        return status

    # ------------------------------------------------------------ recovery
    @_db(write=True)
    def recover(self, job_ids: Iterable[str], policy: str, reason: str,
                max_attempts: int) -> builtins.list[tuple[str, str, str]]:
        """Re-queue (or fail) running jobs whose worker is gone or whose lease expired.

        Returns
        -------
        list of (job_id, new_status, error)
            One entry per job changed: ``queued`` (re-queued), ``failed`` or ``cancelled``.
        """
        changed = []
        now = time.time()
        with self._tx() as c:
            for job_id in job_ids:
                row = c.execute("SELECT status, attempts, cancel_requested_at FROM jobs WHERE id=?",
                                (job_id,)).fetchone()
                if row is None or row["status"] != "running":
                    continue
                if row["cancel_requested_at"] is not None:
                    new, err = "cancelled", f"cancelled ({reason})"
                    c.execute(
                        "UPDATE jobs SET status='cancelled', finished_at=?, updated_at=?, claim=NULL, error=? "
                        "WHERE id=?",
                        (now, now, err, job_id),
                    )
                elif policy == "requeue" and row["attempts"] < max_attempts:
                    new, err = "queued", f"re-queued: {reason}"
                    c.execute(
                        "UPDATE jobs SET status='queued', claim=NULL, worker_pid=NULL, started_at=NULL, updated_at=?,"
                        " error=? WHERE id=?",
                        (now, err, job_id),
                    )
                else:
                    why = reason if policy == "fail" else f"{reason}; gave up after {row['attempts']} attempt(s)"
                    new, err = "failed", f"interrupted: {why}"
                    c.execute(
                        "UPDATE jobs SET status='failed', finished_at=?, updated_at=?, claim=NULL, error=? WHERE id=?",
                        (now, now, err, job_id),
                    )
                changed.append((job_id, new, err))
        return changed
