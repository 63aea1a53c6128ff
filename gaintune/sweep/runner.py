"""``run_sweep``: expand a fleet, skip what the store has finished, run the rest on a backend, record it.

The sweep folder ``OUT`` holds the store (:mod:`gaintune.sweep.store`) and ``sweep.json``, the
manifest of the last run (the fleet's name and its items' keys and labels, in fleet order), which
``gaintune sweep summary`` joins with the store. Run again with the same ``OUT``, a sweep resumes:
an item whose key has a finished record is not run again.
"""

from __future__ import annotations

import json
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Literal

from gaintune.errors import GaintuneError
from gaintune.sweep.backends import cpus_here, run_local, run_ray
from gaintune.sweep.fleet import Item, expand, load_fleet
from gaintune.sweep.store import DB_NAME, DIR_NAME, Store, open_store
from gaintune.sweep.worker import Hook, error_record

__all__ = ["MANIFEST", "SweepOptions", "SweepReport", "plan", "run_sweep", "read_manifest"]

#: The manifest file of a sweep folder.
MANIFEST = "sweep.json"


@dataclass(frozen=True)
class SweepOptions:
    """How a sweep runs.

    Attributes
    ----------
    backend
        ``local`` (worker processes) or ``ray`` (one Ray task per item).
    address
        The Ray cluster (``auto`` or ``HOST:PORT``); None: ``$RAY_ADDRESS``, else a local cluster.
    workers
        Local worker processes, or the CPUs of a local Ray cluster (default: this machine's CPUs
        divided by ``cpus_per_task``).
    cpus_per_task
        CPUs each item asks for (Ray's ``num_cpus``; the item's torch threads).
    store
        ``sqlite`` (``OUT/sweep.db``) or ``dir`` (``OUT/results/KEY.json``).
    retries
        How often an item whose worker died is run again before it is recorded ``crashed``.
    hook
        Test and benchmark instrumentation of the workers (:class:`~gaintune.sweep.worker.Hook`).
    """

    backend: Literal["local", "ray"] = "local"
    address: str | None = None
    workers: int | None = None
    cpus_per_task: int = 1
    store: Literal["sqlite", "dir"] = "sqlite"
    retries: int = 3
    hook: Hook | None = None


@dataclass
class SweepReport:
    """What one run of a sweep did (the store holds every record)."""

    name: str
    items: int  # distinct items of the fleet
    skipped: int = 0  # finished in an earlier run: not run again
    ran: int = 0  # records written by this run
    refused: int = 0  # records for an item already finished (never written twice)
    counts: dict[str, int] = field(default_factory=dict)  # this run's records by outcome: pass, fail, error, crashed
    wall_s: float = 0.0

    def count(self, rec: dict[str, Any]) -> str:
        """Count ``rec`` under its outcome and return it."""
        outcome = rec["status"] if rec["status"] != "done" else (rec.get("verdict") or "done")
        self.counts[outcome] = self.counts.get(outcome, 0) + 1
        return outcome


def plan(fleet_path: str | Path) -> tuple[str, list[Item]]:
    """The fleet's name and its distinct items (an item repeated by the fleet runs once)."""
    fleet, root = load_fleet(fleet_path)
    seen: dict[str, Item] = {}
    for item in expand(fleet, root):
        seen.setdefault(item.key, item)
    return fleet.name, list(seen.values())


def _check_store(out: Path, kind: str) -> None:
    other = {"sqlite": out / DIR_NAME, "dir": out / DB_NAME}[kind]
    if other.exists():
        theirs = "dir" if kind == "sqlite" else "sqlite"
        raise GaintuneError("store", f"{out} holds a {theirs} store from an earlier sweep; resume it with --store "
                                     f"{theirs}, or give another --out")


def _write_manifest(out: Path, name: str, fleet_path: Path, items: list[Item]) -> None:
    from gaintune.files import write_atomic

    doc = {"name": name, "fleet": str(fleet_path), "kind": items[0].kind if items else None,
           "items": [{"index": i.index, "key": i.key, "label": i.label} for i in items]}
    write_atomic(out / MANIFEST, json.dumps(doc, indent=1) + "\n")


def read_manifest(out: Path) -> dict[str, Any]:
    """The manifest of the sweep folder ``out`` (GaintuneError naming ``out`` when there is none)."""
    path = out / MANIFEST
    if not path.is_file():
        raise GaintuneError("out", f"{out} holds no sweep ({MANIFEST} is missing); give the --out of a sweep")
    try:
        doc = json.loads(path.read_text())
    except ValueError as exc:
        raise GaintuneError("out", f"{path} is not valid JSON: {exc}") from None
    return doc


def _dispatch(jobs: list[dict[str, Any]], record: Callable[[dict[str, Any]], None], options: SweepOptions) -> None:
    workers = options.workers or max(1, cpus_here() // max(1, options.cpus_per_task))
    if options.backend == "ray":
        run_ray(jobs, record, address=options.address, workers=options.workers, cpus_per_task=options.cpus_per_task,
                hook=options.hook, retries=options.retries)
    else:
        run_local(jobs, record, workers=workers, hook=options.hook, retries=options.retries)


def _recorder(store: Store, report: SweepReport,
              on_record: Callable[[dict[str, Any], SweepReport], None] | None) -> Callable[[dict[str, Any]], None]:
    """What the backends call with each record: store it (once), count it, tell ``on_record``."""

    def record(rec: dict[str, Any]) -> None:
        if store.put(rec):
            report.ran += 1
            report.count(rec)
        else:
            report.refused += 1
        if on_record is not None:
            on_record(rec, report)

    return record


def run_sweep(fleet_path: str | Path, out: str | Path, options: SweepOptions | None = None,
              on_record: Callable[[dict[str, Any], SweepReport], None] | None = None,
              on_start: Callable[[SweepReport, int], None] | None = None) -> SweepReport:
    """Run the fleet at ``fleet_path`` into the sweep folder ``out``; resume what a run there left.

    Parameters
    ----------
    fleet_path
        The fleet file (:mod:`gaintune.sweep.fleet`).
    out
        The sweep folder: the store and the manifest.
    options
        Backend, workers, store (:class:`SweepOptions`).
    on_record
        Called in the driver after each record is stored, with the record and the report so far.
    on_start
        Called once before any item runs, with the report and the number of items to run.

    Returns
    -------
    SweepReport
        What this run did.

    Raises
    ------
    GaintuneError
        A bad fleet file (:class:`~gaintune.sweep.fleet.FleetError`), a store of the other kind in
        ``out``, an unreachable Ray cluster or a missing Ray install. A bad item fails alone.
    """
    options = options or SweepOptions()
    out = Path(out)
    name, items = plan(fleet_path)
    _check_store(out, options.store)
    store = open_store(out, options.store)
    t0 = time.perf_counter()
    try:
        _write_manifest(out, name, Path(fleet_path).resolve(), items)
        finished = store.finished_keys()
        report = SweepReport(name=name, items=len(items), skipped=sum(i.key in finished for i in items))
        record = _recorder(store, report, on_record)
        todo = [i for i in items if i.key not in finished]
        if on_start is not None:
            on_start(report, len(todo))
        for i in todo:
            if i.error is not None:  # an invalid document: recorded failed without running
                record(error_record({"key": i.key, "label": i.label, "kind": i.kind}, "error", i.error))
        jobs = [{"key": i.key, "label": i.label, "kind": i.kind, "doc": i.doc, "cpus": options.cpus_per_task}
                for i in todo if i.error is None]
        if jobs:
            _dispatch(jobs, record, options)
        report.wall_s = time.perf_counter() - t0
        return report
    finally:
        store.close()
