"""``gaintune tuner ...``: train a tuner for a plant family, query it, list the ready-made ones, update, schedule.

A thin front end over :mod:`gaintune.tuners`:

* ``train SPEC --out DIR`` / ``train --family fotd --ctype pi --ms 1.4 --out DIR``:
  :func:`gaintune.tuners.train.train` with a progress bar (resumable after a kill);
* ``query NAME|DIR -p K=2 -p T=60 -p L=10``: :meth:`gaintune.tuners.tuner.Tuner.query`, torch-free
  (every heavy import is inside the command functions; ``tests/cli/test_tuner_cli.py`` checks it);
* ``list``: :func:`gaintune.tuners.listing.shipped`;
* ``update DIR --spec NEW.yaml``: training continued from DIR's agent on a changed family;
* ``schedule NAME|DIR --var H0 --grid 2:20:10``: :func:`gaintune.tuners.scheduling.schedule_from_tuner`,
  verified, exported, optionally compared with the best single fixed PI.

Exit codes as everywhere: 2 for bad input (naming the field), 3 when a verdict fails.
"""

from __future__ import annotations

import json
import math
from pathlib import Path
from typing import TYPE_CHECKING, Annotated, Any

import typer

from gaintune.cli.common import EPILOG, EXIT_VERIFY, InputError, _f, _json_num, check_out_dir, err, handle_errors, out

if TYPE_CHECKING:  # pragma: no cover
    from gaintune.tuners.problems import TunerProblem
    from gaintune.tuners.tuner import Tuner, TunerAnswer

__all__ = ["tuner_app", "parse_params"]

tuner_app = typer.Typer(
    help="Trained tuners: verified gains for a plant of a family in milliseconds (train, query, list, update, "
         "schedule). See docs/tuners.md.",
    no_args_is_help=True, epilog=EPILOG, rich_markup_mode=None)

TunerArg = Annotated[str, typer.Argument(
    metavar="NAME|DIR", help="A ready-made tuner's name ('gaintune tuner list') or a tuner folder.")]
EpisodesOpt = Annotated[int | None, typer.Option(
    "--episodes", min=1, help="Training episodes (one plant of the family each). Default: 60,000.")]
SeedOpt = Annotated[int, typer.Option("--seed", min=0, help="Training seed.")]
NoResumeOpt = Annotated[bool, typer.Option(
    "--no-resume", help="Start afresh even if a checkpoint of the same run is there.")]
#: TrainSettings fields the commands do not choose (the library's defaults; tests shrink the network's batches).
TRAIN_DEFAULTS: dict[str, Any] = {}


# ----------------------------------------------------------------------------------------- input


def parse_params(items: list[str]) -> dict[str, float]:
    """``["K=2", "T=60"]`` -> ``{"K": 2.0, "T": 60.0}``; InputError naming ``--param`` otherwise."""
    params: dict[str, float] = {}
    for item in items:
        name, sep, value = item.partition("=")
        name = name.strip()
        if not sep or not name or not value.strip():
            raise InputError("--param", f"expected NAME=VALUE, e.g. -p K=2, got {item!r}")
        try:
            x = float(value)
        except ValueError:
            raise InputError("--param", f"{name}: the value must be a number, got {value!r}") from None
        if not math.isfinite(x):
            raise InputError("--param", f"{name}: the value must be finite, got {value!r}")
        if name in params:
            raise InputError("--param", f"{name} is given twice")
        params[name] = x
    return params


def _problem(spec_path: Path | None, family: str | None, ctype: str | None, ms: float | None) -> TunerProblem:
    """The training problem: a spec's randomize block, or a ready-made family."""
    from gaintune.tuners.problems import FamilyProblem, SpecProblem

    if (spec_path is None) == (family is None):
        raise InputError("spec", "give either SPEC (a spec with a randomize block) or --family fotd|sotd|ipd")
    if spec_path is not None:
        for opt, v in (("--ctype", ctype), ("--ms", ms)):
            if v is not None:
                raise InputError(opt, "only with --family; with SPEC its loops and requirements say it")
        from gaintune.cli.common import load_spec_file

        return SpecProblem(load_spec_file(spec_path))
    ctype = ctype or "pi"
    if ctype not in ("pi", "pid"):
        raise InputError("--ctype", f"must be pi or pid, got {ctype!r}")
    ms = 1.4 if ms is None else ms
    if not (math.isfinite(ms) and ms > 1.0):
        raise InputError("--ms", f"the Ms limit must be a number > 1, got {ms:g}")
    return FamilyProblem(str(family), ctype, ms)


