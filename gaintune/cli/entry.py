"""The ``gaintune`` process entry: run the command, then exit without tearing the interpreter down.

A finished command's process spends a long time in interpreter teardown (freeing every module
and object one by one) that no one needs: measured on this project's machine, 0.85-0.9 s after
a ``gaintune tune`` (torch, torch._dynamo, SB3, numba and matplotlib loaded) and 0.16 s after a
``gaintune verify`` (numba), against 5 ms for a bare interpreter. So when the command runs as the
program itself (the console script, ``python -m gaintune``, ``python -m gaintune.cli``), its
:class:`SystemExit` ends the process the way the interpreter would, minus the teardown:

1. the exit code is worked out as the interpreter does (None -> 0, an int as is, anything else is
   printed to stderr and gives 1);
2. every :mod:`atexit` handler runs (logging shutdown, weakref finalizers such as temporary
   directories, multiprocessing clean-up, coverage);
3. stdout and stderr are flushed;
4. ``os._exit(code)``.

Everything else falls back to the ordinary exit, unchanged: a call from anything but a
``__main__`` module (tests, programs embedding :data:`gaintune.cli.app`), an exception other than
:class:`SystemExit` (traceback as usual), a live non-daemon thread (the interpreter would join
it), a profiler or tracer (``python -m cProfile``, a debugger, coverage: they report after the
program returns), a failed flush (e.g. a closed pipe: the interpreter reports it),
``GAINTUNE_FULL_EXIT=1``, and the long-running ``serve`` command (it sets :data:`FAST_EXIT` to False).

A command run as the program also starts with the cyclic garbage collector's first threshold raised
to :data:`GC_THRESHOLD0` allocations (CPython's default is 700). Start-up imports millions of objects
(numba, numpy, pydantic, torch), and at the default every few hundred allocations trigger a
collection that, every tenth and hundredth time, walks all of them: measured, 0.05 s of a 0.8 s
``gaintune verify`` and 0.35 s of a 6.4 s ``gaintune tune``. Reference counting still frees acyclic
garbage at once; cycles wait for at most that many allocations. Embedding callers keep their own
settings. The threshold is above what a ``gaintune tuner query`` allocates after it is raised
(~155,000 objects, numba's and scipy's imports among them): at 50,000 it ran three collections that
walked those start-up objects (0.11 s of its ~1.7 s of CPU, measured at a load of ~3), now none.

It also keeps freed memory in the heap (glibc only, :func:`keep_heap`): temporaries up to
:data:`MMAP_THRESHOLD` come from the heap instead of fresh mappings, and up to :data:`TRIM_THRESHOLD`
of freed heap is not handed back to the system. An answer's NumPy temporaries (frequency grids of
2,000 to 5,000 complex points, a few rows each) were otherwise mapped, faulted in and handed back time
and again: ~160 page faults per tuner answer, 14 with the thresholds; side by side in fresh processes
(four pairs, the same 50 plants, 3 runs each), the answer's p50 went from 8.4-8.9 ms to 8.0-8.4 ms and
its p95 from 9.5-10.2 ms to 8.9-9.5 ms. A user's own ``MALLOC_MMAP_THRESHOLD_`` or
``MALLOC_TRIM_THRESHOLD_`` wins; embedding callers keep their allocator as it is.
"""

from __future__ import annotations

import atexit
import gc
import os
import sys
import threading
from typing import Any

import typer

__all__ = ["GaintuneTyper", "FAST_EXIT", "GC_THRESHOLD0", "MMAP_THRESHOLD", "TRIM_THRESHOLD", "keep_heap",
           "exit_without_teardown"]

