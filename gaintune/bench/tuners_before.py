"""``gaintune bench tuners --before DIR``: a tuner's in-process answer time, this checkout beside an older one.

The machine is shared, and its speed moves from one hour to the next by more than a code change does: two
runs of ``gaintune bench tuners`` at different times do not tell whether a change made the answer faster.
This mode times the same answers in both checkouts in one run, alternated round by round (this tree,
then DIR, then this tree ...), each round a fresh process with ``PYTHONPATH`` set to its tree (and its
compiled kernels where that tree keeps them, built by its first round when missing) and the process
settings the ``gaintune`` command makes (the cyclic collector's threshold and glibc's malloc thresholds,
:mod:`gaintune.cli.entry`), as the benchmark's own in-process figures have them; an older tree gets them
too, so the ratio measures the code. A round loads the
tuner, answers the first plant once (a warm-up), then answers every held-out plant
:data:`~gaintune.bench.tuners.TIMING_REPEATS` times; a plant's figure is the median process CPU time of its
runs. The table gives each round's p50 and p95 over the plants, their median over the rounds, the ratio
after / before, and how many answers (gains, cost, verdict) the two trees give alike: a speed-up that
changes answers says so here.

Give DIR as a ``git worktree add /tmp/before <rev>`` of the revision to compare with.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from gaintune.bench.compare import md_table

__all__ = ["CHILD", "check_tree", "measure_before", "render_before"]

#: One round in a fresh process: ``python -c CHILD NAME REPEATS PLANTS_JSON``; prints one JSON line.
CHILD = r"""
import gc, json, sys, time
import numpy as np
name, repeats, plants = sys.argv[1], int(sys.argv[2]), json.loads(sys.argv[3])
gc.set_threshold(250_000, *gc.get_threshold()[1:])  # the collector's threshold the gaintune command sets
try:  # and its malloc thresholds (gaintune.cli.entry.keep_heap), in either tree: the ratio measures the code
    import ctypes
    ctypes.CDLL(None).mallopt(-3, 32 << 20)
    ctypes.CDLL(None).mallopt(-1, 64 << 20)
except (OSError, AttributeError):
    pass
try:  # a tree with the single-lane kernel compiled ahead of time answers on it, as a user's query does
    from gaintune.sim.kernel_aot import AOT, aot_missing
    from gaintune.sim.precompile import compile_here
    if aot_missing():
        compile_here(AOT)
except ImportError:
    pass
from gaintune.tuners.tuner import Tuner
tuner = Tuner.load(name)
tuner.query(plants[0])
cpu, answers = [], []
for p in plants:
    runs = []
    for _ in range(repeats):
        c0 = time.process_time()
        a = tuner.query(p)
        runs.append(1e3 * (time.process_time() - c0))
    cpu.append(float(np.median(runs)))
    answers.append([a.gains, a.cost, a.verdict])
