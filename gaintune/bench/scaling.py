"""``gaintune bench scaling``: budget-to-quality curves of the RL search and CMA-ES, on any spec.

For every problem, every method and every seed, one search is run at the largest budget and its
**anytime curve** is read at each budget of ``--budgets``: the best feasible plain cost found within
that many simulations, over the problem's reference cost. The ``answer`` column is the method's own
answer at the full budget (RL alone: ``rl_cost``, ``refine: false``; CMA-ES: its answer), settled on
the exact requirements like every answer, with its verification verdict and closed-loop stability
(:func:`gaintune.verification.verify`, the MIMO verdict on a loop graph).

Problems: ``--problems`` names problems of ``--suite`` or built-in models (``quadrotor``,
``robot_arm6``, ``process_train``, ...: the model's example spec); ``--spec`` takes spec files
instead. The reference of a suite problem or spec file is its reference optimum (multistart search,
cached); a built-in model's is the best cost any run of this invocation reached (at 100+ gains a
reference search would cost more than the runs), so 1.000 there is the best answer seen.

Methods (:data:`METHODS`):

* ``rl``: :func:`gaintune.search.tune` with the library defaults (``refine: false``);
* ``rl-fixed-std``: the same with PPO's initial exploration fixed at ``log_std_init = -1`` whatever
  the gain count (the default before :func:`gaintune.search.agents.exploration_log_std`);
* ``rl-per-loop``: the default RL with the per-loop repair (only the loops that miss a requirement
  are scaled onto the boundary: :func:`gaintune.evaluation.boundary_estimate.onto_boundary_estimate`);
* ``cmaes``: CMA-ES (``run_baseline(spec, "cmaes")``) in the same box, from the same start.

Simulations on the curve: the RL search's count includes its set-up (the search box and the
reward scale, charged to its budget; column ``set-up sims``); CMA-ES counts its own evaluations (its
box is the same). The machine's load average is recorded with the table.

    gaintune bench scaling [--suite cascades --problems six_lag_cascade quadrotor] [--spec FILE ...]
                           [--methods rl cmaes] [--seeds 0 1 2] [--budgets 2000 5000 10000 20000] [--out DIR]

Writes ``scaling_<problems>[-<methods>].md`` and ``.json`` to ``--out`` (the methods named unless they are
``rl cmaes``).
"""

from __future__ import annotations

import argparse
import functools
import os
import sys
import time
import warnings
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

from gaintune.bench.arguments import (
    BenchParser,
    add_out_argument,
    budget_int,
    fail,
    resolve_out,
    seed_int,
    select_problems,
)
from gaintune.bench.compare import fmt, fmt_ratio, md_table, ratio, stats, write_outputs
from gaintune.bench.references import reference_for
from gaintune.bench.suite import BenchCase, get_suite, suite_names, timed_row

__all__ = ["METHODS", "run_method", "curve_at", "answer_check", "resolve_problems", "run_scaling",
           "render_markdown", "main"]

#: What each method changes in the RL search (``tune`` keyword arguments); None: CMA-ES.
METHODS: dict[str, dict[str, Any] | None] = {
    "rl": {},
    "rl-fixed-std": {"fixed_std": True},
    "rl-per-loop": {"per_loop_repair": True},
    "cmaes": None,
}

#: Budgets the curve is read at when ``--budgets`` is not given (the largest is the run's budget).
DEFAULT_BUDGETS = (1000, 2000, 5000, 10000, 20000)

#: The family of a built-in model's problem: its reference is the best run, not a reference search.
MODEL_FAMILY = "model"


def curve_at(points: Sequence[tuple[int, float]], budgets: Sequence[int]) -> list[float | None]:
    """Best cost reached within each budget: ``points`` are (simulations, best feasible cost so far); None where
    nothing feasible was found yet."""
    out: list[float | None] = []
    for b in budgets:
        within = [c for s, c in points if s <= b]
        out.append(min(within) if within else None)
    return out


def _fixed_std_overrides(algo: str) -> dict[str, Any]:
    """Agent overrides that pin PPO's initial log std at -1 (the fixed default) whatever the gain count."""
    from gaintune.search.agents import agent_defaults

    kw = agent_defaults(algo, 32, 1, 1)
    pk = dict(kw.get("policy_kwargs") or {})
    pk["log_std_init"] = -1.0
    return {"policy_kwargs": pk}


