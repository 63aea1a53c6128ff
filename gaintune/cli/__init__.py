"""``gaintune``: thin command-line front end over the library (typer + rich).

Exit codes: 0 success, 2 invalid input (the message names the field),
3 verification failed. See ``docs/cli.md``.

This package holds the typer :data:`app` and its commands; its modules hold the rest:

* :mod:`gaintune.cli.common`: exit codes, consoles, error handling
  (:func:`handle_errors`, :class:`InputError`), input loading and formatting helpers;
* :mod:`gaintune.cli.output`: result summaries, tables, plots and ``--out`` folders;
* :mod:`gaintune.cli.tuning`: running a tune with its progress bar (``tune``, ``demo``);
* :mod:`gaintune.cli.exporting`: the verdict gate of ``export``;
* :mod:`gaintune.cli.tuner`: the ``tuner`` sub-app (train, query, list, update, schedule) and
  :mod:`gaintune.cli.schedule`, its ``schedule`` command;
* :mod:`gaintune.cli.bench`: the ``bench`` sub-app (:data:`BENCH`);
* :mod:`gaintune.cli.entry`: :data:`app`'s class, which ends a command run as the program
  without interpreter teardown (0.9 s after a tune).

``python -m gaintune.cli`` runs :data:`app` (``gaintune/cli/__main__.py``).
"""

from __future__ import annotations

import importlib  # noqa: F401 - gaintune.cli.importlib: tests replace importlib.import_module through it
import json
import sys
from pathlib import Path
from typing import Annotated

import typer

from gaintune.cli.bench import BENCH, bench_app  # noqa: F401 - BENCH: gaintune.cli.BENCH (tests)
from gaintune.cli.common import (
    EPILOG,
    EXIT_INPUT,
    EXIT_OK,
    EXIT_VERIFY,
    InputError,
    _command_line,
    apply_overrides,
    check_out_dir,
    err,
    handle_errors,
    load_gains,
    load_result,
    load_spec_file,
    out,
    output_errors,
    reverify_result,
)
from gaintune.cli.entry import GaintuneTyper
from gaintune.cli.exporting import _checked_at_dt
from gaintune.cli.output import (
    _plot_runs,
    _print_plant,
    _print_plants,
    _print_simulation,
    _simulation_json,
    _write_outputs,  # noqa: F401 - gaintune.cli._write_outputs, used by tests
)
from gaintune.cli.sweep import sweep_app
from gaintune.cli.tuner import tuner_app

# the commands call _get_tune through this module, so gaintune.cli._get_tune can be replaced (tests do)
from gaintune.cli.tuning import _check_quick_options, _finish, _get_tune, _run_tune, demo_spec, run_quick
from gaintune.search.algos import ALGO_NAMES

__all__ = ["app", "EXIT_OK", "EXIT_INPUT", "EXIT_VERIFY"]

app = GaintuneTyper(
    name="gaintune",
    help="RL-based controller gain tuning with frozen-gain verification.",
    epilog=EPILOG,
    no_args_is_help=True,
    add_completion=False,
    pretty_exceptions_enable=False,
    rich_markup_mode=None,
)
plants_app = typer.Typer(help="Built-in plant models: 'gaintune plants' lists them, 'gaintune plants show NAME' "
                         "shows one.", invoke_without_command=True, epilog=EPILOG)
app.add_typer(plants_app, name="plants")
app.add_typer(bench_app, name="bench")
app.add_typer(tuner_app, name="tuner")
app.add_typer(sweep_app, name="sweep")


# --------------------------------------------------------------- commands

