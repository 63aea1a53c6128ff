"""Process pool for the synchronous CPU-bound endpoints (``/v1/verify``, ``/v1/simulate``, tuner queries).

Verification is Python + NumPy on small arrays and holds the GIL, so threads add
contention rather than throughput. ``compute_processes`` warm worker processes
(spawned once, at start-up, from the server's main thread) run the computations
instead; each keeps the per-spec caches of :mod:`gaintune.verification.context` (plant,
layout, linearisation, simulator) between requests. ``compute_processes = 0``
computes in the server process, in at most ``compute_threads`` threads.

Each worker has its own pipe (a socket pair) carrying length-prefixed pickles. The server's
end belongs to the event loop and is read and written only through an asyncio stream (one
reader task per worker): no executor threads and no shared result queue on the request path,
and messages of any size. (Blocking-style ``Connection.recv_bytes`` on a descriptor the loop
watches failed under uvloop, whose ``add_reader`` makes the descriptor non-blocking: every
answer larger than a socket buffer respawned its worker.) Workers die with the server
(``PR_SET_PDEATHSIG`` plus a parent watch), and the pool is shut down (workers joined) when
the app stops. A worker that dies is replaced at once; the request it was computing is
computed in a thread instead. ``ComputePool.restarts`` and ``ComputePool.fallbacks`` count
both, for ``/metrics``.
"""

from __future__ import annotations

import asyncio
import json
import logging
import multiprocessing as mp
import os
import pickle
import socket
import struct
import threading
from collections import deque
from collections.abc import Callable
from concurrent.futures import Future
from typing import Any, BinaryIO

from gaintune.cache import LRU

__all__ = ["ComputePool", "compute_verify", "compute_simulate", "compute_tuner_query", "warm_up_compute"]

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
    from gaintune.verification import verify

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
    from gaintune.verification import verify

    try:
        report = verify(spec, gains, robust=robust, nonlinear=nonlinear, plant=plant, layout=layout,
                        spec_hash=spec_hash)
    except GaintuneError as exc:
        return "gains", problem_details(exc)
    except Exception as exc:  # noqa: BLE001 - user input must never produce a 500
        log.warning("verify failed unexpectedly", exc_info=True)
        return "error", f"{type(exc).__name__}: {str(exc)[:300]}"
    return "ok", report.model_dump_json().encode()


#: Tuners a compute process keeps loaded when the caller passes no cache (the pool's worker processes).
TUNER_CACHE_SIZE = 16
_tuners: LRU[str, Any] | None = None


def _process_tuners() -> LRU[str, Any]:
    global _tuners
    if _tuners is None:
        _tuners = LRU(TUNER_CACHE_SIZE)
    return _tuners


def compute_tuner_query(folder: str, key: str, params: dict[str, float], refine: int,
                        cache: LRU[str, Any] | None = None) -> tuple[str, Any]:
    """A tuner's answer for one plant: ``("ok", JSON bytes)`` | ``("invalid", problem details)`` | ``("error", msg)``.

    The tuner at ``folder`` is loaded once per ``key`` (its folder and content) and kept in ``cache``
    (the app's LRU when computed in the server, this process's own in a pool worker). Never raises
    for bad input: a parameter the tuner does not know, a bad value or a plant outside its family is
    "invalid", naming the field.
    """
    from gaintune.errors import GaintuneError, problem_details
    from gaintune.tuners.tuner import OutsideFamilyError, Tuner
    from gaintune_api.problem_details import json_safe

    tuners = cache if cache is not None else _process_tuners()
    try:
        tuner = tuners.get_or_build(key, lambda: Tuner.load(folder))
        answer = tuner.query(params, refine=refine)
    except OutsideFamilyError as exc:
        return "invalid", [{"loc": exc.field, "msg": exc.message}]
    except GaintuneError as exc:
        return "invalid", problem_details(exc)
    except Exception as exc:  # noqa: BLE001 - user input must never produce a 500
        log.warning("tuner query failed unexpectedly", exc_info=True)
        return "error", f"{type(exc).__name__}: {str(exc)[:300]}"
    return "ok", json.dumps(json_safe(answer.as_dict()), allow_nan=False).encode()


def compute_simulate(spec, gains, chosen: list[int], max_points: int, plant=None, layout=None) -> tuple[str, Any]:
    """``("ok", JSON bytes of a SimulateResponse)`` | ``("gains", problem details)`` | ``("error", message)``."""
    from gaintune.errors import GaintuneError, problem_details
    from gaintune_api.simulation import simulate_payload

    try:
        return "ok", simulate_payload(spec, gains, chosen, max_points, plant, layout)
    except GaintuneError as exc:
        return "gains", problem_details(exc)
    except Exception as exc:  # noqa: BLE001 - user input must never produce a 500
        log.warning("simulate failed unexpectedly", exc_info=True)
        return "error", f"{type(exc).__name__}: {str(exc)[:300]}"


# ------------------------------------------------------------------ worker loop

