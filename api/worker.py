"""Job worker: a separate process that claims queued jobs from the job store and runs the RL search (or, for a job of
kind ``tuner``, a tuner's training: :mod:`gaintune_api.tuner_jobs`).

Run inside the server (``Settings.workers`` processes, started and restarted by
:mod:`gaintune_api.supervisor`) or standalone next to it: ``python -m gaintune_api.worker``.

While a job runs, a monitor thread (:class:`gaintune_api.attempt.Attempt`) writes progress and a heartbeat every
``heartbeat_interval`` seconds and polls the job's ``cancel_requested_at``
flag and the wall-time limit. Either sets the ``cancel`` event that
:func:`gaintune.search.tune` checks (and the progress callback returns
False). If the search has not returned ``cancel_grace`` seconds later, the
worker writes the final state itself and exits hard; its supervisor starts a
new one.

Fencing: the attempt writes its files into its own staging folder
(:meth:`gaintune_api.jobfiles.JobFiles.stage`) and all its database writes carry its
claim token. A worker that lost its lease (frozen past ``heartbeat_timeout``,
then resumed after the job was recovered) learns it at its next heartbeat, stops
the search and discards its files; if it reaches the end first, the fenced
commit refuses it. Storage faults never crash the worker: a job whose folder
cannot be written fails once with the named cause; a result that cannot be
written because the database is read-only, full or locked is kept and retried
while the attempt still owns the job. The retry is safe after a COMMIT that
failed once the files were renamed into place: the promotion runs at most once
and later tries reuse its manifest, so finished work is written, not recomputed.

A worker started by the supervisor also beats a shared-memory *pulse* from a
thread, so the supervisor and ``/readyz`` can tell a frozen process from a live one,
and publishes the claim it holds (:func:`gaintune_api.job_store.claim_tag`, 0 when idle),
so the supervisor kills it for an expired lease only while it still holds that attempt.
"""

from __future__ import annotations

import logging
import os
import signal
import sys
import threading
import time
import traceback
from collections.abc import Callable
from pathlib import Path
from typing import TYPE_CHECKING, Any, Protocol

from gaintune_api.attempt import Attempt
from gaintune_api.job_commit import commit as _commit
from gaintune_api.job_commit import error_text as _error_text
from gaintune_api.job_commit import outcome as _outcome
from gaintune_api.job_store import JobRow, claim_tag
from gaintune_api.jobfiles import JobFiles
from gaintune_api.settings import Settings, warn_unknown_settings
from gaintune_api.storage_faults import FaultInjector, StorageFault, classify
from gaintune_api.stores import Store, missing_extra, open_store

if TYPE_CHECKING:
    from gaintune.spec import TuningSpec

__all__ = ["worker_main", "run_job", "process_next", "PROCESS_NAME"]

log = logging.getLogger("gaintune.worker")

#: The name workers give themselves (``/proc/<pid>/comm``, ``ps``): how operators and the chaos benchmark find them.
PROCESS_NAME = "gaintune-worker"


class SharedNumber(Protocol):
    """A number shared with the supervisor (``multiprocessing.Value('d')`` or ``Value('q')``)."""

    value: float


def _prctl(option: int, arg: int | bytes) -> None:
    if sys.platform.startswith("linux"):
        try:
            import ctypes

            ctypes.CDLL("libc.so.6", use_errno=True).prctl(option, arg, 0, 0, 0)
        except Exception:  # pragma: no cover - best effort
            pass


def _die_with_parent(parent: int) -> None:
    """Linux: get SIGKILL when the parent (server) dies, so no orphan keeps running a recovered job."""
    _prctl(1, signal.SIGKILL)  # PR_SET_PDEATHSIG
    if os.getppid() != parent:
        os._exit(0)


def _start_pulse(pulse: SharedNumber, interval: float) -> None:
    """Beat ``pulse.value = time.time()`` every ``interval`` s from a daemon thread (stops when the process freezes)."""

    def beat() -> None:
        while True:
            pulse.value = time.time()
            time.sleep(interval)

    threading.Thread(target=beat, name="pulse", daemon=True).start()


def _default_tune() -> Callable[..., Any]:
    """:func:`gaintune.search.tune`, imported on first use: it is heavy (torch), and only workers need it."""
    from gaintune.search import tune

    return tune


