"""Running a tune for ``gaintune tune`` and ``gaintune demo``: the search, its progress bar and the finish.

* :func:`demo_spec`: the built-in demo problem;
* :func:`_get_tune`: the RL search (:func:`gaintune.search.tune`), or exit 1 when it is
  not available. The commands look it up through :mod:`gaintune.cli`, so it can be
  replaced there;
* :func:`_run_tune`: run it, with a progress bar on stderr unless ``--json``;
* :func:`_finish`: write ``--out``, print the summary or the JSON, exit 3 on a failed
  verification.

Names with a leading underscore are internal to :mod:`gaintune.cli`.
"""

from __future__ import annotations

import sys
from collections.abc import Callable
from pathlib import Path
from typing import Any

import typer

from gaintune.cli.common import EXIT_VERIFY, _f, apply_overrides, err, out
from gaintune.cli.compiling import compile_simulator
from gaintune.cli.output import _print_summary, _write_outputs

__all__ = ["demo_spec", "_get_tune", "_run_tune", "_finish"]


def demo_spec(budget: int | None = None, seed: int | None = None):
    """The built-in demo problem: PID on the ``lag_n`` model 1/(s+1)^3 (fast to tune)."""
    from gaintune.plants.library import load_model
    from gaintune.spec import load_spec

    spec = load_spec(load_model("lag_n").example_spec())
    spec = apply_overrides(spec, budget=budget, seed=seed)
    return spec


def _get_tune() -> Callable:
    """:func:`gaintune.search.tune`, or exit 1 when the search stack (torch, stable-baselines3) is missing."""
    try:
        # from the module itself: once anything imported the submodule gaintune.search.tune (as
        # gaintune.__getattr__ does), the package attribute gaintune.search.tune is that module
        from gaintune.search.tune import tune
    except ImportError as exc:
        err.print(f"error: the RL search (gaintune.search.tune) is not available: {exc}", markup=False)
        raise typer.Exit(1) from None
    return tune


#: What the progress bar says in each phase of a tune (gaintune.search.result.Progress.phase).
_PHASES = {"search": "searching", "settle": "settling onto the requirements", "refine": "refining",
           "verify": "verifying the answer"}


def _run_tune(tune: Callable, spec, *, out_dir: Path | None, json_out: bool, baselines: bool, command: str,
              warm_start: Path | None = None) -> Any:
    """Run ``tune`` (from :func:`_get_tune`) on ``spec``: quietly with ``json_out``, else with a progress bar on
    stderr."""
    kwargs: dict[str, Any] = dict(out_dir=str(out_dir) if out_dir else None, verify=True, baselines=baselines)
    if warm_start is not None:
        kwargs["warm_start"] = str(warm_start)
    import inspect

    try:
        if "command" in inspect.signature(tune).parameters:
            kwargs["command"] = command
    except (TypeError, ValueError):  # pragma: no cover - not introspectable
        pass
    compile_simulator(None if json_out else err)  # a fresh install's first run: say so, compile side by side
    if json_out:
        return tune(spec, progress=None, **kwargs)
    from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn

    with Progress(
        TextColumn("[bold]{task.description}"), BarColumn(), MofNCompleteColumn(), TextColumn("sims"),
        TextColumn("best cost {task.fields[best]}"), TextColumn("ETA {task.fields[eta]}"), TimeElapsedColumn(),
        console=err.real(), transient=False,
    ) as bar:
        task = bar.add_task(f"tuning {spec.name} ({spec.search.algo})", total=spec.search.budget, best="-", eta="-")

        def progress(p) -> bool:
            bar.update(task, completed=min(p.sims, p.budget), total=p.budget,
                       description=f"{_PHASES.get(p.phase, p.phase)} ({spec.search.algo})",
                       best=_f(p.best_cost), eta="-" if p.eta is None else f"{max(p.eta, 0.0):.0f}s")
            return True

        return tune(spec, progress=progress, **kwargs)


def _finish(result, *, out_dir: Path | None, json_out: bool, command: str) -> None:
    """Write the outputs, print the result (JSON or summary), and exit 3 when verification failed."""
    if not result.provenance.command:
        result.provenance.command = command
    if out_dir is not None:
        _write_outputs(result, out_dir, console=err if json_out else out)
    if json_out:
        sys.stdout.write(result.model_dump_json(indent=2) + "\n")
    else:
        _print_summary(result)
    if result.verdict == "fail":
        raise typer.Exit(EXIT_VERIFY)
