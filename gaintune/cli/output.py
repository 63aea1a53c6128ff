"""What the ``gaintune`` commands print and write: result summaries, tables, plots and output folders.

* :func:`_print_summary`: the gains, margins, requirements, metrics and verdict of a
  tuning result (``tune``, ``demo``);
* :func:`_write_outputs`: result.json, report.html and the gain exports in ``--out``;
* :func:`_print_simulation`, :func:`_simulation_json` and :func:`_plot_runs`: the
  ``simulate`` table, its JSON document and the time-response plot;
* :func:`_print_plants` and :func:`_print_plant`: the ``plants`` listing and
  ``plants show``.

Every name is internal to :mod:`gaintune.cli` (hence the leading underscore).
"""

from __future__ import annotations

import io
import sys
from pathlib import Path
from typing import TYPE_CHECKING, Any

from gaintune.cli.common import InputError, _Console, _f, _json_num, out, output_errors

if TYPE_CHECKING:  # pragma: no cover
    from rich.console import Console

__all__ = ["_print_summary", "_write_outputs", "_print_simulation", "_simulation_json", "_plot_runs", "_print_plants",
           "_print_plant"]


# ------------------------------------------------------------ tuning result


def _print_summary(result, console: Console | _Console = out) -> None:
    """The tune's summary: gains table (titled by the verdict), cost, margins and metrics."""
    from rich.table import Table  # deferred on purpose: `gaintune verify` prints no rich table

    verdict = result.verdict
    passed = verdict == "pass"
    if passed:
        title = "Accepted gains"
    else:
        title = "Gains - FAILED verification, NOT accepted" if verdict == "fail" else "Gains (unverified)"
    t = Table(title=title, title_style="bold green" if passed else "bold red")
    t.add_column("loop")
    t.add_column("gain")
    t.add_column("value", justify="right")
    t.add_column("the loop in the other PID form")
    forms = _pid_forms(result)
    for loop, g in result.gains.items():
        other = _other_form(forms.get(loop), g)
        for i, (k, v) in enumerate(g.items()):
            t.add_row(loop, k, _f(v, 6), other if i == 0 else "")
    console.print(t)
    rep = result.verification
    if rep is not None:
        _print_margins(rep, console)
    if result.baselines:
        _print_baselines(result, console)
    if result.metrics:
        keys = ("iae", "overshoot", "rise_time", "settling_time", "sse", "peak_u")
        mt = Table(title="Metrics (nominal plant)")
        mt.add_column("scenario")
        for k in keys:
            mt.add_column(k, justify="right")
        for sc, vals in result.metrics.items():
            mt.add_row(sc, *[_f(vals.get(k)) for k in keys])
        console.print(mt)
    from gaintune.evaluation.evaluator import DIVERGED_COST  # loaded already: the search ran

    cost = "- (its simulation diverged)" if result.cost >= DIVERGED_COST else _f(result.cost)
    console.print(f"cost {cost} (plain objective) after {result.sims} simulations in "
                  f"{result.wall_time:.1f} s ({result.algo}, stopped: {result.stopped})")
    if verdict == "pass":
        console.print("[bold green]verdict: PASS[/]")
    elif verdict == "fail":
        console.print("[bold red]verdict: FAILED[/] - the gains are not accepted")
        for r in rep.reasons:
            console.print(f"  - {r}", markup=False)
    else:
        console.print("verdict: not verified")
    if result.diagnosis is not None:
        console.print(result.diagnosis.summary, markup=False)
        for h in result.diagnosis.hints:
            console.print(f"  hint: {h}", markup=False)


def _pid_forms(result) -> dict[str, str]:
    """Loop name -> PID form ("parallel" or "ideal") of the result's spec; LQ loops left out."""
    loops = (result.spec or {}).get("loops") or []
    return {lp.get("name") or f"loop{i}": lp.get("form", "parallel") for i, lp in enumerate(loops)
            if lp.get("type", "pid") in ("p", "pi", "pd", "pid")}


def _other_form(form: str | None, gains: dict[str, float]) -> str:
    from gaintune.controllers.forms import other_form_text

    return other_form_text(form, gains, lambda v: _f(v, 4))


