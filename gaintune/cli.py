"""``gaintune``: thin command-line front end over the library (typer + rich).

Exit codes: 0 success, 2 invalid input (the message names the field),
3 verification failed. See ``docs/cli.md``.
"""

from __future__ import annotations

import functools
import importlib
import json
import math
import shlex
import sys
from pathlib import Path
from typing import Any, Callable, Optional

import typer
from rich.console import Console
from rich.table import Table

from gaintune.fmt import fmt

__all__ = ["app", "EXIT_OK", "EXIT_INPUT", "EXIT_VERIFY"]

EXIT_OK, EXIT_INPUT, EXIT_VERIFY = 0, 2, 3

EPILOG = (
    "Exit codes: 0 success; 2 invalid input (spec, gains or file: the message names the field); "
    "3 verification failed (the gains are not accepted). Docs: docs/cli.md"
)

app = typer.Typer(
    name="gaintune",
    help="RL-based controller gain tuning with frozen-gain verification.",
    epilog=EPILOG,
    no_args_is_help=True,
    add_completion=False,
    pretty_exceptions_enable=False,
    rich_markup_mode=None,
)
plants_app = typer.Typer(help="Built-in plant models: list them, or show one.", invoke_without_command=True, epilog=EPILOG)
bench_app = typer.Typer(help="Benchmarks (arguments after the command are passed through; --help shows each benchmark's own options).",
                        no_args_is_help=True, epilog=EPILOG)
app.add_typer(plants_app, name="plants")
app.add_typer(bench_app, name="bench")

out = Console()
err = Console(stderr=True, soft_wrap=True)


class InputError(Exception):
    """Bad user input found by the CLI itself (file missing, unreadable gains, ...)."""

    def __init__(self, field: str, message: str) -> None:
        super().__init__(f"{field}: {message}")
        self.field, self.message = field, message


def _problem_lines(exc: BaseException) -> list[str]:
    from gaintune.errors import problem_details

    if isinstance(exc, InputError):
        return [f"{exc.field}: {exc.message}"]
    return [f"{d['loc']}: {d['msg']}" if d["loc"] else d["msg"] for d in problem_details(exc)]


def _input_errors() -> tuple[type[BaseException], ...]:
    import yaml
    from pydantic import ValidationError

    from gaintune.errors import GaintuneError

    return (InputError, GaintuneError, ValidationError, yaml.YAMLError, json.JSONDecodeError, FileNotFoundError, IsADirectoryError)


def handle_errors(fn: Callable) -> Callable:
    """Bad input -> ``error: <field>: <message>`` lines on stderr and exit 2, never a traceback."""

    @functools.wraps(fn)
    def wrapper(*args: Any, **kwargs: Any) -> Any:
        try:
            return fn(*args, **kwargs)
        except typer.Exit:
            raise
        except _input_errors() as exc:
            for line in _problem_lines(exc):
                err.print(f"error: {line}", markup=False, highlight=False)
            raise typer.Exit(EXIT_INPUT) from None
        except KeyboardInterrupt:
            err.print("interrupted", markup=False)
            raise typer.Exit(130) from None

    return wrapper


# ----------------------------------------------------------------- inputs


def _read_file(path: Path, field: str) -> str:
    if not path.exists():
        raise InputError(field, f"file not found: {path}")
    if path.is_dir():
        raise InputError(field, f"{path} is a directory, expected a file")
    try:
        return path.read_text()
    except (OSError, UnicodeDecodeError) as exc:
        raise InputError(field, f"cannot read {path}: {exc}") from None


def _parse_mapping(text: str, field: str) -> Any:
    import yaml

    try:
        return json.loads(text) if text.lstrip().startswith(("{", "[")) else yaml.safe_load(text)
    except (yaml.YAMLError, json.JSONDecodeError) as exc:
        raise InputError(field, f"not valid JSON/YAML: {exc}") from None


