"""Process pool for the synchronous CPU-bound endpoints (``/v1/verify``, ``/v1/simulate``).

Verification is Python + NumPy on small arrays and holds the GIL, so threads add
contention rather than throughput. ``compute_processes`` warm worker processes
(spawned once, at start-up, from the server's main thread) run the computations
instead; each keeps the per-spec caches of :mod:`gaintune.verify.context` (plant,
layout, linearisation, simulator) between requests. ``compute_processes = 0``
computes in the server process, in at most ``compute_threads`` threads.

Each worker has its own pipe, watched by the server's event loop (``loop.add_reader``):
no executor threads and no shared result queue on the request path. Workers die with the
server (``PR_SET_PDEATHSIG`` plus a parent watch), and the pool is shut down (workers
joined) when the app stops. A worker that dies is replaced at once; the request it was
computing is computed in a thread instead.
"""

from __future__ import annotations

import asyncio
import logging
import multiprocessing as mp
import os
import pickle
import threading
from collections import deque
from concurrent.futures import Future
from typing import Any, Callable

from gaintune.cache import LRU

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
    from gaintune_api.worker import _die_with_parent

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


def compute_verify(spec, gains, robust, nonlinear, plant=None, layout=None, spec_hash=None) -> tuple[str, Any]:
    """``("ok", report JSON bytes)`` | ``("gains", problem details)`` | ``("error", message)``.

    Never raises for bad input: the caller maps the tags to HTTP problems. ``spec_hash``:
    ``spec.content_hash()``, already computed by the server.
    """
    from gaintune.errors import GaintuneError, problem_details
    from gaintune.verify import verify

    try:
        report = verify(spec, gains, robust=robust, nonlinear=nonlinear, plant=plant, layout=layout, spec_hash=spec_hash)
    except GaintuneError as exc:
        return "gains", problem_details(exc)
    except Exception as exc:  # noqa: BLE001 - user input must never produce a 500
        log.warning("verify failed unexpectedly", exc_info=True)
        return "error", f"{type(exc).__name__}: {str(exc)[:300]}"
    return "ok", report.model_dump_json().encode()


def compute_policy(tuners: LRU[str, Any], key: str, agent: Any, spec: dict[str, Any], grid: dict[str, Any],
                   max_points: int) -> tuple[str, Any]:
    """Answers of a job's trained policy over ``grid`` -> ("ok", JSON bytes) or ("invalid", [{loc, msg}]).

    The tuner (agent and training problem: torch, the search box) is loaded once per job and kept in
    ``tuners``, so a later request costs the answers only (milliseconds each)."""
    from gaintune.errors import GaintuneError, problem_details
    from gaintune.search.policy import PolicyTuner
    from gaintune.spec import load_spec
    from gaintune_api.schemas import PolicyAnswers

    try:
        tuner = tuners.get_or_build(key, lambda: PolicyTuner(agent, load_spec(spec)))
        answers = tuner.schedule({k: v if isinstance(v, list) else [v] for k, v in grid.items()}, max_points)
    except GaintuneError as exc:
        return "invalid", problem_details(exc)
    return "ok", PolicyAnswers(answers=answers).model_dump_json().encode()


def compute_simulate(spec, gains, chosen: list[int], max_points: int, plant=None, layout=None) -> tuple[str, Any]:
    """``("ok", SimulateResponse)`` | ``("gains", problem details)`` | ``("error", message)``."""
    from gaintune_api.simulation import simulate_response
    from gaintune.errors import GaintuneError, problem_details

    try:
        return "ok", simulate_response(spec, gains, chosen, max_points, plant, layout)
    except GaintuneError as exc:
        return "gains", problem_details(exc)
    except Exception as exc:  # noqa: BLE001 - user input must never produce a 500
        log.warning("simulate failed unexpectedly", exc_info=True)
        return "error", f"{type(exc).__name__}: {str(exc)[:300]}"


# ------------------------------------------------------------------ worker loop

#: Objects (specs) each worker keeps by key, so that a known one is sent as a reference only.
#: The server mirrors every worker's LRU exactly (same operations, in message order).
KNOWN_SIZE = 32


class _Store:
    """An argument to remember under ``key`` (in the worker's LRU) and pass on."""

    __slots__ = ("key", "obj")

    def __init__(self, key: str, obj: Any) -> None:
        self.key, self.obj = key, obj


