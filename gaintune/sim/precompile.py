"""Compile the kernel's variants ahead of their first call, side by side, when numba's cache lacks them.

numba compiles a function on one core, and each variant of the kernel costs ~20 s of CPU. On a
cold on-disk cache (a fresh install, a new numba, an edited kernel) a tune's first calls would
compile them one after the other. :func:`precompile` compiles the missing ones at the same time:
this process compiles one, child processes the others (up to one per CPU), and the children's
machine code reaches this process through numba's on-disk cache, loaded on the variant's first
call. On two cores the wait is that of the costliest variant rather than of their sum.

:func:`missing` says which variants the cache lacks without compiling anything: it asks numba's
cache index for the signature every call has (the argument types of a tiny problem's record).
It reads numba internals; where they differ (another numba, caching off) it reports nothing
missing, and the variants compile on first call as numba always does.

Example
-------
>>> from gaintune.sim.precompile import missing, precompile
>>> precompile(missing())  # doctest: +SKIP
"""

from __future__ import annotations

import os
import subprocess
import sys
import threading
from collections.abc import Callable, Sequence
from pathlib import Path

from gaintune.provenance import cpus_here
from gaintune.sim.kernel.drivers import COMPILED
from gaintune.sim.simulator import Simulator
from gaintune.spec import load_spec

__all__ = ["missing", "precompile", "compile_here"]

#: The tiny problem whose record has the argument types of every call (one PI loop on 1/(s+1)).
_SAMPLE = {"plant": {"tf": {"num": [1], "den": [1, 1]}}, "loops": [{"type": "pi"}],
           "scenario": {"dt": 0.1, "horizon": 0.5}}


def _sample_args() -> tuple:
    """The compiled functions' arguments for one candidate of the tiny problem (record, then chunk range)."""
    sim = Simulator(load_spec(_SAMPLE))
    return (*sim.kernel_args(sim.layout.full(sim.layout.initial_tuned())), 0, 1)


def _cached(dispatcher, sig: tuple) -> bool:
    """Whether ``dispatcher`` has ``sig`` loaded or in numba's on-disk cache index (True when unsure)."""
    if tuple(sig) in dispatcher.overloads:
        return True
    try:
        cache = dispatcher._cache
        key = cache._index_key(sig, dispatcher.targetctx.codegen())
        return key in cache._cache_file._load_index()
    except Exception:  # noqa: BLE001 - numba internals differ, or no cache: leave it to numba
        return True


def missing(variants: Sequence[str] = tuple(COMPILED)) -> list[str]:
    """The variants (names of :data:`~gaintune.sim.kernel.drivers.COMPILED`) not compiled yet.

    Parameters
    ----------
    variants
        The variants to check (default all: what a tune calls).

    Returns
    -------
    list[str]
        Those neither loaded in this process nor held by numba's on-disk cache, in the given order.
    """
    args = _sample_args()
    out = []
    for name in variants:
        fn = COMPILED[name]
        if not _cached(fn, tuple(fn.typeof_pyval(a) for a in args)):
            out.append(name)
    return out


def compile_here(name: str) -> None:
    """Compile (or load) variant ``name`` in this process; numba writes its on-disk cache."""
    COMPILED[name](*_sample_args())


def _child(name: str) -> subprocess.Popen:
    """A child process compiling ``name`` with this process's gaintune (first on its ``PYTHONPATH``)."""
    root = str(Path(__file__).resolve().parents[2])
    env = {**os.environ, "PYTHONPATH": os.pathsep.join(filter(None, [root, os.environ.get("PYTHONPATH")]))}
    code = f"from gaintune.sim.precompile import compile_here; compile_here({name!r})"
    return subprocess.Popen([sys.executable, "-c", code], env=env, stdin=subprocess.DEVNULL,
                            stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)




def precompile(variants: Sequence[str], on_progress: Callable[[int, int], None] | None = None,
               processes: int | None = None) -> dict[str, str]:
    """Compile ``variants`` at the same time: the first in this process, the others in child processes.

    Parameters
    ----------
    variants
        Names of :data:`~gaintune.sim.kernel.drivers.COMPILED`, e.g. from :func:`missing`.
    on_progress
        Called as ``on_progress(done, total)`` at the start and as each variant is compiled
        (from this thread or a thread waiting for a child).
    processes
        At most this many compiles at a time, this process's included (default: the CPUs
        this process may use; with one, all compile here, one after the other).

    Returns
    -------
    dict[str, str]
        Variants whose child failed, with its last error line. They compile on first call
        instead, as numba does without this.
    """
    run = _Run(list(variants), on_progress)
    width = max(1, processes or cpus_here())
    here, others = (run.todo, []) if width == 1 else (run.todo[:1], run.todo[1:])
    slots = threading.Semaphore(max(1, width - 1))  # children at a time, beside this process's compile
    waiters = [threading.Thread(target=run.child, args=(name, slots), daemon=True) for name in others]
    try:
        for t in waiters:
            t.start()
        for name in here:
            compile_here(name)
            run.finished(name, None)
        for t in waiters:
            t.join()
    finally:
        run.stop()
    return run.failed


class _Run:
    """The state of one :func:`precompile`: progress, failures, and the children to stop if interrupted."""

    def __init__(self, todo: list[str], on_progress: Callable[[int, int], None] | None) -> None:
        self.todo, self.done = todo, 0
        self.failed: dict[str, str] = {}
        self._report = on_progress or (lambda done, total: None)
        self._lock, self._stopped = threading.Lock(), False
        self._children: list[subprocess.Popen] = []
        self._report(0, len(todo))

    def finished(self, name: str, err: str | None) -> None:
        with self._lock:
            self.done += 1
            if err is not None:
                self.failed[name] = err
            self._report(self.done, len(self.todo))

    def child(self, name: str, slots: threading.Semaphore) -> None:
        """Compile ``name`` in a child process (waiting for a slot), then report it."""
        with slots:
            with self._lock:
                if self._stopped:
                    return
                p = _child(name)
                self._children.append(p)
            _, err = p.communicate()
        lines = err.decode(errors="replace").strip().splitlines()
        self.finished(name, None if p.returncode == 0 else (lines[-1] if lines else f"exit code {p.returncode}"))

    def stop(self) -> None:
        """Kill the children still compiling (this process was interrupted) and start no more."""
        with self._lock:
            self._stopped = True
            for p in self._children:
                if p.poll() is None:
                    p.kill()
