"""``gaintune bench compare``: every baseline and the RL search on every problem of a suite.

For each problem and method: cost, IAE, effort, overshoot, GM, PM, Ms (from
:func:`gaintune.verification.verify`), the verdict, simulations, wall time and the
ratio to the reference optimum. Methods that do not apply (rules on LQ loops,
unstable or oscillatory plants) are listed as ``n/a`` with the reason. Ends
with a summary per method: median and worst ratio and the pass rate.

    gaintune bench compare [--suite default] [--problems lag3_pid ...] [--methods simc cmaes rl ...]
                           [--seed 0] [--budget N] [--out bench/results]
    python -m gaintune.bench.compare ...

Writes ``compare_<suite>.md`` and ``compare_<suite>.json`` to ``--out``.
The helpers below (ratios, statistics, Markdown) are shared with
:mod:`gaintune.bench.search`.
"""

from __future__ import annotations

import argparse
import functools
import json
import math
import sys
import warnings
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from gaintune.bench.arguments import (
    BenchParser,
    add_out_argument,
    budget_int,
    fail,
    non_negative_int,
    resolve_out,
    seed_int,
    select_problems,
)
from gaintune.bench.references import reference_for, reference_summary
from gaintune.bench.suite import (
    BenchCase,
    describe_problems,
    suite_names,
    timed_row,
)
from gaintune.evaluation.evaluator import DIVERGED_COST
from gaintune.fmt import fmt

if TYPE_CHECKING:  # pragma: no cover
    from gaintune.spec import Gains
    from gaintune.verification.report import VerificationReport

__all__ = [
    "DEFAULT_METHODS",
    "ratio",
    "stats",
    "fmt",
    "fmt_ratio",
    "md_table",
    "gain_figures",
    "run_method",
    "run_compare",
    "summarize",
    "render_markdown",
    "main",
]

#: Methods run by default, in table order (``rl`` = :func:`gaintune.search.tune`).
DEFAULT_METHODS: tuple[str, ...] = (
    "zn_step", "zn_ultimate", "simc", "amigo", "imc", "random", "cmaes", "de", "nelder_mead", "rl", "reference",
)


# ------------------------------------------------------------------ helpers


def ratio(cost: float | None, ref: float | None) -> float | None:
    """cost / ref; ``inf`` for a diverged cost; None when either is missing or ref <= 0."""
    if cost is None or ref is None or not (ref > 0) or not math.isfinite(ref):
        return None
    if not math.isfinite(cost) or cost >= DIVERGED_COST:
        return math.inf
    return float(cost) / float(ref)


def stats(values: Sequence[float | None]) -> dict[str, float | int | None]:
    """Median and worst (max) of the non-None values (inf counts as worst); n = how many."""
    v = [float(x) for x in values if x is not None and not (isinstance(x, float) and math.isnan(x))]
    if not v:
        return {"n": 0, "median": None, "worst": None}
    return {"n": len(v), "median": float(np.median(v)), "worst": float(max(v))}


def fmt_ratio(x: Any) -> str:
    """Ratio cell: 4 decimals (1.0003 must not print as 1), '-' when missing, 'inf' when diverged."""
    if x is None or (isinstance(x, float) and math.isnan(x)):
        return "-"
    if isinstance(x, str):
        return x
    if math.isinf(x):
        return "inf"
    return f"{x:.4f}" if x < 100 else f"{x:.4g}"


def md_table(header: Sequence[str], rows: Sequence[Sequence[Any]]) -> str:
    """A Markdown table (cells formatted with :func:`fmt`, '|' escaped)."""
    def cell(x: Any) -> str:
        return fmt(x).replace("|", "\\|").replace("\n", " ")

    out = ["| " + " | ".join(header) + " |", "|" + "|".join("---" for _ in header) + "|"]
    out += ["| " + " | ".join(cell(c) for c in r) + " |" for r in rows]
    return "\n".join(out)