def answer_check(spec: Any, gains: Any, report: Any = None) -> dict[str, Any]:
    """The verification verdict of an answer and its closed-loop stability (the MIMO verdict on a loop graph),
    from ``report`` when the search verified it already; ``verdict`` None with ``check_error`` when the check
    itself failed (the run's figures are kept)."""
    from gaintune.verification import verify

    if gains is None and report is None:
        return {"verdict": None, "stable": None}
    try:
        rep = report if report is not None else verify(spec, gains)
    except Exception as exc:  # noqa: BLE001 - a failed check must not lose the run's figures
        return {"verdict": None, "check_error": f"{type(exc).__name__}: {exc}"} | _linear_check(spec, gains)
    return {"verdict": rep.verdict, "stable": bool(rep.stability.stable), "stability": "verdict",
            "reasons": list(rep.reasons)[:3]}


def _linear_check(spec: Any, gains: Any) -> dict[str, Any]:
    """Stability from the bench's own linear check of a loop graph (:mod:`gaintune.bench.scale_check`), for an
    answer the verdict could not be computed on."""
    from gaintune.bench.scale_check import closed_loop_stable

    try:
        stable, how = closed_loop_stable(spec, dict(gains))
    except Exception as exc:  # noqa: BLE001 - as above
        return {"stable": None, "stability": f"linear check failed: {type(exc).__name__}: {exc}"}
    return {"stable": stable, "stability": f"linear check: {how}"}


def run_method(problem: BenchCase, method: str, seed: int, budget: int) -> dict[str, Any]:
    """One run of ``method`` on ``problem`` at ``budget`` simulations: its answer, anytime curve, set-up
    simulations, wall time (the search alone) and the answer's verdict and stability."""
    spec = problem.tuning_spec(budget=budget, seed=seed)
    spec = spec.model_copy(update={"search": spec.search.model_copy(update={"refine": False})})
    opts = METHODS[method]
    if opts is None:
        from gaintune.baselines import run_baseline
        from gaintune.envs.problem import GainProblem

        cm = run_baseline(spec, "cmaes", budget=budget, seed=seed, evaluator=GainProblem(spec).evaluator)
        out: dict[str, Any] = {"cost": cm.cost, "feasible": cm.feasible, "sims": cm.n_sims, "setup_sims": 0,
                               "wall_time": cm.wall_time, "curve": [list(p) for p in cm.history]}
        return out | answer_check(spec, cm.gains)
    from gaintune.search import tune

    overrides = _fixed_std_overrides(spec.search.algo) if opts.get("fixed_std") else None
    t0 = time.perf_counter()
    res = tune(spec, verify=True, agent_overrides=overrides, per_loop_repair=bool(opts.get("per_loop_repair")))
    curve = [[res.setup_sims + c.sims, c.best_cost] for c in res.curve if c.feasible]
    out = {"cost": res.rl_cost, "feasible": res.rl_feasible, "sims": res.sims, "setup_sims": res.setup_sims,
           "wall_time": time.perf_counter() - t0, "curve": curve}
    return out | answer_check(spec, res.gains, res.verification)


def _model_problem(name: str) -> BenchCase:
    """A built-in model's example spec as a benchmark problem."""
    from gaintune.plants.library import load_model
    from gaintune.spec import load_spec

    d = load_spec(load_model(name).example_spec()).model_dump(mode="json", exclude_defaults=True)
    return BenchCase(name, f"built-in model {name} (its example spec)", d, MODEL_FAMILY)


def resolve_problems(suite: str, names: Sequence[str]) -> list[BenchCase]:
    """Each name as a problem of ``suite`` or else a built-in model; an unknown name exits 2 naming ``--problems``."""
    from gaintune.plants.library import list_models

    in_suite = {p.name for p in get_suite(suite)}
    models = list_models()
    unknown = [n for n in names if n not in in_suite and n not in models]
    if unknown:
        fail("--problems", f"unknown problem(s) {unknown}: give a problem of suite {suite} "
                           f"({', '.join(sorted(in_suite))}) or a built-in model ({', '.join(models)})")
    return [select_problems(suite, [n])[0] if n in in_suite else _model_problem(n) for n in names]


def _n_gains(problem: BenchCase) -> int:
    """Tuned gains of the problem (its layout's search dimension)."""
    from gaintune.controllers.layout import GainLayout
    from gaintune.plants import build_plant

    spec = problem.tuning_spec()
    plant = build_plant(spec.plant)
    return GainLayout(spec, plant.states, plant=plant).n_tuned


