"""``gaintune bench tuners``: a trained tuner against the per-plant optimum and the classical rules.

On ``--plants`` held-out FOTD plants ``K e^{-Ls}/(Ts+1)`` (seed ``--seed``, default 12345, which no
tuner is trained on; L/T log-uniform over 0.05..10, T over 1..100 s, K over 0.5..5), each with the
one tuning problem of the FOTD tuners (:func:`gaintune.tuners.families.problem_spec`: unit load
step at the input, cost = its IAE, Ms <= 1.4 at the exact limit), it measures:

* the **reference**: the per-plant constrained optimum (PI: the MIGO boundary optimum; PID: a
  multistart search or the best rule), verified, cached in ``<out>/reference_tuners.json``
  (:mod:`gaintune.bench.tuners_refs`);
* **AMIGO** and **SIMC** on the plant's exact model: ratio = cost / reference cost, and the verdict;
* the **tuner** ``--tuner`` (default ``fotd_pi_ms1.4``, ``fotd_pid_ms1.4`` for ``--ctype pid``) zero-shot
  and with ``--refine N`` extra simulations: the same ratio and verdict, recomputed here from its gains
  (and compared with the cost and verdict it reports), how often it beats each rule where the rule
  passes (the exceptions listed), and its answer time: in-process percentiles of the policy's forward
  pass and of the whole answer (wall and process CPU time), and ``gaintune tuner query`` as
  ``--fresh-runs`` fresh processes (wall and CPU time; :mod:`gaintune.bench.tuners_timing`).

``--rules-only`` measures the rules against the reference alone. Without it, a tuner that cannot be
imported or loaded exits 2 before any work. Writes ``tuners.md`` and ``tuners.json`` to ``--out``
(default ``bench/results``). Timings are figures of a shared machine, never asserted in tests.
"""

from __future__ import annotations

import os
import shlex
import sys
import time
from collections.abc import Callable, Mapping, Sequence
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
    seed_int,
)
from gaintune.bench.compare import fmt_ratio, md_table, publish, ratio, stats
from gaintune.bench.references import RESCORE_RTOL
from gaintune.bench.tuners_refs import (
    HELD_OUT_SEED,
    RULES,
    Case,
    held_out_plants,
    judge,
    make_case,
    reference_for_plant,
    rule_gains,
)
from gaintune.bench.tuners_timing import fresh_process_timing, in_process_timing
from gaintune.bench.tuners_update import CHUNK, CURVE_EVERY, training_figures
from gaintune.fmt import fmt

__all__ = ["DEFAULT_TUNER", "MS_MAX", "TunerUnavailable", "load_tuner", "measure", "render", "main"]

#: The shipped tuner each controller type is judged by default.
DEFAULT_TUNER = {"pi": "fotd_pi_ms1.4", "pid": "fotd_pid_ms1.4"}
#: The Ms limit of the tuning problem (the shipped tuners' ``ms1.4``).
MS_MAX = 1.4
#: Display names of the methods, in table order.
TITLES = {"amigo": "AMIGO", "simc": "SIMC", "tuner": "tuner", "refine": "tuner + refine"}


class TunerUnavailable(Exception):
    """The trained tuner cannot be imported or loaded (the message says which and why)."""


def load_tuner(name: str) -> Any:
    """``gaintune.tuners.tuner.Tuner.load(name)``; :class:`TunerUnavailable` with the reason otherwise."""
    try:
        from gaintune.tuners.tuner import Tuner
    except ImportError as exc:
        raise TunerUnavailable(
            f"the trained-tuner core (gaintune.tuners.tuner) cannot be imported on this tree ({exc}); no tuner "
            "was measured. Run with --rules-only to measure the rules against the optimum") from None
    try:
        return Tuner.load(name)
    except Exception as exc:  # an unknown name, a broken artefact folder ...: the user's input, named
        raise TunerUnavailable(f"cannot load tuner {name!r}: {type(exc).__name__}: {exc}") from None


# ------------------------------------------------------------------ measuring


