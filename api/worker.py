"""Job worker: a separate process that claims queued jobs from SQLite and runs the RL search.

Run inside the server (``Settings.workers`` processes, started and restarted by
:mod:`api.supervisor`) or standalone next to it: ``python -m api.worker``.

While a job runs, a monitor thread writes progress and a heartbeat every
``heartbeat_interval`` seconds and polls the job's ``cancel_requested_at``
flag and the wall-time limit. Either sets the ``cancel`` event that
:func:`gaintune.search.tune` checks (and the progress callback returns
False). If the search has not returned ``cancel_grace`` seconds later, the
worker writes the final state itself and exits hard; its supervisor starts a
new one.
"""

from __future__ import annotations

import logging
import os
import signal
import sys
import threading
import time
import traceback
from pathlib import Path
from typing import Any, Callable

from api.settings import Settings
from api.store import JobRow, JobStore

__all__ = ["worker_main", "run_job", "process_next"]

log = logging.getLogger("gaintune.worker")


def _die_with_parent(parent: int) -> None:
    """Linux: get SIGKILL when the parent (server) dies, so no orphan keeps running a recovered job."""
    if sys.platform.startswith("linux"):
        try:
            import ctypes

            ctypes.CDLL("libc.so.6", use_errno=True).prctl(1, signal.SIGKILL)  # PR_SET_PDEATHSIG
        except Exception:  # pragma: no cover - best effort
            pass
    if os.getppid() != parent:
        os._exit(0)


def _error_text(exc: BaseException) -> str:
    from gaintune.errors import GaintuneError

    if isinstance(exc, GaintuneError):
        return f"{exc.field}: {exc.message}"
    return f"internal error during tuning ({type(exc).__name__}: {str(exc)[:500]})"


def run_job(store: JobStore, job: JobRow, settings: Settings, tune: Callable[..., Any] | None = None,
            *, hard_exit: bool = True) -> str:
    """Run one claimed job to a terminal state. Returns the status written."""
    from gaintune.spec import TuningSpec

    if tune is None:
        from gaintune.search import tune as tune  # noqa: PLW0127 - heavy import, only in workers

    assert job.claim is not None
    claim = job.claim
    spec = TuningSpec.model_validate_json(job.spec)
    out_dir = settings.jobs_dir / job.id
    out_dir.mkdir(parents=True, exist_ok=True)
    cancel = threading.Event()
    done = threading.Event()
    state: dict[str, Any] = {"progress": None, "reason": None, "since": None}
    t0 = time.monotonic()

    def stop(reason: str) -> None:
        if not cancel.is_set():
            state["reason"], state["since"] = reason, time.monotonic()
            cancel.set()

    def monitor() -> None:
        while not done.wait(settings.heartbeat_interval):
            try:
                owned, cancel_req = store.heartbeat(job.id, claim, state["progress"])
            except Exception:  # DB busy for 30 s: try again next tick
                log.exception("heartbeat failed for job %s", job.id)
                continue
            if not owned:
                stop("lost")
            elif cancel_req:
                stop("cancelled")
            elif time.monotonic() - t0 > settings.job_wall_time:
                stop("wall_time")
            if cancel.is_set() and time.monotonic() - state["since"] > settings.cancel_grace and not done.is_set():
                status, err = _final_status(state["reason"], settings)
                if state["reason"] != "lost":
                    store.finish(job.id, claim, status, error=f"{err}; the search did not stop within "
                                 f"{settings.cancel_grace:g} s and its worker was restarted")
                log.warning("job %s did not stop within the grace period: exiting worker", job.id)
                if hard_exit:
                    os._exit(70)
                return

    def progress(p: Any) -> bool:
        state["progress"] = p.model_dump() if hasattr(p, "model_dump") else dict(p)
        if settings.test_hold_file is not None:  # tests only; None (off) unless GAINTUNE_TEST_HOLD_FILE is set
            _hold_while_exists(settings.test_hold_file, cancel)
        return not cancel.is_set()

    th = threading.Thread(target=monitor, name=f"monitor-{job.id[:8]}", daemon=True)
    th.start()
    result = None
    error: str | None = None
    try:
        extra = {"command": f"POST /v1/tune (job {job.id})"} if _accepts(tune, "command") else {}
        result = tune(spec, progress=progress, out_dir=out_dir, verify=True, cancel=cancel, **extra)
    except BaseException as exc:  # noqa: BLE001 - a job failure must never kill the worker loop
        if isinstance(exc, (KeyboardInterrupt, SystemExit)):
            raise
        error = _error_text(exc)
        from gaintune.errors import GaintuneError

        if not isinstance(exc, GaintuneError):
            log.error("job %s crashed:\n%s", job.id, traceback.format_exc())
    finally:
        done.set()
    reason = state["reason"]
    if reason == "lost":
        return "lost"
    payload = None
    final_progress = state["progress"]
    if result is not None:
        payload = result.model_dump(mode="python")
        final_progress = {**(final_progress or {}), "sims": result.sims, "elapsed": result.wall_time, "eta": 0.0,
                          "budget": spec.search.budget, "best_cost": result.cost, "phase": "done"}
    if reason is not None:
        status, err = _final_status(reason, settings)
        error = err if error is None else f"{err}; {error}"
    elif error is not None:
        status = "failed"
    else:
        status = "succeeded"
    store.finish(job.id, claim, status, result=payload, error=error, progress=final_progress)
    log.info("job %s %s", job.id, status)
    return status


