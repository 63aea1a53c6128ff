"""``gaintune bench quick``: ``gaintune tune --quick`` on the ``standard`` suite's SISO problems.

For every single-loop problem of the ``standard`` suite (:mod:`gaintune.bench.standard`: load steps
under Ms <= 1.4, setpoint steps under PM >= 60 deg) it runs
:func:`gaintune.tuners.quick.quick_tune` with the tuners of ``--tuners`` (default: the shipped
ones) and reports:

* the answer's cost / the suite's **reference** (:func:`gaintune.bench.references.reference_for`,
  cached in ``<out>/reference_standard.json``; computed and cached when missing) and its verdict,
  and which candidate won (the tuner's gains or a rule's, moved onto the boundary);
* the tuner's own candidate after the move onto the boundary, as a ratio to the reference;
* **AMIGO** and **SIMC** as the rules give them: ratio and verdict;
* the answer's in-process wall time (median, max), and apart the time with the rules' verdicts
  for the comparison. One untimed answer first compiles and warms the simulator, so the times
  are those of a warm process;
* the problems ``--quick`` refuses (no model applies, no tuner fits) with the message.

The summary's pass rate is over the problems whose reference passes (a refused problem counts as
not passed). Writes ``quick.md`` and ``quick.json`` to ``--out`` (default ``bench/results``).
Figures of a shared machine, never asserted in tests.
"""

from __future__ import annotations

import os
import shlex
import sys
import time
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from gaintune.bench.arguments import (
    BenchParser,
    add_out_argument,
    fail,
    int_range,
    load_now,
    load_span,
    resolve_out,
    select_problems,
)
from gaintune.bench.compare import fmt_ratio, md_table, publish, ratio, stats
from gaintune.bench.references import reference_for
from gaintune.bench.suite import BenchCase
from gaintune.errors import GaintuneError
from gaintune.tuners.quick import DEFAULT_REFINE

__all__ = ["SUITE", "siso_problems", "measure_problem", "measure", "summarize", "render", "main"]

#: The suite measured.
SUITE = "standard"


def siso_problems(names: Sequence[str] | None = None) -> list[BenchCase]:
    """The single-loop problems of the suite (the ``--problems`` among them)."""
    problems = select_problems(SUITE, list(names) if names else None)
    return [p for p in problems if len(p.spec["loops"]) == 1]


def _rule(row: dict[str, Any] | None, ref: float | None) -> dict[str, Any]:
    if row is None:
        return {"ratio": None, "verdict": None}
    return {"ratio": ratio(row.get("cost"), ref), "verdict": (row.get("details") or {}).get("verdict"),
            "reason": row.get("reason")}


def measure_problem(problem: BenchCase, out_dir: Path, tuners_dir: str | Path | None, refine: int = 0,
                    log: Callable[[str], None] | None = None) -> dict[str, Any]:
    """One problem: the reference, the quick answer (timed), the tuner's candidate and the rules."""
    from gaintune.tuners.quick import quick_tune

    ref = reference_for(problem, SUITE, out_dir, log=log)
    row: dict[str, Any] = {"problem": problem.name, "family": problem.family, "requirements":
                           problem.requirements_text(), "reference": ref.get("cost"),
                           "reference_passes": bool(ref.get("passes")), "reference_source": ref.get("source")}
    t0 = time.perf_counter()
    try:
        q = quick_tune(problem.tuning_spec(), tuners_dir=tuners_dir, refine=refine)
    except GaintuneError as exc:
        row.update(refused=f"{exc.field}: {exc.message}", wall_s=time.perf_counter() - t0)
        return row
    total = time.perf_counter() - t0
    by = {b["method"]: b for b in q.result.baselines}
    row.update(model=q.model.text(), tuner=q.tuner.name if q.tuner else "-",
               source=q.source + (" + refine" if q.refined else ""), refine_sims=q.refine_sims, cost=q.result.cost,
               ratio=ratio(q.result.cost, ref.get("cost")), verdict=q.verdict,
               tuner_ratio=ratio(q.tuner_cost, ref.get("cost")), wall_s=q.result.wall_time, total_s=total,
               timing=q.timing, notes=q.notes,
               gains=q.result.gains, **{m: _rule(by.get(m), ref.get("cost")) for m in ("amigo", "simc")})
    return row