def _search(tune: Callable[..., Any], spec: TuningSpec, staging: Path, attempt: Attempt) -> tuple[Any, str | None]:
    """Run the search with ``attempt``'s monitor beside it: (its result or None, the error text or None)."""
    from gaintune.errors import GaintuneError

    job_id = attempt.job.id
    threading.Thread(target=attempt.watch, name=f"monitor-{job_id[:8]}", daemon=True).start()
    result = None
    error: str | None = None
    try:
        extra = {"command": f"POST /v1/tune (job {job_id})"} if _accepts(tune, "command") else {}
        result = tune(spec, progress=attempt.on_progress, out_dir=staging, verify=True, cancel=attempt.cancel,
                      **extra)
    except BaseException as exc:  # noqa: BLE001 - a job failure must never kill the worker loop
        if isinstance(exc, (KeyboardInterrupt, SystemExit)):
            raise
        error = _error_text(exc)
        if not isinstance(exc, GaintuneError) and classify(exc, "data") is None:
            log.error("job %s crashed:\n%s", job_id, traceback.format_exc())
    finally:
        attempt.done.set()
    return result, error


def _final_payload(result: Any, files: JobFiles, job: JobRow, staging: Path, spec: TuningSpec,
                   progress: dict[str, Any] | None) -> tuple[dict[str, Any] | None, dict[str, Any] | None]:
    """The result to store (its agent at its promoted path) and the final progress, from the search's result."""
    if result is None:
        return None, progress
    payload = result.model_dump(mode="python")
    payload["agent_path"] = files.final_path(job.id, payload.get("agent_path"), staging)
    final = {**(progress or {}), "sims": result.sims, "elapsed": result.wall_time, "eta": 0.0,
             "budget": spec.search.budget, "best_cost": result.cost, "phase": "done"}
    return payload, final


def run_job(store: Store, job: JobRow, settings: Settings, tune: Callable[..., Any] | None = None,
            *, hard_exit: bool = True, files: JobFiles | None = None) -> str:
    """Run one claimed job to a terminal state.

    Parameters
    ----------
    store, job
        The job store and the job as claimed (its ``claim`` token fences every write).
    settings
        Service settings.
    tune
        The search (default :func:`gaintune.search.tune`).
    hard_exit
        Exit the process when the search ignores a cancel for ``cancel_grace`` s (worker processes).
    files
        The artefact layer (default: ``settings.jobs_dir`` with the store's fault injector).

    Returns
    -------
    str
        The status written, or ``"lost"`` when the attempt no longer owned the job (nothing written).
    """
    from gaintune.spec import TuningSpec

    files = files or JobFiles(settings.jobs_dir, store.faults)
    if job.kind == "tuner":  # POST /v1/tuners: a tuner's training, not a search
        from gaintune_api.tuner_jobs import run_tuner_job

        return run_tuner_job(store, job, settings, files, hard_exit=hard_exit)
    search = tune if tune is not None else _default_tune()
    claim = job.claim
    assert claim is not None
    spec = TuningSpec.model_validate_json(job.spec)
    try:
        staging = files.stage(job.id, job.attempts, claim)
    except StorageFault as fault:
        # Fail once, naming the cause; re-running cannot help until an operator fixes the disk.
        log.error("job %s cannot write its folder: %s", job.id, fault)
        return _commit(store, files, job, None, "failed", result=None,
                       error=f"storage fault: {fault.detail} The job was not started.", progress=None,
                       settings=settings)
    attempt = Attempt(store, job, claim, settings, hard_exit)
    result, error = _search(search, spec, staging, attempt)
    if attempt.reason == "lost":
        files.discard(staging)
        log.warning("job %s: attempt %d lost its claim (lease expired; the job was recovered): "
                    "stopped, and discarded its files", job.id, job.attempts)
        return "lost"
    payload, final_progress = _final_payload(result, files, job, staging, spec, attempt.progress)
    status, error = _outcome(attempt.reason, error, settings)
    return _commit(store, files, job, staging, status, result=payload, error=error, progress=final_progress,
                   settings=settings)


def _accepts(fn: Callable[..., Any], name: str) -> bool:
    import inspect

    try:
        params = inspect.signature(fn).parameters
    except (TypeError, ValueError):
        return False
    return name in params or any(p.kind is p.VAR_KEYWORD for p in params.values())


def process_next(store: Store, settings: Settings, tune: Callable[..., Any] | None = None) -> str | None:
    """Claim and run one queued job in this process (tests, single-process use). None if the queue is empty."""
    job = store.claim(os.getpid())
    if job is None:
        return None
    return run_job(store, job, settings, tune, hard_exit=False)


def _start_worker(settings_data: dict[str, Any], index: int, parent: int | None,
                  pulse: SharedNumber | None) -> Settings:
    """Set up the worker process (parent death signal, name, pulse, logging); returns its settings."""
    if parent is not None:
        _die_with_parent(parent)
    _prctl(15, PROCESS_NAME.encode())  # PR_SET_NAME
    settings = Settings.model_validate(settings_data)
    if pulse is not None:
        _start_pulse(pulse, settings.heartbeat_interval)
    logging.basicConfig(level=settings.log_level.upper(), format=f"%(asctime)s worker{index} %(levelname)s %(message)s")
    if parent is None:  # the server warns for its own workers
        warn_unknown_settings()
    return settings