def load_spec_file(path: Path):
    from gaintune.spec import load_spec

    data = _parse_mapping(_read_file(path, "spec"), "spec")
    if not isinstance(data, dict):
        raise InputError("spec", "must be a mapping with at least 'plant' and 'loops'")
    return load_spec(data)


def load_gains(value: str) -> dict[str, dict[str, float]]:
    """``--gains``: a JSON/YAML file (a result.json's ``gains`` is taken) or inline JSON."""
    text = value
    if not value.lstrip().startswith("{"):
        text = _read_file(Path(value), "gains")
    data = _parse_mapping(text, "gains")
    if isinstance(data, dict) and "gains" in data and isinstance(data["gains"], dict):
        data = data["gains"]
    if not isinstance(data, dict):
        raise InputError("gains", "must be a mapping {loop: {gain: value}} (JSON or YAML)")
    return data


def load_result(path: Path):
    from pydantic import ValidationError

    from gaintune.search.result import TuneResult

    text = _read_file(path, "result")
    try:
        return TuneResult.model_validate_json(text)
    except ValidationError as exc:
        if any(e["type"] == "json_invalid" for e in exc.errors()):
            raise InputError("result", f"{path} is not valid JSON") from None
        raise


def apply_overrides(spec, *, algo: str | None = None, budget: int | None = None, seed: int | None = None, workers: int | None = None):
    """Override ``search`` settings and re-validate the whole spec."""
    from gaintune.spec import TuningSpec

    upd: dict[str, Any] = {}
    if algo is not None:
        upd["algo"] = algo
    if budget is not None:
        upd["budget"] = budget
    if seed is not None:
        upd["seed"] = seed
    if workers is not None:
        upd["n_envs"] = workers
    if not upd:
        return spec
    data = spec.model_dump()
    data["search"] = {**data["search"], **upd}
    return TuningSpec.model_validate(data)


def _command_line(*parts: Any, **options: Any) -> str:
    """The command that re-runs this result: positional parts, then the options that were given."""
    words = ["gaintune", *[str(p) for p in parts]]
    for k, v in options.items():
        if v is None or v is False:
            continue
        words.append(f"--{k.replace('_', '-')}")
        if v is not True:
            words.append(str(v))
    return shlex.join(words)


# --------------------------------------------------------------- output


_f = fmt  # one formatter for every table (gaintune.fmt)


def _print_summary(result, console: Console = out) -> None:
    from gaintune.report import load_verification

    verdict = result.verdict
    passed = verdict == "pass"
    title = "Accepted gains" if passed else ("Gains - FAILED verification, NOT accepted" if verdict == "fail" else "Gains (unverified)")
    t = Table(title=title, title_style="bold green" if passed else "bold red")
    t.add_column("loop")
    t.add_column("gain")
    t.add_column("value", justify="right")
    for loop, g in result.gains.items():
        for k, v in g.items():
            t.add_row(loop, k, _f(v, 6))
    console.print(t)
    if result.verification:
        rep = load_verification(result.verification)
        m = Table(title="Margins per loop (nominal)")
        for c in ("loop", "break", "GM dB", "PM deg", "wc rad/s", "DM s", "Ms", "Mt"):
            m.add_column(c, justify="left" if c in ("loop", "break") else "right")
        for f in rep.loops:
            m.add_row(f.loop, "ctrl" if f.break_point == "controller_output" else "u", _f(f.gm_db, 3), _f(f.pm_deg, 3),
                      _f(f.pm_freq, 3), _f(f.delay_margin, 3), _f(f.ms, 3), _f(f.mt, 3))
        console.print(m)
        if rep.requirements:
            q = Table(title="Requirements")
            for c in ("requirement", "value", "limit", "result", "at"):
                q.add_column(c)
            for r in rep.requirements:
                q.add_row(r.requirement, _f(r.value), _f(r.limit), "[green]pass[/]" if r.passed else "[red]FAIL[/]",
                          f"{r.loop}/{r.break_point}/{r.case}" if r.loop else r.case)
            console.print(q)
    if result.metrics:
        keys = ("iae", "overshoot", "rise_time", "settling_time", "sse", "peak_u")
        mt = Table(title="Metrics (nominal plant)")
        mt.add_column("scenario")
        for k in keys:
            mt.add_column(k, justify="right")
        for sc, vals in result.metrics.items():
            mt.add_row(sc, *[_f(vals.get(k)) for k in keys])
        console.print(mt)
    console.print(f"cost {_f(result.cost)} (plain objective) after {result.sims} simulations in {result.wall_time:.1f} s "
                  f"({result.algo}, stopped: {result.stopped})")
    if verdict == "pass":
        console.print("[bold green]verdict: PASS[/]")
    elif verdict == "fail":
        console.print("[bold red]verdict: FAILED[/] - the gains are not accepted")
        for r in (result.verification or {}).get("reasons", []):
            console.print(f"  - {r}", markup=False)
    else:
        console.print("verdict: not verified")
    if result.diagnosis is not None:
        console.print(result.diagnosis.summary, markup=False)
        for h in result.diagnosis.hints:
            console.print(f"  hint: {h}", markup=False)


