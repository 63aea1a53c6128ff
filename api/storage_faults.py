"""Storage faults, named: which store (job database or data directory) failed, and how.

A full or read-only disk is an operating condition, not a bug. The job store and
the artefact layer turn the exceptions such a disk gives (``sqlite3.OperationalError``
"attempt to write a readonly database" / "database or disk is full", ``OSError``
``EROFS`` / ``ENOSPC``, ...) into a :class:`StorageFault` that names the store and
the cause. The API answers it with 503 (507 when full), a problem body with a
``cause`` member and ``Retry-After``; workers fail the job once with that cause
instead of crashing.

:class:`FaultInjector` is a tests-only hook (``Settings.test_storage_fault_file``):
while its file exists, the words in it make the storage layer raise exactly those
exceptions, deterministically and even as root (where ``chmod`` does not make a
directory read-only).
"""

from __future__ import annotations

import errno
import sqlite3
from dataclasses import dataclass
from pathlib import Path
from typing import Literal

__all__ = ["StorageFault", "classify", "FaultInjector", "Where", "Kind"]

Where = Literal["database", "data"]
Kind = Literal["read-only", "full", "unavailable"]

_WHERE_SLUG = {"database": "database", "data": "data-dir"}
_WHERE_TEXT = {"database": "job database", "data": "data directory"}
_KIND_TEXT = {"read-only": "is read-only", "full": "is full", "unavailable": "cannot be used"}

# SQLite primary result codes (the low byte of ``sqlite_errorcode``).
_SQLITE_KIND: dict[int, Kind] = {8: "read-only", 13: "full", 10: "unavailable", 14: "unavailable", 5: "unavailable",
                                 6: "unavailable", 15: "unavailable", 3: "read-only"}
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
        ``"read-only"``, ``"full"`` or ``"unavailable"`` (I/O error, cannot open, locked).
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
            elif "disk i/o" in msg or "unable to open" in msg or "locked" in msg:
                kind = "unavailable"
        return None if kind is None else StorageFault(where or "database", kind, str(exc)[:300])
    if isinstance(exc, OSError) and exc.errno in _ERRNO_KIND:
        text = exc.strerror or str(exc)
        if exc.filename:
            text = f"{text}: {exc.filename}"
        return StorageFault(where or "data", _ERRNO_KIND[exc.errno], f"{errno.errorcode.get(exc.errno, exc.errno)}, {text}"[:300])
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

    The file is read on every guarded write, so tests switch faults on and off in a running
    server and its workers. ``path`` None (production): :meth:`check` does nothing.
    """

    def __init__(self, path: Path | None) -> None:
        self.path = path

    def active(self) -> set[str]:
        """The fault words switched on now."""
        if self.path is None:
            return set()
        try:
            text = self.path.read_text()
        except OSError:
            return set()
        return {w.strip().lower() for w in text.replace(",", " ").split() if w.strip()}

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

    @staticmethod
    def _raise(where: Where, kind: str, target: str | Path) -> None:
        if where == "database":
            msg, code = ("attempt to write a readonly database", 8) if kind == "readonly" else ("database or disk is full", 13)
            exc = sqlite3.OperationalError(msg)
            exc.sqlite_errorcode = code  # type: ignore[attr-defined] - as sqlite3 sets it
            raise exc
        num = errno.EROFS if kind == "readonly" else errno.ENOSPC
        raise OSError(num, f"{'Read-only file system' if kind == 'readonly' else 'No space left on device'} (injected)",
                      str(target) or None)
