"""``gaintune bench scale``: budget-to-quality curves of RL alone and CMA-ES as the gain count grows.

Each problem is a built-in model's example spec (``quadrotor``, ``robot_arm6``, ``process_train``, ...),
a spec file, or a benchmark-suite problem written ``suite:<suite>/<problem>`` (e.g.
``suite:cascades/six_lag_cascade``). For every problem, method and seed one search runs at the largest
budget and its anytime curve is read at every budget of ``--budgets``: the best feasible cost found
within that many simulations. The RL search runs alone (``refine: false``) and its count includes its
set-up simulations (the search box and the reward scale; column ``set-up sims``); CMA-ES
(``run_baseline(spec, "cmaes")``) searches the same box from the same start and counts only its own
simulations. Each answer's closed-loop stability is checked on the linear continuous-time loop
(:mod:`gaintune.bench.scale_check`; the MIMO verdict itself is ``-`` until MIMO verification is wired).

Cells are costs over the best cost any run reached on that problem (``best``), so 1.000 is the best
answer seen; the bench does not compute a separate reference optimum (at 100+ gains it would cost
more than the runs). Wall time per run and the machine's load average are printed with the table.

    gaintune bench scale --problems quadrotor robot_arm6 process_train --budgets 500 1000 2000 --seeds 0
"""

from __future__ import annotations

import argparse
import os
import sys
import time
import warnings
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

from gaintune.bench.arguments import BenchParser, add_out_argument, budget_int, fail, resolve_out, seed_int
from gaintune.bench.compare import fmt_ratio, md_table, write_outputs

__all__ = ["METHODS", "curve_at", "load_problem", "run_one", "run_scale", "render_markdown", "main"]

#: The methods compared: the RL search alone and CMA-ES at equal budget.
METHODS = ("rl", "cmaes")


def curve_at(points: Sequence[tuple[int, float]], budgets: Sequence[int]) -> list[float | None]:
    """Best cost within each budget; ``points`` are (simulations, best feasible cost so far)."""
    out: list[float | None] = []
    for b in budgets:
        within = [c for s, c in points if s <= b]
        out.append(min(within) if within else None)
    return out


def load_problem(name: str) -> Any:
    """The :class:`~gaintune.spec.TuningSpec` of a model name, a spec file or ``suite:<suite>/<problem>``."""
    from gaintune.errors import SpecError
    from gaintune.spec import load_spec

    try:
        if name.startswith("suite:"):
            from gaintune.bench.arguments import select_problems

            suite, _, prob = name[len("suite:"):].partition("/")
            return select_problems(suite, [prob])[0].tuning_spec()
        if Path(name).suffix in (".yaml", ".yml", ".json"):
            return load_spec(name)
        from gaintune.plants.library import load_model

        return load_spec(load_model(name).example_spec())
    except (SpecError, OSError, ValueError, KeyError) as exc:
        fail("--problems", f"{name}: {exc} (give a built-in model name, a spec file or suite:<suite>/<problem>)")


def _with_search(spec: Any, budget: int, seed: int) -> Any:
    search = spec.search.model_copy(update={"budget": budget, "seed": seed, "refine": False})
    return spec.model_copy(update={"search": search})


def run_one(spec: Any, method: str, seed: int, budget: int) -> dict[str, Any]:
    """One search of ``method`` at ``budget`` simulations: its answer, anytime curve and wall time."""
    spec = _with_search(spec, budget, seed)
    t0 = time.perf_counter()
    if method == "cmaes":
        from gaintune.baselines import run_baseline

        cm = run_baseline(spec, "cmaes", budget=budget, seed=seed)
        out: dict[str, Any] = {"cost": cm.cost, "feasible": cm.feasible, "sims": cm.n_sims, "setup_sims": 0,
               "wall_time": time.perf_counter() - t0, "curve": [list(p) for p in cm.history]}
        gains = cm.gains
    else:
        from gaintune.search import tune

        res = tune(spec, verify=True)
        curve = [[res.setup_sims + c.sims, c.best_cost] for c in res.curve if c.feasible]
        out = {"cost": res.rl_cost, "feasible": res.rl_feasible, "sims": res.sims, "setup_sims": res.setup_sims,
               "wall_time": time.perf_counter() - t0, "verdict": res.verdict, "curve": curve}
        gains = res.gains
    if gains is not None:
        from gaintune.bench.scale_check import closed_loop_stable

        try:
            out["stable"], out["stability"] = closed_loop_stable(spec, gains)
        except Exception as exc:  # noqa: BLE001 - a failed check must not lose the run's figures
            out["stable"], out["stability"] = None, f"check failed: {type(exc).__name__}: {exc}"
    return out


def _n_gains(spec: Any) -> int:
    from gaintune.sim import Simulator

    return int(Simulator(spec).layout.n_tuned)


