"""``gaintune policy RUN``: a trained tuner's gains for other plants of its family, each verified.

* :func:`parse_params`: ``--param K=1.5`` / ``--param T=0.5,1,2`` -> a grid (exit 2 naming the option);
* :func:`run_policy`: load the run once, answer every grid point, print a table (or JSON), exit 3 when
  any point fails its verification.

Names with a leading underscore are internal to :mod:`gaintune.cli`.
"""

from __future__ import annotations

import json
import math
from pathlib import Path

import typer

from gaintune.cli.common import EXIT_VERIFY, InputError, _f, out

__all__ = ["parse_params", "run_policy"]

#: Most grid points one command answers (a schedule of 50 x 50 is already more than a table shows).
MAX_POINTS = 10_000


def parse_params(items: list[str]) -> dict[str, list[float]]:
    """``["K=1.5", "T=0.5,1,2"]`` -> ``{"K": [1.5], "T": [0.5, 1.0, 2.0]}``; InputError naming ``--param``."""
    grid: dict[str, list[float]] = {}
    for item in items:
        name, sep, values = item.partition("=")
        name = name.strip()
        if not sep or not name or not values.strip():
            raise InputError("--param", f"expected NAME=VALUE or NAME=V1,V2,..., got {item!r}")
        try:
            nums = [float(v) for v in values.split(",")]
        except ValueError:
            raise InputError("--param", f"{name}: values must be numbers, got {values!r}") from None
        if not all(math.isfinite(v) for v in nums):
            raise InputError("--param", f"{name}: values must be finite, got {values!r}")
        if name in grid:
            raise InputError("--param", f"{name} is given twice; give its values once, comma-separated")
        grid[name] = nums
    if math.prod(len(v) for v in grid.values()) > MAX_POINTS:
        raise InputError("--param", f"the grid has more than {MAX_POINTS:,} points; give fewer values")
    return grid


def run_policy(run: Path, params: list[str], json_out: bool) -> None:
    """Answer the grid of ``params`` with the run's trained policy; exit 3 when a point's gains fail."""
    grid = parse_params(params)
    from gaintune.search.policy import PolicyTuner  # torch + SB3: only once the input is known good

    answers = PolicyTuner.from_run(run).schedule(grid)
    if json_out:
        print(json.dumps([a.model_dump(mode="json") for a in answers], indent=2))
    else:
        _print_answers(answers)
    if any(a.verdict != "pass" for a in answers):
        raise typer.Exit(EXIT_VERIFY)


def _print_answers(answers) -> None:
    from rich.table import Table  # deferred: `gaintune verify` loads this module and no table

    names = list(answers[0].params)
    gains = [(loop, g) for loop, gs in answers[0].gains.items() for g in gs]
    table = Table(title="Trained policy: gains per plant (only PASS rows are accepted)")
    for n in names:
        table.add_column(n, justify="right")
    for loop, g in gains:
        table.add_column(f"{loop}.{g}", justify="right")
    for col in ("verdict", "Ms", "PM deg", "answer time ms"):
        table.add_column(col, justify="right")
    for a in answers:
        ok = a.verdict == "pass"
        fig = min(a.verification.loops, key=lambda f: f.pm_deg, default=None)
        cells = [_f(a.params[n]) + ("*" if n in a.outside else "") for n in names]
        # a failed row's gains are shown for diagnosis, struck through: never as an answer
        cells += [(_f(a.gains[loop][g]) if ok else f"[strike]{_f(a.gains[loop][g])}[/strike]") for loop, g in gains]
        cells += ["PASS" if ok else "[bold red]FAIL[/bold red]",
                  _f(max((f.ms for f in a.verification.loops), default=None)), _f(fig.pm_deg if fig else None),
                  f"{a.elapsed_ms:.0f}"]
        table.add_row(*cells)
    out.print(table)
    if any(a.outside for a in answers):
        out.print("* outside the range the policy was trained over: it extrapolates there")
    for a in answers:
        if a.verdict != "pass":
            why = a.verification.reasons[0] if a.verification.reasons else "verification failed"
            out.print(f"FAIL at {a.params}: {why}",
                      markup=False)
