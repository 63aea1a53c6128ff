"""``gaintune bench search``: how close the RL search gets to the optimum, at what cost.

For every problem of a suite and every seed, run :func:`gaintune.search.tune`
(the library's defaults; only the budget, seed and algorithm are set) and report

* ``RL/ref``: the RL agent alone (``rl_cost``: best of its deterministic policy
  and the best gains it saw) over the reference optimum;
* ``refined/ref``: the final answer after tune()'s local polish, over the reference;
* ``RL/CMA-ES``: ``rl_cost`` over CMA-ES run with the SAME number of
  simulations (``run_baseline(spec, "cmaes", budget=result.sims, seed)``);
* simulations used, wall time and the verification verdict of the frozen gains.

The summary gives the median and worst of each ratio over the runs, the
largest simulation count and wall time, and the verification pass rate.
Reference optima are cached in ``<out>/reference_<suite>.json`` keyed by a
hash of the problem (see :func:`gaintune.bench.references.reference_for`).

    gaintune bench search [--suite default] [--problems ...] [--algo ppo] [--budget N] [--seeds 0 1 2] [--out DIR]
    python -m gaintune.bench.search ...

Writes ``search_<suite>.md`` and ``search_<suite>.json`` to ``--out``.
"""

from __future__ import annotations

import argparse
import functools
import sys
import warnings
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

from gaintune.bench.arguments import (
    BenchParser,
    add_out_argument,
    budget_int,
    non_negative_int,
    resolve_out,
    seed_int,
    select_problems,
)
from gaintune.bench.compare import fmt, fmt_ratio, md_table, ratio, set_threads, stats, write_outputs
from gaintune.bench.references import reference_for, reference_summary
from gaintune.bench.suite import (
    BenchCase,
    describe_problems,
    suite_names,
    timed_row,
)

__all__ = ["run_one", "run_search", "summarize", "per_problem", "render_markdown", "main"]


def run_one(problem: BenchCase, seed: int, *, algo: str = "ppo", budget: int | None = None,
            reference: dict[str, Any] | None = None, repair: bool = True) -> dict[str, Any]:
    """One RL run on ``problem`` and CMA-ES at the same simulation count; the raw figures (no ratios).

    ``repair=False`` turns the RL search's constraint projection off (``search.repair``), for the ablation.
    """
    from gaintune.baselines import run_baseline
    from gaintune.envs.problem import GainProblem
    from gaintune.search import tune

    spec = problem.tuning_spec(budget=budget, seed=seed)
    if algo != spec.search.algo or not repair:
        spec = spec.model_copy(update={"search": spec.search.model_copy(update={"algo": algo, "repair": repair})})
    res = tune(spec, verify=True)
    cm = run_baseline(spec, "cmaes", budget=max(int(res.sims), 1), seed=seed, evaluator=GainProblem(spec).evaluator)
    return {
        "problem": problem.name,
        "seed": seed,
        "algo": res.algo,
        "budget": spec.search.budget,
        "rl_cost": res.rl_cost,
        "policy_cost": res.policy_cost,
        "cost": res.cost,
        "gains": res.gains,
        "gains_source": res.gains_source,
        "sims": res.sims,
        "rl_sims": res.rl_sims,
        "wall_time": res.wall_time,
        "stopped": res.stopped,
        "verdict": res.verdict,
        "reasons": list(res.verification.reasons) if res.verification is not None else [],
        "cmaes_cost": cm.cost,
        "cmaes_sims": cm.n_sims,
        "cmaes_wall_time": cm.wall_time,
    }


def _add_ratios(row: dict[str, Any], ref_cost: float | None) -> dict[str, Any]:
    row["reference_cost"] = ref_cost
    row["rl_ratio"] = ratio(row.get("rl_cost"), ref_cost)
    row["refined_ratio"] = ratio(row.get("cost"), ref_cost)
    row["rl_vs_cmaes"] = ratio(row.get("rl_cost"), row.get("cmaes_cost"))
    row["cmaes_ratio"] = ratio(row.get("cmaes_cost"), ref_cost)
    return row


def run_search(
    problems: Sequence[BenchCase],
    suite: str,
    seeds: Sequence[int] = (0, 1, 2),
    *,
    algo: str = "ppo",
    budget: int | None = None,
    out_dir: str | Path | None = None,
    refresh_reference: bool = False,
    log: Callable[[str], None] | None = None,
    runner: Callable[..., dict[str, Any]] | None = None,
) -> dict[str, Any]:
    """Every (problem, seed) run with ratios, per-problem aggregates and the summary (JSON-able).

    ``runner(problem, seed, algo=, budget=, reference=)`` defaults to :func:`run_one`.
    """
    runner = runner or run_one
    rows: list[dict[str, Any]] = []
    refs: dict[str, Any] = {}
    for p in problems:
        ref = reference_for(p, suite, out_dir, refresh=refresh_reference, log=log)
        refs[p.name] = reference_summary(ref, "gains")
        for seed in seeds:
            row, elapsed = timed_row(
                functools.partial(runner, p, seed, algo=algo, budget=budget, reference=ref),
                {"problem": p.name, "seed": seed, "algo": algo},
            )
            rows.append(_add_ratios(row, ref.get("cost")))
            if log:
                log(f"  {p.name:<20} seed {seed}: RL/ref {fmt_ratio(row['rl_ratio'])} refined/ref "
                    f"{fmt_ratio(row['refined_ratio'])} RL/CMA-ES {fmt_ratio(row['rl_vs_cmaes'])} "
                    f"sims {fmt(row.get('sims'))} {row.get('verdict')} "
                    f"({elapsed:.1f} s)" + (f" ERROR {row['error']}" if row.get("error") else ""))
    return {
        "suite": suite,
        "algo": algo,
        "seeds": list(seeds),
        "budget_override": budget,
        "problems": describe_problems(problems, budget),
        "references": refs,
        "rows": rows,
        "per_problem": per_problem(rows),
        "summary": summarize(rows),
    }


