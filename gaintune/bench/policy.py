"""``gaintune bench policy``: a trained tuner's answer time beside the search that trained it.

Trains gaintune's PPO (``--budget`` simulations, default 3,000) on a plant family with
randomised parameters (PI on K/(T s + 1)^2, K and T in [0.5, 2], Ms <= 1.6), then loads it
as a :class:`gaintune.search.policy.PolicyTuner` and answers ``--points`` plants of the family
(a grid over K and T). Every answer is the policy's gains, repaired onto that plant's
requirement boundary and verified on it, as ``gaintune policy`` and ``POST /v1/jobs/{id}/policy``
give them. Printed side by side, in one run: the search's wall time, the tuner's load time, and
the answer time (median, p95, max), with how many answers passed verification. The machine is
shared: compare figures of one run. Written to ``--out`` (default ``bench/results``).
"""

from __future__ import annotations

import tempfile
import time
from collections.abc import Sequence
from typing import Any

import numpy as np

from gaintune.bench.arguments import BenchParser, add_out_argument, budget_int, int_range, resolve_out, seed_int
from gaintune.bench.compare import md_table, write_outputs

__all__ = ["FAMILY", "main"]

FAMILY = {
    "name": "pi_family",
    "plant": {"tf": {"num": ["K"], "den": "(T*s+1)^2"}, "params": {"K": 1.0, "T": 1.0}},
    "loops": [{"type": "pi"}],
    "scenario": {"dt": 0.05, "horizon": 20},
    "requirements": {"ms_max": 1.6},
    "randomize": {"params": {"K": [0.5, 2.0], "T": [0.5, 2.0]}},
}


def measure(budget: int, points: int, seed: int) -> tuple[list[list[Any]], dict[str, Any]]:
    """Rows ``[what, figure, unit]`` and the raw figures."""
    from gaintune.search.policy import PolicyTuner
    from gaintune.search.tune import tune
    from gaintune.spec import load_spec

    spec = load_spec({**FAMILY, "search": {"budget": budget, "seed": seed}})
    with tempfile.TemporaryDirectory() as tmp:
        t0 = time.perf_counter()
        result = tune(spec, out_dir=tmp)
        search_s = time.perf_counter() - t0
        t0 = time.perf_counter()
        tuner = PolicyTuner(f"{tmp}/agent.zip", spec)
        load_s = time.perf_counter() - t0
    side = max(int(round(points ** 0.5)), 1)
    grid = {"K": list(np.linspace(0.5, 2.0, side)), "T": list(np.linspace(0.5, 2.0, max(points // side, 1)))}
    tuner.answer()  # warm-up: the first answer compiles nothing, but fills the OS and numpy caches
    answers = tuner.schedule(grid)
    ms = np.array([a.elapsed_ms for a in answers])
    passed = sum(a.verdict == "pass" for a in answers)
    raw: dict[str, Any] = {
        "budget": budget, "seed": seed, "search_s": search_s, "search_verdict": result.verdict, "load_s": load_s,
        "answers": len(answers), "passed": passed, "median_ms": float(np.median(ms)),
        "p95_ms": float(np.percentile(ms, 95)), "max_ms": float(ms.max()),
    }
    rows = [
        [f"search that trained the policy ({budget:,} sims, verdict {result.verdict})", f"{search_s:.2f}", "s"],
        ["load the tuner here (torch loaded, search box cached; a fresh process adds the ~2 s import)",
         f"{load_s:.2f}", "s"],
        [f"answer one plant, median of {len(answers)}", f"{raw['median_ms']:.1f}", "ms"],
        ["answer one plant, p95", f"{raw['p95_ms']:.1f}", "ms"],
        ["answer one plant, max", f"{raw['max_ms']:.1f}", "ms"],
        ["answers that passed verification", f"{passed} / {len(answers)}", "-"],
        ["search time / median answer time", f"{search_s / (raw['median_ms'] / 1e3):,.0f}", "x"],
    ]
    return rows, raw


def main(argv: Sequence[str] | None = None) -> int:
    """``gaintune bench policy``: train, load and answer; print the table and write it to ``--out``."""
    ap = BenchParser(prog="gaintune bench policy", description=__doc__.splitlines()[0])
    ap.add_argument("--budget", type=budget_int, default=3000,
                    help="simulations of the training search (default 3000)")
    ap.add_argument("--points", type=int_range(1, 10_000), default=25,
                    help="plants answered (a K x T grid, default 25)")
    ap.add_argument("--seed", type=seed_int, default=0, help="seed of the training search (default 0)")
    add_out_argument(ap)
    args = ap.parse_args(argv)
    out = resolve_out(args.out)
    rows, raw = measure(args.budget, args.points, args.seed)
    table = md_table(["what", "figure", "unit"], rows)
    print(table)
    title = f"# gaintune bench policy --budget {args.budget} --points {args.points} --seed {args.seed}"
    _, md = write_outputs(raw, out, "policy", f"{title}\n\n{table}\n")
    print(f"wrote {md}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
