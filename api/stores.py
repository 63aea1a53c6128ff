"""Which job store a process uses: SQLite (the embedded default) or PostgreSQL (``GAINTUNE_DB_URL``).

:class:`Store` is what the server, its supervisor and the workers need of a job store; both
:class:`gaintune_api.job_store.JobStore` (one SQLite file, one machine) and
:class:`gaintune_api.job_store_pg.PgJobStore` (several API servers and workers on several machines)
provide it, with the same leases and fencing tokens. :func:`open_store` picks one from the settings.
"""

from __future__ import annotations

import builtins
from collections.abc import Callable, Iterable
from typing import Protocol

from gaintune_api.job_rows import HOST, JobRow
from gaintune_api.settings import Settings
from gaintune_api.storage_faults import FaultInjector

__all__ = ["Store", "open_store", "missing_extra"]


class Store(Protocol):
    """A durable job store (see :class:`gaintune_api.job_store.JobStore` for each method's contract)."""

    #: ``"sqlite"`` or ``"postgresql"``.
    kind: str
    faults: FaultInjector

    def init(self) -> None:
        """Create the schema (idempotent)."""

    def ping(self) -> None:
        """Raise StorageFault unless the database can be read."""

    def probe_write(self) -> None:
        """Raise StorageFault unless a one-row write commits within the write timeout."""

    def create(self, owner: str, spec_json: str, spec_hash: str, spec_name: str, *, idem_key: str | None,
               max_queue: int, kind: str = "tune") -> tuple[JobRow, bool]:
        """Queue a job: (job, created)."""

    def get(self, job_id: str, owner: str | None = None) -> JobRow | None:
        """One job, or None."""

    def list(self, owner: str, status: str | None, limit: int, offset: int) -> tuple[builtins.list[JobRow], int]:
        """One page of ``owner``'s jobs and their total."""

    def counts(self) -> dict[str, int]:
        """Jobs per status."""

    def running(self) -> builtins.list[JobRow]:
        """Every running job."""

    def request_cancel(self, job_id: str, owner: str) -> tuple[JobRow | None, bool]:
        """Cancel a queued job, or flag a running one."""

    def claim(self, pid: int, host: str = HOST) -> JobRow | None:
        """Take the oldest queued job for worker ``pid`` on ``host``."""

    def heartbeat(self, job_id: str, claim: str, progress: dict | None) -> tuple[bool, bool]:
        """Record progress, fenced: (still owned, cancel requested)."""

    def owns(self, job_id: str, claim: str) -> bool:
        """Whether ``claim`` still owns the running job."""

    def finish(self, job_id: str, claim: str | None, status: str, *, result: dict | None = None,
               error: str | None = None, progress: dict | None = None,
               promote: Callable[[], dict | None] | None = None) -> str | None:
        """Write the final state, fenced by ``claim``; the status written or None."""

    def recover(self, job_ids: Iterable[str], policy: str, reason: str,
                max_attempts: int) -> builtins.list[tuple[str, str, str]]:
        """Re-queue (or fail) running jobs: (job_id, new_status, error) per job changed."""


def open_store(settings: Settings, faults: FaultInjector | None = None) -> Store:
    """The job store the settings name: PostgreSQL when ``db_url`` is set, else SQLite at ``db_path``.

    The schema is not created here (call :meth:`Store.init`).
    """
    faults = faults or FaultInjector(settings.test_storage_fault_file)
    if settings.db_url:
        from gaintune_api.job_store_pg import PgJobStore

        return PgJobStore(settings.db_url, faults, idle_timeout=settings.db_idle_timeout)
    from gaintune_api.job_store import JobStore

    return JobStore(settings.db_path, faults)


def missing_extra(settings: Settings) -> str | None:
    """What the settings need that is not installed (the extra to install), or None."""
    import importlib.util

    if settings.db_url and importlib.util.find_spec("psycopg_pool") is None:
        return "GAINTUNE_DB_URL (a PostgreSQL job store) needs psycopg: pip install 'gaintune[postgres]'"
    if settings.backend == "ray" and importlib.util.find_spec("ray") is None:
        return "GAINTUNE_BACKEND=ray needs Ray: pip install 'gaintune[ray]' (or unset GAINTUNE_BACKEND)"
    return None
