"""Where the items of a sweep run: local worker processes (the default) or Ray tasks.

Both take the jobs still to run and call ``on_record`` in the driver with each item's record
as it arrives; the driver alone writes the store.

* :func:`run_local`: a :class:`~concurrent.futures.ProcessPoolExecutor` of spawned worker
  processes (spawned, not forked: the driver may hold torch and numba threads). A pool broken
  by a worker that died is replaced and its unfinished items submitted again, each at most
  ``retries`` more times; then the item is recorded ``crashed``. On Linux the workers die with
  the driver.
* :func:`run_ray`: one Ray task per item with ``num_cpus`` = CPUs per task; Ray retries a task
  whose worker died (``max_retries``). ``address`` names a running cluster (``auto``, or
  ``HOST:PORT``); without one (and without ``RAY_ADDRESS``) a local cluster is started for the
  sweep and stopped after it. Ray is imported here only (the optional extra ``gaintune[ray]``).
"""

from __future__ import annotations

import multiprocessing
import os
import signal
import sys
from collections import Counter
from collections.abc import Callable
from concurrent.futures import FIRST_COMPLETED, Future, ProcessPoolExecutor, wait
from concurrent.futures.process import BrokenProcessPool
from typing import Any

from gaintune.errors import GaintuneError
from gaintune.provenance import cpus_here
from gaintune.sweep.worker import Hook, error_record, run_item

__all__ = ["OnRecord", "run_local", "run_ray", "cpus_here", "import_ray"]

OnRecord = Callable[[dict[str, Any]], None]




def _die_with_driver(driver: int) -> None:
    """Worker initializer (Linux): SIGKILL this worker when the driver dies.

    Without it, the workers of a killed driver run on through the items already queued to them
    (up to workers + 1), results nobody records, while the restarted sweep runs them again."""
    try:
        import ctypes

        ctypes.CDLL(None, use_errno=True).prctl(1, signal.SIGKILL)  # 1: PR_SET_PDEATHSIG
    except (OSError, AttributeError):  # pragma: no cover - not Linux: such workers finish their queue
        return
    if os.getppid() != driver:  # the driver died before the line above
        os._exit(1)


def _drain(pool: ProcessPoolExecutor, jobs: list[dict[str, Any]], on_record: OnRecord,
           hook: Hook | None) -> list[dict[str, Any]]:
    """Run ``jobs`` on ``pool``; return the jobs lost to a broken pool (a worker died)."""
    futures: dict[Future, dict[str, Any]] = {pool.submit(run_item, j, hook): j for j in jobs}
    lost = []
    pending = set(futures)
    while pending:
        done, pending = wait(pending, return_when=FIRST_COMPLETED)
        for f in done:
            try:
                rec = f.result()
            except BrokenProcessPool:
                lost.append(futures[f])
                continue
            on_record(rec)
    return lost


def run_local(jobs: list[dict[str, Any]], on_record: OnRecord, *, workers: int, hook: Hook | None = None,
              retries: int = 3) -> None:
    """Run ``jobs`` in ``workers`` spawned worker processes, calling ``on_record`` with each record."""
    tries: Counter[str] = Counter()
    todo = list(jobs)
    ctx = multiprocessing.get_context("spawn")
    while todo:
        pool = ProcessPoolExecutor(max_workers=max(1, min(workers, len(todo))), mp_context=ctx,
                                   initializer=_die_with_driver, initargs=(os.getpid(),))
        try:
            lost = _drain(pool, todo, on_record, hook)
        finally:
            pool.shutdown(wait=True, cancel_futures=True)
        todo = []
        for job in lost:
            tries[job["key"]] += 1
            if tries[job["key"]] > retries:
                on_record(error_record(job, "crashed", f"the worker process died {tries[job['key']]} times"))
            else:
                todo.append(job)


# ---------------------------------------------------------------------------------------- ray


def import_ray() -> Any:
    """The ``ray`` module, or a GaintuneError naming the extra to install."""
    if "ray" not in sys.modules:
        _token_auth_if_token()  # Ray reads RAY_AUTH_MODE once, when it is imported
    try:
        import ray
    except ImportError:
        raise GaintuneError("backend", "the ray backend needs Ray: pip install 'gaintune[ray]' (or use --backend "
                                       "local)") from None
    return ray


def _token_auth_if_token() -> None:
    """Send this machine's Ray token when it has one and RAY_AUTH_MODE is unset, as ``ray start`` does.

    A cluster started with token authentication (Ray's default where a token exists) refuses a
    client without it; a cluster without authentication ignores the token. A local cluster
    (``ray.init()`` without an address) uses token authentication by default anyway."""
    from pathlib import Path

    has_token = os.environ.get("RAY_AUTH_TOKEN") or os.environ.get("RAY_AUTH_TOKEN_PATH") or \
        (Path.home() / ".ray" / "auth_token").is_file()
    if "RAY_AUTH_MODE" not in os.environ and has_token:
        os.environ["RAY_AUTH_MODE"] = "token"


def connect(ray: Any, address: str | None, workers: int | None) -> bool:
    """Connect to the cluster at ``address`` (or ``$RAY_ADDRESS``), else start a local one.

    Returns
    -------
    bool
        True when this call connected (the caller then disconnects); False when Ray was already up.
    """
    if ray.is_initialized():
        return False
    os.environ.setdefault("RAY_USAGE_STATS_ENABLED", "0")
    quiet: dict[str, Any] = dict(include_dashboard=False, logging_level="ERROR", log_to_driver=False)
    try:
        if address or os.environ.get("RAY_ADDRESS"):
            ray.init(address=address, **quiet)
        else:
            # "local": a new cluster for this sweep, never one another program left running here
            ray.init(address="local", num_cpus=workers or cpus_here(), **quiet)
    except (ConnectionError, ValueError, RuntimeError) as exc:
        where = address or os.environ.get("RAY_ADDRESS")
        raise GaintuneError("address", f"cannot reach a Ray cluster at {where}: {exc}; start one with 'ray start "
                                       "--head', or drop --address for a local one") from None
    return True


def run_ray(jobs: list[dict[str, Any]], on_record: OnRecord, *, address: str | None = None,
            workers: int | None = None, cpus_per_task: float = 1, hook: Hook | None = None,
            retries: int = 3) -> None:
    """Run ``jobs`` as Ray tasks (``num_cpus=cpus_per_task``), calling ``on_record`` with each record."""
    ray = import_ray()
    mine = connect(ray, address, workers)
    try:
        task = ray.remote(run_item).options(num_cpus=cpus_per_task, max_retries=retries, retry_exceptions=False)
        refs = {task.remote(j, hook): j for j in jobs}
        pending = list(refs)
        while pending:
            ready, pending = ray.wait(pending, num_returns=min(len(pending), 32), timeout=0.5)
            for ref in ready:
                try:
                    rec = ray.get(ref)
                except ray.exceptions.RayError as exc:  # the worker was lost more than max_retries times
                    rec = error_record(refs[ref], "crashed", f"the Ray worker was lost: {type(exc).__name__}")
                on_record(rec)
    finally:
        if mine:
            ray.shutdown()
