"""The first run's compile of the simulator, shown: "compiling the simulator (first run only)".

On a cold numba cache (a fresh install) the simulator's kernel variants compile before a tune
can simulate, ~20 s of CPU each. :func:`compile_simulator` compiles the missing ones side by
side (:func:`gaintune.sim.precompile.precompile`) behind their own progress line, so the tune's
progress bar then starts on a warm simulator. With the cache warm it costs a cache lookup.
"""

from __future__ import annotations

from typing import Any

__all__ = ["COMPILE_MESSAGE", "compile_simulator", "compile_single_kernel"]

#: What the progress display says while the kernel compiles.
COMPILE_MESSAGE = "compiling the simulator (first run only)"


def compile_simulator(console: Any | None) -> list[str]:
    """Compile the kernel variants numba's cache lacks, with a progress line on ``console``.

    Parameters
    ----------
    console
        A :class:`rich.console.Console` for the progress line, or None to compile quietly
        (``--json``: stdout holds the result only).

    Returns
    -------
    list[str]
        The variants that were compiled (empty when the cache had them all).
    """
    from gaintune.sim.precompile import missing

    return _compile(console, missing())


def compile_single_kernel(console: Any | None) -> list[str]:
    """Build the single-lane kernel compiled ahead of time where it is missing, with the same progress line.

    For the commands that simulate one candidate at a time in a fresh process (``gaintune tuner query``):
    their first run builds it (~17 s of CPU, beside numba's compile of the JIT single-lane variant, which a
    cold cache needs anyway), and every later one loads it without numba. The other commands do not build it:
    a first tune's compile stays the JIT variants'. A build that fails is noted and not tried again
    (:func:`gaintune.sim.kernel_aot.aot_missing`); the query then runs on the JIT variant. Nothing imports
    numba when the module is in place.
    """
    from gaintune.sim.kernel_aot import AOT, aot_missing

    return _compile(console, [AOT] if aot_missing() else [])


def _compile(console: Any | None, todo: list[str]) -> list[str]:
    """:func:`gaintune.sim.precompile.precompile` of ``todo`` behind the progress line (none when empty)."""
    if not todo:
        return []
    from gaintune.sim.precompile import precompile

    if console is None:
        precompile(todo)
        return todo
    from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn

    with Progress(TextColumn("[bold]{task.description}"), BarColumn(), MofNCompleteColumn(),
                  TextColumn("kernel variants"), TimeElapsedColumn(), console=console, transient=False) as bar:
        task = bar.add_task(COMPILE_MESSAGE, total=len(todo))
        precompile(todo, on_progress=lambda done, total: bar.update(task, completed=done, total=total))
    return todo