def _settle_references(refs: dict[str, Any], rows: list[dict[str, Any]]) -> None:
    """A built-in model's reference is the best cost any run reached; then every row's ratios to its reference."""
    for name, ref in refs.items():
        if ref["basis"] == "best run":
            costs = [c for r in rows if r["problem"] == name for c in [r.get("cost"), *r["at"]] if c is not None]
            ref["cost"] = min(costs) if costs else None
    for r in rows:
        ref = refs[r["problem"]]["cost"]
        r.update(reference_cost=ref, ratio=ratio(r.get("cost"), ref), curve_ratio=[ratio(c, ref) for c in r["at"]])


def run_scaling(problems: Sequence[BenchCase], suite: str, methods: Sequence[str], seeds: Sequence[int],
                budgets: Sequence[int], out_dir: Path, log: Callable[[str], None] | None = None) -> dict[str, Any]:
    """Every (problem, method, seed) run with its curve read at ``budgets``, as ratios to the reference."""
    rows: list[dict[str, Any]] = []
    refs: dict[str, Any] = {}
    budget = max(budgets)
    for p in problems:
        model = p.family == MODEL_FAMILY
        ref = None if model else reference_for(p, suite, out_dir, log=log).get("cost")
        n_gains = _n_gains(p)
        refs[p.name] = {"cost": ref, "n_gains": n_gains, "n_loops": len(p.tuning_spec().loops),
                        "basis": "best run" if model else "reference optimum"}
        for method in methods:
            for seed in seeds:
                row, _ = timed_row(functools.partial(run_method, p, method, seed, budget), {"cost": None, "curve": []})
                row.update(problem=p.name, method=method, seed=seed, n_gains=n_gains,
                           at=curve_at(row.get("curve") or [], budgets))
                rows.append(row)
                if log:
                    log(f"  {p.name} ({n_gains} gains) {method:<13} seed {seed}: answer {fmt(row.get('cost'))}"
                        f" curve {' '.join(fmt(x) for x in row['at'])} verdict {row.get('verdict')} "
                        f"({fmt(row.get('wall_time'), 3)} s)" + (f" ERROR {row['error']}" if row.get("error") else ""))
    _settle_references(refs, rows)
    return {"suite": suite, "methods": list(methods), "seeds": list(seeds), "budgets": list(budgets),
            "references": refs, "rows": rows, "load_average": list(os.getloadavg()), "cpus": os.cpu_count()}


def _cell(values: Sequence[float | None]) -> str:
    """``median (worst)`` over seeds, ``-`` when no run reached a feasible cost."""
    st = stats(values)
    if not st["n"]:
        return "-"
    return fmt_ratio(st["median"]) if st["n"] == 1 else f"{fmt_ratio(st['median'])} ({fmt_ratio(st['worst'])})"


def _yes(x: bool | None) -> str:
    return "-" if x is None else ("yes" if x else "NO")


def _stable(row: dict[str, Any]) -> str:
    """The stable cell, marked when it comes from the bench's linear check instead of the verdict."""
    linear = str(row.get("stability", "")).startswith("linear")
    return _yes(row.get("stable")) + (" (linear check)" if linear else "")


