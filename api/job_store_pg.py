"""The job store on PostgreSQL (``GAINTUNE_DB_URL``): several API servers and workers on several machines.

The same store as :class:`gaintune_api.job_store.JobStore` (same rows, leases and fencing tokens), with
PostgreSQL's row locks in place of SQLite's one write lock:

* a claim takes the oldest queued row with ``SELECT ... FOR UPDATE SKIP LOCKED``: claims on several
  machines never take the same job and never wait for each other;
* every write that reads a row first locks that row only (``FOR UPDATE``), so writes to other jobs
  go on while one job's row is held; the final write checks the attempt's claim token and promotes
  its files inside that transaction, as on SQLite;
* a stuck transaction cannot block the service: each connection sets ``lock_timeout`` (a write that
  waits for a row lock longer than ``write_timeout`` is refused: StorageFault ``database-locked``),
  ``statement_timeout``, and ``idle_in_transaction_session_timeout`` (``idle_timeout``): the server
  closes the connection of a process frozen inside a transaction, which rolls it back and frees its
  locks. The frozen worker's job is then recovered when its lease expires, as on SQLite. (SQLite has
  one write lock for the whole file, held until its holder is killed: see docs/api.md.)

Timestamps are the clients' ``time.time()``: keep the hosts' clocks in sync (NTP), as leases compare them.
"""

from __future__ import annotations

import builtins
import os
import sqlite3
import threading
import time
import uuid
from collections.abc import Callable, Iterable, Iterator
from contextlib import contextmanager
from functools import wraps
from typing import Any, TypeVar

from gaintune_api.job_rows import (
    _COLS,
    HOST,
    STATUSES,
    TERMINAL,
    IdempotencyConflict,
    JobRow,
    QueueFull,
    dumps,
)
from gaintune_api.storage_faults import FaultInjector, Kind, StorageFault, classify

__all__ = ["PgJobStore", "classify_pg", "redact_url"]

_F = TypeVar("_F", bound=Callable[..., Any])

_SCHEMA = """
CREATE TABLE IF NOT EXISTS jobs (
    seq BIGINT GENERATED ALWAYS AS IDENTITY PRIMARY KEY,
    id TEXT NOT NULL UNIQUE,
    owner TEXT NOT NULL,
    idem_key TEXT,
    status TEXT NOT NULL,
    spec TEXT NOT NULL,
    spec_hash TEXT NOT NULL,
    spec_name TEXT NOT NULL,
    created_at DOUBLE PRECISION NOT NULL,
    updated_at DOUBLE PRECISION NOT NULL,
    started_at DOUBLE PRECISION,
    finished_at DOUBLE PRECISION,
    progress TEXT,
    result TEXT,
    error TEXT,
    cancel_requested_at DOUBLE PRECISION,
    claim TEXT,
    worker_pid INTEGER,
    heartbeat_at DOUBLE PRECISION,
    attempts INTEGER NOT NULL DEFAULT 0,
    artifacts TEXT,
    kind TEXT NOT NULL DEFAULT 'tune',
    worker_host TEXT
);
CREATE TABLE IF NOT EXISTS probe (id INTEGER PRIMARY KEY, at DOUBLE PRECISION NOT NULL);
CREATE UNIQUE INDEX IF NOT EXISTS jobs_idem ON jobs(owner, idem_key) WHERE idem_key IS NOT NULL;
CREATE INDEX IF NOT EXISTS jobs_status ON jobs(status, seq);
CREATE INDEX IF NOT EXISTS jobs_owner ON jobs(owner, seq);
"""

#: SQLSTATE classes and codes -> StorageFault kind (anything else from the connection: ``unavailable``).
_SQLSTATE_KIND: dict[str, Kind] = {
    "55P03": "locked",  # lock_not_available: lock_timeout
    "57014": "locked",  # query_canceled: statement_timeout
    "40P01": "locked",  # deadlock_detected
    "40001": "locked",  # serialization_failure
    "53100": "full",  # disk_full
    "53200": "full",  # out_of_memory
    "25006": "read-only",  # read_only_sql_transaction (a hot standby)
    "42501": "read-only",  # insufficient_privilege
}