def _accepts(fn: Callable[..., Any], name: str) -> bool:
    import inspect

    try:
        params = inspect.signature(fn).parameters
    except (TypeError, ValueError):
        return False
    return name in params or any(p.kind is p.VAR_KEYWORD for p in params.values())


def _hold_while_exists(path: Path, cancel: threading.Event, poll: float = 0.05) -> None:
    """Test hook (``Settings.test_hold_file``): pause the search while *path* exists.

    Integration tests kill a worker or its server "during a job"; a small job can finish before the test
    even sees it running, so they hold it here, after its first progress report, instead of sleeping and
    hoping. The monitor thread keeps heartbeating (the job stays ``running`` with progress); a cancel, a
    wall-time stop or a lost claim ends the hold at once.
    """
    while not cancel.is_set() and path.exists():
        cancel.wait(poll)


def _final_status(reason: str | None, settings: Settings) -> tuple[str, str]:
    if reason == "cancelled":
        return "cancelled", "cancelled on request"
    if reason == "wall_time":
        return "failed", f"exceeded the per-job wall-time limit of {settings.job_wall_time:g} s"
    return "failed", "worker lost the job"


def process_next(store: JobStore, settings: Settings, tune: Callable[..., Any] | None = None) -> str | None:
    """Claim and run one queued job in this process (tests, single-process use). None if the queue is empty."""
    job = store.claim(os.getpid())
    if job is None:
        return None
    return run_job(store, job, settings, tune, hard_exit=False)


def worker_main(settings_data: dict[str, Any], index: int = 0, parent: int | None = None) -> None:
    """Worker process entry point: claim jobs until the parent dies or SIGTERM."""
    if parent is not None:
        _die_with_parent(parent)
    settings = Settings.model_validate(settings_data)
    logging.basicConfig(level=settings.log_level.upper(), format=f"%(asctime)s worker{index} %(levelname)s %(message)s")
    store = JobStore(settings.db_path)
    store.init()
    try:
        from gaintune.search import tune
    except Exception as exc:  # noqa: BLE001
        log.error("gaintune.search.tune is not importable (%s); worker exits", exc)
        time.sleep(5)
        raise SystemExit(3)
    log.info("worker %d (pid %d) ready", index, os.getpid())
    while True:
        if parent is not None and os.getppid() != parent:
            return
        job = store.claim(os.getpid())
        if job is None:
            time.sleep(settings.poll_interval)
            continue
        log.info("worker %d runs job %s (attempt %d)", index, job.id, job.attempts)
        run_job(store, job, settings, tune)


def main(argv: list[str] | None = None) -> None:
    """Standalone worker: ``python -m api.worker`` (settings from GAINTUNE_* env vars)."""
    import argparse

    ap = argparse.ArgumentParser(description="gaintune job worker (polls the SQLite job store)")
    ap.add_argument("--index", type=int, default=0)
    args = ap.parse_args(argv)
    worker_main(Settings().model_dump(mode="json"), args.index)


if __name__ == "__main__":
    main()