def _close(a: Any, b: Any) -> bool:
    try:
        return abs(float(a) - float(b)) <= RESCORE_RTOL * max(abs(float(b)), 1e-300)
    except (TypeError, ValueError):
        return False


#: Runs of each plant's zero-shot query timed (the first is the one judged): its time is their median.
TIMING_REPEATS = 3


def _timed_query(tuner: Any, case: Case, refine: int) -> tuple[Any, float]:
    """One query and its process CPU time in ms (beside the answer's wall time: a shared machine's load
    inflates both)."""
    c0 = time.process_time()
    a = tuner.query(dict(case.values), refine=refine)
    return a, 1e3 * (time.process_time() - c0)


def tuner_answer(tuner: Any, case: Case, ref_cost: float | None, refine: int, repeats: int = 1) -> dict[str, Any]:
    """One query, judged here: the bench's own cost and verdict beside the ones the tuner reports.

    ``repeats`` > 1 runs the same query again that many times in all: ``elapsed_ms`` and ``cpu_ms`` are then the
    median over the runs (``first_elapsed_ms`` and ``first_cpu_ms`` the first run's), so one interruption by
    another process on a shared machine does not set the plant's figure; ``same_answer`` says whether every
    run gave the first run's gains (a query is deterministic).
    """
    try:
        a, cpu_ms = _timed_query(tuner, case, refine)
        out = judge(case, a.gains, ref_cost)
        again = [_timed_query(tuner, case, refine) for _ in range(repeats - 1)]
    except Exception as exc:  # a tuner defect is a row of the table, not the end of the benchmark
        return {"gains": None, "cost": None, "ratio": None, "verdict": "error", "ms": None,
                "error": f"{type(exc).__name__}: {exc}"}
    walls, cpus = [a.elapsed_ms] + [b.elapsed_ms for b, _ in again], [cpu_ms] + [c for _, c in again]
    out.update(tuner_cost=a.cost, tuner_verdict=a.verdict, cost_agrees=_close(a.cost, out["cost"]),
               verdict_agrees=a.verdict == out["verdict"], policy_ms=a.policy_ms,
               elapsed_ms=float(np.median(walls)), cpu_ms=float(np.median(cpus)), n_sims=a.n_sims)
    if repeats > 1:
        out.update(first_elapsed_ms=a.elapsed_ms, first_cpu_ms=cpu_ms, repeats=repeats,
                   same_answer=all(b.gains == a.gains for b, _ in again))
    return out


def measure_plant(case: Case, out_dir: Path, tuner: Any, refine: int,
                  log: Callable[[str], None] | None = None) -> dict[str, Any]:
    """One plant's row: the reference, the rules and (with ``tuner``) its zero-shot and refined answers."""
    rules = {}
    for name in RULES:
        gains, reason = rule_gains(name, case)
        rules[name] = judge(case, gains, None) if gains is not None else {**judge(case, None, None), "reason": reason}
    ref = reference_for_plant(case, rules, out_dir, log)
    checked = judge(case, ref["gains"], ref["cost"])  # the verdict now, whatever the cache says
    v = case.values
    row: dict[str, Any] = {
        "index": case.index, "K": v["K"], "T": v["T"], "L": v["L"], "L/T": v["L"] / v["T"],
        "reference": {k: ref.get(k) for k in ("cost", "gains", "source", "n_sims", "wall_time", "cached", "key")}
        | {"verdict": checked["verdict"], "ms": checked["ms"]},
    }
    for name, r in rules.items():
        row[name] = {**r, "ratio": ratio(r["cost"], ref["cost"])}
    if tuner is not None:
        row["tuner"] = tuner_answer(tuner, case, ref["cost"], 0, TIMING_REPEATS)
        row["refine"] = tuner_answer(tuner, case, ref["cost"], refine)
    return row