def redact_url(url: str) -> str:
    """``url`` without its password (for logs and fault messages)."""
    from urllib.parse import urlsplit, urlunsplit

    parts = urlsplit(url)
    if parts.password is None:
        return url
    return urlunsplit(parts._replace(netloc=parts.netloc.replace(f":{parts.password}@", ":***@", 1)))


def classify_pg(exc: BaseException) -> StorageFault | None:
    """The StorageFault a psycopg error means (None: not a storage condition, e.g. a bug in a query)."""
    import psycopg
    import psycopg_pool

    if isinstance(exc, psycopg_pool.PoolTimeout):
        return StorageFault("database", "unavailable", f"no database connection within the timeout ({exc})")
    if not isinstance(exc, psycopg.Error):
        return None
    kind = _SQLSTATE_KIND.get(exc.sqlstate or "")
    if kind is None and isinstance(exc, psycopg.OperationalError):
        kind = "unavailable"  # connection refused or lost, server shutting down, ...
    if kind is None:
        return None
    return StorageFault("database", kind, str(exc).strip().splitlines()[0] if str(exc).strip() else type(exc).__name__)


def _db(fn: _F) -> _F:
    """Run a store method with storage errors named (StorageFault); injected write faults first for writes."""

    @wraps(fn)
    def wrapper(self: PgJobStore, *args: Any, **kw: Any) -> Any:
        try:
            return fn(self, *args, **kw)
        except sqlite3.Error as exc:  # an injected fault (tests only): FaultInjector raises SQLite's errors
            fault = classify(exc, "database")
            if fault is None:
                raise
            raise fault from exc
        except Exception as exc:
            fault = classify_pg(exc)
            if fault is None:
                raise
            raise fault from exc

    return wrapper  # type: ignore[return-value]  # functools.wraps keeps fn's signature; mypy cannot see it