def _write_outputs(result, out_dir: Path, console: Console = out) -> None:
    from gaintune.export import write_exports
    from gaintune.report import render_report

    out_dir.mkdir(parents=True, exist_ok=True)
    (out_dir / "result.json").write_text(result.model_dump_json(indent=2))
    render_report(result, out_dir / "report.html")
    paths = write_exports(result, out_dir)
    console.print(f"wrote {out_dir / 'result.json'}, {out_dir / 'report.html'}, " + ", ".join(str(p) for p in paths))
    withheld = getattr(paths, "withheld", [])
    if withheld:
        why = getattr(paths, "reason", None) or "no reason recorded"
        verdict = getattr(paths, "verdict", None) or "unverified"
        console.print(f"not written: {', '.join(withheld)} - the gains are not accepted (verdict {verdict}: {why}); "
                      "gains.json/gains.yaml are marked accepted: false", markup=False, highlight=False)
        for p in getattr(paths, "removed", []):
            console.print(f"removed stale {p} from an earlier run", markup=False, highlight=False)


def _get_tune() -> Callable:
    try:
        from gaintune.search import tune
    except ImportError as exc:
        err.print(f"error: the RL search (gaintune.search.tune) is not available: {exc}", markup=False)
        raise typer.Exit(1) from None
    return tune


def _run_tune(spec, *, out_dir: Path | None, json_out: bool, baselines: bool, command: str) -> Any:
    tune = _get_tune()
    kwargs: dict[str, Any] = dict(out_dir=str(out_dir) if out_dir else None, verify=True, baselines=baselines)
    import inspect

    try:
        if "command" in inspect.signature(tune).parameters:
            kwargs["command"] = command
    except (TypeError, ValueError):  # pragma: no cover - not introspectable
        pass
    if json_out:
        return tune(spec, progress=None, **kwargs)
    from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn

    with Progress(
        TextColumn("[bold]{task.description}"), BarColumn(), MofNCompleteColumn(), TextColumn("sims"),
        TextColumn("best cost {task.fields[best]}"), TextColumn("ETA {task.fields[eta]}"), TimeElapsedColumn(),
        console=err, transient=False,
    ) as bar:
        task = bar.add_task(f"tuning {spec.name} ({spec.search.algo})", total=spec.search.budget, best="-", eta="-")

        def progress(p) -> bool:
            bar.update(task, completed=min(p.sims, p.budget), total=p.budget, description=f"{p.phase} ({spec.search.algo})",
                       best=_f(p.best_cost), eta="-" if p.eta is None else f"{p.eta:.0f}s")
            return True

        return tune(spec, progress=progress, **kwargs)


def _finish(result, *, out_dir: Path | None, json_out: bool, command: str) -> None:
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


# --------------------------------------------------------------- commands

ALGOS = ("ppo", "sac", "td3", "a2c", "ddpg")