def measure(plants: Sequence[Mapping[str, float]], out_dir: Path, *, ctype: str = "pi", tuner_name: str | None = None,
            refine: int = 300, fresh_runs: int = 0, tuner_factory: Callable[[str], Any] | None = None,
            log: Callable[[str], None] | None = None) -> dict[str, Any]:
    """Every plant's row, the summary and the timing. ``tuner_name`` None: the rules against the reference only.

    ``tuner_factory(name)`` replaces :func:`load_tuner` (tests inject a fake tuner); the fresh-process
    timing (``fresh_runs`` > 0) always runs the real ``gaintune tuner query``. Raises
    :class:`TunerUnavailable` before any reference is computed when the tuner cannot be loaded.
    """
    tuner, load_s = None, None
    if tuner_name is not None:
        t0 = time.perf_counter()
        tuner = (tuner_factory or load_tuner)(tuner_name)
        load_s = time.perf_counter() - t0
    cases = [make_case(i, v, ctype, MS_MAX) for i, v in enumerate(plants)]
    first_ms = None
    if tuner is not None:  # warm-up, not counted: the first answer fills caches
        t0 = time.perf_counter()
        tuner_answer(tuner, cases[0], None, 0)
        first_ms = (time.perf_counter() - t0) * 1e3
    rows = []
    for case in cases:
        rows.append(measure_plant(case, out_dir, tuner, refine, log))
        if log:
            log(f"plant {case.index + 1}/{len(cases)} done")
    methods = [*RULES, *(("tuner", "refine") if tuner is not None else ())]
    timing: dict[str, Any] = {}
    if tuner is not None:
        timing = {"load_s": load_s, "first_query_ms": first_ms,
                  "in_process": in_process_timing(rows, ["tuner", "refine"])}
        if fresh_runs > 0 and tuner_name is not None:
            timing["fresh_process"] = fresh_process_timing(tuner_name, plants, fresh_runs)
    return {"settings": {"plants": len(plants), "ctype": ctype, "ms_max": MS_MAX, "tuner": tuner_name,
                         "refine": refine if tuner is not None else None, "fresh_runs": fresh_runs},
            "methods": methods, "rows": rows, "summary": summarize(rows, methods),
            "reference": reference_figures(rows), "timing": timing}


# ------------------------------------------------------------------ summary


def _beats(rows: Sequence[Mapping[str, Any]], method: str, rule: str) -> dict[str, Any]:
    """How often ``method`` passes with a lower cost than ``rule``, among the plants where ``rule`` passes."""
    where = [r for r in rows if r[rule]["verdict"] == "pass"]
    wins, exceptions = 0, []
    for r in where:
        a, b = r[method], r[rule]
        if a["verdict"] == "pass" and a["cost"] is not None and a["cost"] < b["cost"]:
            wins += 1
            continue
        why = (f"verdict {a['verdict']}" if a["verdict"] != "pass"
               else f"cost {fmt(a['cost'], 6)} >= {TITLES[rule]}'s {fmt(b['cost'], 6)}")
        exceptions.append({"plant": r["index"], "L/T": r["L/T"], "why": why})
    return {"wins": wins, "rule_passes": len(where), "exceptions": exceptions}


def summarize(rows: Sequence[Mapping[str, Any]], methods: Sequence[str]) -> dict[str, dict[str, Any]]:
    """Per method: ratio median and worst (all plants, and where it passes), pass count, wins over each rule."""
    out: dict[str, dict[str, Any]] = {}
    for m in methods:
        answers = [r[m] for r in rows]
        passing = [a for a in answers if a["verdict"] == "pass"]
        every, ok = stats([a["ratio"] for a in answers]), stats([a["ratio"] for a in passing])
        s: dict[str, Any] = {
            "plants": len(answers), "pass": len(passing), "median_ms": stats([a["ms"] for a in answers])["median"],
            "median_ratio": every["median"],
            "worst_ratio": every["worst"], "median_ratio_passing": ok["median"], "worst_ratio_passing": ok["worst"],
            "beats": {rule: _beats(rows, m, rule) for rule in RULES if rule != m},
        }
        if m in ("tuner", "refine"):
            sims = [a["n_sims"] for a in answers if a.get("n_sims") is not None]
            s.update(errors=sum(a["verdict"] == "error" for a in answers),
                     cost_agrees=sum(bool(a.get("cost_agrees")) for a in answers),
                     verdict_agrees=sum(bool(a.get("verdict_agrees")) for a in answers),
                     max_sims=max(sims, default=None))
        out[m] = s
    return out