def _jsonable(x: Any) -> Any:
    """inf/nan -> strings 'inf'/'-inf'/None, numpy scalars -> Python (strict JSON)."""
    if isinstance(x, dict):
        return {str(k): _jsonable(v) for k, v in x.items()}
    if isinstance(x, (list, tuple)):
        return [_jsonable(v) for v in x]
    if isinstance(x, (np.floating, np.integer)):
        x = x.item()
    if isinstance(x, float):
        if math.isnan(x):
            return None
        if math.isinf(x):
            return "inf" if x > 0 else "-inf"
    return x


def _verification_figures(report: VerificationReport) -> dict[str, Any]:
    """Binding GM (dB, min), PM (deg, min), Ms (max) over loops/break points, verdict and reasons."""
    loops = report.loops
    return {"gm_db": min((f.gm_db for f in loops), default=None),
            "pm_deg": min((f.pm_deg for f in loops), default=None),
            "ms": max((f.ms for f in loops), default=None), "stable": report.stability.stable,
            "verdict": report.verdict, "reasons": list(report.reasons)}


def gain_figures(problem_obj, gains: Gains, report: VerificationReport | None = None) -> dict[str, Any]:
    """Cost and time-domain metrics of ``gains`` on the nominal problem, plus verification figures.

    ``problem_obj`` is a :class:`gaintune.envs.problem.GainProblem`. IAE and effort are
    summed over scenarios by weight; overshoot (%) is the largest over the scenarios.
    ``report`` is the verification report of ``gains`` (run here when omitted).
    """
    from gaintune.verification import verify

    ev, layout = problem_obj.evaluator, problem_obj.layout
    spec = problem_obj.spec
    tuned = np.asarray(layout.from_dict(gains))[layout.tuned_idx]
    n0 = ev.n_sims
    scores = ev.evaluate(tuned[None, :])
    ev.n_sims = n0  # scoring for the table is not part of any method's budget
    costs, results = scores.cost, scores.results
    iae = effort = perf = 0.0
    measure = spec.objective.measure
    over: list[float] = []
    diverged = False
    for sc, r in zip(spec.scenarios, results, strict=True):  # one result per scenario
        m = r.metrics
        iae += sc.weight * float(m["iae"][0])
        perf += sc.weight * float(m[measure][0])
        effort += sc.weight * float(m["effort"][0])
        diverged |= bool(m["diverged"][0])
        o = float(m["overshoot"][0])
        if math.isfinite(o):
            over.append(o)
    figures: dict[str, Any]
    try:
        if report is None:
            report = verify(spec, gains, plant=problem_obj.plant, layout=layout)
    except Exception as exc:  # a gain set verification rejects is reported, not fatal
        figures = {"gm_db": None, "pm_deg": None, "ms": None, "stable": None, "verdict": "fail",
                   "reasons": [f"verification error: {type(exc).__name__}: {exc}"]}
    else:
        figures = _verification_figures(report)
    out = {
        "cost": float(costs[0]),  # the plain cost, never a penalised figure
        "feasible": bool(scores.feasible[0]),
        "iae": None if diverged else iae,
        "perf": None if diverged else perf,
        "measure": measure,
        "effort": None if diverged else effort,
        "overshoot": max(over) if over and not diverged else None,
        "diverged": diverged or float(costs[0]) >= DIVERGED_COST,
    }
    out.update(figures)
    return out


# ------------------------------------------------------------------ running


def run_method(
    problem: BenchCase, method: str, *, seed: int = 0, budget: int | None = None,
    reference: dict[str, Any] | None = None, agent_overrides: dict[str, Any] | None = None,
) -> dict[str, Any]:
    """One (problem, method) row: applicability, gains, cost, metrics, verification, sims, wall time."""
    from gaintune.baselines import run_baseline
    from gaintune.envs.problem import GainProblem

    spec = problem.tuning_spec(budget=budget, seed=seed)
    gp = GainProblem(spec)
    row: dict[str, Any] = {"problem": problem.name, "method": method, "applicable": True, "reason": None}
    report = None
    extra: dict[str, Any] = {}
    if method == "reference":
        if reference is None or reference.get("gains") is None:
            return {**row, "applicable": False, "reason": "no reference optimum"}
        gains, sims, wall = reference["gains"], reference.get("n_sims", 0), reference.get("wall_time", 0.0)
        extra = {"source": reference.get("source"), "cached": True}
    elif method == "rl":
        from gaintune.search import tune

        tr = tune(spec, verify=True, agent_overrides=agent_overrides)
        gains, sims, wall, report = tr.gains, tr.sims, tr.wall_time, tr.verification
        extra = {"rl_cost": tr.rl_cost, "policy_cost": tr.policy_cost, "gains_source": tr.gains_source,
                 "rl_sims": tr.rl_sims}
    else:
        br = run_baseline(spec, method, budget=spec.search.budget, seed=seed, evaluator=gp.evaluator)
        if br.gains is None:
            return {**row, "applicable": False, "reason": br.reason, "wall_time": br.wall_time}
        gains, sims, wall = br.gains, br.n_sims, br.wall_time
    row.update(gains=gains, sims=int(sims), wall_time=float(wall), **extra)
    row.update(gain_figures(gp, gains, report))
    return row