def run_scale(names: Sequence[str], methods: Sequence[str], seeds: Sequence[int], budgets: Sequence[int],
              log: Callable[[str], None] | None = None) -> dict[str, Any]:
    """Every (problem, method, seed) run, with its curve read at ``budgets``."""
    rows: list[dict[str, Any]] = []
    problems: dict[str, Any] = {}
    for name in names:
        spec = load_problem(name)
        n = _n_gains(spec)
        problems[name] = {"n_gains": n, "n_loops": len(spec.loops)}
        for method in methods:
            for seed in seeds:
                try:
                    row = run_one(spec, method, seed, max(budgets))
                except Exception as exc:  # noqa: BLE001 - a failed run is a row of the table, not a crash
                    row = {"cost": None, "curve": [], "error": f"{type(exc).__name__}: {exc}"}
                row.update(problem=name, method=method, seed=seed, n_gains=n,
                           at=curve_at(row.get("curve") or [], budgets))
                rows.append(row)
                if log:
                    log(f"  {name} ({n} gains) {method:<6} seed {seed}: cost {row.get('cost')} "
                        f"wall {row.get('wall_time', 0):.1f} s" + (f" ERROR {row['error']}" if "error" in row else ""))
    for name in names:
        costs = [c for r in rows if r["problem"] == name for c in [r.get("cost"), *r["at"]] if c is not None]
        problems[name]["best"] = min(costs) if costs else None
    return {"methods": list(methods), "seeds": list(seeds), "budgets": list(budgets), "problems": problems,
            "rows": rows, "load_average": list(os.getloadavg()), "cpus": os.cpu_count()}


def _r(c: float | None, best: float | None) -> str:
    return fmt_ratio(c / best) if c is not None and best else "-"


def _yes(x: bool | None) -> str:
    return "-" if x is None else ("yes" if x else "NO")


def render_markdown(result: dict[str, Any], command: str = "") -> str:
    """Per problem: one row per run, the curve as cost / best, then the answer, verdict and wall time."""
    budgets = result["budgets"]
    la = result.get("load_average") or []
    lines = ["# gaintune bench scale: budget-to-quality curves, RL alone vs CMA-ES", ""]
    if command:
        lines += [f"Command: `{command}`", ""]
    lines += [f"Machine: {result.get('cpus')} CPUs, load average at the end "
              f"{' '.join(f'{x:.1f}' for x in la)}. Cells: best feasible cost within that many simulations / the "
              "best cost any run reached on the problem (`best`).", ""]
    for name, p in result["problems"].items():
        lines += [f"## {name}: {p['n_loops']} loops, {p['n_gains']} tuned gains, best {p['best']}", ""]
        body = [[r["method"], r["seed"], *(_r(c, p["best"]) for c in r["at"]), _r(r.get("cost"), p["best"]),
                 r.get("setup_sims", "-"), _yes(r.get("stable")), r.get("verdict") or "-",
                 f"{r.get('wall_time', 0):.1f}", r.get("error", "")]
                for r in result["rows"] if r["problem"] == name]
        lines += [md_table(["method", "seed", *(f"{b:,}" for b in budgets), "answer", "set-up sims",
                            "closed loop stable", "verdict", "wall s", "error"], body), ""]
    return "\n".join(lines).rstrip() + "\n"


def build_parser() -> argparse.ArgumentParser:
    """The options of ``gaintune bench scale``."""
    ap = BenchParser(prog="gaintune bench scale",
                     description="Budget-to-quality curves of RL alone and CMA-ES on built-in models or spec files.")
    ap.add_argument("--problems", nargs="+", metavar="NAME", default=["quadrotor", "robot_arm6", "process_train"],
                    help="built-in model names, spec files or suite:<suite>/<problem>")
    ap.add_argument("--methods", nargs="+", choices=METHODS, default=list(METHODS), help="methods (default: both)")
    ap.add_argument("--seeds", nargs="+", type=seed_int, default=[0], help="seeds (default 0)")
    ap.add_argument("--budgets", nargs="+", type=budget_int, default=[250, 500, 1000],
                    help="budgets the curve is read at; the largest is each run's budget")
    add_out_argument(ap)
    ap.add_argument("--quiet", action="store_true", help="no progress lines on stderr")
    return ap


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point of ``gaintune bench scale`` (returns the exit code)."""
    args = build_parser().parse_args(argv)
    for name in args.problems:  # refuse a bad name before any search starts
        load_problem(name)
    out = resolve_out(args.out)
    log = None if args.quiet else (lambda s: print(s, file=sys.stderr, flush=True))
    command = ("gaintune bench scale " + " ".join(sys.argv[1:] if argv is None else argv)).strip()
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        result = run_scale(args.problems, args.methods, args.seeds, sorted(args.budgets), log)
    result["command"] = command
    md = render_markdown(result, command)
    jp, mp = write_outputs(result, Path(out), "scale_" + "-".join(Path(p).stem for p in args.problems)[:80], md)
    print(md)
    print(f"wrote {jp} and {mp}", file=sys.stderr)
    return 0


if __name__ == "__main__":
    sys.exit(main())