def reference_figures(rows: Sequence[Mapping[str, Any]]) -> dict[str, Any]:
    """How many references pass verification, their sources, and the time of those computed in this run."""
    refs = [r["reference"] for r in rows]
    computed = [x["wall_time"] for x in refs if not x.get("cached") and x.get("wall_time") is not None]
    sources: dict[str, int] = {}
    for x in refs:
        sources[str(x.get("source"))] = sources.get(str(x.get("source")), 0) + 1
    return {"plants": len(refs), "pass": sum(x["verdict"] == "pass" for x in refs), "sources": sources,
            "computed": len(computed), "cached": len(refs) - len(computed), "computed_s": sum(computed),
            "computed_median_s": stats(computed)["median"], "computed_max_s": stats(computed)["worst"]}


# ------------------------------------------------------------------ output

#: What the tables mean (the report's opening paragraph).
LEGEND = (
    "Ratio = plain cost (load-step IAE) / the plant's reference optimum on the exact Ms limit (1 = optimal; "
    "below 1 only by violating the limit). Costs and verdicts of every method, the tuner's included, are "
    "computed here: the same evaluator and `verify()` for all. `beats` = passes with a lower cost than the "
    "rule, counted over the plants where the rule passes. `*` = verdict fail."
)


def _summary_table(result: Mapping[str, Any]) -> str:
    head = ["method", "median ratio", "worst ratio", "median ratio (passing)", "worst ratio (passing)", "pass",
            "median Ms", *(f"beats {TITLES[r]}" for r in RULES), "errors", "cost agrees", "verdict agrees",
            "max sims"]
    body = []
    for m in result["methods"]:
        s = result["summary"][m]
        beats = [f"{s['beats'][r]['wins']}/{s['beats'][r]['rule_passes']}" if r in s["beats"] else "-" for r in RULES]
        agree = [f"{s[k]}/{s['plants']}" if k in s else "-" for k in ("cost_agrees", "verdict_agrees")]
        body.append([TITLES[m], fmt_ratio(s["median_ratio"]), fmt_ratio(s["worst_ratio"]),
                     fmt_ratio(s["median_ratio_passing"]), fmt_ratio(s["worst_ratio_passing"]),
                     f"{s['pass']}/{s['plants']}", s["median_ms"], *beats, s.get("errors", "-"), *agree,
                     s.get("max_sims")])
    return md_table(head, body)


def _reference_text(result: Mapping[str, Any]) -> str:
    f = result["reference"]
    src = ", ".join(f"{k} {v}" for k, v in sorted(f["sources"].items()))
    took = (f"computed for {f['computed']} plants in {f['computed_s']:.1f} s (median {f['computed_median_s']:.2f} s, "
            f"max {f['computed_max_s']:.2f} s per plant)" if f["computed"] else "none computed")
    return (f"Reference: {f['pass']} of {f['plants']} pass verification; source: {src}; {took}; "
            f"{f['cached']} read from the cache (re-scored).")


#: The in-process answer times of the timing table: key in ``in_process[mode]``, and its name.
TIMED = (("policy_ms", "policy forward pass"), ("elapsed_ms", "whole answer (repair, verification), wall"),
         ("cpu_ms", "whole answer, process CPU time"),
         ("first_elapsed_ms", "whole answer, wall, the first run alone"),
         ("first_cpu_ms", "whole answer, process CPU time, the first run alone"))