def per_problem(rows: Sequence[dict[str, Any]]) -> dict[str, dict[str, Any]]:
    """Per problem over its seeds: median and worst of each ratio, passes, largest sims and wall time."""
    out: dict[str, dict[str, Any]] = {}
    for name in dict.fromkeys(r["problem"] for r in rows):
        mine = [r for r in rows if r["problem"] == name]
        out[name] = {
            "runs": len(mine),
            "rl_ratio": stats([r.get("rl_ratio") for r in mine]),
            "refined_ratio": stats([r.get("refined_ratio") for r in mine]),
            "rl_vs_cmaes": stats([r.get("rl_vs_cmaes") for r in mine]),
            "pass": sum(1 for r in mine if r.get("verdict") == "pass"),
            "max_sims": stats([r.get("sims") for r in mine])["worst"],
            "max_wall_time": stats([r.get("wall_time") for r in mine])["worst"],
        }
    return out


def summarize(rows: Sequence[dict[str, Any]]) -> dict[str, Any]:
    """Median and worst ratios over all runs, largest sims and wall time, verification pass rate."""
    n = len(rows)
    passed = sum(1 for r in rows if r.get("verdict") == "pass")
    return {
        "runs": n,
        "errors": sum(1 for r in rows if r.get("error")),
        "rl_ratio": stats([r.get("rl_ratio") for r in rows]),
        "refined_ratio": stats([r.get("refined_ratio") for r in rows]),
        "rl_vs_cmaes": stats([r.get("rl_vs_cmaes") for r in rows]),
        "cmaes_ratio": stats([r.get("cmaes_ratio") for r in rows]),
        "max_sims": stats([r.get("sims") for r in rows])["worst"],
        "max_wall_time": stats([r.get("wall_time") for r in rows])["worst"],
        "median_wall_time": stats([r.get("wall_time") for r in rows])["median"],
        "pass": passed,
        "pass_rate": passed / n if n else None,
    }


#: What the search report's ratios mean (its opening paragraph).
_LEGEND = (
    "RL/ref = `rl_cost` (RL agent alone: best of deterministic policy and best gains seen) / reference optimum; "
    "refined/ref = final cost after tune()'s local polish / reference; RL/CMA-ES = `rl_cost` / CMA-ES cost at "
    "the same number of simulations (`result.sims`). Verdict = `verify()` of the frozen gains against the "
    "problem's requirements."
)


def render_markdown(result: dict[str, Any], command: str = "") -> str:
    """Runs table, per-problem table and summary as Markdown."""
    lines = [f"# gaintune bench search: suite `{result['suite']}`, algo `{result['algo']}`", ""]
    if command:
        lines += [f"Command: `{command}`", ""]
    lines += [_LEGEND, "", "## Summary", ""]
    lines += _summary_section(result["summary"])
    lines += ["## Per problem (over seeds: median, worst in brackets)", ""]
    lines += [_per_problem_table(result), "", "## Runs", ""]
    lines += [_runs_table(result["rows"]), ""]
    fails = [(r["problem"], r["seed"], r.get("error") or "; ".join(r.get("reasons") or []))
             for r in result["rows"] if r.get("error") or r.get("verdict") == "fail"]
    if fails:
        lines += ["Verification failures and errors:", ""]
        lines += [f"- {p} seed {s}: {why}" for p, s, why in fails]
        lines.append("")
    return "\n".join(lines).rstrip() + "\n"


def _summary_section(s: dict[str, Any]) -> list[str]:
    """Median and worst of each ratio over all runs, then one line of counts, spend and pass rate."""

    def mw(st: dict[str, Any]) -> list[Any]:
        return [fmt_ratio(st["median"]), fmt_ratio(st["worst"])]

    body = [
        ["RL/ref", *mw(s["rl_ratio"])],
        ["refined/ref", *mw(s["refined_ratio"])],
        ["RL/CMA-ES (same sims)", *mw(s["rl_vs_cmaes"])],
        ["CMA-ES/ref (same sims)", *mw(s["cmaes_ratio"])],
    ]
    pr = f"{s['pass']}/{s['runs']}" if s["runs"] else "-"
    return [
        md_table(["ratio", "median", "worst"], body),
        "",
        f"Runs: {s['runs']} (errors: {s['errors']}); max simulations {fmt(s['max_sims'])}; wall time median "
        f"{fmt(s['median_wall_time'], 3)} s, max {fmt(s['max_wall_time'], 3)} s; verification pass rate {pr}.",
        "",
    ]


