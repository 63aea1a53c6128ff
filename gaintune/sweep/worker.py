"""One item of a sweep, run in a worker process (a local pool's or a Ray worker's): :func:`run_item`.

A job is a plain mapping ``{key, kind, doc, cpus}`` and the answer a plain mapping (a
:data:`RECORD_FIELDS` row), so both cross process and machine boundaries as they are. Nothing
an item does escapes it: any exception becomes that item's ``error`` record.

:class:`Hook` lets tests and ``gaintune bench sweep`` watch and hold workers: a ledger file
gets a ``start``/``done`` line per attempt, and a gate file holds each attempt until it exists
(so a worker can be killed while it is known to be running an item).
"""

from __future__ import annotations

import functools
import os
import socket
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

__all__ = ["RECORD_FIELDS", "Hook", "run_item", "error_record"]

#: The fields of one result record, in the store's column order.
RECORD_FIELDS = ("key", "label", "kind", "status", "error", "verdict", "cost", "gains", "sims", "seed", "note",
                 "wall_s", "cpu_s", "started", "finished", "host", "pid")

#: How long a held attempt waits for its gate at most (a test that forgot it must not hang).
GATE_TIMEOUT_S = 300.0


@dataclass(frozen=True)
class Hook:
    """Watch and hold the workers (tests and the benchmark; never the CLI).

    Attributes
    ----------
    ledger
        A file each attempt appends ``start KEY PID`` and ``done KEY PID`` lines to.
    gate
        A file each attempt waits for (after its start line) before it runs.
    """

    ledger: str | None = None
    gate: str | None = None

    def mark(self, what: str, key: str) -> None:
        """Append one ledger line (a single small ``O_APPEND`` write: lines of concurrent workers never mix)."""
        if self.ledger is None:
            return
        fd = os.open(self.ledger, os.O_WRONLY | os.O_APPEND | os.O_CREAT, 0o644)
        try:
            os.write(fd, f"{what} {key} {os.getpid()}\n".encode())
        finally:
            os.close(fd)

    def wait(self) -> None:
        """Block until the gate file exists (at most :data:`GATE_TIMEOUT_S`)."""
        if self.gate is None:
            return
        end = time.monotonic() + GATE_TIMEOUT_S
        while not os.path.exists(self.gate) and time.monotonic() < end:
            time.sleep(0.02)


def error_record(job: dict[str, Any], status: str, error: str) -> dict[str, Any]:
    """The record of an item that did not run to an answer (``status`` ``error`` or ``crashed``)."""
    rec: dict[str, Any] = dict.fromkeys(RECORD_FIELDS)
    rec.update(key=job["key"], label=job.get("label"), kind=job["kind"], status=status, error=error)
    return rec


@functools.lru_cache(maxsize=8)
def _tuner(ref: str) -> Any:
    """A loaded tuner, kept for the next query of the same worker (loading costs ~1 s, a query ~50 ms)."""
    from gaintune.tuners.tuner import Tuner

    return Tuner.load(ref)


def _run_tune(doc: dict[str, Any]) -> dict[str, Any]:
    from gaintune.search.tuning import tune
    from gaintune.spec import TuningSpec

    spec = TuningSpec.model_validate(doc)
    r = tune(spec, verify=True)
    reasons = r.verification.reasons if r.verification is not None else []
    return dict(verdict=r.verdict, cost=float(r.cost), gains=r.gains, sims=int(r.sims), seed=spec.search.seed,
                note=reasons[0] if reasons else None)


def _run_query(doc: dict[str, Any]) -> dict[str, Any]:
    a = _tuner(doc["tuner"]).query(doc["params"], refine=doc["refine"], seed=doc["seed"])
    reasons = a.verification.reasons if a.verification is not None else []
    return dict(verdict=a.verdict, cost=float(a.cost), gains=a.gains, sims=int(a.n_sims), seed=doc["seed"],
                note=reasons[0] if reasons else None)


def _threads(cpus: int) -> None:
    """Keep the item's threads (simulator, torch) to the CPUs it asked for, so workers do not contend."""
    from gaintune.sim.threads import set_sim_threads

    set_sim_threads(cpus)
    if cpus > 1:
        import torch

        torch.set_num_threads(cpus)


def run_item(job: dict[str, Any], hook: Hook | None = None) -> dict[str, Any]:
    """Run one job and return its record: ``done`` with the answer, or ``error`` with what went wrong.

    Parameters
    ----------
    job
        ``{key, label, kind, doc, cpus}``: ``kind`` ``tune`` runs :func:`gaintune.search.tune` on the spec
        ``doc``; ``query`` asks ``Tuner.load(doc["tuner"]).query(doc["params"], ...)``.
    hook
        Test and benchmark instrumentation (:class:`Hook`).

    Returns
    -------
    dict
        One value per :data:`RECORD_FIELDS` name.
    """
    hook = hook or Hook()
    hook.mark("start", job["key"])
    hook.wait()
    started = time.time()
    t0, c0 = time.perf_counter(), time.process_time()
    try:
        _threads(int(job.get("cpus", 1)))
        answer = _run_tune(job["doc"]) if job["kind"] == "tune" else _run_query(job["doc"])
    except Exception as exc:  # one item's failure is that item's record, never the sweep's end
        from gaintune.errors import problem_details

        text = "; ".join(f"{d['loc']}: {d['msg']}" if d["loc"] else d["msg"] for d in problem_details(exc))
        rec = error_record(job, "error", f"{type(exc).__name__}: {text}")
    else:
        rec = error_record(job, "done", "")
        rec.update(answer, error=None)
    rec.update(wall_s=time.perf_counter() - t0, cpu_s=time.process_time() - c0, started=started,
               finished=time.time(), host=socket.gethostname(), pid=os.getpid())
    hook.mark("done", job["key"])
    return rec


def ledger_lines(path: str | Path) -> list[tuple[str, str, int]]:
    """The ``(what, key, pid)`` lines of a ledger file (none when it does not exist)."""
    p = Path(path)
    if not p.exists():
        return []
    out = []
    for line in p.read_text().splitlines():
        what, key, pid = line.split()
        out.append((what, key, int(pid)))
    return out
