"""Storage faults, named: which store (job database or data directory) failed, and how.

A full or read-only disk is an operating condition, not a bug. The job store and
the artefact layer turn the exceptions such a disk gives (``sqlite3.OperationalError``
"attempt to write a readonly database" / "database or disk is full", ``OSError``
``EROFS`` / ``ENOSPC``, ...) into a :class:`StorageFault` that names the store and
the cause. The API answers it with 503 (507 when full), a problem body with a
``cause`` member and ``Retry-After``; workers fail the job once with that cause
instead of crashing. A database whose write lock another process holds past the
store's write timeout is ``locked`` (503): writes fail fast instead of queueing,
and :func:`wal_write_lock_holder` tells the supervisor which process holds it.

:class:`FaultInjector` is a tests-only hook (``Settings.test_storage_fault_file``):
while its file exists, the words in it make the storage layer raise exactly those
exceptions, deterministically and even as root (where ``chmod`` does not make a
directory read-only).
"""

from __future__ import annotations

import errno
import os
import sqlite3
from dataclasses import dataclass
from pathlib import Path
from typing import Literal

__all__ = ["StorageFault", "classify", "FaultInjector", "Where", "Kind", "wal_write_lock_holder"]

Where = Literal["database", "data"]
Kind = Literal["read-only", "full", "unavailable", "locked"]

_WHERE_SLUG = {"database": "database", "data": "data-dir"}
_WHERE_TEXT = {"database": "job database", "data": "data directory"}
_KIND_TEXT = {"read-only": "is read-only", "full": "is full", "unavailable": "cannot be used",
              "locked": "is locked by another writer"}

# SQLite primary result codes (the low byte of ``sqlite_errorcode``).
_SQLITE_KIND: dict[int, Kind] = {8: "read-only", 13: "full", 10: "unavailable", 14: "unavailable", 5: "locked",
                                 6: "locked", 15: "unavailable", 3: "read-only"}
_ERRNO_KIND: dict[int, Kind] = {errno.EROFS: "read-only", errno.EACCES: "read-only", errno.EPERM: "read-only",
                                errno.ENOSPC: "full", errno.EDQUOT: "full", errno.EFBIG: "full",
                                errno.EIO: "unavailable", errno.ENOTCONN: "unavailable", errno.ESTALE: "unavailable"}


@dataclass(eq=False)
class StorageFault(Exception):
    """The job database or the data directory cannot be written (or read).

    Parameters
    ----------
    where
        ``"database"`` (the SQLite job store) or ``"data"`` (the artefact folder).
    kind
        ``"read-only"``, ``"full"``, ``"unavailable"`` (I/O error, cannot open) or ``"locked"``
        (another process held the write lock past the write timeout).
    reason
        The underlying error text, e.g. ``"attempt to write a readonly database"``.
    """

    where: Where
    kind: Kind
    reason: str

    def __post_init__(self) -> None:
        super().__init__(self.detail)

    @property
    def cause(self) -> str:
        """Machine-readable cause, e.g. ``database-read-only`` or ``data-dir-full``."""
        return f"{_WHERE_SLUG[self.where]}-{self.kind}"

    @property
    def status(self) -> int:
        """HTTP status: 507 Insufficient Storage when full, else 503."""
        return 507 if self.kind == "full" else 503

    @property
    def detail(self) -> str:
        """One sentence naming the store and the cause."""
        return f"The {_WHERE_TEXT[self.where]} {_KIND_TEXT[self.kind]} ({self.reason})."

    def __str__(self) -> str:
        return self.detail


def classify(exc: BaseException, where: Where | None = None) -> StorageFault | None:
    """The :class:`StorageFault` an exception means, or None when it is not a storage fault.

    Parameters
    ----------
    exc
        Any exception. ``sqlite3`` errors count as the database's; ``OSError`` as the
        data directory's unless ``where`` says otherwise.
    where
        The store the caller was using, when known.
    """
    if isinstance(exc, StorageFault):
        return exc
    if isinstance(exc, sqlite3.Error):
        code = getattr(exc, "sqlite_errorcode", None)
        kind = _SQLITE_KIND.get(code & 0xFF) if isinstance(code, int) else None
        msg = str(exc).lower()
        if kind is None:
            if "readonly" in msg or "read-only" in msg:
                kind = "read-only"
            elif "disk is full" in msg or "database or disk is full" in msg:
                kind = "full"
            elif "locked" in msg:
                kind = "locked"
            elif "disk i/o" in msg or "unable to open" in msg:
                kind = "unavailable"
        return None if kind is None else StorageFault(where or "database", kind, str(exc)[:300])
    if isinstance(exc, OSError) and exc.errno in _ERRNO_KIND:
        text = exc.strerror or str(exc)
        if exc.filename:
            text = f"{text}: {exc.filename}"
        name = errno.errorcode.get(exc.errno, exc.errno)
        return StorageFault(where or "data", _ERRNO_KIND[exc.errno], f"{name}, {text}"[:300])
    return None