def _median_worst_cell(st: dict[str, Any]) -> str:
    """``median (worst)`` of a ratio over seeds; the median alone for one seed, - for none."""
    if not st["n"]:
        return "-"
    return fmt_ratio(st["median"]) if st["n"] == 1 else f"{fmt_ratio(st['median'])} ({fmt_ratio(st['worst'])})"


def _per_problem_table(result: dict[str, Any]) -> str:
    """One row per problem: reference cost, each ratio over its seeds, passes, spend and requirements."""
    titles = {p["name"]: p for p in result["problems"]}
    body = []
    for name, pp in result["per_problem"].items():
        ref = result["references"].get(name, {})
        body.append([name, ref.get("cost"), _median_worst_cell(pp["rl_ratio"]),
                     _median_worst_cell(pp["refined_ratio"]), _median_worst_cell(pp["rl_vs_cmaes"]),
                     f"{pp['pass']}/{pp['runs']}", pp["max_sims"], pp["max_wall_time"],
                     titles.get(name, {}).get("requirements", "")])
    return md_table(["problem", "reference", "RL/ref", "refined/ref", "RL/CMA-ES", "pass", "max sims", "max wall s",
                     "requirements"], body)


def _runs_table(rows: list[dict[str, Any]]) -> str:
    """One row per (problem, seed) run: costs, ratios, spend, where the answer came from and the verdict."""
    body = []
    for r in rows:
        body.append([r["problem"], r["seed"], r.get("reference_cost"), r.get("rl_cost"), fmt_ratio(r.get("rl_ratio")),
                     r.get("cost"), fmt_ratio(r.get("refined_ratio")), r.get("cmaes_cost"),
                     fmt_ratio(r.get("rl_vs_cmaes")), r.get("sims"), r.get("rl_sims"), r.get("wall_time"),
                     r.get("gains_source"), "error" if r.get("error") else r.get("verdict")])
    return md_table(["problem", "seed", "reference", "RL cost", "RL/ref", "refined", "refined/ref", "CMA-ES",
                     "RL/CMA-ES", "sims", "RL sims", "wall s", "answer", "verdict"], body)


def build_parser() -> argparse.ArgumentParser:
    """The options of ``gaintune bench search``."""
    from gaintune.search.algos import ALGO_NAMES

    ap = BenchParser(
        prog="gaintune bench search",
        description="Measure the RL gain search against the reference optimum and CMA-ES at the same budget.",
    )
    ap.add_argument("--suite", default="default", choices=suite_names(), help="benchmark suite (default: default)")
    ap.add_argument("--problems", nargs="+", metavar="NAME", help="only these problems of the suite")
    ap.add_argument("--algo", default="ppo", choices=sorted(ALGO_NAMES), help="RL algorithm (default ppo)")
    ap.add_argument("--budget", type=budget_int,
                    help="simulation budget of every problem (default: each problem's own)")
    ap.add_argument("--seeds", nargs="+", type=seed_int, default=[0, 1, 2], help="seeds (default 0 1 2)")
    add_out_argument(ap)
    ap.add_argument("--refresh-reference", action="store_true", help="recompute the cached reference optima")
    ap.add_argument("--threads", type=non_negative_int, default=0,
                    help="torch threads for the run (default 0: keep the library's setting, GAINTUNE_TORCH_THREADS)")
    ap.add_argument("--quiet", action="store_true", help="no progress lines on stderr")
    ap.add_argument("--no-repair", action="store_true",
                    help="ablation: RL without the projection of infeasible samples onto the boundary (search.repair)")
    return ap


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point of ``gaintune bench search`` (returns the exit code)."""
    args = build_parser().parse_args(argv)
    problems = select_problems(args.suite, args.problems)
    out = resolve_out(args.out)
    set_threads(args.threads)
    log = None if args.quiet else (lambda s: print(s, file=sys.stderr, flush=True))
    command = ("gaintune bench search " + " ".join(sys.argv[1:] if argv is None else argv)).strip()
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        runner = functools.partial(run_one, repair=False) if args.no_repair else None
        result = run_search(problems, args.suite, args.seeds, algo=args.algo, budget=args.budget, out_dir=out,
                            refresh_reference=args.refresh_reference, log=log, runner=runner)
    result["command"] = command
    from gaintune.provenance import versions

    result["versions"] = versions()
    md = render_markdown(result, command)
    stem = f"search_{args.suite}" + (f"-{args.algo}" if args.algo != "ppo" else "")
    stem += "-no-repair" if args.no_repair else ""
    stem += "-partial" if (args.problems or args.budget is not None) else ""
    jp, mp = write_outputs(result, Path(out), stem, md)
    print(md)
    print(f"wrote {jp} and {mp}", file=sys.stderr)
    return 0


if __name__ == "__main__":
    sys.exit(main())