def measure(problems: Sequence[BenchCase], out_dir: Path, tuners_dir: str | Path | None = None, refine: int = 0,
            log: Callable[[str], None] | None = None) -> dict[str, Any]:
    """Every problem's row (after one untimed warm-up answer) and the summary."""
    from gaintune.tuners.quick import quick_tune

    if problems:  # the first answer of a process compiles and warms the simulator: not timed
        try:
            quick_tune(problems[0].tuning_spec(), tuners_dir=tuners_dir)
        except GaintuneError:
            pass
    rows = []
    for p in problems:
        if log:
            log(f"{p.name} ...")
        rows.append(measure_problem(p, out_dir, tuners_dir, refine, log))
    return {"suite": SUITE, "tuners": str(tuners_dir) if tuners_dir else "shipped", "refine": refine, "rows": rows,
            "summary": summarize(rows)}


def summarize(rows: Sequence[dict[str, Any]]) -> dict[str, Any]:
    """Median/worst ratios, pass counts where the reference passes, wall time, wins, refusals."""
    answered = [r for r in rows if "refused" not in r]
    feasible = [r for r in rows if r["reference_passes"]]
    walls = [r["wall_s"] for r in answered]
    totals = [r["total_s"] for r in answered]
    out = {
        "problems": len(rows), "answered": len(answered), "refused": len(rows) - len(answered),
        "ratio": stats([r["ratio"] for r in answered]),
        "tuner_ratio": stats([r["tuner_ratio"] for r in answered]),
        "passed_where_reference_passes": sum(r.get("verdict") == "pass" for r in feasible),
        "reference_passes": len(feasible),
        "wall_s": {"median": float(np.median(walls)) if walls else None, "max": max(walls) if walls else None},
        "total_s": {"median": float(np.median(totals)) if totals else None, "max": max(totals) if totals else None},
        "source": {s: sum(str(r.get("source", "")).split(" ")[0] == s for r in answered)
                   for s in ("tuner", "amigo", "simc")},
        "refined": sum(str(r.get("source", "")).endswith("refine") for r in answered),
    }
    for m in ("amigo", "simc"):
        out[m] = {"ratio": stats([r[m]["ratio"] for r in answered if r[m]["verdict"] is not None]),
                  "passed": sum(r[m]["verdict"] == "pass" for r in answered),
                  "quick_not_worse_where_rule_passes": sum(
                      r[m]["verdict"] == "pass" and r["verdict"] == "pass" and r["ratio"] is not None
                      and r[m]["ratio"] is not None and r["ratio"] <= r[m]["ratio"] * (1 + 1e-9) for r in answered),
                  "rule_passes": sum(r[m]["verdict"] == "pass" for r in answered)}
    return out


def _summary_table(s: dict[str, Any]) -> str:
    r, t = s["ratio"], s["tuner_ratio"]
    rows = [
        ["quick answer: cost / reference, median (worst)", f"{fmt_ratio(r['median'])} ({fmt_ratio(r['worst'])})",
         "median <= 1.03"],
        ["quick answer: pass where the reference passes",
         f"{s['passed_where_reference_passes']} / {s['reference_passes']}", "all"],
        ["quick answer: wall time per problem, median / max (s)",
         f"{_s(s['wall_s']['median'])} / {_s(s['wall_s']['max'])}", "<= 1 s each"],
        ["with the rules' verdicts for the comparison, median / max (s)",
         f"{_s(s['total_s']['median'])} / {_s(s['total_s']['max'])}", ""],
        ["answered / refused", f"{s['answered']} / {s['refused']}", ""],
        ["tuner's candidate alone: cost / reference, median (worst)",
         f"{fmt_ratio(t['median'])} ({fmt_ratio(t['worst'])})", ""],
        ["winning candidate: tuner / amigo / simc (refinement improved it)",
         " / ".join(str(s["source"][k]) for k in ("tuner", "amigo", "simc")) + f" ({s['refined']})", ""],
    ]
    for m in ("amigo", "simc"):
        x = s[m]
        rows.append([f"{m.upper()} as the rule gives it: cost / reference, median (worst); passes",
                     f"{fmt_ratio(x['ratio']['median'])} ({fmt_ratio(x['ratio']['worst'])}); {x['passed']}", ""])
        rows.append([f"quick not worse than {m.upper()} where {m.upper()} passes",
                     f"{x['quick_not_worse_where_rule_passes']} / {x['rule_passes']}", ""])
    return md_table(["figure", "measured", "target"], rows)