def _timing_rows(timing: Mapping[str, Any], refine: int | None) -> list[list[Any]]:
    rows: list[list[Any]] = [
        ["load the tuner in this process", fmt(timing["load_s"]), "s"],
        ["first query after loading (warm-up, not counted below)", fmt(timing["first_query_ms"]), "ms"]]
    for mode, label in (("tuner", "zero-shot"), ("refine", f"refine {refine}")):
        t = timing["in_process"][mode]
        for what, name in TIMED:
            if what in t and t[what]["n"]:  # results written before a figure was measured have none
                each = f", each the median of {t['repeats']} runs" if t.get("repeats", 1) > 1 and what in (
                    "elapsed_ms", "cpu_ms") else ""
                rows.append([f"{label}: {name}{each}, p50 / p95 over {t[what]['n']} plants",
                             f"{fmt(t[what]['p50'])} / {fmt(t[what]['p95'])}", "ms"])
        if t.get("same_answer") is not None:
            rows.append([f"{label}: plants whose repeated runs gave the first run's gains", t["same_answer"], "-"])
    fresh = timing.get("fresh_process")
    if fresh:
        rows += [[f"fresh process `{fresh['command']}`, median / max of {fresh['ok']} of {fresh['runs']} runs",
                  f"{fmt(fresh['median_s'])} / {fmt(fresh['max_s'])}", "s"]]
        if fresh.get("cpu_median_s") is not None:
            rows.append(["fresh process, its CPU time (user + system), median / max",
                         f"{fmt(fresh['cpu_median_s'])} / {fmt(fresh['cpu_max_s'])}", "s"])
        rows += _floor_rows(fresh) + _jit_rows(fresh)
        rows += [
                 ["fresh-process answers that printed valid JSON", f"{fresh['json_ok']} / {fresh['ok']}", "-"],
                 ["torch imported by the query (same CLI path, in a child)", fmt(fresh["torch_imported"]), "-"]]
        if "numba_imported" in fresh:  # results written before the kernel was compiled ahead of time have none
            rows += [["numba imported by the query (same child)", fmt(fresh["numba_imported"]), "-"],
                     ["single-lane kernel compiled ahead of time", fresh["aot_kernel"], "-"]]
        rows += [[f"failed run (exit {x['code']})", x["error"], "-"] for x in fresh["failures"][:3]]
    return rows


def _floor_rows(fresh: Mapping[str, Any]) -> list[list[Any]]:
    """The import-only processes timed beside the queries, and the query's median minus theirs."""
    floor = fresh.get("floor")  # results written before the floor was timed have none
    if not floor or floor.get("median_s") is None:
        return []
    rows = [[f"beside each: a fresh `{floor['command']}` (the numeric libraries alone), median / max wall",
             f"{fmt(floor['median_s'])} / {fmt(floor['max_s'])}", "s"]]
    if floor.get("cpu_median_s") is not None:
        rows.append(["the same, its CPU time (user + system), median / max",
                     f"{fmt(floor['cpu_median_s'])} / {fmt(floor['cpu_max_s'])}", "s"])
    if fresh.get("median_s") is not None:
        rows.append(["fresh query minus those imports, median wall (gaintune's CLI, spec, modules and the answer)",
                     fmt(fresh["median_s"] - floor["median_s"]), "s"])
    return rows


def _jit_rows(fresh: Mapping[str, Any]) -> list[list[Any]]:
    """The same query on numba's JIT kernel, timed beside it (what a query cost before the ahead-of-time module)."""
    jit = fresh.get("jit")  # results written before the module have none
    if not jit or jit.get("median_s") is None:
        return []
    rows = [[f"beside each: `{jit['command']}` (numba's JIT kernel, cache warm), median / max wall",
             f"{fmt(jit['median_s'])} / {fmt(jit['max_s'])}", "s"]]
    if fresh.get("median_s") is not None:
        ratio = fresh["median_s"] / jit["median_s"]
        rows.append(["fresh query / the same on the JIT kernel, median wall", fmt(ratio, 3), "-"])
    return rows


def _exceptions(result: Mapping[str, Any]) -> list[str]:
    lines = []
    for m in ("tuner", "refine"):
        for rule, b in result["summary"][m]["beats"].items():
            shown = ", ".join(f"#{x['plant']} (L/T {fmt(x['L/T'], 3)}: {x['why']})" for x in b["exceptions"])
            lines.append(f"- {TITLES[m]} vs {TITLES[rule]}: {len(b['exceptions'])} of {b['rule_passes']}"
                         + (f": {shown}" if shown else ""))
    return lines