#: Whether a command run as the program may skip interpreter teardown (``serve`` turns it off).
FAST_EXIT = True
#: The cyclic collector's first threshold for a command run as the program (see the module docstring).
GC_THRESHOLD0 = 250_000
#: glibc's M_MMAP_THRESHOLD for a command run as the program: allocations below it come from the heap.
MMAP_THRESHOLD = 32 << 20
#: glibc's M_TRIM_THRESHOLD for a command run as the program: freed heap kept up to this size.
TRIM_THRESHOLD = 64 << 20
#: mallopt's parameter numbers (glibc's malloc.h).
_M_TRIM_THRESHOLD, _M_MMAP_THRESHOLD = -1, -3


def keep_heap() -> bool:
    """Set glibc's mmap and trim thresholds to :data:`MMAP_THRESHOLD` and :data:`TRIM_THRESHOLD` (the module
    docstring says why). Returns whether they were set: not off Linux, not where the C library has no
    ``mallopt`` or refuses (e.g. musl), and not when the user set either with glibc's environment variables."""
    if not sys.platform.startswith("linux") or any(
            v in os.environ for v in ("MALLOC_MMAP_THRESHOLD_", "MALLOC_TRIM_THRESHOLD_")):
        return False
    import ctypes  # numpy has imported it already

    try:
        mallopt = ctypes.CDLL(None).mallopt  # the process's own C library
    except (OSError, AttributeError):
        return False
    mallopt.argtypes, mallopt.restype = [ctypes.c_int, ctypes.c_int], ctypes.c_int
    return bool(mallopt(_M_MMAP_THRESHOLD, MMAP_THRESHOLD)) and bool(mallopt(_M_TRIM_THRESHOLD, TRIM_THRESHOLD))


def _exit_code(code: Any) -> int:
    """The process exit code of ``SystemExit(code)``, as the interpreter derives it."""
    if code is None:
        return 0
    if isinstance(code, int):
        return code
    try:
        sys.stderr.write(f"{code}\n")
    except Exception:  # pragma: no cover - stderr unusable: the interpreter would ignore it too
        pass
    return 1


def _may_skip_teardown() -> bool:
    if not FAST_EXIT or os.environ.get("GAINTUNE_FULL_EXIT") == "1":
        return False
    if not hasattr(atexit, "_run_exitfuncs"):  # pragma: no cover - not CPython
        return False
    if sys.getprofile() is not None or sys.gettrace() is not None:  # cProfile, a debugger, coverage
        return False
    main = threading.main_thread()
    return not any(t is not main and t.is_alive() and not t.daemon for t in threading.enumerate())


def exit_without_teardown(code: Any) -> None:
    """End the process with ``SystemExit(code)``'s exit code, after the atexit handlers and a flush
    of stdout/stderr, skipping interpreter teardown; raises ``SystemExit(code)`` (the ordinary
    exit) instead when that is not safe (see the module docstring)."""
    if not _may_skip_teardown():
        raise SystemExit(code)
    try:
        sys.stdout.flush()
        sys.stderr.flush()
    except Exception:  # e.g. BrokenPipeError: let the interpreter report it as it always does
        raise SystemExit(code) from None
    status = _exit_code(code)
    atexit._run_exitfuncs()
    try:
        sys.stdout.flush()
        sys.stderr.flush()
    except Exception:  # pragma: no cover - handlers wrote to a closed pipe
        pass
    os._exit(status & 0xFF)  # the status the OS keeps of sys.exit(status)


class GaintuneTyper(typer.Typer):
    """:class:`typer.Typer` whose call as the program exits through :func:`exit_without_teardown`."""

    def __call__(self, *args: Any, **kwargs: Any) -> Any:
        caller = sys._getframe(1).f_globals.get("__name__")
        if caller != "__main__":
            return super().__call__(*args, **kwargs)
        t0, t1, t2 = gc.get_threshold()
        gc.set_threshold(max(GC_THRESHOLD0, t0), t1, t2)
        keep_heap()
        try:
            return super().__call__(*args, **kwargs)
        except SystemExit as exc:
            exit_without_teardown(exc.code)
            raise  # pragma: no cover - exit_without_teardown raised or exited