def _s(x: float | None) -> str:
    return "-" if x is None else f"{x:.3f}"


def _cell(r: dict[str, Any]) -> str:
    if r["verdict"] is None:
        return "-"
    return fmt_ratio(r["ratio"]) + ("" if r["verdict"] == "pass" else " *")


def _problem_table(rows: Sequence[dict[str, Any]]) -> str:
    body = []
    for r in rows:
        if "refused" in r:
            body.append([r["problem"], "refused", "-", "-", "-", "-", "-", "-", _s(r["wall_s"]), r["refused"]])
            continue
        body.append([r["problem"], r["model"], r["tuner"], r["source"],
                     fmt_ratio(r["ratio"]) + ("" if r["verdict"] == "pass" else " *"),
                     fmt_ratio(r["tuner_ratio"]), _cell(r["amigo"]), _cell(r["simc"]), _s(r["wall_s"]),
                     "; ".join(r["notes"])])
    return md_table(["problem", "model", "tuner", "won", "quick", "tuner alone", "AMIGO", "SIMC", "s (answer)",
                     "notes"],
                    body)


def render(result: dict[str, Any], command: str) -> str:
    """The benchmark as Markdown: the command, the summary table and one row per problem."""
    lines = [f"# {command}", "",
             f"`gaintune tune --quick` on the SISO problems of the `{result['suite']}` suite; tuners: "
             f"{result['tuners']}; refine {result['refine']}; {os.cpu_count()} CPUs, load average "
             f"{result.get('loadavg', '-')}.", "",
             "Ratios are cost / the suite's cached reference (lower is better); `*` = verdict fail. "
             "`tuner alone` = the tuner's gains moved onto the true plant's boundary; `won` = the candidate "
             "the answer came from. Wall times are in-process, after one untimed warm-up answer; the answer's time "
             "(model, tuner, settling, refinement, verification) excludes the rules' verdicts for the comparison, "
             "shown apart.", "",
             "## Summary", "", _summary_table(result["summary"]), "", "## Per problem", "",
             _problem_table(result["rows"])]
    return "\n".join(lines) + "\n"


def build_parser() -> BenchParser:
    """The options of ``gaintune bench quick``."""
    ap = BenchParser(prog="gaintune bench quick", description=__doc__.splitlines()[0].split(": ", 1)[1])
    ap.add_argument("--problems", nargs="+", default=None, help="problems of the standard suite (default: all SISO)")
    ap.add_argument("--refine", type=int_range(0, 100_000), default=DEFAULT_REFINE,
                    help=f"simulations of the refinement after the settling (default {DEFAULT_REFINE}, as "
                         "`tune --quick`; 0: none)")
    ap.add_argument("--tuners", type=Path, default=None,
                    help="folder of tuner folders to choose from (default: the tuners shipped with gaintune)")
    add_out_argument(ap)
    return ap


def main(argv: Sequence[str] | None = None) -> int:
    """``gaintune bench quick``: measure, print the tables, write ``quick.md`` and ``quick.json``."""
    argv = list(sys.argv[1:] if argv is None else argv)
    args = build_parser().parse_args(argv)
    if args.tuners is not None and not args.tuners.is_dir():
        fail("--tuners", f"{args.tuners} is not a folder; give a folder of tuner folders (each with tuner.json)")
    out = resolve_out(args.out)
    command = shlex.join(["gaintune", "bench", "quick", *argv])
    load0 = load_now()
    result = measure(siso_problems(args.problems), out, args.tuners, args.refine,
                     log=lambda m: print(m, file=sys.stderr, flush=True))
    result["loadavg"] = load_span(load0)
    result["command"] = command
    return publish(result, out, "quick", render(result, command))


if __name__ == "__main__":
    raise SystemExit(main())
