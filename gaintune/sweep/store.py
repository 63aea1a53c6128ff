"""The results store of a sweep: one record per item key, SQLite (default) or a folder of JSON files.

Writes are idempotent: the first *finished* record of a key (``done`` or ``error``) is kept
and every later one for that key is refused (:meth:`SqliteStore.put` returns False), so a
retried or resumed item can never be recorded twice. A ``crashed`` record (the worker was lost
after its retries) may be replaced by a finished one; a resumed sweep runs such items again.

``OUT/sweep.db`` is the SQLite store (WAL journal: ``gaintune sweep summary`` reads while a
sweep writes); ``OUT/results/KEY.json`` the folder store (``--store dir``).
"""

from __future__ import annotations

import json
import sqlite3
from pathlib import Path
from typing import Any, Protocol

from gaintune.sweep.worker import RECORD_FIELDS

__all__ = ["FINISHED", "Store", "SqliteStore", "DirStore", "open_store", "existing_store", "DB_NAME", "DIR_NAME"]

#: Statuses of an item that will not run again.
FINISHED = ("done", "error")
DB_NAME, DIR_NAME = "sweep.db", "results"

_COLUMNS = {"sims": "INTEGER", "seed": "INTEGER", "pid": "INTEGER", "cost": "REAL", "wall_s": "REAL",
            "cpu_s": "REAL", "started": "REAL", "finished": "REAL"}


class Store(Protocol):
    """What the sweep needs of a store."""

    def finished_keys(self) -> set[str]:
        """Keys whose record is final (``done`` or ``error``)."""
        ...

    def put(self, record: dict[str, Any]) -> bool:
        """Store ``record`` unless its key is already finished; True when it was written."""
        ...

    def records(self) -> list[dict[str, Any]]:
        """Every record (``gains`` as a mapping)."""
        ...

    def close(self) -> None:
        """Release the store."""
        ...


class SqliteStore:
    """Records in the table ``results`` of ``OUT/sweep.db``, one row per key."""

    def __init__(self, path: Path) -> None:
        self.path = path
        self._db = sqlite3.connect(path, timeout=30.0)
        self._db.execute("PRAGMA journal_mode=WAL")
        # a commit survives the driver's death without an fsync each (an OS crash may lose the last few,
        # which then run again): 0.2 ms a record instead of 2.1 ms here, so one driver keeps up with 512 workers
        self._db.execute("PRAGMA synchronous=NORMAL")
        cols = ", ".join(f"{c} {_COLUMNS.get(c, 'TEXT')}" + (" PRIMARY KEY" if c == "key" else "")
                         for c in RECORD_FIELDS)
        with self._db:
            self._db.execute(f"CREATE TABLE IF NOT EXISTS results ({cols})")

    def finished_keys(self) -> set[str]:
        """Keys whose record is ``done`` or ``error``."""
        rows = self._db.execute("SELECT key FROM results WHERE status IN (?, ?)", FINISHED)
        return {r[0] for r in rows}

    def put(self, record: dict[str, Any]) -> bool:
        """Insert ``record``; replace only a ``crashed`` row of its key. True when written."""
        values = [json.dumps(record["gains"]) if c == "gains" and record.get(c) is not None else record.get(c)
                  for c in RECORD_FIELDS]
        cols = ", ".join(RECORD_FIELDS)
        updates = ", ".join(f"{c} = excluded.{c}" for c in RECORD_FIELDS if c != "key")
        with self._db:  # one transaction per record: a killed driver loses at most the records in flight
            cur = self._db.execute(
                f"INSERT INTO results ({cols}) VALUES ({', '.join('?' * len(RECORD_FIELDS))}) "
                f"ON CONFLICT(key) DO UPDATE SET {updates} WHERE results.status = 'crashed'", values)
        return cur.rowcount > 0

    def records(self) -> list[dict[str, Any]]:
        """Every row as a record."""
        rows = self._db.execute(f"SELECT {', '.join(RECORD_FIELDS)} FROM results")
        out = []
        for row in rows:
            rec = dict(zip(RECORD_FIELDS, row, strict=True))
            rec["gains"] = json.loads(rec["gains"]) if rec["gains"] else None
            out.append(rec)
        return out

    def close(self) -> None:
        """Close the connection."""
        self._db.close()


class DirStore:
    """Records as ``OUT/results/KEY.json``, each written atomically."""

    def __init__(self, folder: Path) -> None:
        self.folder = folder
        folder.mkdir(parents=True, exist_ok=True)

    def _read(self, path: Path) -> dict[str, Any] | None:
        try:
            rec = json.loads(path.read_text())
        except (OSError, ValueError):  # a file being replaced, or not one of ours
            return None
        return rec if isinstance(rec, dict) and "key" in rec else None

    def finished_keys(self) -> set[str]:
        """Keys whose file holds a ``done`` or ``error`` record."""
        return {r["key"] for r in self.records() if r.get("status") in FINISHED}

    def put(self, record: dict[str, Any]) -> bool:
        """Write ``KEY.json`` unless it holds a finished record already. True when written."""
        from gaintune.files import write_atomic

        path = self.folder / f"{record['key']}.json"
        old = self._read(path) if path.exists() else None
        if old is not None and old.get("status") in FINISHED:
            return False
        write_atomic(path, json.dumps({c: record.get(c) for c in RECORD_FIELDS}, indent=1) + "\n")
        return True

    def records(self) -> list[dict[str, Any]]:
        """Every record file's record."""
        recs = (self._read(p) for p in sorted(self.folder.glob("*.json")))
        return [r for r in recs if r is not None]

    def close(self) -> None:
        """Nothing to release."""


def open_store(out: Path, kind: str) -> Store:
    """The store of the sweep folder ``out`` (made if missing): ``sqlite`` or ``dir``."""
    out.mkdir(parents=True, exist_ok=True)
    if kind == "sqlite":
        return SqliteStore(out / DB_NAME)
    return DirStore(out / DIR_NAME)


def existing_store(out: Path) -> Store | None:
    """The store a sweep left in ``out``, or None when there is none."""
    if (out / DB_NAME).is_file():
        return SqliteStore(out / DB_NAME)
    if (out / DIR_NAME).is_dir():
        return DirStore(out / DIR_NAME)
    return None