def run_compare(
    problems: Sequence[BenchCase],
    suite: str,
    methods: Sequence[str] = DEFAULT_METHODS,
    *,
    seed: int = 0,
    budget: int | None = None,
    out_dir: str | Path | None = None,
    refresh_reference: bool = False,
    log: Callable[[str], None] | None = None,
    runner: Callable[..., dict[str, Any]] | None = None,
) -> dict[str, Any]:
    """Run every method on every problem; returns the JSON-able result (rows, references, summary).

    ``runner(problem, method, seed=, budget=, reference=)`` defaults to :func:`run_method`.
    """
    runner = runner or run_method
    rows: list[dict[str, Any]] = []
    refs: dict[str, Any] = {}
    for p in problems:
        ref = reference_for(p, suite, out_dir, refresh=refresh_reference, log=log)
        refs[p.name] = reference_summary(ref, "exact")
        for m in methods:
            row, elapsed = timed_row(
                functools.partial(runner, p, m, seed=seed, budget=budget, reference=ref),
                {"problem": p.name, "method": m, "applicable": True, "cost": None},
            )
            row["ratio"] = ratio(row.get("cost"), ref.get("cost")) if row.get("applicable") else None
            rows.append(row)
            if log:
                what = (f"cost {fmt(row.get('cost'))} ratio {fmt(row['ratio'])} {row.get('verdict')}"
                        if row.get("applicable") else f"n/a: {row.get('reason')}")
                log(f"  {p.name:<20} {m:<12} {what} ({elapsed:.1f} s)")
    return {
        "suite": suite,
        "seed": seed,
        "budget_override": budget,
        "methods": list(methods),
        "problems": describe_problems(problems, budget),
        "references": refs,
        "rows": rows,
        "summary": summarize(rows, methods),
    }


def summarize(rows: Sequence[dict[str, Any]], methods: Sequence[str]) -> dict[str, dict[str, Any]]:
    """Per method: problems applied to, n/a count, median and worst ratio, pass rate, divergences."""
    out: dict[str, dict[str, Any]] = {}
    for m in methods:
        mine = [r for r in rows if r["method"] == m]
        app = [r for r in mine if r.get("applicable")]
        st = stats([r.get("ratio") for r in app])
        passed = sum(1 for r in app if r.get("verdict") == "pass")
        out[m] = {
            "applied": len(app),
            "n_a": len(mine) - len(app),
            "median_ratio": st["median"],
            "worst_ratio": st["worst"],
            "pass": passed,
            "pass_rate": passed / len(app) if app else None,
            "diverged": sum(1 for r in app if r.get("diverged")),
            "errors": sum(1 for r in app if r.get("error")),
            "median_sims": stats([r.get("sims") for r in app])["median"],
            "max_wall_time": stats([r.get("wall_time") for r in app])["worst"],
        }
    return out


# ------------------------------------------------------------------ output


def _cost_cell(r: dict[str, Any]) -> Any:
    if r.get("error"):
        return "error"
    if r.get("diverged"):
        return "diverged"
    return r.get("cost")


