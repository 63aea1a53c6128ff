"""``gaintune bench constraints``: does the searched constraint agree with the verdict near the boundary?

Every search ranks candidates on the fast requirement estimate
(:func:`gaintune.verification.quick.requirement_violation`, through
:meth:`gaintune.evaluation.evaluator.Evaluator.requirement_violation`); the verdict comes from the
exact :func:`gaintune.verification.verify`. They must agree where it matters: close to the
constraint boundary, where a constrained optimum lies.

For each problem the benchmark finds a point on the boundary (the layout's start gains,
every gain scaled by one factor, bisected onto the boundary with the exact check), samples candidates
around it (independent log-normal perturbations of every tuned gain, ``--spread``
relative, default 3 %), and compares "feasible by the search estimate" with "meets every
requirement and is stable by the exact verification" (nominal plant and, for randomised
specs, the robust set; the nonlinear simulation check is not part of the requirements).
"""

from __future__ import annotations

import argparse
import time
from collections.abc import Sequence
from typing import Any

import numpy as np

from gaintune.bench.arguments import (
    MAX_BATCH,
    BenchParser,
    add_out_argument,
    float_range,
    int_range,
    resolve_out,
    seed_int,
    select_problems,
)
from gaintune.bench.compare import md_table, write_outputs
from gaintune.bench.suite import BenchCase, suite_names

__all__ = ["agreement", "main"]


def _boundary_point(ev: Any) -> np.ndarray | None:
    """The start gains scaled (every tuned gain by one factor) onto the exact requirement boundary, or None."""
    from gaintune.evaluation.boundary_exact import normalised_margin
    from gaintune.verification import verify

    t0 = ev.layout.initial_tuned()

    def margin(a: float) -> float:
        return normalised_margin(verify(ev.spec, ev.layout.full(t0 * a), nonlinear=False, plant=ev.plant,
                                        layout=ev.layout))[0]

    m1 = margin(1.0)
    step = np.sqrt(2.0) if m1 >= 0 else 1.0 / np.sqrt(2.0)
    ok, a = 1.0, 1.0
    for _ in range(24):  # walk by sqrt(2) until the verdict on the requirements flips
        ok, a = a, a * step
        if (margin(a) >= 0) != (m1 >= 0):
            break
    else:
        return None
    good, bad = (ok, a) if m1 >= 0 else (a, ok)
    while abs(np.log(bad / good)) > 1e-7:  # bisection in log scale onto the boundary
        mid = float(np.sqrt(good * bad))
        good, bad = (mid, bad) if margin(mid) >= 0 else (good, mid)
    return t0 * good


def agreement(problem: BenchCase, n: int = 200, spread: float = 0.03, seed: int = 0) -> dict[str, Any]:
    """Agreement of the searched constraint with the verdict on ``n`` candidates near the boundary."""
    from gaintune.evaluation.boundary_exact import normalised_margin
    from gaintune.evaluation.search_box import make_evaluator
    from gaintune.verification import verify

    # the estimate on the exact limits (no requirements.backoff): its agreement with the verdict is measured
    ev = make_evaluator(problem.tuning_spec(), exact=True)
    t0 = time.perf_counter()
    centre = _boundary_point(ev)
    if centre is None:
        return {"problem": problem.name, "n": 0, "note": "no boundary point found from the start gains"}
    rng = np.random.default_rng(seed)
    cands = centre * np.exp(rng.normal(0.0, spread, (n, centre.size)))
    searched = ev.requirement_violation(cands) <= 0
    exact = np.empty(n, dtype=bool)
    margins = np.empty(n)
    for i, t in enumerate(cands):
        rep = verify(ev.spec, ev.layout.full(t), nonlinear=False, plant=ev.plant, layout=ev.layout)
        margins[i] = normalised_margin(rep)[0]
        exact[i] = margins[i] >= 0
    agree = searched == exact
    wrong = np.abs(margins[~agree])
    return {
        "problem": problem.name,
        "n": n,
        "agree": int(agree.sum()),
        "agree_pct": 100.0 * float(agree.mean()),
        "feasible_exact": int(exact.sum()),
        "search_says_feasible_exact_fails": int((searched & ~exact).sum()),
        "search_says_infeasible_exact_passes": int((~searched & exact).sum()),
        "max_abs_margin_of_disagreement": float(wrong.max()) if wrong.size else None,
        "wall_time": time.perf_counter() - t0,
    }


def build_parser() -> argparse.ArgumentParser:
    """The options of ``gaintune bench constraints``."""
    ap = BenchParser(prog="gaintune bench constraints", description=__doc__.splitlines()[0])
    ap.add_argument("--suite", default="standard", choices=suite_names())
    ap.add_argument("--problems", nargs="+", metavar="NAME")
    ap.add_argument("--n", type=int_range(1, MAX_BATCH), default=200, help="candidates per problem (default 200)")
    # above a spread of 1 (100 %) the far tail of exp(N(0, spread)) overflows the gains to inf
    ap.add_argument("--spread", type=float_range(0.0, 1.0), default=0.03,
                    help="relative log-normal spread of each gain, > 0 and <= 1 (default 0.03)")
    ap.add_argument("--seed", type=seed_int, default=0)
    add_out_argument(ap)
    return ap


def main(argv: Sequence[str] | None = None) -> int:
    """``gaintune bench constraints``: the agreement on every problem of the suite, printed and written to ``--out``."""
    args = build_parser().parse_args(argv)
    problems = select_problems(args.suite, args.problems)
    out = resolve_out(args.out)
    rows = []
    for p in problems:
        r = agreement(p, args.n, args.spread, args.seed)
        rows.append(r)
        print(f"  {p.name:<24} " + (f"{r['agree']}/{r['n']} agree ({r['agree_pct']:.1f} %)" if r["n"] else r["note"]),
              flush=True)
    total = sum(r["n"] for r in rows)
    agree = sum(r.get("agree", 0) for r in rows)
    table = md_table(
        ["problem", "candidates", "agree %", "exact feasible", "search feasible / exact fails",
         "search infeasible / exact passes", "max |margin| where they disagree"],
        [[r["problem"], r["n"], r.get("agree_pct"), r.get("feasible_exact"), r.get("search_says_feasible_exact_fails"),
          r.get("search_says_infeasible_exact_passes"), r.get("max_abs_margin_of_disagreement")] for r in rows],
    )
    summary = (f"overall: {agree}/{total} candidates agree ({100.0 * agree / max(total, 1):.2f} %), "
               f"spread {args.spread:g}")
    print(table)
    print(summary)
    write_outputs({"rows": rows, "summary": summary, "spread": args.spread, "n": args.n},
                  out, f"constraints_{args.suite}",
                  f"# gaintune bench constraints --suite {args.suite}\n\n{table}\n\n{summary}\n")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