def _settings(episodes: int | None, seed: int) -> Any:
    """The training settings: the defaults, with the episodes and seed given."""
    from gaintune.tuners.train import TrainSettings

    chosen: dict[str, Any] = {"seed": seed} if episodes is None else {"seed": seed, "episodes": episodes}
    return TrainSettings(**{**TRAIN_DEFAULTS, **chosen})


# ----------------------------------------------------------------------------------------- query


def _load(name_or_dir: str) -> Tuner:
    from gaintune.tuners.tuner import Tuner

    return Tuner.load(name_or_dir)


def _answer_json(answer: TunerAnswer) -> dict[str, Any]:
    """``answer.as_dict()`` with non-finite numbers as null (JSON has none)."""
    d = answer.as_dict()
    d["cost"] = _json_num(d["cost"])
    return d


def _print_answer(tuner: Tuner, answer: TunerAnswer) -> None:
    """One row: the gains (struck through unless PASS), verdict, cost, context, timings, simulations."""
    from rich.table import Table  # deferred: a missing tuner exits before any table

    ok = answer.verdict == "pass"
    plant = ", ".join(f"{k} = {_f(v)}" for k, v in answer.params.items())
    table = Table(title=f"{tuner.name}: {plant}", caption="the gains are accepted only on PASS")
    gains = [(loop, g) for loop, gs in answer.gains.items() for g in gs]
    ranges = _ranges(tuner)
    refined = ["refining"] if answer.refined else []
    heads = [g if len(answer.gains) == 1 else f"{loop}.{g}" for loop, g in gains]
    for col in heads + ["verdict", "cost", *(r["name"] for r in ranges),
                                                        "policy ms", "answer ms", "sims", *refined]:
        table.add_column(col, justify="left" if col == "verdict" else "right")
    cells = [_f(answer.gains[loop][g]) if ok else f"[strike]{_f(answer.gains[loop][g])}[/strike]" for loop, g in gains]
    cells += ["PASS" if ok else "[bold red]FAIL[/bold red]", _f(answer.cost),
              *(_f(_ratio(r["variable"], answer.context[r["variable"]], tuner)) for r in ranges),
              f"{answer.policy_ms:.2f}", f"{answer.elapsed_ms:.0f}",
              f"{answer.n_sims}", *([f"{answer.refined}"] if answer.refined else [])]
    table.add_row(*cells)
    out.print(table)
    rep = answer.verification
    if not ok and rep is not None:
        out.print(f"FAIL: {rep.reasons[0] if rep.reasons else 'verification failed'}", markup=False, soft_wrap=True)


def _ranges(tuner: Tuner) -> list[dict[str, Any]]:
    from gaintune.tuners.listing import context_ranges

    return context_ranges(tuner.problem)


def _ratio(variable: str, x: float, tuner: Tuner) -> float:
    """A family tuner's ``tau`` as the ratio its range is given in (L/T); anything else as it is."""
    from gaintune.tuners.problems import FamilyProblem

    return x / (1.0 - x) if isinstance(tuner.problem, FamilyProblem) and variable == "tau" and x < 1 else x


@tuner_app.command("query")
@handle_errors
def query_cmd(
    tuner: TunerArg,
    param: Annotated[list[str] | None, typer.Option(
        "--param", "-p", metavar="NAME=VALUE", help="A plant parameter (e.g. -p K=2 -p T=60 -p L=10).")] = None,
    json_out: Annotated[bool, typer.Option("--json", help="Print the answer as JSON.")] = False,
    refine: Annotated[int, typer.Option(
        "--refine", min=0, max=1_000_000, help="Continue from the answer with at most N more simulations.")] = 0,
) -> None:
    """Verified gains for one plant: the policy's answer (NumPy), moved onto its boundary, verified. Exit 3 on FAIL."""
    params = parse_params(param or [])
    t = _load(tuner)
    from gaintune.cli.compiling import compile_single_kernel
    from gaintune.tuners.tuner import OutsideFamilyError

    compile_single_kernel(None if json_out else err)  # a first run only: later ones load it without numba

    try:
        answer = t.query(params, refine=refine)
    except OutsideFamilyError as exc:
        raise InputError(exc.field, exc.message) from None
    if json_out:
        print(json.dumps(_answer_json(answer), indent=2))
    else:
        _print_answer(t, answer)
    if answer.verdict != "pass":
        raise typer.Exit(EXIT_VERIFY)


