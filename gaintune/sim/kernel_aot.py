"""The single-lane kernel compiled ahead of time: a fresh process simulates one candidate without numba.

A fresh ``gaintune tuner query`` simulates a handful of single candidates. Through numba's JIT
that costs ~0.25 s before the first one runs: importing numba (~0.15 s) and starting its runtime
and loading the cached machine code (~0.08 s), 40 % of the whole query. numba's ahead-of-time
compiler (:mod:`numba.pycc`) compiles the same source into an extension module that carries its
own copy of numba's runtime, so importing it needs numpy only.

:func:`gaintune.sim.precompile.build_single` compiles the JIT single-lane variant's source
(:data:`gaintune.sim.kernel.drivers.COMPILED` ``["single"]``) with everything that sets its machine
code taken from that variant: its numba flags (``error_model="numpy"``, ``fastmath={"contract"}``),
its compiler pipeline (:class:`gaintune.sim.kernel.pipeline.SerialKernelCompiler`), the host CPU and
its features, and the argument types of every call (:func:`gaintune.sim.precompile._sample_args`).
The numbers are the JIT variant's, bit for bit (``tests/sim/test_kernel_aot.py``).
:func:`gaintune.cli.compiling.compile_single_kernel` builds it on the first ``gaintune tuner query``
(a tune's first run compiles only the JIT variants).

The module is named after the kernel's sources (:func:`source_tag`), the numba release and the CPU,
and kept where numba keeps its cache: ``NUMBA_CACHE_DIR`` when set, else the kernel package's
``__pycache__`` when writable, else the user's cache folder. An edited kernel, another numba or
another CPU looks for another file. Where none is found, or it does not load, or pycc or a C
compiler is missing (pycc is pending deprecation in numba), the JIT variant runs as before.
``GAINTUNE_KERNEL_AOT=0`` turns the module off (neither loaded nor built): every candidate then runs
on numba's JIT variants, which ``gaintune bench tuners`` times beside it.
"""

from __future__ import annotations

import functools
import hashlib
import importlib.machinery
import importlib.metadata
import importlib.util
import os
import platform
import re
import sysconfig
from collections.abc import Callable
from pathlib import Path
from typing import Any

__all__ = ["source_tag", "module_name", "load_single", "aot_missing", "enabled", "failed_note", "dirs", "module_file",
           "AOT", "SWITCH"]

#: The name :func:`gaintune.sim.precompile.precompile` knows this build by, beside the JIT variants.
AOT = "single_aot"

#: The environment variable that turns the module off where it is ``0``.
SWITCH = "GAINTUNE_KERNEL_AOT"

_KERNEL_DIR = Path(__file__).parent / "kernel"


def source_tag(package: Path = _KERNEL_DIR) -> str:
    """Hash of every source file the kernel compiles from (the kernel package, and the tape op codes).

    The JIT variants' names carry it too (numba's cache checks only the file of the function it
    compiles, not the stages inlined into it).
    """
    h = hashlib.blake2b(digest_size=6)
    for path in sorted(package.glob("*.py")) + [Path(__file__).parent / "tape.py"]:
        h.update(path.name.encode())
        h.update(path.read_bytes())
    return h.hexdigest()


def _cpu_tag() -> str:
    """The CPU the machine code is for: model and instruction-set flags (no llvmlite import needed)."""
    h = hashlib.blake2b(platform.machine().encode(), digest_size=4)
    try:
        with open("/proc/cpuinfo", encoding="utf-8", errors="replace") as f:
            seen = set()
            for line in f:
                key = line.split(":", 1)[0].strip()
                if key in ("model name", "flags", "Features", "CPU part") and key not in seen:
                    seen.add(key)
                    h.update(line.encode())
    except OSError:
        h.update(platform.processor().encode())
    return h.hexdigest()


@functools.cache
def module_name() -> str:
    """The extension module's name: kernel sources, numba release and CPU (its init symbol is ``PyInit_`` + it)."""
    try:
        numba_version = importlib.metadata.version("numba")
    except importlib.metadata.PackageNotFoundError:
        numba_version = "none"
    return f"gaintune_kernel_single_{source_tag()}_{re.sub(r'[^0-9A-Za-z]', '_', numba_version)}_{_cpu_tag()}"


def dirs() -> list[Path]:
    """Where the module may be, in numba's order for its own cache."""
    if os.environ.get("NUMBA_CACHE_DIR"):
        return [Path(os.environ["NUMBA_CACHE_DIR"]) / "gaintune_aot"]
    user = Path(os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache") / "gaintune" / "aot"
    return [_KERNEL_DIR / "__pycache__", user]


def module_file(folder: Path) -> Path:
    """The module's path in ``folder``."""
    return folder / (module_name() + (sysconfig.get_config_var("EXT_SUFFIX") or ".so"))


def enabled() -> bool:
    """Whether the module may be used and built (:data:`SWITCH` is not ``0``)."""
    return os.environ.get(SWITCH, "1").strip() != "0"


def aot_missing() -> bool:
    """Whether the module for this kernel, numba and CPU is neither built nor known to fail to build.

    A failed build leaves a ``.failed`` note (no pycc, no C compiler), so every first run does not try
    again; an edited kernel or another numba tries afresh. Nothing is imported. False when turned off.
    """
    return enabled() and not any(module_file(d).is_file() or failed_note(d).is_file() for d in dirs())


def failed_note(folder: Path) -> Path:
    """Where a failed build's note goes in ``folder``."""
    return folder / (module_name() + ".failed")


@functools.cache
def load_single() -> Callable[..., Any] | None:
    """The ahead-of-time single-lane kernel (same arguments as the JIT one), or None where it is not built.

    A module that does not import (damaged, built for another Python) is passed over: the JIT variant runs.
    Read once per process (as ``GAINTUNE_KERNEL_AOT`` is).
    """
    if not enabled():
        return None
    for folder in dirs():
        path = module_file(folder)
        if not path.is_file():
            continue
        try:
            loader = importlib.machinery.ExtensionFileLoader(module_name(), str(path))
            spec = importlib.util.spec_from_file_location(module_name(), path, loader=loader)
            if spec is None:
                continue
            module = importlib.util.module_from_spec(spec)
            loader.exec_module(module)
            return module.single
        except (ImportError, OSError, AttributeError):
            continue
    return None