def _cell(a: Mapping[str, Any] | None) -> str:
    if a is None:
        return "-"
    return fmt_ratio(a.get("ratio")) + ("" if a.get("verdict") == "pass" else "*")


def _plant_table(result: Mapping[str, Any]) -> str:
    tuned = "tuner" in result["methods"]
    head = ["#", "K", "T", "L", "L/T", "ref cost", "ref", "AMIGO ratio", "AMIGO", "SIMC ratio", "SIMC",
            *(["tuner ratio", "tuner", "refine ratio"] if tuned else [])]
    body = []
    for r in result["rows"]:
        ref = r["reference"]
        cells = [r["index"], r["K"], r["T"], r["L"], fmt(r["L/T"], 3), fmt(ref["cost"], 6), ref["verdict"]]
        for m in RULES:
            cells += [fmt_ratio(r[m]["ratio"]), r[m]["verdict"]]
        if tuned:
            cells += [fmt_ratio(r["tuner"]["ratio"]), r["tuner"]["verdict"], _cell(r["refine"])]
        body.append(cells)
    return md_table(head, body)


def render(result: Mapping[str, Any], command: str) -> str:
    """The benchmark as Markdown: the command, the summary, the reference, answer times, exceptions, every plant."""
    s = result["settings"]
    tuner = f"tuner `{s['tuner']}`, refine {s['refine']}" if s["tuner"] else "rules only (no tuner measured)"
    lines = [f"# {command}", "",
             f"{s['plants']} held-out FOTD plants K e^(-Ls)/(Ts+1), {s['ctype'].upper()}, unit load step at the "
             f"input, Ms <= {s['ms_max']:g} (exact limit); {tuner}; {os.cpu_count()} CPUs, load average "
             f"{result.get('loadavg', '-')}.", "", LEGEND, "", "## Summary", "", _summary_table(result), "",
             _reference_text(result), ""]
    if result.get("training"):
        t = result["training"]
        lines += ["## Training", "", md_table(["what", "figure"], [
            ["algorithm, episodes, simulations", f"{t['algo']}, {t['episodes']:,}, {t['sims']:,}"],
            ["training wall time (s, on the machine that built it)", t["wall_s"]],
            ["validation on its own held-out contexts: median / worst ratio, passed",
             f"{t['validation_median']:.4f} / {t['validation_worst']:.4f}, "
             f"{t['validation_passed']}/{t['validation_n']}"],
            ["tuner folder size (KB)", t["size_kb"]]]), ""]
    if result["timing"]:
        table = md_table(["what", "figure", "unit"], _timing_rows(result["timing"], s["refine"]))
        lines += ["## Answer time", "", table, ""]
        lines += ["## Plants where the tuner does not beat a passing rule", "", *_exceptions(result), ""]
    lines += ["## Per plant", "", _plant_table(result), "", "`ref` = the reference's verdict"
              + ("; refine ratio `*` = verdict fail." if result["timing"] else ".")]
    return "\n".join(lines) + "\n"


# ------------------------------------------------------------------ CLI