#: What the comparison's figures mean (the report's opening paragraph).
_LEGEND = (
    "Ratio = cost / reference optimum (1 = optimal). GM (dB) and PM (deg) are the smallest, Ms the largest "
    "over loops and break points (loop-at-a-time, from `verify()`); the verdict checks the problem's "
    "requirements. perf = the objective's performance measure (IAE, or ISE for the LQ problem) and effort = "
    "int u^2, both summed over scenarios; overshoot is the largest over scenarios. Sims = closed-loop "
    "simulations spent (rules: 1; reference: its own multistart budget, cached)."
)


def render_markdown(result: dict[str, Any], command: str = "") -> str:
    """The comparison as Markdown: one table per problem, a ratio matrix, the per-method summary."""
    lines = [f"# gaintune bench compare: suite `{result['suite']}`", ""]
    if command:
        lines += [f"Command: `{command}`", ""]
    lines += [_LEGEND, "", "## Summary per method", ""]
    lines += [_summary_table(result), "", "## Ratio to the reference optimum", ""]
    by = {(r["problem"], r["method"]): r for r in result["rows"]}
    lines += [_ratio_matrix(result, by), "", "`*` = verification verdict fail; n/a = method does not apply.", ""]
    lines += ["## Per problem", ""]
    for p in result["problems"]:
        lines += _problem_section(result, p, by)
    return "\n".join(lines).rstrip() + "\n"


def _summary_table(result: dict[str, Any]) -> str:
    """One row per method: applicability, median and worst ratio, pass rate, divergences, spend."""
    head = ["method", "applied", "n/a", "median ratio", "worst ratio", "pass rate", "diverged", "median sims",
            "max wall s"]
    body = []
    for m in result["methods"]:
        s = result["summary"][m]
        pr = None if s["pass_rate"] is None else f"{s['pass']}/{s['applied']}"
        body.append([m, s["applied"], s["n_a"], fmt_ratio(s["median_ratio"]), fmt_ratio(s["worst_ratio"]), pr,
                     s["diverged"], s["median_sims"], s["max_wall_time"]])
    return md_table(head, body)


def _ratio_cell(r: dict[str, Any] | None) -> str:
    """A ratio-matrix cell: the ratio (``*`` when verification fails), or -, n/a, error."""
    if r is None:
        return "-"
    if not r.get("applicable"):
        return "n/a"
    if r.get("error"):
        return "error"
    mark = "" if r.get("verdict") == "pass" else "*"
    return fmt_ratio(r.get("ratio")) + mark


def _ratio_matrix(result: dict[str, Any], by: dict[tuple[str, str], dict[str, Any]]) -> str:
    """Problems down, methods across: every row's ratio to the reference optimum."""
    methods = result["methods"]
    mat = [[p["name"], *(_ratio_cell(by.get((p["name"], m))) for m in methods)] for p in result["problems"]]
    return md_table(["problem", *methods], mat)


def _problem_section(result: dict[str, Any], p: dict[str, Any], by: dict[tuple[str, str], dict[str, Any]]) -> list[str]:
    """One problem's heading, objective and reference, its table of methods and the n/a or error notes."""
    head = ["method", "cost", "ratio", "perf", "effort", "overshoot %", "GM dB", "PM deg", "Ms", "verdict", "sims",
            "wall s"]
    ref = result["references"].get(p["name"], {})
    lines = [
        f"### {p['name']}: {p['title']}",
        "",
        f"Objective {p['objective']}; requirements {p['requirements']}; budget {p['budget']} simulations; "
        f"reference cost {fmt(ref.get('cost'), 7)} ({ref.get('source')}).",
        "",
    ]
    body: list[list[Any]] = []
    notes = []
    for m in result["methods"]:
        r = by.get((p["name"], m))
        if r is None:
            continue
        if not r.get("applicable"):
            body.append([m, "n/a", "-", "-", "-", "-", "-", "-", "-", "-", "-", r.get("wall_time")])
            notes.append(f"- {m}: n/a - {r.get('reason')}")
            continue
        body.append([m, _cost_cell(r), fmt_ratio(r.get("ratio")), r.get("perf"), r.get("effort"), r.get("overshoot"),
                     r.get("gm_db"), r.get("pm_deg"), r.get("ms"), r.get("verdict"), r.get("sims"),
                     r.get("wall_time")])
        if r.get("error"):
            notes.append(f"- {m}: error - {r['error']}")
    lines += [md_table(head, body), ""]
    if notes:
        lines += notes + [""]
    return lines