def _print_margins(rep, console: Console | _Console) -> None:
    """Margins per loop and the requirement lines; an unstable loop's are 'not applicable', never pass."""
    from rich.table import Table

    from gaintune.verification.report import NOT_APPLICABLE

    m = Table(title="Margins per loop (nominal)")
    for c in ("loop", "break", "GM dB", "PM deg", "wc rad/s", "DM s", "Ms", "Mt"):
        m.add_column(c, justify="left" if c in ("loop", "break") else "right")
    if not rep.stability.stable:
        m.add_row("(all)", "", NOT_APPLICABLE, "", "", "", "", "")
    for f in rep.loops if rep.stability.stable else []:
        m.add_row(f.loop, "ctrl" if f.break_point == "controller_output" else "u", _f(f.gm_db, 3), _f(f.pm_deg, 3),
                  _f(f.pm_freq, 3), _f(f.delay_margin, 3), _f(f.ms, 3), _f(f.mt, 3))
    console.print(m)
    if rep.requirements:
        q = Table(title="Requirements")
        for c in ("requirement", "value", "limit", "result", "at"):
            q.add_column(c)
        for r in rep.requirements:
            status = {"pass": "[green]pass[/]", "fail": "[red]FAIL[/]", "n/a": NOT_APPLICABLE}[r.status]
            value = "-" if r.status == "n/a" else _f(r.value)
            where = f"{r.loop}/{r.break_point}/{r.case}" if r.loop else r.case
            q.add_row(r.requirement, value, _f(r.limit), status, where)
        console.print(q)


def _print_baselines(result, console: Console | _Console) -> None:
    """The baselines of ``tune --baselines`` beside this result: gains, cost, simulations, feasibility."""
    from rich.table import Table

    b = Table(title="Baselines (same cost and requirements estimate as the search)")
    for c in ("method", "gains", "cost", "vs this", "sims", "feasible", "note"):
        b.add_column(c, justify="right" if c in ("cost", "vs this", "sims") else "left")
    b.add_row(f"gaintune ({result.algo})", _gains_line(result.gains), _f(result.cost), "1", _f(result.sims),
              "yes" if result.verdict == "pass" else "-", "this result")
    for row in result.baselines:
        cost = row.get("cost")
        ratio = _f(cost / result.cost, 4) if cost is not None and result.cost and result.cost > 0 else "-"
        feasible = {True: "yes", False: "no", None: "-"}[row.get("feasible")]
        b.add_row(str(row.get("method", "?")), _gains_line(row.get("gains")), _f(cost), ratio, _f(row.get("n_sims")),
                  feasible, row.get("reason") or "")
    console.print(b)


def _gains_line(gains: dict[str, dict[str, float]] | None) -> str:
    if not gains:
        return "-"
    return "; ".join(", ".join(f"{k} {_f(v, 4)}" for k, v in g.items()) if len(gains) == 1 else
                     f"{loop}: " + ", ".join(f"{k} {_f(v, 4)}" for k, v in g.items()) for loop, g in gains.items())


def _write_outputs(result, out_dir: Path, console: Console | _Console = out) -> None:
    """result.json, report.html and the gain exports in ``out_dir``, each written atomically.

    A file-level symlink planted in the folder is replaced, never written through
    (:func:`gaintune.files.write_atomic`); the folder itself may be a link (the user's choice).
    """
    from gaintune.export import write_exports
    from gaintune.files import write_atomic
    from gaintune.report import render_report

    out_dir.mkdir(parents=True, exist_ok=True)
    write_atomic(out_dir / "result.json", result.model_dump_json(indent=2))
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


# --------------------------------------------------------------- simulation


def _simulation_json(results, switches, *, traces: bool) -> dict[str, Any]:
    """The ``simulate --json`` document: metrics (and with ``traces``, the time traces) per scenario."""
    from gaintune.sim.chatter import CHATTER_SWITCHES

    doc = {}
    for r, n in zip(results, switches, strict=True):
        d: dict[str, Any] = {"metrics": {k: _json_num(v[0]) for k, v in r.metrics.items()}}
        d["metrics"].update(saturation_switches=n, chattering=n >= CHATTER_SWITCHES)
        if traces:
            d["t"] = r.t.tolist()
            d["traces"] = {k: [_json_num(x) for x in v[0]] for k, v in r.traces.items()}
        doc[r.scenario] = d
    return doc