#: A frame on a worker's pipe: this header (the pickle's length, 8 bytes big-endian), then the pickle.
_HEADER = struct.Struct("!Q")
#: Bytes the server's stream reader buffers before it pauses the transport (a 16-scenario simulate
#: answer is about 1.5 MB; larger frames still arrive whole, in more reads).
_STREAM_LIMIT = 1 << 21

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


def _send(wfile: BinaryIO, msg: tuple) -> None:
    """Write ``msg`` as one frame: its pickle's length (:data:`_HEADER`), then the pickle."""
    try:
        data = pickle.dumps(msg, pickle.HIGHEST_PROTOCOL)
    except Exception as exc:  # noqa: BLE001 - e.g. an unpicklable answer: the server computes it in a thread
        data = pickle.dumps(("exc", RuntimeError(f"answer not picklable: {exc!r}"[:300])), pickle.HIGHEST_PROTOCOL)
    wfile.write(_HEADER.pack(len(data)))
    wfile.write(data)
    wfile.flush()


def _worker_main(sock: socket.socket, parent: int) -> None:
    """A compute worker: warm up, report ``("warm", pid)``, then answer ``(fn, args)`` frames with
    ``("ok", fn(*args))`` (or ``("exc", exception)``) until EOF (the server closed its end).

    The worker's end of the pipe is blocking: buffered files read and write whole frames of any size.
    """
    _init_worker(parent)
    rfile, wfile = sock.makefile("rb"), sock.makefile("wb")
    try:
        _send(wfile, ("warm", warm_up_compute()))
    except Exception as exc:  # noqa: BLE001 - warm-up is an optimisation only
        log.warning("compute worker warm-up failed", exc_info=True)
        _send(wfile, ("warm", exc))
    known: LRU[str, Any] = LRU(KNOWN_SIZE)
    while True:
        try:
            head = rfile.read(_HEADER.size)
            data = rfile.read(_HEADER.unpack(head)[0]) if len(head) == _HEADER.size else b""
        except OSError:
            break
        if not data:  # EOF (a request frame is never empty)
            break
        try:
            fn, args = pickle.loads(data)
            msg = ("ok", fn(*_resolve(args, known)))
        except Exception as exc:  # noqa: BLE001 - reported to the server, which computes in a thread
            msg = ("exc", exc)
        try:
            _send(wfile, msg)
        except OSError:
            break


# ------------------------------------------------------------------ server side


class _Worker:
    __slots__ = ("proc", "sock", "writer", "task", "warm", "ready", "pending", "known", "pending_key")

    def __init__(self, proc, sock: socket.socket, warm: Future) -> None:
        self.proc, self.sock, self.warm = proc, sock, warm
        self.writer: asyncio.StreamWriter | None = None  # set once the reader task has attached the socket
        self.task: asyncio.Task | None = None  # the reader task (:meth:`ComputePool._serve`)
        self.ready = False  # warmed up and not computing
        self.pending: asyncio.Future | None = None
        self.known: LRU[str, None] = LRU(KNOWN_SIZE)  # mirror of the worker's LRU
        self.pending_key: str | None = None