def write_outputs(result: dict[str, Any], out_dir: Path, stem: str, markdown: str) -> tuple[Path, Path]:
    """Write ``<stem>.json`` and ``<stem>.md`` to ``out_dir`` (created if missing).

    Exits 2 naming ``--out`` when they cannot be written.
    """
    out_dir = Path(out_dir)
    jp, mp = out_dir / f"{stem}.json", out_dir / f"{stem}.md"
    try:  # --out was checked at parse time; this catches a folder removed or filled since
        out_dir.mkdir(parents=True, exist_ok=True)
        jp.write_text(json.dumps(_jsonable(result), indent=1) + "\n")
        mp.write_text(markdown)
    except OSError as exc:
        fail("--out", f"cannot write {exc.filename or out_dir} ({exc.strerror or exc}); give a writable folder")
    return jp, mp


def publish(result: dict[str, Any], out_dir: Path, stem: str, markdown: str) -> int:
    """Print ``markdown``, write ``<stem>.json`` and ``<stem>.md`` (:func:`write_outputs`), say where; returns 0."""
    print(markdown)
    _, mp = write_outputs(result, out_dir, stem, markdown)
    print(f"wrote {mp}")
    return 0


def set_threads(n: int | None) -> None:
    """Limit torch's intra-op threads (small MLPs on a busy machine run far faster on one thread)."""
    if n is None or n <= 0:
        return
    try:
        import torch

        torch.set_num_threads(n)
    except ImportError:
        pass


# ------------------------------------------------------------------ CLI


def build_parser() -> argparse.ArgumentParser:
    """The options of ``gaintune bench compare``."""
    from gaintune.baselines import METHODS

    ap = BenchParser(
        prog="gaintune bench compare",
        description="Compare classical rules, black-box optimisers, the RL search and the reference optimum on a "
        "benchmark suite.",
    )
    ap.add_argument("--suite", default="default", choices=suite_names(), help="benchmark suite (default: default)")
    ap.add_argument("--problems", nargs="+", metavar="NAME", help="only these problems of the suite")
    ap.add_argument("--methods", nargs="+", metavar="METHOD", default=list(DEFAULT_METHODS), choices=[*METHODS, "rl"],
                    help=f"methods in table order, from {' '.join([*METHODS, 'rl'])} "
                    f"(default: {' '.join(DEFAULT_METHODS)})")
    ap.add_argument("--seed", type=seed_int, default=0, help="seed of the stochastic methods (default 0)")
    ap.add_argument("--budget", type=budget_int,
                    help="simulation budget of every problem (default: each problem's own)")
    add_out_argument(ap)
    ap.add_argument("--refresh-reference", action="store_true", help="recompute the cached reference optima")
    ap.add_argument("--threads", type=non_negative_int, default=0,
                    help="torch threads for the run (default 0: keep the library's setting, GAINTUNE_TORCH_THREADS)")
    ap.add_argument("--quiet", action="store_true", help="no progress lines on stderr")
    return ap


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point of ``gaintune bench compare`` (returns the exit code)."""
    args = build_parser().parse_args(argv)
    problems = select_problems(args.suite, args.problems)
    out = resolve_out(args.out)
    set_threads(args.threads)
    log = None if args.quiet else (lambda s: print(s, file=sys.stderr, flush=True))
    command = "gaintune bench compare " + " ".join(sys.argv[1:] if argv is None else argv)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        result = run_compare(problems, args.suite, args.methods, seed=args.seed, budget=args.budget, out_dir=out,
                             refresh_reference=args.refresh_reference, log=log)
    result["command"] = command.strip()
    from gaintune.provenance import versions

    result["versions"] = versions()
    md = render_markdown(result, command.strip())
    stem = f"compare_{args.suite}" + ("" if not args.problems and args.budget is None else "-partial")
    jp, mp = write_outputs(result, Path(out), stem, md)
    print(md)
    print(f"wrote {jp} and {mp}", file=sys.stderr)
    return 0


if __name__ == "__main__":
    sys.exit(main())