def _print_simulation(spec, results, switches) -> None:
    """The ``simulate`` table (one column per scenario) and a warning for every chattering run."""
    from rich.table import Table  # deferred on purpose: `gaintune verify` prints no rich table

    from gaintune.sim.chatter import CHATTER_SWITCHES

    keys = ("iae", "ise", "itae", "effort", "tv", "overshoot", "rise_time", "settling_time", "sse", "peak_u",
            "sat_frac", "load_iae", "diverged", "tripped")
    t = Table(title=f"Simulation of {spec.name!r} (nominal plant)")
    t.add_column("metric")
    for r in results:
        t.add_column(r.scenario, justify="right")
    for k in keys:
        t.add_row(k, *[str(bool(r.metrics[k][0])) if r.metrics[k].dtype == bool else _f(float(r.metrics[k][0]))
                       for r in results])
    t.add_row("saturation_switches", *[str(n) for n in switches])
    t.add_row("chattering", *[str(n >= CHATTER_SWITCHES) for n in switches])
    out.print(t)
    for r, n in zip(results, switches, strict=True):
        if n >= CHATTER_SWITCHES:
            out.print(f"warning: scenario {r.scenario!r}: the actuator chatters between its limits ({n} limit-to-limit "
                      "switches); the run is bounded but this is not a working loop", markup=False)


def _plot_runs(spec, sim, results, path: Path) -> None:
    """Save the time responses of every scenario to ``path`` (PNG, SVG or PDF)."""
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
    buf = io.BytesIO()
    try:  # rendered in memory, then put in place atomically: a symlink at the path is not written through
        fig.savefig(buf, format=path.suffix[1:].lower() or "png")
    except ValueError as exc:  # unknown extension
        raise InputError("plot", str(exc)) from None
    finally:
        plt.close(fig)
    from gaintune.files import write_atomic

    with output_errors(path, "plot"):
        write_atomic(path, buf.getvalue())


# ------------------------------------------------------------------- plants


def _print_plants() -> None:
    """The table of every built-in plant model."""
    from rich.table import Table  # deferred on purpose: `gaintune verify` prints no rich table

    from gaintune.plants.library import list_models, load_model, models_dir

    names = list_models()
    if not names:  # a GAINTUNE_MODELS folder that is missing or holds no model
        out.print(f"no plant models in {models_dir()} (GAINTUNE_MODELS chooses the folder)", markup=False)
        return
    t = Table(title="Built-in plant models (use in a spec as plant: {model: NAME})")
    # the name is what a spec needs: never truncated or wrapped; the other columns wrap instead
    t.add_column("name", style="bold", no_wrap=True, overflow="fold", min_width=max(len(n) for n in names))
    t.add_column("title", ratio=3, overflow="fold")
    t.add_column("parameters", ratio=2, overflow="fold")
    t.add_column("outputs", ratio=2, overflow="fold")
    for name in names:
        m = load_model(name)
        t.add_row(name, m.title, ", ".join(m.parameters), ", ".join(m.outputs))
    out.print(t)


def _print_plant(m) -> None:
    """One model: parameters with units, signals and its example spec (as YAML, straight to stdout)."""
    import yaml
    from rich.table import Table  # deferred on purpose: `gaintune verify` prints no rich table

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
    if m.inputs:  # several inputs
        for k, s in m.inputs.items():
            o.add_row(f"input {k}", s.unit, s.description)
    else:
        o.add_row("input u", m.input.unit, m.input.description)
    for k, s in m.outputs.items():
        o.add_row(f"output {k}", s.unit, s.description)
    out.print(o)
    out.print("Example spec (save as spec.yaml, then: gaintune tune spec.yaml):")
    out.file.flush()
    sys.stdout.write(yaml.safe_dump(m.example_spec(), sort_keys=False, width=1000))