class FaultInjector:
    """Tests only: make the storage layer fail as a read-only or full disk would.

    While ``path`` exists, each whitespace- or comma-separated word in it turns on one fault
    for writes (reads are unaffected, as on a read-only mount):

    ``db:readonly`` / ``db:full``
        Job-database writes raise ``sqlite3.OperationalError`` "attempt to write a readonly
        database" (SQLITE_READONLY) / "database or disk is full" (SQLITE_FULL).
    ``data:readonly`` / ``data:full``
        Data-directory writes raise ``OSError`` ``EROFS`` / ``ENOSPC``.
    ``db:full@finish`` (optionally ``db:full@finish=N``)
        The COMMIT of a job's final write (:meth:`gaintune_api.job_store.JobStore.finish`) raises
        SQLITE_FULL after the transaction did its work (the files are already renamed into
        place), and the transaction is rolled back: the disk filling up just as a job finishes.
        With ``=N`` only the next N such commits fail; the word then removes itself (rewriting
        the file: use counts from one process at a time).

    The file is read on every guarded write, so tests switch faults on and off in a running
    server and its workers. ``path`` None (production): :meth:`check` does nothing.
    """

    def __init__(self, path: Path | None) -> None:
        self.path = path

    def _words(self) -> list[str]:
        if self.path is None:
            return []
        try:
            text = self.path.read_text()
        except OSError:
            return []
        return [w.strip().lower() for w in text.replace(",", " ").split() if w.strip()]

    def active(self) -> set[str]:
        """The fault words switched on now."""
        return set(self._words())

    def check(self, where: Where, target: str | Path = "") -> None:
        """Raise the injected fault for a write to ``where`` (``target``: the path, for the message)."""
        if self.path is None:
            return
        words = self.active()
        if not words:
            return
        prefix = "db" if where == "database" else "data"
        if f"{prefix}:readonly" in words:
            self._raise(where, "readonly", target)
        if f"{prefix}:full" in words:
            self._raise(where, "full", target)

    def check_commit(self, point: str) -> None:
        """Raise SQLITE_FULL at the COMMIT of ``point`` (``"finish"``) while ``db:full@<point>`` is on."""
        if self.path is None:
            return
        words = self._words()
        word = f"db:full@{point}"
        for k, w in enumerate(words):
            name, _, count = w.partition("=")
            if name != word:
                continue
            if count.isdigit():  # counted: use one up, drop the word at zero
                left = int(count) - 1
                words[k] = f"{word}={left}" if left > 0 else ""
                self.path.write_text(" ".join(x for x in words if x))
            self._raise("database", "full", "")

    @staticmethod
    def _raise(where: Where, kind: str, target: str | Path) -> None:
        if where == "database":
            msg, code = (("attempt to write a readonly database", 8) if kind == "readonly"
                         else ("database or disk is full", 13))
            exc = sqlite3.OperationalError(msg)
            exc.sqlite_errorcode = code  # as sqlite3 sets it on its own errors
            raise exc
        num = errno.EROFS if kind == "readonly" else errno.ENOSPC
        raise OSError(num, f"{'Read-only file system' if kind == 'readonly' else 'No space left on device'} (injected)",
                      str(target) or None)


#: The byte of a WAL database's ``-shm`` file that SQLite locks (fcntl, exclusive) while a connection writes.
_WAL_WRITE_LOCK_BYTE = 120


def wal_write_lock_holder(db_path: str | Path) -> int | None:
    """The pid of the process holding the write lock of the WAL-mode SQLite database ``db_path``, or None.

    Read from ``/proc/locks`` (Linux): SQLite's WAL write lock is a POSIX lock on byte 120 of
    the ``-shm`` file. Reading it never opens the database files: closing a descriptor of a file
    drops every POSIX lock this process holds on it, which would break this process's own
    SQLite connections. None when nobody holds the lock, the holder is on another host (a
    network file system), or ``/proc/locks`` is not there.
    """
    try:
        st = os.stat(f"{db_path}-shm")
        text = Path("/proc/locks").read_text()
    except OSError:
        return None
    dev = f"{os.major(st.st_dev):02x}:{os.minor(st.st_dev):02x}:{st.st_ino}"
    for line in text.splitlines():
        # "1: POSIX  ADVISORY  WRITE 9476 fe:00:2146835 120 120"
        f = line.split()
        if len(f) >= 8 and f[1] == "POSIX" and f[3] == "WRITE" and f[5] == dev:
            try:
                start, end = int(f[6]), (int(f[7]) if f[7] != "EOF" else 1 << 62)
                pid = int(f[4])
            except ValueError:
                continue
            if start <= _WAL_WRITE_LOCK_BYTE <= end and pid > 0:
                return pid
    return None