def build_parser() -> BenchParser:
    """The options of ``gaintune bench tuners``."""
    ap = BenchParser(prog="gaintune bench tuners", description=__doc__.splitlines()[0].split(": ", 1)[1])
    ap.add_argument("--plants", type=int_range(1, 10_000), default=50, help="held-out plants (default 50)")
    ap.add_argument("--seed", type=seed_int, default=HELD_OUT_SEED,
                    help=f"seed of the held-out plants (default {HELD_OUT_SEED}, never used in training)")
    ap.add_argument("--ctype", choices=("pi", "pid"), default="pi", help="controller type (default pi)")
    ap.add_argument("--tuner", default=None,
                    help="shipped tuner name or artefact folder (default fotd_pi_ms1.4, fotd_pid_ms1.4 for pid)")
    ap.add_argument("--refine", type=int_range(1, 100_000), default=300,
                    help="extra simulations of the refined row (default 300)")
    ap.add_argument("--fresh-runs", type=int_range(0, 1000), default=7,
                    help="fresh `gaintune tuner query` processes timed (default 7; 0: none)")
    ap.add_argument("--rules-only", action="store_true", help="AMIGO and SIMC against the reference only")
    ap.add_argument("--update", action="store_true",
                    help="instead: 'tuner update' vs a cold start on a changed family (writes tuners_update.*, "
                         "with --shipped-only tuners_update_shipped.*)")
    ap.add_argument("--update-episodes", type=int_range(1024, 1_000_000), default=8192,
                    help="training episodes of each --update run (default 8192)")
    ap.add_argument("--update-curve-every", type=int_range(16, 1_000_000), default=CURVE_EVERY,
                    help=f"episodes between the training curves' points in --update (default {CURVE_EVERY}; a "
                         f"measurement only: both runs train in chunks of {CHUNK} episodes whatever it is)")
    ap.add_argument("--shipped-only", action="store_true",
                    help="with --update: only the cold start and the update from the shipped tuner (skips training a "
                         "base with its agent, as long as a shipped tuner's training, and the tune --warm-start runs)")
    ap.add_argument("--algo-compare", action="store_true",
                    help="instead: TD3 vs PPO trained on one family at equal episodes (writes tuners_algo.*)")
    ap.add_argument("--algo-episodes", type=int_range(256, 1_000_000), default=4096,
                    help="training episodes of each --algo-compare run (default 4096)")
    ap.add_argument("--algo-family", choices=("fotd", "sotd", "ipd"), default="fotd",
                    help="family of --algo-compare (default fotd; controller --ctype, Ms <= 1.4)")
    ap.add_argument("--algo-contexts", type=int_range(1, 1000), default=16,
                    help="held-out contexts each --algo-compare tuner is scored on (default 16)")
    ap.add_argument("--before", type=Path, default=None,
                    help="instead: time the zero-shot answers of this checkout beside an older one (DIR), alternated "
                         "in one run (writes tuners_before.*)")
    ap.add_argument("--rounds", type=int_range(1, 100), default=3,
                    help="rounds per checkout of --before (default 3)")
    add_out_argument(ap)
    return ap


def main(argv: Sequence[str] | None = None) -> int:
    """``gaintune bench tuners``: measure, print the tables, write ``tuners.md`` and ``tuners.json``."""
    argv = list(sys.argv[1:] if argv is None else argv)
    args = build_parser().parse_args(argv)
    if args.rules_only and args.tuner is not None:
        fail("--tuner", "--rules-only measures no tuner; drop --tuner or --rules-only")
    out = resolve_out(args.out)
    name = None if args.rules_only else (args.tuner or DEFAULT_TUNER[args.ctype])
    command = shlex.join(["gaintune", "bench", "tuners", *argv])
    if args.update:
        from gaintune.bench.tuners_update import main_update

        return main_update(args, args.tuner or DEFAULT_TUNER["pi"], out, command)
    if args.algo_compare:
        from gaintune.bench.tuners_algo import main_algo

        return main_algo(args, out, command)
    if args.before is not None:
        from gaintune.bench.tuners_before import check_tree, main_before

        if name is None or (why := check_tree(args.before)) is not None:
            fail("--before", "--rules-only times no tuner" if name is None else str(why))
        return main_before(args, name, held_out_plants(args.plants, args.seed), TIMING_REPEATS, out, command)
    load0 = load_now()
    try:
        result = measure(held_out_plants(args.plants, args.seed), out, ctype=args.ctype, tuner_name=name,
                         refine=args.refine, fresh_runs=args.fresh_runs,
                         log=lambda m: print(m, file=sys.stderr, flush=True))
    except TunerUnavailable as exc:
        fail("--tuner", str(exc))
    result["loadavg"] = load_span(load0)
    if name is not None:
        result["training"] = training_figures(name)
    result["command"] = command
    result["settings"]["seed"] = args.seed
    return publish(result, out, "tuners", render(result, command))


if __name__ == "__main__":
    raise SystemExit(main())
