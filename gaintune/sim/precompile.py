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

import contextlib
import os
import subprocess
import sys
import tempfile
import threading
import warnings
from collections.abc import Callable, Iterator, Sequence
from pathlib import Path
from typing import Any

from gaintune.provenance import cpus_here
from gaintune.sim.kernel.drivers import COMPILED
from gaintune.sim.kernel_aot import AOT, dirs, failed_note, load_single, module_file, module_name
from gaintune.sim.simulator import Simulator
from gaintune.spec import load_spec

__all__ = ["missing", "precompile", "compile_here", "build_single"]

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
    """Compile (or load) variant ``name`` in this process; numba writes its on-disk cache.

    :data:`gaintune.sim.kernel_aot.AOT` builds the ahead-of-time single-lane module instead.
    """
    if name == AOT:
        build_single()
        return
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
        Names of :data:`~gaintune.sim.kernel.drivers.COMPILED`, e.g. from :func:`missing`, or
        :data:`~gaintune.sim.kernel_aot.AOT` (the ahead-of-time single-lane module).
    on_progress
        Called as ``on_progress(done, total)`` at the start and as each variant is compiled
        (from this thread or a thread waiting for a child).
    processes
        At most this many compiles at a time, this process's included (default: the CPUs
        this process may use; with one, all compile here, one after the other).

    Returns
    -------
    dict[str, str]
        Variants that failed to compile (here or in a child), with the last error line. They compile
        on first call instead, as numba does without this (the ahead-of-time module: the JIT variant runs).
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
            try:
                compile_here(name)
            except Exception as exc:  # noqa: BLE001 - reported as a child's failure is: it compiles on first call
                run.finished(name, f"{type(exc).__name__}: {exc}")
            else:
                run.finished(name, None)
        for t in waiters:
            t.join()
    finally:
        run.stop()
        load_single.cache_clear()  # a child may have built the ahead-of-time module this process looked for
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


# ------------------------------------------------------------------ the single-lane kernel ahead of time

def _writable_dir() -> Path:
    """The first folder of :func:`gaintune.sim.kernel_aot.dirs` this process can write to (created)."""
    for folder in dirs():
        try:
            folder.mkdir(parents=True, exist_ok=True)
            probe = tempfile.NamedTemporaryFile(dir=folder)  # os.access says yes to root on read-only mounts
            probe.close()
            return folder
        except OSError:
            continue
    raise OSError(f"no writable folder for the compiled kernel among {[str(d) for d in dirs()]}")


def build_single() -> Path:
    """Compile the single-lane kernel ahead of time (~17 s of CPU) and put it in place atomically
    (:mod:`gaintune.sim.kernel_aot` says what it is and where it goes).

    Returns the module's path. Raises ImportError where numba has no pycc, and the C compiler's
    error where the build fails; the JIT variant is unaffected either way. Two processes building at
    once wait for each other (a file lock), and the second finds the module built.
    """
    from filelock import FileLock

    folder = _writable_dir()
    target = module_file(folder)
    with FileLock(str(folder / (module_name() + ".lock"))):
        if not target.is_file():
            with tempfile.TemporaryDirectory(dir=folder) as tmp:
                try:
                    built = _compile(Path(tmp))
                except Exception as exc:
                    failed_note(folder).write_text(f"{type(exc).__name__}: {exc}\n", encoding="utf-8")
                    raise
                os.replace(built, target)
    # built here or, meanwhile, by another process: a load that found nothing before must look again
    load_single.cache_clear()
    return target


@contextlib.contextmanager
def _swapped(owner: Any, name: str, value: Any) -> Iterator[None]:
    """``owner.name`` is ``value`` inside the block (put back after it, raised or not)."""
    old = getattr(owner, name)
    setattr(owner, name, value)
    try:
        yield
    finally:
        setattr(owner, name, old)


def _compile(out_dir: Path) -> Path:
    """pycc's compile of the JIT single-lane variant's source, with that variant's flags, pipeline and CPU."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # pycc's pending-deprecation warning: the JIT variant is the fallback
        from numba.core.codegen import AOTCPUCodegen, JITCPUCodegen
        from numba.core.compiler import Flags
        from numba.pycc import CC
        from numba.pycc import compiler as pycc_compiler

    from gaintune.sim.kernel.pipeline import SerialKernelCompiler

    jit = COMPILED["single"]
    arg_types = tuple(jit.typeof_pyval(a) for a in _sample_args())
    jit.compile(arg_types)
    plain = pycc_compiler.compile_extra

    def as_the_jit_variant(typingctx, targetctx, func, args, return_type, flags, locals, library=None, **_: Any):
        # the JIT variant's flags (error model, fastmath contraction, ...) with pycc's own switches kept
        ours = Flags()
        jit._compiler.targetdescr.options.parse_as_flags(ours, jit.targetoptions)
        for switch in ("no_compile", "nrt", "no_cpython_wrapper", "no_cfunc_wrapper"):
            setattr(ours, switch, getattr(flags, switch))
        return plain(typingctx, targetctx, func, args, return_type, ours, locals, library=library,
                     pipeline_class=SerialKernelCompiler)

    cc = CC(module_name())
    cc.output_dir = str(out_dir)
    cc.target_cpu = "host"
    cc.verbose = False
    cc.export("single", jit.overloads[arg_types].signature)(jit.py_func)
    # pycc takes no pipeline, and selects ISA features by CPU model alone: a virtual machine can mask some of
    # the model's (an illegal instruction at run time). Both are the JIT's for this build only.
    with _swapped(pycc_compiler, "compile_extra", as_the_jit_variant), \
            _swapped(AOTCPUCodegen, "_customize_tm_features", JITCPUCodegen._customize_tm_features):
        cc.compile()
    built = [p for p in out_dir.iterdir() if p.name.startswith(module_name()) and p.suffix in (".so", ".pyd")]
    if not built:
        raise OSError(f"pycc wrote no module to {out_dir}")
    return built[0]