class ComputePool:
    """``n`` spawned worker processes, each on its own pipe, read and written with asyncio streams.

    No executor threads: a request is pickled onto an idle worker's pipe from the event loop,
    and each worker's reader task resolves the request's future when the answer arrives.
    :meth:`start` and :meth:`shutdown` run on the event loop's thread, which is the main thread
    under uvicorn (PDEATHSIG follows the spawning thread).

    ``restarts`` counts workers respawned, ``fallbacks`` requests the running pool answered
    with None (the caller computes them in a thread); ``/metrics`` exports both.
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

    def _started_loop(self) -> asyncio.AbstractEventLoop:
        """The event loop :meth:`start` ran on (workers are spawned and awaited only while the pool runs)."""
        assert self._loop is not None, "compute pool not started"
        return self._loop

    def _spawn(self) -> _Worker:
        ctx = mp.get_context("spawn")
        here, there = socket.socketpair()
        proc = ctx.Process(target=_worker_main, args=(there, os.getpid()), name="gaintune-compute", daemon=True)
        proc.start()
        there.close()  # the worker's end: EOF here when the worker dies
        w = _Worker(proc, here, Future())
        w.task = self._started_loop().create_task(self._serve(w))
        return w

    async def _serve(self, w: _Worker) -> None:
        """Read ``w``'s answer frames until its pipe closes or breaks, then replace the worker.

        The event loop owns the server's end of the pipe (uvloop even makes it non-blocking), so it is
        read and written only through an asyncio stream: a frame of any size arrives in as many reads
        as it takes, and the transport buffers a request of any size without blocking the loop.
        """
        try:
            reader, w.writer = await asyncio.open_connection(sock=w.sock, limit=_STREAM_LIMIT)
            while True:
                (n,) = _HEADER.unpack(await reader.readexactly(_HEADER.size))
                self._on_message(w, await reader.readexactly(n))
        except Exception as exc:  # noqa: BLE001 - whatever broke the pipe, the worker is replaced
            if not isinstance(exc, (asyncio.IncompleteReadError, OSError)):
                log.error("compute worker pipe failed", exc_info=True)
            self._lost(w)

    @property
    def pids(self) -> list[int]:
        """The pids of the pool's current worker processes, sorted."""
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
        f = self._started_loop().create_future()
        self._waiters.append(f)
        try:
            return await f
        except asyncio.CancelledError:
            if f.done() and not f.cancelled():  # handed a worker, then cancelled: pass it on
                self._release(f.result())
            raise

    async def run(self, fn: Callable, *args, ref: tuple[int, str] | None = None) -> Any:
        """``fn(*args)`` in a worker; None when that worker died or failed (the caller computes in a thread).

        ``ref = (i, key)``: ``args[i]`` is fully determined by ``key`` (a spec and its content
        hash); a worker that has it already gets only the key.
        """
        if self._loop is None:
            return None
        w = await self._acquire()
        if ref is not None:
            i, key = ref
            known = key in w.known
            args = args[:i] + (_Ref(key) if known else _Store(key, args[i]),) + args[i + 1:]
        try:
            data = pickle.dumps((fn, args), pickle.HIGHEST_PROTOCOL)
        except Exception:  # noqa: BLE001 - not sent: the worker is free again, the caller computes in a thread
            log.warning("compute request not picklable; computing in a thread", exc_info=True)
            self._release(w)
            self.fallbacks += 1
            return None
        if w.writer is None or w.writer.is_closing():  # the pipe closed (the worker died) since it was handed out
            self._lost(w)
            self.fallbacks += 1
            return None
        if ref is not None and known:  # the same LRU operations as the worker's _resolve, in the same order:
            w.known.get(key)  # a read makes it the most recently used
        elif ref is not None:
            w.known.put(key, None)
        fut = self._loop.create_future()
        w.pending, w.pending_key = fut, ref[1] if ref is not None else None
        w.writer.writelines((_HEADER.pack(len(data)), data))  # buffered by the transport: never blocks
        # a cancelled request leaves the worker busy until its answer arrives (then discarded)
        return await fut

    def _on_message(self, w: _Worker, data: bytes) -> None:
        try:
            kind, value = pickle.loads(data)
        except Exception as exc:  # noqa: BLE001 - the frame was read whole: only this answer is lost
            kind, value = "exc", exc
        if not w.warm.done():  # the first frame: ("warm", pid or the warm-up's exception)
            if isinstance(value, BaseException):
                w.warm.set_exception(value)
            else:
                w.warm.set_result(value)
            self._release(w)
            return
        fut = w.pending
        if kind == "ok" and fut is not None and not fut.done():
            fut.set_result(value)
        elif kind != "ok":
            log.warning("compute worker raised %r; computing in a thread", value)
            self._fall_back(w)
        if kind != "ok" and w.pending_key is not None:
            w.known.pop(w.pending_key, None)  # resend it in full next time (heals a broken mirror)
        self._release(w)

    def _fall_back(self, w: _Worker) -> None:
        """``w``'s request (unless cancelled) gets None: the caller computes it in a thread."""
        if w.pending is not None and not w.pending.done():
            w.pending.set_result(None)
            self.fallbacks += 1

    def _settle(self, w: _Worker, warm_error: str) -> None:
        """A retired worker: its request gets None (computed in a thread), an unfinished warm-up fails."""
        self._fall_back(w)
        if not w.warm.done():
            w.warm.set_exception(RuntimeError(warm_error))

    @staticmethod
    def _close(w: _Worker) -> None:
        """Close the server's end of ``w``'s pipe now: the worker reads EOF and exits."""
        try:
            w.sock.shutdown(socket.SHUT_RDWR)  # at once, without waiting for the loop to close the transport
        except OSError:
            pass
        if w.writer is not None:
            w.writer.close()
        else:
            w.sock.close()

    def _lost(self, w: _Worker) -> None:
        """A worker died (or its pipe broke): answer its request with None and start a new one."""
        if w not in self._workers:
            return
        log.warning("compute worker %s died; starting a new one", w.proc.pid)
        self._close(w)
        w.proc.kill()  # already dead, or abandoned with its pipe
        w.proc.join(timeout=0.1)
        self._settle(w, "compute worker died during warm-up")
        i = self._workers.index(w)
        self._workers[i] = self._spawn()
        self.restarts += 1

    def shutdown(self) -> None:
        """Stop and join every worker: a request in a worker gets None (computed in a thread), requests
        waiting for a worker are cancelled."""
        self._loop = None
        workers, self._workers = self._workers, []
        for w in workers:
            if w.task is not None:
                w.task.cancel()
            self._close(w)
        for w in workers:
            w.proc.join(timeout=5)
            if w.proc.is_alive():
                w.proc.kill()
                w.proc.join(timeout=5)
            self._settle(w, "compute pool shut down")
        while self._waiters:
            f = self._waiters.popleft()
            if not f.done():
                f.cancel()