class PgJobStore:
    """Jobs in a PostgreSQL database. Safe to use from many threads, processes and machines.

    Parameters
    ----------
    url
        ``postgresql://user:password@host:port/dbname``.
    faults
        Tests only: injected storage faults (see :class:`gaintune_api.storage_faults.FaultInjector`).
    write_timeout
        Most seconds a write waits for a row lock (``lock_timeout``) or for a pooled connection.
    idle_timeout
        ``idle_in_transaction_session_timeout``: the server closes a connection left inside a
        transaction this long (its process frozen), freeing its row locks.
    statement_timeout
        Most seconds one statement may run.
    pool_size
        Most connections this process opens.
    """

    #: Which database this store runs on.
    kind = "postgresql"

    def __init__(self, url: str, faults: FaultInjector | None = None, write_timeout: float = 1.5,
                 idle_timeout: float = 5.0, statement_timeout: float = 10.0, pool_size: int = 8) -> None:
        self.url = url
        self.faults = faults or FaultInjector(None)
        self.write_timeout, self.idle_timeout, self.statement_timeout = write_timeout, idle_timeout, statement_timeout
        self.pool_size = pool_size
        self._pool: Any = None
        self._pool_pid: int | None = None
        self._mu = threading.Lock()

    def __repr__(self) -> str:
        return f"PgJobStore({redact_url(self.url)!r})"

    # ------------------------------------------------------------ plumbing
    def _configure(self, conn: Any) -> None:
        """Session limits of every connection: a stuck transaction or lock cannot stall the others."""
        ms = {"lock_timeout": self.write_timeout, "statement_timeout": self.statement_timeout,
              "idle_in_transaction_session_timeout": self.idle_timeout}
        for name, seconds in ms.items():
            conn.execute(f"SET {name} = {max(1, int(seconds * 1000))}")

    def _get_pool(self) -> Any:
        """This process's connection pool (a new one after a fork: connections are not shared)."""
        with self._mu:
            if self._pool is None or self._pool_pid != os.getpid():
                from psycopg.rows import dict_row
                from psycopg_pool import ConnectionPool

                self._pool = ConnectionPool(
                    self.url, min_size=1, max_size=self.pool_size, timeout=max(self.write_timeout, 5.0),
                    kwargs={"autocommit": True, "row_factory": dict_row, "connect_timeout": 5},
                    configure=self._configure, check=ConnectionPool.check_connection, open=True,
                    name=f"gaintune-jobs-{os.getpid()}",
                )
                self._pool_pid = os.getpid()
            return self._pool

    @contextmanager
    def _conn(self) -> Iterator[Any]:
        with self._get_pool().connection() as conn:
            yield conn

    @contextmanager
    def _tx(self, point: str | None = None) -> Iterator[Any]:
        """One write transaction; ``point``: tests only, a fault injected at its COMMIT (``db:full@<point>``)."""
        self.faults.check("database", redact_url(self.url))
        with self._conn() as conn, conn.transaction():
            yield conn
            if point:
                self.faults.check_commit(point)

    def close(self) -> None:
        """Close this process's connections."""
        with self._mu:
            if self._pool is not None and self._pool_pid == os.getpid():
                self._pool.close()
            self._pool = None

    @_db
    def init(self) -> None:
        """Create the schema (idempotent; several servers may start at once)."""
        with self._conn() as conn, conn.transaction():
            # One creator at a time: concurrent CREATE ... IF NOT EXISTS can still collide in the catalog.
            conn.execute("SELECT pg_advisory_xact_lock(7263541)")
            conn.execute(_SCHEMA)

    @_db
    def ping(self) -> None:
        """Raise StorageFault unless the database can be read."""
        with self._conn() as conn:
            conn.execute("SELECT 1").fetchone()

    @_db
    def probe_write(self) -> None:
        """Raise StorageFault unless a one-row write commits within the write timeout (readiness check)."""
        with self._tx() as c:
            c.execute("INSERT INTO probe (id, at) VALUES (%s, %s) ON CONFLICT (id) DO UPDATE SET at = EXCLUDED.at",
                      (os.getpid(), time.time()))

    # -------------------------------------------------------------- create
    @_db
    def create(
        self, owner: str, spec_json: str, spec_hash: str, spec_name: str, *, idem_key: str | None, max_queue: int,
        kind: str = "tune",
    ) -> tuple[JobRow, bool]:
        """Queue a job. Returns (job, created); an existing job for the same idempotency key is returned as is.

        Two servers given the same key at once: the unique index refuses the second insert, which
        then returns the first job. Raises QueueFull or IdempotencyConflict.
        """
        import psycopg

        try:
            return self._create(owner, spec_json, spec_hash, spec_name, idem_key, max_queue, kind)
        except psycopg.errors.UniqueViolation:
            return self._create(owner, spec_json, spec_hash, spec_name, idem_key, max_queue, kind)

    def _create(self, owner: str, spec_json: str, spec_hash: str, spec_name: str, idem_key: str | None,
                max_queue: int, kind: str) -> tuple[JobRow, bool]:
        with self._tx() as c:
            if idem_key is not None:
                row = c.execute(f"SELECT {_COLS} FROM jobs WHERE owner=%s AND idem_key=%s",
                                (owner, idem_key)).fetchone()
                if row is not None:
                    if row["spec_hash"] != spec_hash or row["kind"] != kind:
                        raise IdempotencyConflict(row["id"])
                    return JobRow.from_row(row), False
            queued = c.execute("SELECT COUNT(*) AS n FROM jobs WHERE status='queued'").fetchone()["n"]
            if queued >= max_queue:
                raise QueueFull()
            now = time.time()
            row = c.execute(
                "INSERT INTO jobs (id, owner, idem_key, status, spec, spec_hash, spec_name, created_at, updated_at,"
                f" kind) VALUES (%s, %s, %s, 'queued', %s, %s, %s, %s, %s, %s) RETURNING {_COLS}",
                (uuid.uuid4().hex, owner, idem_key, spec_json, spec_hash, spec_name, now, now, kind),
            ).fetchone()
            return JobRow.from_row(row), True

    # --------------------------------------------------------------- read
    @_db
    def get(self, job_id: str, owner: str | None = None) -> JobRow | None:
        """The job ``job_id`` (only if ``owner`` owns it, when given), or None."""
        q = f"SELECT {_COLS} FROM jobs WHERE id=%s"
        args: tuple = (job_id,)
        if owner is not None:
            q += " AND owner=%s"
            args += (owner,)
        with self._conn() as conn:
            row = conn.execute(q, args).fetchone()
        return None if row is None else JobRow.from_row(row)

    @_db
    def list(self, owner: str, status: str | None, limit: int, offset: int) -> tuple[builtins.list[JobRow], int]:
        """One page of ``owner``'s jobs, newest first (optionally one ``status`` only), and their total count."""
        where = "owner=%s"
        args: builtins.list[Any] = [owner]
        if status is not None:
            where += " AND status=%s"
            args.append(status)
        with self._conn() as conn:
            total = conn.execute(f"SELECT COUNT(*) AS n FROM jobs WHERE {where}", args).fetchone()["n"]
            rows = conn.execute(f"SELECT {_COLS} FROM jobs WHERE {where} ORDER BY seq DESC LIMIT %s OFFSET %s",
                                [*args, limit, offset]).fetchall()
        return [JobRow.from_row(r) for r in rows], total

    @_db
    def counts(self) -> dict[str, int]:
        """The number of jobs in each status (every status listed, 0 included)."""
        out = {s: 0 for s in STATUSES}
        with self._conn() as conn:
            for r in conn.execute("SELECT status, COUNT(*) AS n FROM jobs GROUP BY status"):
                out[r["status"]] = r["n"]
        return out

    @_db
    def running(self) -> builtins.list[JobRow]:
        """Every running job."""
        with self._conn() as conn:
            rows = conn.execute(f"SELECT {_COLS} FROM jobs WHERE status='running'").fetchall()
        return [JobRow.from_row(r) for r in rows]

    # -------------------------------------------------------------- cancel
    @_db
    def request_cancel(self, job_id: str, owner: str) -> tuple[JobRow | None, bool]:
        """Queued -> cancelled at once; running -> flagged for its worker (see JobStore.request_cancel)."""
        now = time.time()
        with self._tx() as c:
            row = c.execute(f"SELECT {_COLS} FROM jobs WHERE id=%s AND owner=%s FOR UPDATE",
                            (job_id, owner)).fetchone()
            if row is None:
                return None, False
            if row["status"] == "queued":
                c.execute("UPDATE jobs SET status='cancelled', finished_at=%s, updated_at=%s, cancel_requested_at=%s,"
                          " error='cancelled before it started' WHERE id=%s", (now, now, now, job_id))
            elif row["status"] == "running" and row["cancel_requested_at"] is None:
                c.execute("UPDATE jobs SET cancel_requested_at=%s, updated_at=%s WHERE id=%s", (now, now, job_id))
            row = c.execute(f"SELECT {_COLS} FROM jobs WHERE id=%s", (job_id,)).fetchone()
        job = JobRow.from_row(row)
        return job, job.status == "running" or (job.status == "cancelled" and job.cancel_requested_at == now)

    # -------------------------------------------------------------- worker
    @_db
    def claim(self, pid: int, host: str = HOST) -> JobRow | None:
        """Take the oldest queued job for worker ``pid`` on ``host`` (rows other claims hold are skipped)."""
        now = time.time()
        with self._tx() as c:
            row = c.execute(
                "UPDATE jobs SET status='running', claim=%s, worker_pid=%s, worker_host=%s, started_at=%s,"
                " heartbeat_at=%s, updated_at=%s, attempts=attempts+1, error=NULL WHERE seq = ("
                "SELECT seq FROM jobs WHERE status='queued' ORDER BY seq LIMIT 1 FOR UPDATE SKIP LOCKED)"
                f" RETURNING {_COLS}",
                (uuid.uuid4().hex, pid, host, now, now, now),
            ).fetchone()
        return None if row is None else JobRow.from_row(row)

    @_db
    def heartbeat(self, job_id: str, claim: str, progress: dict | None) -> tuple[bool, bool]:
        """Record progress. Returns (still_owned, cancel_requested)."""
        now = time.time()
        with self._tx() as c:
            if progress is not None:
                row = c.execute(
                    "UPDATE jobs SET heartbeat_at=%s, updated_at=%s, progress=%s WHERE id=%s AND claim=%s"
                    " AND status='running' RETURNING cancel_requested_at",
                    (now, now, dumps(progress), job_id, claim)).fetchone()
            else:
                row = c.execute("UPDATE jobs SET heartbeat_at=%s WHERE id=%s AND claim=%s AND status='running'"
                                " RETURNING cancel_requested_at", (now, job_id, claim)).fetchone()
        if row is None:
            return False, True
        return True, row["cancel_requested_at"] is not None

    @_db
    def owns(self, job_id: str, claim: str) -> bool:
        """Whether the attempt holding ``claim`` still owns the running job (a read)."""
        with self._conn() as conn:
            row = conn.execute("SELECT 1 FROM jobs WHERE id=%s AND claim=%s AND status='running'",
                               (job_id, claim)).fetchone()
        return row is not None

    @_db
    def finish(
        self, job_id: str, claim: str | None, status: str, *, result: dict | None = None, error: str | None = None,
        progress: dict | None = None, promote: Callable[[], dict | None] | None = None,
    ) -> str | None:
        """Write the final state of a running job, fenced by its claim token (see :meth:`JobStore.finish`).

        The job's row is locked (``FOR UPDATE``) from the claim check to the COMMIT, so the promotion
        of the attempt's files and its final write are one step for every other server and worker.
        """
        assert status in TERMINAL
        with self._tx("finish") as c:
            row = c.execute("SELECT status, claim, cancel_requested_at FROM jobs WHERE id=%s FOR UPDATE",
                            (job_id,)).fetchone()
            if row is None or row["status"] != "running" or (claim is not None and row["claim"] != claim):
                return None
            if row["cancel_requested_at"] is not None and status != "cancelled":
                why = "the search had finished before it saw the request; its result is kept" \
                    if status == "succeeded" else f"the job was ending {status}"
                status, error = "cancelled", f"cancelled on request ({why})" + (f"; {error}" if error else "")
            manifest = promote() if promote is not None else None
            now = time.time()
            c.execute(
                "UPDATE jobs SET status=%s, finished_at=%s, updated_at=%s, result=COALESCE(%s, result), error=%s,"
                " progress=COALESCE(%s, progress), artifacts=COALESCE(%s, artifacts), claim=NULL WHERE id=%s",
                (status, now, now, None if result is None else dumps(result), error,
                 None if progress is None else dumps(progress), None if manifest is None else dumps(manifest), job_id),
            )
        return status

    # ------------------------------------------------------------ recovery
    @_db
    def recover(self, job_ids: Iterable[str], policy: str, reason: str,
                max_attempts: int) -> builtins.list[tuple[str, str, str]]:
        """Re-queue (or fail) running jobs whose worker is gone or whose lease expired.

        A row another transaction holds is skipped (``SKIP LOCKED``): it is being written now, or its
        writer is frozen and the server closes its connection after ``idle_timeout``; the next pass
        sees it again.
        """
        changed = []
        now = time.time()
        with self._tx() as c:
            for job_id in job_ids:
                row = c.execute("SELECT status, attempts, cancel_requested_at FROM jobs WHERE id=%s"
                                " FOR UPDATE SKIP LOCKED", (job_id,)).fetchone()
                if row is None or row["status"] != "running":
                    continue
                new, err, sql = _recovery(row, policy, reason, max_attempts)
                c.execute(sql, {"now": now, "err": err, "id": job_id})
                changed.append((job_id, new, err))
        return changed


def _recovery(row: dict[str, Any], policy: str, reason: str, max_attempts: int) -> tuple[str, str, str]:
    """(new status, error text, the UPDATE taking ``now``, ``err`` and ``id``) for one recovered running job."""
    if row["cancel_requested_at"] is not None:
        return ("cancelled", f"cancelled ({reason})",
                "UPDATE jobs SET status='cancelled', finished_at=%(now)s, updated_at=%(now)s, claim=NULL,"
                " error=%(err)s WHERE id=%(id)s")
    if policy == "requeue" and row["attempts"] < max_attempts:
        return ("queued", f"re-queued: {reason}",
                "UPDATE jobs SET status='queued', claim=NULL, worker_pid=NULL, worker_host=NULL, started_at=NULL,"
                " updated_at=%(now)s, error=%(err)s WHERE id=%(id)s")
    why = reason if policy == "fail" else f"{reason}; gave up after {row['attempts']} attempt(s)"
    return ("failed", f"interrupted: {why}",
            "UPDATE jobs SET status='failed', finished_at=%(now)s, updated_at=%(now)s, claim=NULL, error=%(err)s"
            " WHERE id=%(id)s")
