"""The first run's compile of the simulator, shown: "compiling the simulator (first run only)".

On a cold numba cache (a fresh install) the simulator's kernel variants compile before a tune
can simulate, ~20 s of CPU each. :func:`compile_simulator` compiles the missing ones side by
side (:func:`gaintune.sim.precompile.precompile`) behind their own progress line, so the tune's
progress bar then starts on a warm simulator. With the cache warm it costs a cache lookup.
"""

from __future__ import annotations

from typing import Any

__all__ = ["COMPILE_MESSAGE", "compile_simulator"]

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
    from gaintune.sim.kernel_aot import AOT, aot_missing
    from gaintune.sim.precompile import missing, precompile

    todo = missing() + ([AOT] if aot_missing() else [])
    if not todo:
        return []
    if console is None:
        precompile(todo)
        return todo
    from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn

    with Progress(TextColumn("[bold]{task.description}"), BarColumn(), MofNCompleteColumn(),
                  TextColumn("kernel variants"), TimeElapsedColumn(), console=console, transient=False) as bar:
        task = bar.add_task(COMPILE_MESSAGE, total=len(todo))
        precompile(todo, on_progress=lambda done, total: bar.update(task, completed=done, total=total))
    return todo