@app.command()
@handle_errors
def tune(
    spec_path: Annotated[Path, typer.Argument(metavar="SPEC", help="Tuning spec (YAML or JSON).")],
    out_dir: Annotated[Path | None, typer.Option(
        "--out", "-o", help="Write result.json, report.html, gains.{json,yaml,h,m} and the agent here.")] = None,
    json_out: Annotated[bool, typer.Option(
        "--json", help="Print the result JSON on stdout (no progress bar).")] = False,
    algo: Annotated[str | None, typer.Option("--algo", help=f"Override search.algo ({', '.join(ALGO_NAMES)}).")] = None,
    budget: Annotated[int | None, typer.Option("--budget", help="Override search.budget (simulations).")] = None,
    seed: Annotated[int | None, typer.Option("--seed", help="Override search.seed.")] = None,
    workers: Annotated[int | None, typer.Option(
        "--workers", help="Override search.n_envs (parallel environments).")] = None,
    baselines: Annotated[bool, typer.Option(
        "--baselines", help="Also run the baselines for comparison (in the result and report).")] = False,
    warm_start: Annotated[Path | None, typer.Option(
        "--warm-start", metavar="AGENT.zip",
        help="Continue training a saved agent (a tune's agent.zip) on this spec: same loops and randomised "
             "parameters.")] = None,
    quick: Annotated[bool, typer.Option(
        "--quick", help="No search: fit the loop's FOTD/SOTD model, ask the ready-made tuner, settle and verify on "
                        "the true plant, and show the answer beside AMIGO and SIMC (one SISO PI/PID loop).")] = False,
    refine: Annotated[int | None, typer.Option(
        "--refine", min=0, max=100_000, help="With --quick: simulations of the local refinement after the settling "
                                             "(default 300; 0: none).")] = None,
    compare_search: Annotated[int | None, typer.Option(
        "--compare-search", min=10, metavar="BUDGET",
        help="With --quick: also run the search with this budget and show its answer in the comparison.")] = None,
    tuners: Annotated[Path | None, typer.Option(
        "--tuners", metavar="DIR", help="With --quick: a folder of tuner folders to choose from (default: the "
                                        "shipped tuners).")] = None,
) -> None:
    """Tune the gains of SPEC with RL, verify them and print a summary. Exit 3 if verification fails."""
    spec = apply_overrides(load_spec_file(spec_path), algo=algo, budget=budget, seed=seed, workers=workers)
    if out_dir is not None:
        check_out_dir(out_dir)
    if quick:
        _quick(spec, spec_path, out_dir=out_dir, json_out=json_out, seed=seed, refine=refine,
               compare_search=compare_search, tuners=tuners,
               search_options=dict(algo=algo, budget=budget, workers=workers, baselines=baselines,
                                   warm_start=warm_start))
        return
    for name, value in (("refine", refine), ("compare_search", compare_search), ("tuners", tuners)):
        if value is not None:
            raise InputError(name, f"--{name.replace('_', '-')} goes with --quick; add --quick, or drop it")
    command = _command_line("tune", spec_path, algo=algo, budget=budget, seed=spec.search.seed, workers=workers,
                            baselines=baselines, warm_start=warm_start)
    result = _run_tune(_get_tune(), spec, out_dir=out_dir, json_out=json_out, baselines=baselines, command=command,
                       warm_start=warm_start)
    _finish(result, out_dir=out_dir, json_out=json_out, command=command)


def _quick(spec, spec_path: Path, *, out_dir: Path | None, json_out: bool, seed: int | None, refine: int | None,
           compare_search: int | None, tuners: Path | None, search_options: dict) -> None:
    """``tune --quick``: refuse the search's options, then :func:`gaintune.cli.tuning.run_quick`."""
    from gaintune.tuners.quick import DEFAULT_REFINE

    _check_quick_options(**search_options)
    if tuners is not None and not tuners.is_dir():
        raise InputError("tuners", f"{tuners} is not a folder; give a folder of tuner folders (each with tuner.json)")
    command = _command_line("tune", spec_path, quick=True, seed=seed, refine=refine, compare_search=compare_search,
                            tuners=tuners)
    run_quick(spec, out_dir=out_dir, json_out=json_out, tuners=tuners,
              refine=DEFAULT_REFINE if refine is None else refine, compare_search=compare_search or 0,
              command=command)


@app.command()
@handle_errors
def demo(
    out_dir: Annotated[Path, typer.Option("--out", "-o", help="Output folder.")] = Path("out/demo"),
    budget: Annotated[int | None, typer.Option("--budget", help="Override the search budget (simulations).")] = None,
    seed: Annotated[int | None, typer.Option("--seed")] = None,
    json_out: Annotated[bool, typer.Option("--json", help="Print the result JSON on stdout.")] = False,
) -> None:
    """Tune the built-in demo loop (PID on 1/(s+1)^3), verify it and write result, report and exports to --out."""
    spec = demo_spec(budget, seed)
    check_out_dir(out_dir)
    command = _command_line("demo", budget=budget, seed=spec.search.seed)
    result = _run_tune(_get_tune(), spec, out_dir=out_dir, json_out=json_out, baselines=False, command=command)
    _finish(result, out_dir=out_dir, json_out=json_out, command=command)
    if not json_out:
        out.print(f"open {out_dir / 'report.html'} in a browser")