def _open_store(settings: Settings, index: int) -> Store:
    """The job store (SQLite, or PostgreSQL when ``db_url`` is set), its schema created if it can be written."""
    store = open_store(settings, FaultInjector(settings.test_storage_fault_file))
    try:
        store.init()
    except StorageFault as fault:  # the schema is there already; claims retry until the disk is fixed
        log.warning("worker %d: database not initialised (%s)", index, fault)
    return store


def _import_search() -> Callable[..., Any]:
    """The search, or exit 3 (after a pause, so the supervisor does not restart it in a tight loop)."""
    try:
        return _default_tune()
    except Exception as exc:  # noqa: BLE001 - any import failure: the worker cannot run jobs at all
        log.error("gaintune.search.tune is not importable (%s); worker exits", exc)
        time.sleep(5)
        raise SystemExit(3) from exc


def _claim(store: Store, index: int, outage: StorageFault | None) -> tuple[JobRow | None, StorageFault | None]:
    """Claim the next queued job: (the job or None, the storage fault that prevented the claim or None)."""
    try:
        job = store.claim(os.getpid())
    except StorageFault as fault:
        if outage is None:
            log.warning("worker %d cannot claim jobs: %s; retrying", index, fault)
        return None, fault
    if outage is not None:
        log.info("worker %d: the database accepts writes again", index)
    return job, None


def _run_claimed(store: Store, job: JobRow, settings: Settings, tune: Callable[..., Any], index: int,
                 holding: SharedNumber | None) -> None:
    """Run a claimed job, publishing its claim in ``holding`` meanwhile; a failure around it fails the job."""
    log.info("worker %d runs job %s (attempt %d)", index, job.id, job.attempts)
    if holding is not None:
        holding.value = claim_tag(job.claim)
    try:
        run_job(store, job, settings, tune)
    except Exception:  # noqa: BLE001 - a bug around one job must not kill the worker
        log.exception("worker %d: job %s failed outside the search", index, job.id)
        try:
            store.finish(job.id, job.claim, "failed", error="internal error in the job worker (logged)")
        except Exception:  # noqa: BLE001 - logged; the supervisor's lease check finishes the job instead
            log.exception("worker %d: job %s: final state not written", index, job.id)
    finally:
        if holding is not None:
            holding.value = 0


def worker_main(settings_data: dict[str, Any], index: int = 0, parent: int | None = None,
                pulse: SharedNumber | None = None, holding: SharedNumber | None = None) -> None:
    """Worker process entry point: claim jobs until the parent dies or SIGTERM.

    Parameters
    ----------
    settings_data
        ``Settings.model_dump(mode="json")`` of the server.
    index
        Worker number (for logs).
    parent
        The server's pid: the worker dies with it (None: standalone).
    pulse
        A shared ``multiprocessing.Value('d')`` the worker beats every ``heartbeat_interval`` (None: standalone).
    holding
        A shared ``multiprocessing.Value('q')``: the :func:`gaintune_api.job_store.claim_tag` of the attempt
        this worker runs, 0 when idle (None: standalone).
    """
    settings = _start_worker(settings_data, index, parent, pulse)
    store = _open_store(settings, index)
    tune = _import_search()
    log.info("worker %d (pid %d) ready", index, os.getpid())
    outage: StorageFault | None = None
    while parent is None or os.getppid() == parent:
        job, outage = _claim(store, index, outage)
        if outage is not None:  # a read-only or full database: wait, never crash-loop
            time.sleep(min(4 * settings.poll_interval, 2.0))
        elif job is None:
            time.sleep(settings.poll_interval)
        else:
            _run_claimed(store, job, settings, tune, index, holding)


def main(argv: list[str] | None = None) -> None:
    """Standalone worker: ``python -m gaintune_api.worker`` (settings from GAINTUNE_* env vars)."""
    import argparse

    ap = argparse.ArgumentParser(description="gaintune job worker (polls the job store: SQLite or GAINTUNE_DB_URL)")
    ap.add_argument("--index", type=int, default=0)
    args = ap.parse_args(argv)
    settings = Settings()
    missing = missing_extra(settings)
    if missing is not None:
        print(f"error: {missing}", file=sys.stderr)
        raise SystemExit(2)
    worker_main(settings.model_dump(mode="json"), args.index)


if __name__ == "__main__":
    main()