@app.command()
@handle_errors
def tune(
    spec_path: Path = typer.Argument(..., metavar="SPEC", help="Tuning spec (YAML or JSON)."),
    out_dir: Optional[Path] = typer.Option(None, "--out", "-o", help="Write result.json, report.html, gains.{json,yaml,h,m} and the agent here."),
    json_out: bool = typer.Option(False, "--json", help="Print the result JSON on stdout (no progress bar)."),
    algo: Optional[str] = typer.Option(None, "--algo", help=f"Override search.algo ({', '.join(ALGOS)})."),
    budget: Optional[int] = typer.Option(None, "--budget", help="Override search.budget (simulations)."),
    seed: Optional[int] = typer.Option(None, "--seed", help="Override search.seed."),
    workers: Optional[int] = typer.Option(None, "--workers", help="Override search.n_envs (parallel environments)."),
    baselines: bool = typer.Option(False, "--baselines", help="Also run the baselines for comparison (in the result and report)."),
) -> None:
    """Tune the gains of SPEC with RL, verify them and print a summary. Exit 3 if verification fails."""
    spec = apply_overrides(load_spec_file(spec_path), algo=algo, budget=budget, seed=seed, workers=workers)
    command = _command_line("tune", spec_path, algo=algo, budget=budget, seed=spec.search.seed, workers=workers, baselines=baselines)
    result = _run_tune(spec, out_dir=out_dir, json_out=json_out, baselines=baselines, command=command)
    _finish(result, out_dir=out_dir, json_out=json_out, command=command)


def demo_spec(budget: int | None = None, seed: int | None = None):
    """The built-in demo problem: PID on the ``lag_n`` model 1/(s+1)^3 (fast to tune)."""
    from gaintune.plants.library import load_model
    from gaintune.spec import load_spec

    spec = load_spec(load_model("lag_n").example_spec())
    spec = apply_overrides(spec, budget=budget, seed=seed)
    return spec


@app.command()
@handle_errors
def demo(
    out_dir: Path = typer.Option(Path("out/demo"), "--out", "-o", help="Output folder."),
    budget: Optional[int] = typer.Option(None, "--budget", help="Override the search budget (simulations)."),
    seed: Optional[int] = typer.Option(None, "--seed"),
    json_out: bool = typer.Option(False, "--json", help="Print the result JSON on stdout."),
) -> None:
    """Tune the built-in demo loop (PID on 1/(s+1)^3), verify it and write result, report and exports to --out."""
    spec = demo_spec(budget, seed)
    command = _command_line("demo", budget=budget, seed=spec.search.seed)
    result = _run_tune(spec, out_dir=out_dir, json_out=json_out, baselines=False, command=command)
    _finish(result, out_dir=out_dir, json_out=json_out, command=command)
    if not json_out:
        out.print(f"open {out_dir / 'report.html'} in a browser")


