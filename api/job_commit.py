"""The end of a job attempt: its outcome, and its final state written with its files promoted, fenced by its claim.

Shared by the two kinds of job a worker runs: a tuning search (:mod:`gaintune_api.worker`) and a tuner's
training (:mod:`gaintune_api.tuner_jobs`). :func:`commit` keeps finished work through a database outage
(retrying while the attempt owns the job) and fails the job, naming the storage fault, when its files
cannot be renamed into place.
"""

from __future__ import annotations

import logging
import time
from collections.abc import Callable
from pathlib import Path

from gaintune_api.attempt import final_status
from gaintune_api.job_store import JobRow
from gaintune_api.jobfiles import JobFiles
from gaintune_api.settings import Settings
from gaintune_api.storage_faults import StorageFault, classify
from gaintune_api.stores import Store

__all__ = ["error_text", "outcome", "commit"]

log = logging.getLogger("gaintune.worker")


def error_text(exc: BaseException) -> str:
    """Why an attempt failed, for the job's ``error``: the field and message, the storage fault, or the bug."""
    from gaintune.errors import GaintuneError

    if isinstance(exc, GaintuneError):
        return f"{exc.field}: {exc.message}"
    fault = classify(exc, "data")
    if fault is not None:
        return f"storage fault: {fault.detail}"
    return f"internal error during tuning ({type(exc).__name__}: {str(exc)[:500]})"


def _join(a: str | None, b: str) -> str:
    return b if not a else f"{a}; {b}"


def _once(promote: Callable[[], dict | None]) -> Callable[[], dict | None]:
    """``promote`` run at most once; later calls return its manifest.

    The store renames the files inside the finishing transaction; when that transaction's
    COMMIT fails (a full disk), the files are in place but the row is not written. The retry
    must find them there and commit the same manifest, not rename again (the staged files
    are gone: ENOENT).
    """
    done: list[dict | None] = []

    def run() -> dict | None:
        if not done:
            done.append(promote())
        return done[0]

    return run


def outcome(reason: str | None, error: str | None, settings: Settings) -> tuple[str, str | None]:
    """The final status and error of an attempt the monitor stopped for ``reason`` (None: not stopped)."""
    if reason is not None:
        status, err = final_status(reason, settings)
        return status, err if error is None else f"{err}; {error}"
    return ("failed", error) if error is not None else ("succeeded", None)


def commit(store: Store, files: JobFiles, job: JobRow, staging: Path | None, status: str, *,
            result: dict | None, error: str | None, progress: dict | None, settings: Settings) -> str:
    """Write an attempt's final state and promote its files, fenced by its claim; returns the status or "lost".

    A database that cannot be written does not lose the work: the result is kept and the write
    retried (backing off to 2 s, at most a quarter of ``heartbeat_timeout``) for as long as the
    attempt still owns the job. Files that cannot be
    renamed into place fail the job, naming the storage fault.
    """
    claim = job.claim
    assert claim is not None
    promote = None
    if staging is not None:
        try:
            promote = _once(files.promoter(job.id, staging, job.attempts, claim))
        except StorageFault as fault:
            status, error = ("failed" if status == "succeeded" else status), _join(
                error, f"storage fault: the job's files could not be read back: {fault.detail}")
            if result is not None:
                result = {**result, "agent_path": None}
    delay, warned = settings.poll_interval, False
    while True:
        try:
            written = store.finish(job.id, claim, status, result=result, error=error, progress=progress,
                                   promote=promote)
            break
        except StorageFault as fault:
            if fault.where == "data":  # the files could not be renamed into place: finish without them
                log.error("job %s: %s", job.id, fault)
                promote = None
                status = "failed" if status == "succeeded" else status
                error = _join(error, f"storage fault while saving the job's files: {fault.detail}")
                if result is not None:
                    result = {**result, "agent_path": None}
                continue
            if not warned:
                log.warning("job %s: %s result kept, but %s; retrying while this attempt owns the job",
                            job.id, status, fault)
                warned = True
            try:
                if not store.owns(job.id, claim):
                    written = None
                    break
            except StorageFault:
                pass
            time.sleep(delay)
            # Retry well within a lease: once the database is back, the supervisor allows heartbeat_timeout.
            delay = min(2 * delay, 2.0, settings.heartbeat_timeout / 4)
    if staging is not None:
        files.discard(staging)
    if written is None:
        log.warning("job %s: attempt %d no longer owns the job (lease expired; recovered): "
                    "its result and files were discarded", job.id, job.attempts)
        return "lost"
    if warned:
        log.info("job %s: result written after the storage fault cleared", job.id)
    log.info("job %s %s", job.id, written)
    return written