# ------------------------------------------------------------------------------------------ list


def _print_list(items: list[dict[str, Any]]) -> None:
    """Two lines per tuner: what it answers, then how well, how it was trained and its size."""
    for s in items:
        v, t = s["validation"], s["training"]
        ranges = "; ".join(f"{r['name']} {_f(r['lo'])} .. {_f(r['hi'])}" for r in s["context"])
        ms = f", Ms <= {_f(s['ms_max'])}" if s["ms_max"] is not None else ""
        out.print(f"{s['name']}: {s['family']} {s['model']}, {s['controller'].upper()}{ms}, {ranges}",
                  markup=False, highlight=False, soft_wrap=True)
        out.print(f"  validation: cost / per-plant optimum median {_f(v['median_ratio'])}, worst "
                  f"{_f(v['worst_ratio'])}, {v['passed']}/{v['n']} pass; training: {t['episodes']:,} episodes, "
                  f"{_f(t['wall_s'])} s; {s['size_kb']:.1f} KB", markup=False, highlight=False, soft_wrap=True)


@tuner_app.command("list")
@handle_errors
def list_cmd(json_out: Annotated[bool, typer.Option("--json", help="Print the list as JSON.")] = False) -> None:
    """The ready-made tuners: family, controller, Ms limit, range, validation figures, training and size."""
    from gaintune.tuners.listing import shipped

    items = shipped()
    if json_out:
        print(json.dumps(items, indent=2))
    elif not items:
        out.print("no ready-made tuners are installed; train one with "
                  "'gaintune tuner train --family fotd --ctype pi --ms 1.4 --out DIR'", markup=False, soft_wrap=True)
    else:
        _print_list(items)


# -------------------------------------------------------------------------------------- training


def _run_training(problem: TunerProblem, out_dir: Path, settings: Any, *, resume: bool,
                  warm_start: Path | None = None) -> Path:
    """:func:`gaintune.tuners.train.train` with a progress bar on stderr."""
    from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn

    from gaintune.cli.compiling import compile_simulator
    from gaintune.tuners.train import train

    compile_simulator(err)
    with Progress(TextColumn("[bold]{task.description}"), BarColumn(), MofNCompleteColumn(), TextColumn("episodes"),
                  TextColumn("median cost/optimum {task.fields[ratio]}"), TimeElapsedColumn(),
                  console=err.real(), transient=False) as bar:
        task = bar.add_task("training", total=settings.episodes, ratio="-")

        def on_progress(done: int, total: int, info: dict[str, Any]) -> None:
            desc = "validating" if done >= total else "training"
            bar.update(task, completed=done, total=total, description=desc)
            if info.get("ratio") is not None:  # at a checkpoint: the training curve's figure
                bar.update(task, ratio=_f(info["ratio"]))

        try:
            return train(problem, out_dir, settings, on_progress=on_progress, resume=resume, warm_start=warm_start)
        except KeyboardInterrupt:
            err.print("interrupted: the last checkpoint is kept; the same command resumes from it", markup=False)
            raise typer.Exit(130) from None


def _print_trained(folder: Path) -> None:
    """What was trained: the family, the validation figures, the training record, the folder's size."""
    from gaintune.tuners.listing import summary

    s = summary(folder)
    ranges = ", ".join(f"{r['name']} {_f(r['lo'])} .. {_f(r['hi'])}" for r in s["context"])
    ms = f", Ms <= {_f(s['ms_max'])}" if s["ms_max"] is not None else ""
    v, t = s["validation"], s["training"]
    resumed = f", resumed {t['resumed']}x" if t["resumed"] else ""
    lines = [f"wrote tuner {folder} ({s['family']}: {s['model']}, {s['controller'].upper()}{ms}; {ranges})",
             f"validation on {v['n']} held-out plants: cost / per-plant optimum median {_f(v['median_ratio'])}, "
             f"worst {_f(v['worst_ratio'])}; {v['passed']}/{v['n']} pass verification",
             f"training: {t['episodes']:,} episodes, {t['sims']:,} simulations, {_f(t['wall_s'])} s{resumed}",
             f"size: {s['size_kb']:.1f} KB"]
    for line in lines:
        out.print(line, markup=False, highlight=False, soft_wrap=True)