class _Ref:
    """An argument the worker has remembered under ``key``."""

    __slots__ = ("key",)

    def __init__(self, key: str) -> None:
        self.key = key


def _resolve(args: tuple, known: LRU[str, Any]) -> tuple:
    """``args`` with each :class:`_Store` remembered in ``known`` and each :class:`_Ref` looked up there."""
    out = []
    for a in args:
        if isinstance(a, _Store):
            known.put(a.key, a.obj)
            a = a.obj
        elif isinstance(a, _Ref):
            a = known[a.key]  # KeyError: the mirror broke; answered as an error, computed in a thread
        out.append(a)
    return tuple(out)


def _worker_main(conn, parent: int) -> None:
    """A compute worker: warm up, report ``("warm", pid)``, then answer ``(fn, args)`` messages with
    ``("ok", fn(*args))`` (or ``("exc", exception)``) until an empty message or EOF."""
    _init_worker(parent)
    try:
        conn.send_bytes(pickle.dumps(("warm", warm_up_compute()), pickle.HIGHEST_PROTOCOL))
    except Exception as exc:  # noqa: BLE001 - warm-up is an optimisation only
        log.warning("compute worker warm-up failed", exc_info=True)
        conn.send_bytes(pickle.dumps(("warm", exc), pickle.HIGHEST_PROTOCOL))
    known: LRU[str, Any] = LRU(KNOWN_SIZE)
    while True:
        try:
            data = conn.recv_bytes()
        except (EOFError, OSError):
            break
        if not data:
            break
        try:
            fn, args = pickle.loads(data)
            msg = ("ok", fn(*_resolve(args, known)))
        except Exception as exc:  # noqa: BLE001 - reported to the server, which computes in a thread
            msg = ("exc", exc)
        try:
            conn.send_bytes(pickle.dumps(msg, pickle.HIGHEST_PROTOCOL))
        except (EOFError, OSError):
            break


# ------------------------------------------------------------------ server side


class _Worker:
    __slots__ = ("proc", "conn", "warm", "ready", "pending", "known", "pending_key")

    def __init__(self, proc, conn, warm: Future) -> None:
        self.proc, self.conn, self.warm = proc, conn, warm
        self.ready = False  # warmed up and not computing
        self.pending: asyncio.Future | None = None
        self.known: LRU[str, None] = LRU(KNOWN_SIZE)  # mirror of the worker's LRU
        self.pending_key: str | None = None