@app.command()
@handle_errors
def verify(
    spec_path: Path = typer.Argument(..., metavar="SPEC", help="Tuning spec (YAML or JSON)."),
    gains: str = typer.Option(..., "--gains", "-g", help="Gains: a JSON/YAML file (or result.json), or inline JSON '{\"loop0\": {\"Kp\": 1}}'."),
    json_out: bool = typer.Option(False, "--json", help="Print the VerificationReport JSON instead of the table."),
    robust: Optional[bool] = typer.Option(None, "--robust/--no-robust", help="Force the robust check on/off (default: when the spec randomises the plant)."),
) -> None:
    """Verify GAINS against SPEC's requirements and print the table. Exit 3 if they fail."""
    from gaintune.verify import format_table
    from gaintune.verify import verify as run_verify

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
    spec_path: Path = typer.Argument(..., metavar="SPEC", help="Tuning spec (YAML or JSON)."),
    gains: str = typer.Option(..., "--gains", "-g", help="Gains file or inline JSON."),
    plot: Optional[Path] = typer.Option(None, "--plot", help="Save the time responses of every scenario to this PNG/SVG/PDF."),
    json_out: bool = typer.Option(False, "--json", help="Print the metrics as JSON."),
    traces: bool = typer.Option(False, "--traces", help="With --json: include the time traces."),
) -> None:
    """Simulate GAINS on every scenario of SPEC (nominal plant) and print the metrics."""
    from gaintune.sim import Simulator
    from gaintune.sim.chatter import CHATTER_SWITCHES, saturation_switches

    spec = load_spec_file(spec_path)
    sim = Simulator(spec)
    full = sim.layout.from_dict(load_gains(gains))
    results = [sim.run(full[None], scenario=i, traces=True) for i in range(len(spec.scenarios))]
    switches = [saturation_switches(r.traces["u"][0], spec.actuator.limits) for r in results]
    if json_out:
        doc = {}
        for r, n in zip(results, switches):
            d: dict[str, Any] = {"metrics": {k: _json_num(v[0]) for k, v in r.metrics.items()}}
            d["metrics"].update(saturation_switches=n, chattering=n >= CHATTER_SWITCHES)
            if traces:
                d["t"] = r.t.tolist()
                d["traces"] = {k: [_json_num(x) for x in v[0]] for k, v in r.traces.items()}
            doc[r.scenario] = d
        sys.stdout.write(json.dumps(doc, indent=2) + "\n")
    else:
        keys = ("iae", "ise", "itae", "effort", "tv", "overshoot", "rise_time", "settling_time", "sse", "peak_u", "sat_frac",
                "load_iae", "diverged", "tripped")
        t = Table(title=f"Simulation of {spec.name!r} (nominal plant)")
        t.add_column("metric")
        for r in results:
            t.add_column(r.scenario, justify="right")
        for k in keys:
            t.add_row(k, *[str(bool(r.metrics[k][0])) if r.metrics[k].dtype == bool else _f(float(r.metrics[k][0])) for r in results])
        t.add_row("saturation_switches", *[str(n) for n in switches])
        t.add_row("chattering", *[str(n >= CHATTER_SWITCHES) for n in switches])
        out.print(t)
        for r, n in zip(results, switches):
            if n >= CHATTER_SWITCHES:
                out.print(f"warning: scenario {r.scenario!r}: the actuator chatters between its limits ({n} limit-to-limit "
                          "switches); the run is bounded but this is not a working loop", markup=False)
    if plot is not None:
        _plot_runs(spec, sim, results, plot)
        (err if json_out else out).print(f"wrote {plot}")


def _json_num(x: Any) -> Any:
    x = x.item() if hasattr(x, "item") else x
    if isinstance(x, float) and not math.isfinite(x):
        return None
    return x