@tuner_app.command("train")
@handle_errors
def train_cmd(
    out_dir: Annotated[Path, typer.Option("--out", "-o", help="The tuner folder to write (atomically).")],
    spec_path: Annotated[Path | None, typer.Argument(
        metavar="SPEC", help="A spec whose randomize block is the plant family (or use --family).")] = None,
    family: Annotated[str | None, typer.Option(
        "--family", help="A ready-made family instead of SPEC: fotd, sotd or ipd.")] = None,
    ctype: Annotated[str | None, typer.Option("--ctype", help="With --family: pi or pid (default pi).")] = None,
    ms: Annotated[float | None, typer.Option("--ms", help="With --family: the Ms limit (default 1.4).")] = None,
    episodes: EpisodesOpt = None,
    seed: SeedOpt = 0,
    no_resume: NoResumeOpt = False,
) -> None:
    """Train a tuner for a plant family and write it to --out; a killed run resumes from its last checkpoint."""
    problem = _problem(spec_path, family, ctype, ms)
    check_out_dir(out_dir)
    folder = _run_training(problem, out_dir, _settings(episodes, seed), resume=not no_resume)
    _print_trained(folder)


@tuner_app.command("update")
@handle_errors
def update_cmd(
    tuner: Annotated[Path, typer.Argument(metavar="DIR", help="The tuner folder to continue from.")],
    spec_path: Annotated[Path, typer.Option("--spec", help="The changed family: a spec with a randomize block.")],
    out_dir: Annotated[Path | None, typer.Option("--out", "-o", help="Write here (default: replace DIR).")] = None,
    episodes: EpisodesOpt = None,
    seed: SeedOpt = 0,
    no_resume: NoResumeOpt = False,
) -> None:
    """Continue training DIR's tuner on a changed family (same varying parameters and tuned gains)."""
    from gaintune.cli.common import load_spec_file
    from gaintune.tuners import artefact
    from gaintune.tuners.problems import SpecProblem

    folder = artefact.resolve(tuner)
    if out_dir is None and folder.resolve().parent == artefact.SHIPPED_DIR:
        raise InputError("--out", "a ready-made tuner is not changed in place; give --out DIR")
    # no agent.zip needed: the shipped tuners keep only policy.npz and critic.npz, which training continues from
    problem = SpecProblem(load_spec_file(spec_path))
    target = out_dir or folder
    check_out_dir(target)
    done = _run_training(problem, target, _settings(episodes, seed), resume=not no_resume, warm_start=folder)
    _print_trained(done)


# -------------------------------------------------------------------------------------- schedule


@tuner_app.command("schedule")
@handle_errors
def schedule_cmd(
    tuner: TunerArg,
    var: Annotated[str, typer.Option("--var", help="The scheduling variable: a context variable of the tuner.")],
    grid: Annotated[str, typer.Option("--grid", help="start:stop:count (e.g. 2:20:10) or a comma list.")],
    out_dir: Annotated[Path | None, typer.Option(
        "--out", "-o", help="Write schedule.json and the exports (schedule_gains.{json,h,m}) here.")] = None,
    json_out: Annotated[bool, typer.Option("--json", help="Print the schedule and its verification as JSON.")] = False,
    compare: Annotated[bool, typer.Option(
        "--compare", help="Also design the best single fixed PI over the range and compare the level steps.")] = False,
) -> None:
    """A gain schedule over VAR answered by the tuner, fitted at the midpoints and verified. Exit 3 if it fails."""
    from gaintune.cli.schedule import run_schedule
    from gaintune.tuners.schedule import parse_grid

    values = parse_grid(grid)  # bad input exits before the tuner is loaded
    if out_dir is not None:
        check_out_dir(out_dir)
    run_schedule(_load(tuner), var, values, out_dir, json_out=json_out, compare=compare)
