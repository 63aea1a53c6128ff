"""Process pool for the synchronous CPU-bound endpoints (``/v1/verify``, ``/v1/simulate``).

Verification is Python + NumPy on small arrays and holds the GIL, so threads add
contention rather than throughput. ``compute_processes`` warm worker processes
(spawned once, at start-up, from the server's main thread) run the computations
instead; each keeps the per-spec caches of :mod:`gaintune.verify.context` (plant,
layout, linearisation, simulator) between requests. ``compute_processes = 0``
computes in the server process, in at most ``compute_threads`` threads.

Workers die with the server (``PR_SET_PDEATHSIG`` plus a parent watch), and the pool
is shut down (workers joined) when the app stops. A broken pool (a worker killed)
is replaced on the next request, which is computed in a thread meanwhile.
"""

from __future__ import annotations

import asyncio
import logging
import multiprocessing as mp
import os
import threading
from concurrent.futures import Future, ProcessPoolExecutor
from concurrent.futures.process import BrokenProcessPool
from typing import Any, Callable

__all__ = ["ComputePool", "compute_verify", "compute_simulate", "warm_up_compute"]

log = logging.getLogger("gaintune.api")


# ------------------------------------------------------------------ worker side


def _watch_parent(parent: int) -> None:
    import time

    while True:
        if os.getppid() != parent:
            os._exit(0)
        time.sleep(1.0)


def _init_worker(parent: int) -> None:
    """Die with the server; warm the imports and the verification path."""
    from api.worker import _die_with_parent

    _die_with_parent(parent)
    threading.Thread(target=_watch_parent, args=(parent,), name="parent-watch", daemon=True).start()


def warm_up_compute() -> int:
    """Run one tiny verification (imports, compiled simulator). Returns the worker's pid."""
    from gaintune.spec import load_spec
    from gaintune.verify import verify

    spec = load_spec({"plant": {"tf": {"num": [1], "den": "(s+1)^2"}}, "loops": [{"type": "pi"}],
                      "scenario": {"dt": 0.05, "horizon": 5.0}})
    verify(spec, {"loop0": {"Kp": 1.0, "Ki": 0.5}})
    return os.getpid()


def compute_verify(spec, gains, robust, nonlinear, plant=None, layout=None) -> tuple[str, Any]:
    """``("ok", report JSON bytes)`` | ``("gains", problem details)`` | ``("error", message)``.

    Never raises for bad input: the caller maps the tags to HTTP problems.
    """
    from gaintune.errors import GaintuneError, problem_details
    from gaintune.verify import verify

    try:
        report = verify(spec, gains, robust=robust, nonlinear=nonlinear, plant=plant, layout=layout)
    except GaintuneError as exc:
        return "gains", problem_details(exc)
    except Exception as exc:  # noqa: BLE001 - user input must never produce a 500
        log.warning("verify failed unexpectedly", exc_info=True)
        return "error", f"{type(exc).__name__}: {str(exc)[:300]}"
    return "ok", report.model_dump_json().encode()


def compute_simulate(spec, gains, chosen: list[int], max_points: int, plant=None, layout=None) -> tuple[str, Any]:
    """``("ok", SimulateResponse)`` | ``("gains", problem details)`` | ``("error", message)``."""
    from api.routes.simulate import simulate_response
    from gaintune.errors import GaintuneError, problem_details

    try:
        return "ok", simulate_response(spec, gains, chosen, max_points, plant, layout)
    except GaintuneError as exc:
        return "gains", problem_details(exc)
    except Exception as exc:  # noqa: BLE001 - user input must never produce a 500
        log.warning("simulate failed unexpectedly", exc_info=True)
        return "error", f"{type(exc).__name__}: {str(exc)[:300]}"


# ------------------------------------------------------------------ server side


class ComputePool:
    """``n`` spawned worker processes; :meth:`start` and :meth:`shutdown` from the main thread."""

    def __init__(self, n: int) -> None:
        self.n = n
        self._ex: ProcessPoolExecutor | None = None
        self._lock = threading.Lock()
        self.warm: list[Future] = []

    def start(self) -> None:
        """Create the pool and spawn every worker now (PDEATHSIG follows the spawning thread)."""
        self._ex = ProcessPoolExecutor(self.n, mp_context=mp.get_context("spawn"), initializer=_init_worker,
                                       initargs=(os.getpid(),))
        self.warm = [self._ex.submit(warm_up_compute) for _ in range(self.n)]

    @property
    def pids(self) -> list[int]:
        ex = self._ex
        return sorted(p.pid for p in (getattr(ex, "_processes", None) or {}).values()) if ex else []

    async def run(self, fn: Callable, *args) -> Any:
        """``fn(*args)`` in a worker; None when the pool is broken (the caller computes in a thread)."""
        ex = self._ex
        if ex is None:
            return None
        try:
            return await asyncio.wrap_future(ex.submit(fn, *args))
        except BrokenProcessPool:
            log.warning("compute pool broken (a worker died); starting a new one")
            with self._lock:
                if self._ex is ex:
                    ex.shutdown(wait=False, cancel_futures=True)
                    self.start()
            return None

    def shutdown(self) -> None:
        ex, self._ex = self._ex, None
        if ex is not None:
            ex.shutdown(wait=True, cancel_futures=True)
