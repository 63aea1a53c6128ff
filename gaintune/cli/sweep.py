"""``gaintune sweep FLEET.yaml`` and ``gaintune sweep summary DIR``: a thin front end over :mod:`gaintune.sweep`.

``gaintune sweep FLEET ...`` is ``gaintune sweep run FLEET ...`` (:class:`_DefaultRun` puts the
``run`` in front of anything that is not a sub-command). Exit codes: 0 every item passed; 2 the
fleet file or an option is invalid (nothing ran; the message names the field); 3 an item failed
verification, or failed to run (its error is in the summary).
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Annotated, Any

import typer
from typer.core import TyperGroup

from gaintune.cli.common import EPILOG, EXIT_VERIFY, InputError, _f, check_out_dir, err, handle_errors, out

__all__ = ["sweep_app"]


class _DefaultRun(TyperGroup):
    """A group whose first argument, when not one of its commands, is the FLEET of ``run``."""

    def parse_args(self, ctx: Any, args: list[str]) -> list[str]:  # ctx: typer's own (vendored) click Context
        if args and args[0] not in self.commands and args[0] not in ("--help", "-h"):
            args = ["run", *args]
        return super().parse_args(ctx, args)


sweep_app = typer.Typer(
    cls=_DefaultRun, no_args_is_help=True, epilog=EPILOG, rich_markup_mode=None,
    help="Tune many problems in one go: 'gaintune sweep FLEET.yaml --out DIR' (resumable), and "
         "'gaintune sweep summary DIR'. See docs/scale.md.")


def _options(backend: str, address: str | None, workers: int | None, cpus_per_task: int, store: str) -> Any:
    from gaintune.sweep import SweepOptions

    if backend not in ("local", "ray"):
        raise InputError("backend", f"must be local or ray, got {backend!r}")
    if store not in ("sqlite", "dir"):
        raise InputError("store", f"must be sqlite or dir, got {store!r}")
    if address is not None and backend != "ray":
        raise InputError("address", "a Ray cluster's address goes with --backend ray; add it, or drop --address")
    if backend == "ray":
        from gaintune.sweep.backends import import_ray

        import_ray()  # a missing install exits 2 here, before anything runs
    return SweepOptions(backend=backend, address=address, workers=workers,  # type: ignore[arg-type]  # checked above
                        cpus_per_task=cpus_per_task, store=store)  # type: ignore[arg-type]  # checked above


def _run_with_bar(fleet: Path, out_dir: Path, options: Any) -> Any:
    """:func:`gaintune.sweep.run_sweep` with a progress bar (items, outcomes, ETA) on stderr."""
    from rich.progress import (
        BarColumn,
        MofNCompleteColumn,
        Progress,
        TextColumn,
        TimeElapsedColumn,
        TimeRemainingColumn,
    )

    from gaintune.sweep import run_sweep

    with Progress(TextColumn("[bold]{task.description}"), BarColumn(), MofNCompleteColumn(), TextColumn("items"),
                  TextColumn("{task.fields[outcomes]}"), TimeElapsedColumn(), TextColumn("ETA"),
                  TimeRemainingColumn(), console=err.real(), transient=False) as bar:
        task = bar.add_task("sweep", total=None, outcomes="")

        def on_start(report: Any, todo: int) -> None:
            skipped = f" ({report.skipped} finished before)" if report.skipped else ""
            bar.update(task, total=todo, description=f"{report.name}{skipped}")

        def on_record(rec: dict[str, Any], report: Any) -> None:
            bar.update(task, completed=report.ran + report.refused,
                       outcomes=", ".join(f"{k} {v}" for k, v in sorted(report.counts.items())))

        try:
            return run_sweep(fleet, out_dir, options, on_record=on_record, on_start=on_start)
        except KeyboardInterrupt:
            err.print(f"interrupted: the finished items are kept in {out_dir}; the same command resumes", markup=False)
            raise typer.Exit(130) from None


@sweep_app.command("run")
@handle_errors
def run_cmd(
    fleet: Annotated[Path, typer.Argument(metavar="FLEET.yaml", help="The fleet file (docs/scale.md).")],
    out_dir: Annotated[Path | None, typer.Option(
        "--out", "-o", help="The sweep folder (store and manifest); the same --out resumes. Default: "
                            "out/sweep/<fleet file name>.")] = None,
    backend: Annotated[str, typer.Option("--backend", help="local (worker processes) or ray.")] = "local",
    address: Annotated[str | None, typer.Option(
        "--address", help="With --backend ray: a running cluster, auto or HOST:PORT (default: $RAY_ADDRESS, else a "
                          "local cluster for this sweep).")] = None,
    workers: Annotated[int | None, typer.Option(
        "--workers", min=1, max=4096, help="Worker processes (local), or the CPUs of a local Ray cluster. Default: "
                                           "this machine's CPUs / --cpus-per-task.")] = None,
    cpus_per_task: Annotated[int, typer.Option("--cpus-per-task", min=1, max=256, help="CPUs per item.")] = 1,
    store: Annotated[str, typer.Option(
        "--store", help="sqlite (OUT/sweep.db) or dir (OUT/results/*.json).")] = "sqlite",
    json_out: Annotated[bool, typer.Option("--json", help="Print the run's report and totals as JSON.")] = False,
) -> None:
    """Run every item of FLEET (a search or a trained-tuner query each); finished items are never run again."""
    options = _options(backend, address, workers, cpus_per_task, store)
    from gaintune.sweep.runner import plan

    plan(fleet)  # a bad fleet file exits 2 here, before any compile or worker
    out_dir = out_dir or Path("out/sweep") / fleet.stem
    check_out_dir(out_dir)
    from gaintune.cli.compiling import compile_simulator

    compile_simulator(None if json_out else err)  # once here, not once per worker
    report = _run_with_bar(fleet, out_dir, options)
    from gaintune.sweep.summary import summary_rows, totals

    _, rows = summary_rows(out_dir)
    t = totals(rows)
    if json_out:
        print(json.dumps({"run": {"ran": report.ran, "skipped": report.skipped, "refused": report.refused,
                                  "wall_s": report.wall_s, "counts": report.counts}, "totals": t}, indent=2))
    else:
        out.print(f"ran {report.ran} items in {report.wall_s:.1f} s ({report.skipped} finished before, not rerun); "
                  f"results in {out_dir}", markup=False, highlight=False)
        _print_totals(t, rows)
    if t["pass"] != t["items"]:
        raise typer.Exit(EXIT_VERIFY)


def _print_totals(t: dict[str, Any], rows: list[dict[str, Any]]) -> None:
    """The totals line, then each item that did not pass (label, outcome, reason)."""
    rate = "-" if t["pass_rate"] is None else f"{100 * t['pass_rate']:.1f} %"
    out.print(f"items {t['items']}: pass {t['pass']}, fail {t['fail']}, error {t['error']}, crashed {t['crashed']}, "
              f"pending {t['pending']}; pass rate {rate}; cost median {_f(t['cost_median'])} (min "
              f"{_f(t['cost_min'])}, max {_f(t['cost_max'])}); {t['sims']:,} simulations", markup=False,
              highlight=False, soft_wrap=True)
    bad = [r for r in rows if r["status"] != "done" or r["verdict"] != "pass"]
    for r in bad[:20]:
        what = r["verdict"] if r["status"] == "done" else r["status"]
        out.print(f"  {what}: {r['label']}: {r['error'] or r['note'] or ''}", markup=False, highlight=False,
                  soft_wrap=True)
    if len(bad) > 20:
        out.print(f"  ... and {len(bad) - 20} more ('gaintune sweep summary DIR --csv F' lists every item)",
                  markup=False)


def _print_rows(rows: list[dict[str, Any]]) -> None:
    from rich.table import Table

    table = Table()
    for col in ("#", "item", "status", "verdict", "cost", "gains", "sims", "s"):
        table.add_column(col, justify="right" if col in ("#", "cost", "sims", "s") else "left")
    for r in rows:
        loops = json.loads(r["gains"] or "{}")
        gains = ", ".join(f"{g if len(loops) == 1 else f'{loop}.{g}'}={_f(v)}"
                          for loop, gs in loops.items() for g, v in gs.items())
        table.add_row(str(r["index"]), r["label"], r["status"], r["verdict"] or "-", _f(r["cost"]),
                      gains if r["status"] == "done" else (r["error"] or "")[:80], str(r["sims"] or "-"),
                      "-" if r["wall_s"] is None else f"{r['wall_s']:.1f}")
    out.print(table)


@sweep_app.command("summary")
@handle_errors
def summary_cmd(
    out_dir: Annotated[Path, typer.Argument(metavar="DIR", help="A sweep folder (the --out of 'gaintune sweep').")],
    csv_path: Annotated[Path | None, typer.Option("--csv", help="Write one row per item as CSV here.")] = None,
    parquet_path: Annotated[Path | None, typer.Option("--parquet", help="Write the rows as Parquet here.")] = None,
    json_out: Annotated[bool, typer.Option("--json", help="Print the totals and the rows as JSON.")] = False,
    items: Annotated[bool, typer.Option("--items", help="Also print the table of every item.")] = False,
) -> None:
    """The sweep's pass rate, costs and gains: totals, the items that did not pass, and exports."""
    from gaintune.cli.common import output_errors
    from gaintune.sweep.summary import summary_rows, totals, write_csv, write_parquet

    if not out_dir.is_dir():
        raise InputError("out", f"{out_dir} is not a folder; give the --out of a sweep")
    manifest, rows = summary_rows(out_dir)
    t = totals(rows)
    for path, write in ((csv_path, write_csv), (parquet_path, write_parquet)):
        if path is not None:
            with output_errors(path, "--csv" if write is write_csv else "--parquet"):
                write(rows, path)
            err.print(f"wrote {path}", markup=False)
    if json_out:
        print(json.dumps({"name": manifest.get("name"), "totals": t, "rows": rows}, indent=2, default=str))
        return
    out.print(f"sweep {manifest.get('name')} ({manifest.get('fleet')})", markup=False, highlight=False)
    if items:
        _print_rows(rows)
    _print_totals(t, rows)
