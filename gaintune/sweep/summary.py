"""The summary of a sweep folder: one row per item of its manifest, the totals, CSV and Parquet export.

A row holds the item's label, key, status (``done``, ``error``, ``crashed``, or ``pending``
when the store has no record yet), verdict, cost, simulations, seed, timings, error, and its
gains: as JSON (``gains``) and one column per gain (``loop.gain``).
"""

from __future__ import annotations

import csv
import json
import statistics
from pathlib import Path
from typing import Any

from gaintune.errors import GaintuneError
from gaintune.sweep.runner import read_manifest
from gaintune.sweep.store import existing_store

__all__ = ["COLUMNS", "summary_rows", "totals", "write_csv", "write_parquet"]

#: The fixed columns of a summary row (the gain columns follow).
COLUMNS = ("index", "label", "key", "kind", "status", "verdict", "cost", "sims", "seed", "wall_s", "cpu_s", "host",
           "error", "note", "gains")


def summary_rows(out: Path) -> tuple[dict[str, Any], list[dict[str, Any]]]:
    """The manifest of the sweep folder ``out`` and one row per item, in fleet order."""
    manifest = read_manifest(out)
    store = existing_store(out)
    if store is None:
        raise GaintuneError("out", f"{out} holds no results store; run the sweep first")
    try:
        by_key = {r["key"]: r for r in store.records()}
    finally:
        store.close()
    rows = []
    for item in manifest["items"]:
        rec = by_key.get(item["key"]) or {"status": "pending"}
        row: dict[str, Any] = {c: rec.get(c) for c in COLUMNS}
        row.update(index=item["index"], label=item["label"], key=item["key"], kind=manifest.get("kind"),
                   gains=json.dumps(rec["gains"]) if rec.get("gains") else None)
        for loop, gains in (rec.get("gains") or {}).items():
            for g, v in gains.items():
                row[f"{loop}.{g}"] = v
        rows.append(row)
    return manifest, rows


def totals(rows: list[dict[str, Any]]) -> dict[str, Any]:
    """Counts by outcome, the pass rate (of the items that ran to an answer), cost and time figures."""
    done = [r for r in rows if r["status"] == "done"]
    costs = [r["cost"] for r in done if r["cost"] is not None]
    passed = sum(r["verdict"] == "pass" for r in done)
    return {
        "items": len(rows), "done": len(done), "pass": passed, "fail": len(done) - passed,
        "error": sum(r["status"] == "error" for r in rows), "crashed": sum(r["status"] == "crashed" for r in rows),
        "pending": sum(r["status"] == "pending" for r in rows),
        "pass_rate": passed / len(done) if done else None,
        "cost_median": statistics.median(costs) if costs else None,
        "cost_min": min(costs) if costs else None, "cost_max": max(costs) if costs else None,
        "sims": sum(r["sims"] or 0 for r in done), "item_s": sum(r["wall_s"] or 0.0 for r in done),
    }


def _columns(rows: list[dict[str, Any]]) -> list[str]:
    extra = sorted({k for r in rows for k in r} - set(COLUMNS))
    return [*COLUMNS, *extra]


def write_csv(rows: list[dict[str, Any]], path: Path) -> None:
    """Write the rows as CSV (empty cells for missing values)."""
    cols = _columns(rows)
    with open(path, "w", newline="", encoding="utf-8") as fh:
        w = csv.DictWriter(fh, fieldnames=cols)
        w.writeheader()
        for r in rows:
            w.writerow({c: "" if r.get(c) is None else r.get(c) for c in cols})


def write_parquet(rows: list[dict[str, Any]], path: Path) -> None:
    """Write the rows as Parquet (needs pyarrow: the extra ``gaintune[parquet]``)."""
    try:
        import pyarrow as pa
        import pyarrow.parquet as pq
    except ImportError:
        raise GaintuneError("parquet", "writing Parquet needs pyarrow: pip install 'gaintune[parquet]' "
                                       "(or use --csv)") from None
    cols = _columns(rows)
    numeric = {"cost", "wall_s", "cpu_s"} | (set(cols) - set(COLUMNS))
    arrays = {c: pa.array([r.get(c) for r in rows], type=pa.float64() if c in numeric else None) for c in cols}
    pq.write_table(pa.table(arrays), path)
