"""Running a tune for ``gaintune tune`` and ``gaintune demo``: the search, its progress bar and the finish.

* :func:`demo_spec`: the built-in demo problem;
* :func:`_get_tune`: the RL search (:func:`gaintune.search.tune`), or exit 1 when it is
  not available. The commands look it up through :mod:`gaintune.cli`, so it can be
  replaced there;
* :func:`_run_tune`: run it, with a progress bar on stderr unless ``--json``;
* :func:`_finish`: write ``--out``, print the summary or the JSON, exit 3 on a failed
  verification;
* :func:`run_quick`: ``tune --quick`` (:func:`gaintune.tuners.quick.quick_tune`): the answer beside
  AMIGO and SIMC, the same ``--out`` files plus ``quick.json``, exit 3 on a failed verification.

Names with a leading underscore are internal to :mod:`gaintune.cli`.
"""

from __future__ import annotations

import json
import sys
from collections.abc import Callable
from pathlib import Path
from typing import Any

import typer

from gaintune.cli.common import EXIT_VERIFY, InputError, _f, apply_overrides, err, out, output_errors
from gaintune.cli.compiling import compile_simulator
from gaintune.cli.output import _gains_line, _print_summary, _write_outputs

__all__ = ["demo_spec", "_get_tune", "_run_tune", "_finish", "run_quick"]


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
        from gaintune.search.tuning import tune
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


# ------------------------------------------------------------------ tune --quick


def _check_quick_options(**given: Any) -> None:
    """Options of the search that ``--quick`` does not take: exit 2 naming the first one given."""
    for name, value in given.items():
        if value not in (None, False):
            raise InputError(name, f"--{name.replace('_', '-')} sets the search, which --quick does not run; drop it, "
                             "or drop --quick to search")


def run_quick(spec, *, out_dir: Path | None, json_out: bool, tuners: Path | None, refine: int, compare_search: int,
              command: str) -> None:
    """``tune --quick``: the quick answer, its comparison table (or JSON), ``--out``; exit 3 on a fail."""
    from gaintune.tuners.quick import quick_tune

    if compare_search:
        _get_tune()  # the search stack is there (exit 1 naming what is missing otherwise)
    compile_simulator(None if json_out else err)  # a fresh install's first run: say so
    q = quick_tune(spec, tuners_dir=tuners, refine=refine, compare_search=compare_search, command=command)
    result = q.result
    if out_dir is not None:
        _write_outputs(result, out_dir, console=err if json_out else out)
        from gaintune.files import write_atomic

        with output_errors(out_dir / "quick.json"):
            write_atomic(out_dir / "quick.json", json.dumps(q.as_dict(), indent=2, default=str) + "\n")
    if json_out:
        doc = {**json.loads(result.model_dump_json()), "quick": q.as_dict()}
        sys.stdout.write(json.dumps(doc, indent=2, default=str) + "\n")
    else:
        _print_quick(q)
    if result.verdict != "pass":
        raise typer.Exit(EXIT_VERIFY)


def _print_quick(q) -> None:
    """The model, the tuner, the summary of the answer and the comparison with the rules (and the search)."""
    from rich.table import Table

    out.print(f"model: {q.model.text()}", markup=False, highlight=False)
    t = q.tuner
    won = q.source + (f", refined with {q.refine_sims} simulations" if q.refined else "")
    out.print(f"tuner: {t.name if t else 'none'}" + (f" (Ms <= {t.ms_max:g})" if t else "")
              + f"; answer from: {won}", markup=False, highlight=False)
    for n in q.notes:
        out.print(f"note: {n}", markup=False, highlight=False)
    _print_summary(q.result.model_copy(update={"baselines": []}))
    searched = any(r["method"] == "search" for r in q.comparison)
    c = Table(title=f"The quick answer beside the rules{' and the search' if searched else ''} (same plant, cost "
                    "and verdict)")
    for col in ("method", "gains", "cost", "vs quick", "verdict"):
        c.add_column(col, justify="right" if col in ("cost", "vs quick") else "left")
    for row in q.comparison:
        method = f"search ({row['note']})" if row["method"] == "search" else str(row["method"])
        c.add_row(method, _gains_line(row["gains"]), _f(row["cost"]),
                  "-" if row["ratio"] is None else _f(row["ratio"], 4),
                  row["verdict"] or ("-" if row["gains"] else f"n/a: {row.get('note') or ''}"))
    out.print(c)