print(json.dumps({"cpu_ms": cpu, "answers": answers}))
"""


def check_tree(path: Path) -> str | None:
    """Why ``path`` is not a gaintune checkout to compare with (None when it is)."""
    if not (path / "gaintune" / "tuners" / "tuner.py").is_file():
        return f"{path} holds no gaintune checkout with trained tuners (give the checkout's top folder)"
    return None


def _round(tree: Path, name: str, repeats: int, plants: Sequence[dict[str, float]]) -> dict[str, Any]:
    """One round in a fresh process on ``tree``: per-plant CPU ms and answers, or ``{"error": ...}``."""
    env = {**os.environ, "PYTHONPATH": str(tree)}
    p = subprocess.run([sys.executable, "-c", CHILD, name, str(repeats), json.dumps(list(plants))], cwd=str(tree),
                       env=env, capture_output=True, text=True, check=False)
    if p.returncode != 0 or not p.stdout.strip():
        return {"error": (p.stderr.strip().splitlines() or [f"exit {p.returncode}"])[-1]}
    return json.loads(p.stdout.strip().splitlines()[-1])


def _pcts(cpu: Sequence[float]) -> tuple[float, float]:
    return float(np.percentile(cpu, 50)), float(np.percentile(cpu, 95))


def measure_before(before: Path, name: str, plants: Sequence[dict[str, float]], rounds: int,
                   repeats: int) -> dict[str, Any]:
    """Alternated rounds of this checkout ("after") and ``before``; see the module docstring."""
    here = Path(__file__).resolve().parents[2]
    trees = {"after": here, "before": before.resolve()}
    out: dict[str, Any] = {"trees": {k: str(v) for k, v in trees.items()}, "rounds": [], "errors": []}
    last: dict[str, Any] = {}
    for r in range(rounds):
        for tag, tree in trees.items():
            res = _round(tree, name, repeats, plants)
            if "error" in res:
                out["errors"].append(f"{tag}, round {r + 1}: {res['error']}")
                continue
            p50, p95 = _pcts(res["cpu_ms"])
            out["rounds"].append({"tree": tag, "round": r + 1, "p50": p50, "p95": p95})
            last[tag] = res["answers"]
    out["summary"] = _summary(out["rounds"], last)
    return out


def _summary(rounds: Sequence[dict[str, Any]], answers: dict[str, Any]) -> dict[str, Any]:
    """Median p50 and p95 over the rounds per tree, after / before, and how alike the answers are."""
    s: dict[str, Any] = {}
    for tag in ("after", "before"):
        mine = [r for r in rounds if r["tree"] == tag]
        s[tag] = {k: float(np.median([r[k] for r in mine])) if mine else None for k in ("p50", "p95")}
    if s["after"]["p50"] is not None and s["before"]["p50"] is not None:
        s["ratio"] = {k: s["after"][k] / s["before"][k] for k in ("p50", "p95")}
    if "after" in answers and "before" in answers:
        pairs = list(zip(answers["after"], answers["before"], strict=True))
        s["identical"] = sum(a == b for a, b in pairs)
        s["same_verdict"] = sum(a[2] == b[2] for a, b in pairs)
        s["max_rel_cost_diff"] = max(abs(a[1] / b[1] - 1.0) if b[1] else abs(a[1]) for a, b in pairs)
        s["plants"] = len(pairs)
    return s


def render_before(result: dict[str, Any], command: str) -> str:
    """The side-by-side tables as Markdown."""
    s = result["summary"]
    lines = [f"# {command}", "", f"Tuner `{result['name']}`, {result['plants']} held-out plants, each plant's time the "
             f"median process CPU time of {result['repeats']} runs; {result['n_rounds']} rounds per tree, "
             f"alternated; load average {result['loadavg']}. after = {result['trees']['after']} "
             f"({result['commits']['after']}), before = {result['trees']['before']} ({result['commits']['before']}).",
             "", "| tree | round | p50 ms | p95 ms |", "|---|---|---|---|"]
    lines += [f"| {r['tree']} | {r['round']} | {r['p50']:.3f} | {r['p95']:.3f} |" for r in result["rounds"]]
    rows = [[f"{tag}: median over the rounds, p50 / p95 (ms)",
             "-" if s[tag]["p50"] is None else f"{s[tag]['p50']:.3f} / {s[tag]['p95']:.3f}"]
            for tag in ("before", "after")]
    if "ratio" in s:
        rows.append(["after / before, p50 / p95", f"{s['ratio']['p50']:.3f} / {s['ratio']['p95']:.3f}"])
    if "identical" in s:
        rows += [["answers identical to the last bit (gains, cost, verdict)", f"{s['identical']} / {s['plants']}"],
                 ["same verdict", f"{s['same_verdict']} / {s['plants']}"],
                 ["largest relative cost difference", f"{s['max_rel_cost_diff']:.3g}"]]
    lines += ["", md_table(["figure", "value"], rows)]
    lines += [f"- failed round: {e}" for e in result["errors"]]
    return "\n".join(lines) + "\n"


def _commit(tree: Path) -> str:
    """The checkout's short commit (with "+changes" when its gaintune package differs from it: the code a round
    runs; a benchmark's own results written into the tree are not a change of it), or "unknown"."""
    def git(*a: str) -> str:
        p = subprocess.run(["git", "-C", str(tree), *a], capture_output=True, text=True, check=False)
        return p.stdout.strip() if p.returncode == 0 else ""

    rev = git("rev-parse", "--short", "HEAD")
    if not rev:
        return "unknown"
    changed = git("status", "--porcelain", "--untracked-files=no", "--", "gaintune")
    return rev + ("+changes" if changed else "")


def main_before(args: Any, name: str, plants: Sequence[dict[str, float]], repeats: int, out: Path,
                command: str) -> int:
    """``--before DIR``: the side-by-side timing alone; writes ``tuners_before.*``."""
    from gaintune.bench.arguments import load_now, load_span
    from gaintune.bench.compare import publish

    load0 = load_now()
    r = measure_before(args.before, name, plants, args.rounds, repeats)
    r.update(name=name, plants=len(plants), repeats=repeats, n_rounds=args.rounds, command=command,
             commits={k: _commit(Path(v)) for k, v in r["trees"].items()},
             loadavg=load_span(load0))
    publish(r, out, "tuners_before", render_before(r, command))
    return 0 if not r["errors"] else 1