def _plot_runs(spec, sim, results, path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    L = len(spec.loops)
    n = len(results)
    fig, axes = plt.subplots(L + 1, n, figsize=(6 * n, 2.0 * (L + 1) + 0.5), squeeze=False, sharex="col")
    for j, r in enumerate(results):
        for i, lp in enumerate(spec.loops):
            ax = axes[i, j]
            ax.plot(r.t, r.traces[f"sp.{lp.name}"][0], "k--", lw=1, label="setpoint")
            ax.plot(r.t, r.traces[f"y.{lp.name}"][0], lw=1.4, label=lp.name)
            ax.set_ylabel(lp.measure or sim.plant.outputs[0])
            ax.legend(fontsize=8)
            ax.grid(alpha=0.3)
        ax = axes[L, j]
        ax.plot(r.t, r.traces["u"][0], "r", lw=1.2)
        if spec.actuator.limits:
            for v in spec.actuator.limits:
                ax.axhline(v, color="k", ls=":")
        ax.set_ylabel("u")
        ax.set_xlabel("time [s]")
        ax.grid(alpha=0.3)
        axes[0, j].set_title(r.scenario)
    fig.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    try:
        fig.savefig(path)
    except ValueError as exc:  # unknown extension
        raise InputError("plot", str(exc)) from None
    finally:
        plt.close(fig)


@app.command()
@handle_errors
def report(
    result_path: Path = typer.Argument(..., metavar="RESULT.json", help="A result.json written by 'gaintune tune --out'."),
    output: Path = typer.Option(Path("report.html"), "--output", "-o", help="HTML file to write."),
    pdf: bool = typer.Option(False, "--pdf", help="Also print it to PDF (needs /usr/bin/chromium)."),
) -> None:
    """Render the self-contained HTML report of a result (and a PDF with --pdf)."""
    from gaintune.report import ReportError, render_pdf, render_report

    result = load_result(result_path)
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
def plants(ctx: typer.Context) -> None:
    """List the built-in plant models (``gaintune plants show NAME`` for one)."""
    if ctx.invoked_subcommand is not None:
        return
    from gaintune.plants.library import list_models, load_model

    t = Table(title="Built-in plant models (use in a spec as plant: {model: NAME})")
    t.add_column("name", style="bold")
    t.add_column("title")
    t.add_column("parameters")
    t.add_column("outputs")
    for name in list_models():
        m = load_model(name)
        t.add_row(name, m.title, ", ".join(m.parameters), ", ".join(m.outputs))
    out.print(t)


@plants_app.command("show")
@handle_errors
def plants_show(name: str = typer.Argument(..., help="Model name, e.g. dc_motor.")) -> None:
    """Show one model: parameters with units, outputs and a ready-to-run example spec."""
    import yaml

    from gaintune.plants.library import load_model

    m = load_model(name)
    out.print(f"[bold]{m.name}[/]: {m.title}")
    if m.description:
        out.print(m.description.strip(), markup=False)
    t = Table(title="Parameters")
    for c in ("name", "value", "unit", "description"):
        t.add_column(c)
    for k, p in m.parameters.items():
        t.add_row(k, _f(p.value, 6), p.unit, p.description)
    out.print(t)
    o = Table(title="Signals")
    for c in ("signal", "unit", "description"):
        o.add_column(c)
    o.add_row("input u", m.input.unit, m.input.description)
    for k, s in m.outputs.items():
        o.add_row(f"output {k}", s.unit, s.description)
    out.print(o)
    out.print("Example spec (save as spec.yaml, then: gaintune tune spec.yaml):")
    out.file.flush()
    sys.stdout.write(yaml.safe_dump(m.example_spec(), sort_keys=False, width=1000))


@app.command()
@handle_errors
def export(
    result_path: Path = typer.Argument(..., metavar="RESULT.json", help="A result.json written by 'gaintune tune --out'."),
    fmt: str = typer.Option("json", "--format", "-f", help="json | yaml | c | matlab | python"),
    dt: Optional[float] = typer.Option(
        None, "--dt",
        help="Sample time (s) of the exported discrete controller. Default: the dt the result was verified at "
             "(its largest scenario dt). At any other dt the gains are re-verified first, at that dt."),
    output: Optional[Path] = typer.Option(None, "--output", "-o", help="File to write (default: stdout)."),
    allow_unverified: bool = typer.Option(
        False, "--allow-unverified",
        help="Export gains whose verdict at this dt is not PASS (the file is then marked FAILED, with the reason)."),
    force: bool = typer.Option(False, "--force", hidden=True, help="Old name of --allow-unverified."),
) -> None:
    """Export the gains of a result as JSON, YAML, a C header, a MATLAB/Octave snippet or a Python dict.

    The file carries the verification verdict AT the exported sample time: at the dt the result was
    verified at, the stored verdict; at any other --dt, the gains are re-verified at that dt first.
    Exit 3 (nothing written) when that verdict is not PASS, unless --allow-unverified.
    """
    from gaintune.export import FORMATS, export_result, first_reason, result_verdict_at_dt, verified_dt
    from gaintune.spec import TuningSpec

    fmt = fmt.lower()
    if fmt not in FORMATS:
        raise InputError("format", f"unknown format {fmt!r}; choose from {', '.join(FORMATS)}")
    result = load_result(result_path)
    spec = TuningSpec.model_validate(result.spec)
    vdt = verified_dt(spec)
    at = vdt if dt is None else dt
    checked = result_verdict_at_dt(result, at)  # ExportError("dt", ...) -> exit 2
    verdict, report = checked
    reverified = report is not result.verification
    if reverified:
        was = f"the result was verified at dt = {vdt:g} s" if result.verdict is not None else "the result was not verified"
        err.print(f"re-verified at dt = {at:g} s ({was}): {'PASS' if verdict == 'pass' else 'FAILED'}",
                  markup=False, highlight=False)
    if verdict != "pass" and not (allow_unverified or force):
        reason = first_reason(report) or "no reason recorded in the verification report"
        label = "FAILED verification" if verdict == "fail" else f"are not verified (verdict: {verdict})"
        hint = ("" if _close(at, vdt) or result.verdict is None
                else f" They were verified at dt = {vdt:g} s ({result.verdict}), not at this sample time.")
        err.print(
            f"error: not exporting: at dt = {at:g} s these gains {label}: {reason}.{hint} "
            f"Re-tune at dt = {at:g} s (set scenarios[].dt: {at:g} in the spec and run 'gaintune tune'), "
            "or pass --allow-unverified to export them anyway (the file is then marked FAILED).",
            markup=False, highlight=False,
        )
        raise typer.Exit(EXIT_VERIFY)
    text = export_result(result, fmt, dt=at, checked=checked)
    if output is None:
        sys.stdout.write(text)
    else:
        output.parent.mkdir(parents=True, exist_ok=True)
        output.write_text(text)
        err.print(f"wrote {output}")


def _close(a: float, b: float) -> bool:
    return math.isclose(a, b, rel_tol=1e-9, abs_tol=0.0)


@app.command()
def serve(
    host: str = typer.Option("127.0.0.1", "--host"),
    port: int = typer.Option(8000, "--port"),
    workers: int = typer.Option(1, "--workers", help="Worker processes for tuning jobs."),
) -> None:
    """Run the REST API (FastAPI app in api/)."""
    try:
        from api.main import serve as run_server
    except ImportError as exc:
        err.print(f"error: the REST API (api.main.serve) is not available: {exc}", markup=False)
        raise typer.Exit(1) from None
    run_server(host, port, workers)


# ------------------------------------------------------------------ bench

BENCH = {
    "sim": "Simulator throughput (simulations/s).",
    "search": "RL search vs baselines on the benchmark processes.",
    "verify": "Verification speed: nominal, full and the search estimate's batch.",
    "compare": "Compare gaintune with classical rules and optimisers.",
    "constraints": "Agreement of the searched requirement estimate with the verdict near the boundary.",
    "kernel": "The simulator kernel side by side with an earlier git revision of it.",
    "ablation": "RL agents and PPO settings side by side on 1/(s+1)^3 PID.",
    "startup": "End-to-end wall time of --help, import, verify and a 3,000-simulation tune, beside python -c pass.",
    "api": "REST API load test.",
}


def _bench_runner(name: str) -> Callable:
    def run(ctx: typer.Context) -> None:
        try:
            mod = importlib.import_module(f"gaintune.bench.{name}")
        except ModuleNotFoundError as exc:
            err.print(f"error: benchmark '{name}' is not available (module gaintune.bench.{name} is missing: {exc})", markup=False)
            raise typer.Exit(1) from None
        main = getattr(mod, "main", None)
        if main is None:
            err.print(f"error: gaintune.bench.{name} has no main(argv)", markup=False)
            raise typer.Exit(1)
        rc = main(list(ctx.args))
        raise typer.Exit(int(rc or 0))

    run.__doc__ = BENCH[name]
    return run


for _name in BENCH:
    bench_app.command(
        _name,
        context_settings={"allow_extra_args": True, "ignore_unknown_options": True, "help_option_names": []},
        add_help_option=False,
    )(_bench_runner(_name))


def main() -> None:  # pragma: no cover - console entry
    app()


if __name__ == "__main__":  # pragma: no cover
    app()