class ComputePool:
    """``n`` spawned worker processes, each on its own pipe watched by the event loop.

    No executor threads: a request is pickled onto an idle worker's pipe from the event
    loop, and the loop's reader callback resolves the request's future when the answer
    arrives. :meth:`start` and :meth:`shutdown` run on the event loop's thread, which is the
    main thread under uvicorn (PDEATHSIG follows the spawning thread).
    """

    def __init__(self, n: int) -> None:
        self.n = n
        self._workers: list[_Worker] = []
        self._waiters: deque[asyncio.Future] = deque()
        self._loop: asyncio.AbstractEventLoop | None = None
        self.warm: list[Future] = []
        self.restarts = 0  # workers respawned
        self.fallbacks = 0  # requests answered None (computed in a thread) by a running pool

    def start(self) -> None:
        """Spawn every worker now; ``warm[i]`` resolves (to the worker's pid) once it is warmed up."""
        self._loop = asyncio.get_running_loop()
        self._workers = [self._spawn() for _ in range(self.n)]
        self.warm = [w.warm for w in self._workers]

    def _spawn(self) -> _Worker:
        ctx = mp.get_context("spawn")
        here, there = ctx.Pipe(duplex=True)
        proc = ctx.Process(target=_worker_main, args=(there, os.getpid()), name="gaintune-compute", daemon=True)
        proc.start()
        there.close()  # the worker's end: EOF here when the worker dies
        w = _Worker(proc, here, Future())
        self._loop.add_reader(here.fileno(), self._on_message, w)
        return w

    @property
    def pids(self) -> list[int]:
        return sorted(w.proc.pid for w in self._workers)

    # ---------------------------------------------------------------- dispatch
    def _release(self, w: _Worker) -> None:
        w.pending = None
        while self._waiters:
            f = self._waiters.popleft()
            if not f.done():
                f.set_result(w)
                return
        w.ready = True

    async def _acquire(self) -> _Worker:
        for w in self._workers:
            if w.ready:
                w.ready = False
                return w
        f = self._loop.create_future()
        self._waiters.append(f)
        try:
            return await f
        except asyncio.CancelledError:
            if f.done() and not f.cancelled():  # handed a worker, then cancelled: pass it on
                self._release(f.result())
            raise

    async def run(self, fn: Callable, *args, ref: tuple[int, str] | None = None) -> Any:
        """``fn(*args)`` in a worker; None when that worker died (the caller computes in a thread).

        ``ref = (i, key)``: ``args[i]`` is fully determined by ``key`` (a spec and its content
        hash); a worker that has it already gets only the key.
        """
        if self._loop is None:
            return None
        out = await self._dispatch(fn, args, ref)
        if out is None:
            self.fallbacks += 1
        return out

    async def _dispatch(self, fn: Callable, args: tuple, ref: tuple[int, str] | None) -> Any:
        w = await self._acquire()
        fut = self._loop.create_future()
        w.pending = fut
        w.pending_key = ref[1] if ref is not None else None
        if ref is not None:
            i, key = ref
            args = list(args)
            # the same LRU operations as the worker's _resolve, in the same order: the mirror stays exact
            if key in w.known:
                args[i] = _Ref(key)
                w.known.get(key)  # a read: now the most recently used, as in the worker
            else:
                args[i] = _Store(key, args[i])
                w.known.put(key, None)
            args = tuple(args)
        try:
            w.conn.send_bytes(pickle.dumps((fn, args), pickle.HIGHEST_PROTOCOL))
        except (OSError, ValueError):
            self._lost(w)
            return None
        # a cancelled request leaves the worker busy until its answer arrives (then discarded)
        return await fut

    def _on_message(self, w: _Worker) -> None:
        try:
            kind, value = pickle.loads(w.conn.recv_bytes())
        except (EOFError, OSError, pickle.UnpicklingError):
            self._lost(w)
            return
        if kind == "warm":
            if not w.warm.done():
                if isinstance(value, BaseException):
                    w.warm.set_exception(value)
                else:
                    w.warm.set_result(value)
            self._release(w)
            return
        fut = w.pending
        if fut is not None and not fut.done():
            if kind == "ok":
                fut.set_result(value)
            else:
                log.warning("compute worker raised %r; computing in a thread", value)
                fut.set_result(None)
        if kind != "ok" and w.pending_key is not None:
            w.known.pop(w.pending_key, None)  # resend it in full next time (heals a broken mirror)
        self._release(w)

    @staticmethod
    def _settle(w: _Worker, warm_error: str) -> None:
        """A retired worker: its request gets None (computed in a thread), an unfinished warm-up fails."""
        if w.pending is not None and not w.pending.done():
            w.pending.set_result(None)
        if not w.warm.done():
            w.warm.set_exception(RuntimeError(warm_error))

    def _lost(self, w: _Worker) -> None:
        """A worker died (or its pipe broke): answer its request with None and start a new one."""
        if w not in self._workers:
            return
        log.warning("compute worker %s died; starting a new one", w.proc.pid)
        self._loop.remove_reader(w.conn.fileno())
        w.conn.close()
        w.proc.join(timeout=0.1)
        self._settle(w, "compute worker died during warm-up")
        i = self._workers.index(w)
        self._workers[i] = self._spawn()
        self.restarts += 1

    def shutdown(self) -> None:
        """Stop and join every worker; waiting requests get None (computed in a thread)."""
        loop, self._loop = self._loop, None
        workers, self._workers = self._workers, []
        for w in workers:
            try:
                loop.remove_reader(w.conn.fileno())
            except (ValueError, OSError):
                pass
            try:
                w.conn.send_bytes(b"")
            except (OSError, ValueError):
                pass
        for w in workers:
            w.proc.join(timeout=5)
            if w.proc.is_alive():
                w.proc.kill()
                w.proc.join(timeout=5)
            w.conn.close()
            self._settle(w, "compute pool shut down")
        while self._waiters:
            f = self._waiters.popleft()
            if not f.done():
                f.cancel()