@app.command()
@handle_errors
def verify(
    spec_path: Annotated[Path, typer.Argument(metavar="SPEC", help="Tuning spec (YAML or JSON).")],
    gains: Annotated[str, typer.Option(
        "--gains", "-g", help="Gains: a JSON/YAML file (or result.json), or inline JSON '{\"loop0\": {\"Kp\": 1}}'.")],
    json_out: Annotated[bool, typer.Option(
        "--json", help="Print the VerificationReport JSON instead of the table.")] = False,
    robust: Annotated[bool | None, typer.Option(
        "--robust/--no-robust",
        help="Force the robust check on/off (default: when the spec randomises the plant).")] = None,
) -> None:
    """Verify GAINS against SPEC's requirements and print the table. Exit 3 if they fail."""
    from gaintune.verification import format_table
    from gaintune.verification import verify as run_verify

    spec = load_spec_file(spec_path)
    rep = run_verify(spec, load_gains(gains), robust=robust)
    if json_out:
        sys.stdout.write(rep.model_dump_json(indent=2) + "\n")
    else:
        sys.stdout.write(format_table(rep) + "\n")
    if rep.verdict != "pass":
        raise typer.Exit(EXIT_VERIFY)


@app.command()
@handle_errors
def simulate(
    spec_path: Annotated[Path, typer.Argument(metavar="SPEC", help="Tuning spec (YAML or JSON).")],
    gains: Annotated[str, typer.Option("--gains", "-g", help="Gains file or inline JSON.")],
    plot: Annotated[Path | None, typer.Option(
        "--plot", help="Save the time responses of every scenario to this PNG/SVG/PDF.")] = None,
    json_out: Annotated[bool, typer.Option("--json", help="Print the metrics as JSON.")] = False,
    traces: Annotated[bool, typer.Option("--traces", help="With --json: include the time traces.")] = False,
) -> None:
    """Simulate GAINS on every scenario of SPEC (nominal plant) and print the metrics."""
    from gaintune.sim import Simulator
    from gaintune.sim.chatter import saturation_switches

    sim = Simulator(load_spec_file(spec_path))
    spec = sim.spec  # scenario dt/horizon derived from the plant where the spec left them out
    full = sim.layout.from_dict(load_gains(gains))
    results = [sim.run(full[None], scenario=i, traces=True) for i in range(len(spec.scenarios))]
    switches = [saturation_switches(r.traces["u"][0], spec.actuator.limits) for r in results]
    if json_out:
        sys.stdout.write(json.dumps(_simulation_json(results, switches, traces=traces), indent=2) + "\n")
    else:
        _print_simulation(spec, results, switches)
    if plot is not None:
        _plot_runs(spec, sim, results, plot)
        (err if json_out else out).print(f"wrote {plot}")


@app.command()
@handle_errors
def report(
    result_path: Annotated[Path, typer.Argument(
        metavar="RESULT.json", help="A result.json written by 'gaintune tune --out'.")],
    output: Annotated[Path, typer.Option("--output", "-o", help="HTML file to write.")] = Path("report.html"),
    pdf: Annotated[bool, typer.Option("--pdf", help="Also print it to PDF (needs /usr/bin/chromium).")] = False,
) -> None:
    """Render the self-contained HTML report of a result (and a PDF with --pdf). The gains are verified again first."""
    from gaintune.report import ReportError, render_pdf, render_report

    result = load_result(result_path)
    reverify_result(result, result_path)  # the page shows the verdict of the gains, never the file's claim
    with output_errors(output):
        path = render_report(result, output)
    out.print(f"wrote {path}")
    if pdf:
        try:
            p = render_pdf(path, path.with_suffix(".pdf"))
        except ReportError as exc:
            err.print(f"error: {exc.message}", markup=False)
            raise typer.Exit(1) from None
        out.print(f"wrote {p}")