def render_markdown(result: dict[str, Any], command: str = "") -> str:
    """Per problem: one curve row per method (median and worst over seeds), then every run."""
    budgets = result["budgets"]
    la = result.get("load_average") or []
    lines = ["# gaintune bench scaling: budget-to-quality curves", ""]
    if command:
        lines += [f"Command: `{command}`", ""]
    lines += [f"Machine: {result.get('cpus')} CPUs, load average at the end {' '.join(f'{x:.1f}' for x in la)}. "
              "Cells: best feasible cost within that many simulations / the problem's reference (reference optimum; "
              "a built-in model's: the best cost any run reached), median over seeds (worst in brackets). "
              "`answer`: the method's own answer at the full budget (RL alone, `refine: false`), settled on the "
              "exact requirements; `stable`: its verified closed loop.", ""]
    for name, ref in result["references"].items():
        mine = [r for r in result["rows"] if r["problem"] == name]
        loops = f"{ref['n_loops']} loops, " if ref.get("n_loops") else ""
        lines += [f"## {name}: {loops}{ref['n_gains']} gains, reference {fmt(ref['cost'])} "
                  f"({ref.get('basis', 'reference optimum')})", ""]
        body = []
        for m in result["methods"]:
            rs = [r for r in mine if r["method"] == m]
            cells = [_cell([r["curve_ratio"][i] for r in rs]) for i in range(len(budgets))]
            body.append([m, *cells, _cell([r.get("ratio") for r in rs]),
                         fmt(stats([r.get("wall_time") for r in rs])["median"], 3)])
        lines += [md_table(["method", *(f"{b:,}" for b in budgets), "answer", "wall s (median)"], body), ""]
        runs = [[r["method"], r["seed"], fmt_ratio(r.get("ratio")), r.get("sims"), r.get("setup_sims", "-"),
                 fmt(r.get("wall_time"), 3), r.get("verdict") or "-",
                 _stable(r),
                 r.get("error") or r.get("check_error", "")] for r in mine]
        lines += [md_table(["method", "seed", "answer/ref", "sims", "set-up sims", "wall s", "verdict", "stable",
                            "error"], runs), ""]
    return "\n".join(lines).rstrip() + "\n"


def _spec_problems(paths: Sequence[str]) -> list[BenchCase]:
    """A benchmark problem per spec file (its reference is the default multistart search)."""
    from gaintune.errors import SpecError
    from gaintune.spec import load_spec

    out = []
    for path in paths:
        try:
            spec = load_spec(path)
        except (SpecError, OSError, ValueError) as exc:
            fail("--spec", f"{path}: {exc}")
        d = spec.model_dump(mode="json", exclude_defaults=True)
        out.append(BenchCase(Path(path).stem, f"spec file {path}", d, "spec"))
    return out


def build_parser() -> argparse.ArgumentParser:
    """The options of ``gaintune bench scaling``."""
    ap = BenchParser(prog="gaintune bench scaling",
                     description="Budget-to-quality curves of the RL search and CMA-ES on a suite's problems, built-in "
                                 "models or any spec file.")
    ap.add_argument("--suite", default="cascades", choices=suite_names(), help="benchmark suite (default: cascades)")
    ap.add_argument("--problems", nargs="+", metavar="NAME", help="problems of the suite or built-in model names, "
                    "e.g. quadrotor robot_arm6 process_train (default with --suite cascades: six_lag_cascade)")
    ap.add_argument("--spec", nargs="+", metavar="FILE", help="spec files to run instead of suite problems")
    ap.add_argument("--methods", nargs="+", choices=list(METHODS), default=["rl", "cmaes"],
                    help="methods (default: rl cmaes)")
    ap.add_argument("--seeds", nargs="+", type=seed_int, default=[0, 1, 2], help="seeds (default 0 1 2)")
    ap.add_argument("--budgets", nargs="+", type=budget_int, default=list(DEFAULT_BUDGETS),
                    help="simulation budgets the curve is read at; the largest is each run's budget")
    add_out_argument(ap)
    ap.add_argument("--quiet", action="store_true", help="no progress lines on stderr")
    return ap


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point of ``gaintune bench scaling`` (returns the exit code)."""
    args = build_parser().parse_args(argv)
    if args.spec:
        problems, suite = _spec_problems(args.spec), "spec"
    elif args.problems:
        problems, suite = resolve_problems(args.suite, args.problems), args.suite
    else:
        names = ["six_lag_cascade"] if args.suite == "cascades" else None
        problems, suite = select_problems(args.suite, names), args.suite
    out = resolve_out(args.out)
    log = None if args.quiet else (lambda s: print(s, file=sys.stderr, flush=True))
    command = ("gaintune bench scaling " + " ".join(sys.argv[1:] if argv is None else argv)).strip()
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        result = run_scaling(problems, suite, args.methods, args.seeds, sorted(args.budgets), out, log)
    result["command"] = command
    from gaintune.provenance import versions

    result["versions"] = versions()
    md = render_markdown(result, command)
    stem = "scaling_" + "-".join(p.name for p in problems)[:80]
    if args.methods != ["rl", "cmaes"]:  # a run of other methods does not overwrite the default table
        stem += "-" + "-".join(args.methods)
    jp, mp = write_outputs(result, Path(out), stem, md)
    print(md)
    print(f"wrote {jp} and {mp}", file=sys.stderr)
    return 0


if __name__ == "__main__":
    sys.exit(main())