@plants_app.callback()
@handle_errors
def plants(ctx: typer.Context) -> None:
    """List the built-in plant models (``gaintune plants show NAME`` for one)."""
    if ctx.invoked_subcommand is not None:
        return
    _print_plants()


@plants_app.command("show")
@handle_errors
def plants_show(name: Annotated[str, typer.Argument(help="Model name, e.g. dc_motor.")],
                spec: Annotated[bool, typer.Option("--spec", help="Print only the example spec, as YAML (e.g. "
                                                   "'gaintune plants show dc_motor --spec > spec.yaml').")] = False,
                ) -> None:
    """Show one model: parameters with units, outputs and a ready-to-run example spec."""
    from gaintune.plants.library import load_model

    model = load_model(name)
    if spec:
        import yaml

        sys.stdout.write(yaml.safe_dump(model.example_spec(), sort_keys=False, width=1000))
        return
    _print_plant(model)


@app.command()
@handle_errors
def export(
    result_path: Annotated[Path, typer.Argument(
        metavar="RESULT.json", help="A result.json written by 'gaintune tune --out'.")],
    fmt: Annotated[str, typer.Option("--format", "-f", help="json | yaml | c | matlab | python")] = "json",
    dt: Annotated[float | None, typer.Option("--dt",
        help="Sample time (s) of the exported discrete controller. Default: the dt the result was verified at "
             "(its largest scenario dt). The gains are verified again at this dt before anything is written.")] = None,
    output: Annotated[Path | None, typer.Option("--output", "-o", help="File to write (default: stdout).")] = None,
    allow_unverified: Annotated[bool, typer.Option("--allow-unverified",
        help="Export gains whose verdict at this dt is not PASS (the file is then marked FAILED, with the "
             "reason).")] = False,
    force: Annotated[bool, typer.Option("--force", hidden=True, help="Old name of --allow-unverified.")] = False,
) -> None:
    """Export the gains of a result as JSON, YAML, a C header, a MATLAB/Octave snippet or a Python dict.

    The file carries the verification verdict AT the exported sample time: the gains are verified
    again at that dt first (a verdict stored in the result file is never trusted).
    Exit 3 (nothing written) when that verdict is not PASS, unless --allow-unverified.
    """
    from gaintune.export import FORMATS, export_result

    fmt = fmt.lower()
    if fmt not in FORMATS:
        raise InputError("format", f"unknown format {fmt!r}; choose from {', '.join(FORMATS)}")
    result = load_result(result_path)
    at, checked = _checked_at_dt(result, dt, allow_unverified=allow_unverified or force)
    text = export_result(result, fmt, dt=at, checked=checked)
    if output is None:
        sys.stdout.write(text)
    else:
        from gaintune.files import write_atomic

        with output_errors(output):
            output.parent.mkdir(parents=True, exist_ok=True)
            write_atomic(output, text)  # a symlink at --output is replaced, never written through
        err.print(f"wrote {output}")


@app.command()
def serve(
    host: Annotated[str, typer.Option("--host")] = "127.0.0.1",
    port: Annotated[int, typer.Option("--port", min=0, max=65535)] = 8000,
    workers: Annotated[int, typer.Option(
        "--workers", min=0, max=64, help="Worker processes for tuning jobs (0: none).")] = 1,
) -> None:
    """Run the REST API (FastAPI app in api/)."""
    import socket

    from gaintune.cli import entry

    try:  # an unknown host otherwise surfaces as a logged traceback from the server's start-up
        socket.getaddrinfo(host, port)
    except (socket.gaierror, UnicodeError) as exc:
        err.print(f"error: host: cannot resolve {host!r} ({exc}); give an address such as 127.0.0.1", markup=False)
        raise typer.Exit(EXIT_INPUT) from None

    entry.FAST_EXIT = False  # a server's shutdown is not start-up time: the ordinary interpreter exit
    try:
        from gaintune_api.main import serve as run_server
    except ImportError as exc:
        err.print(f"error: the REST API (gaintune_api.main.serve) is not available: {exc}", markup=False)
        raise typer.Exit(1) from None
    run_server(host, port, workers)


def main() -> None:  # pragma: no cover - console entry
    """The ``gaintune`` console command."""
    app()
