"""``gaintune bench mimo``: tuned decentralised PI on the MIMO benchmark plants against the published rows.

Wood-Berry (``models/wood_berry.yaml``'s example: a unit setpoint step on each loop in turn, cost
IAE(e1) + IAE(e2) summed over both steps, no effort term): every published row of
:data:`gaintune.classical.mimo_references.WOOD_BERRY_REFERENCES` (BLT also recomputed by
:func:`gaintune.classical.blt.blt_tune`) is scored and verified by the MIMO verdict. For BLT and
Chen-Seborg, gaintune tunes PI with the requirements set to that row's own MIMO Ms and multiloop
disk margin (``mimo_ms_max``, ``disk_margin_min``): CMA-ES, and ``tune`` (the RL search, then its
CMA-ES polish), at the budgets given. The PID rows (Boyd-Hast-Åström, Garrido; derivative filter
N = 10, not recorded with the published gains) are reference rows.

Quadruple tank (Johansson 2000), minimum and non-minimum phase: the paper's PI (K = 3.0, Ti = 30 s;
K = 2.7, Ti = 40 s) scored and verified on each setting; gaintune tunes PI with the requirements
set to that row's Ms and disk margin where that row is stable, else to the model example's (MIMO
Ms <= 2; the minimum-phase PI is unstable on the non-minimum-phase setting, so no ratio there).
On the non-minimum-phase setting loop y2 is tuned reverse-acting (``direction: reverse``): the
relative gain of the diagonal pairing is negative there (gamma1 + gamma2 < 1), so with loop y1
closed the sign of y2's path flips.

Each row: cost, MIMO Ms, multiloop disk margin at the inputs and at the outputs, the verdict (a
published row against the model example's requirements, a tuned row against the ones it was tuned
for; the tuned rows use ``backoff: 0``, so they may sit on the limit itself), the ratio of the
tuned cost to the published row's, and the ratio to the per-plant constrained optimum under the same
requirements: the best of a multistart CMA-ES (``--ref-restarts`` x ``--ref-sims``, the
``reference`` baseline), cached in ``<out>/reference_mimo.json`` and re-scored before use.
Prints the command, commit and load average first.
"""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
import time
from collections.abc import Sequence
from typing import Any

from gaintune.bench.arguments import BenchParser, add_out_argument, int_range, resolve_out

__all__ = ["main", "reference_rows", "tuned_row", "score"]


def _spec(model: str, **requirements: float) -> Any:
    from gaintune.plants.library import load_model
    from gaintune.spec import load_spec

    data = load_model(model).example_spec()
    data["requirements"] = {**data["requirements"], **requirements}
    return load_spec(data)


def score(spec: Any, gains: dict) -> dict[str, Any]:
    """Cost (the spec's objective, nominal plant), MIMO Ms, disk margins and verdict of one gain set."""
    from gaintune.evaluation.evaluator import Evaluator
    from gaintune.verification import coerce_gains, verify

    ev = Evaluator(spec)
    cost = float(ev.evaluate(ev.layout.tuned_of(coerce_gains(ev.layout, gains))).cost[0])
    rep = verify(spec, gains, nonlinear=False)
    m = rep.mimo
    assert m is not None
    return {"cost": cost, "ms": m.ms, "disk_in": m.disk_input.alpha, "disk_out": m.disk_output.alpha,
            "verdict": rep.verdict, "reasons": rep.reasons, "gains": gains}


def reference_rows(model: str) -> list[tuple[str, dict, str]]:
    """(name, gains by loop, loop type) of every published row of ``model``."""
    from gaintune.classical.blt import blt_tune
    from gaintune.classical.mimo_references import QUADTANK_REFERENCES, WOOD_BERRY_REFERENCES
    from gaintune.plants import build_plant
    from gaintune.plants.mimo import as_mimo

    spec = _spec(model)
    names = [lp.name for lp in spec.loops]
    refs = WOOD_BERRY_REFERENCES if model == "wood_berry" else QUADTANK_REFERENCES
    rows = [(r.method, dict(zip(names, r.gains(), strict=True)), r.form.lower()) for r in refs]
    if model == "wood_berry":
        G = as_mimo(build_plant(spec.plant)).lti()
        from gaintune.lti.mimo import TfMatrix

        assert isinstance(G, TfMatrix)
        sq = TfMatrix(tuple(row[:2] for row in G.entries), inputs=G.inputs[:2], outputs=G.outputs)
        b = blt_tune(sq)
        rows.insert(1, ("BLT (gaintune.classical.blt)",
                        {n: lp.gains() for n, lp in zip(names, b.loops, strict=True)},
                        "pi"))
    return rows


def _with_type(model: str, kind: str, tuned: bool = False, **req: float) -> Any:
    spec = _spec(model, **req)
    # RGA lambda11 = g1 g2/(g1 + g2 - 1) < 0 on the NMP setting: with y1 closed, the sign of y2's path flips
    if tuned and model == "quadruple_tank_nmp":
        loops = [spec.loops[0], spec.loops[1].model_copy(update={"direction": "reverse"})]
        spec = spec.model_copy(update={"loops": loops})
    if kind == "pid":
        loops = [lp.model_copy(update={"type": "pid"}) for lp in spec.loops]
        spec = spec.model_copy(update={"loops": loops})
    return spec


def tuned_row(spec: Any, method: str, budget: int, seed: int) -> dict[str, Any]:
    """gaintune's answer on ``spec``: ``cmaes`` (the baseline optimiser) or ``tune`` (RL search + polish)."""
    t0 = time.perf_counter()
    if method == "cmaes":
        from gaintune.baselines import run_baseline

        res = run_baseline(spec, "cmaes", budget=budget, seed=seed)
        assert res.gains is not None, res
        gains: dict = res.gains
    else:
        from gaintune.search.tuning import tune

        s = spec.model_copy(update={"search": spec.search.model_copy(update={"budget": budget, "seed": seed})})
        gains = tune(s, verify=False).gains
    out = score(spec, gains)
    out["wall_s"] = time.perf_counter() - t0
    return out


def optimum(spec: Any, label: str, args: argparse.Namespace) -> dict[str, Any] | None:
    """The per-plant constrained optimum of ``spec`` (cached multistart CMA-ES), scored as a row; None when
    ``--ref-restarts 0`` or the search found no passing answer."""
    if args.ref_restarts <= 0:
        return None
    from gaintune.bench.references import reference_for
    from gaintune.bench.suite import BenchCase

    case = BenchCase(label, label, spec.model_dump(mode="json", exclude_defaults=True), "mimo",
                     reference={"restarts": args.ref_restarts, "sims_per_restart": args.ref_sims})
    ref = reference_for(case, "mimo", resolve_out(args.out), log=lambda m: print(f"  ({m})", flush=True))
    if ref.get("gains") is None:
        return None
    row = score(spec, ref["gains"])
    row["n_sims"] = ref.get("n_sims")
    return row


def _fmt(name: str, r: dict[str, Any], ref_cost: float | None, opt_cost: float | None = None) -> str:
    ratio = f"{r['cost'] / ref_cost:.3f}" if ref_cost else "-"
    to_opt = f"{r['cost'] / opt_cost:.3f}" if opt_cost else "-"
    return (f"| {name:<44} | {r['cost']:9.3f} | {r['ms']:6.3f} | {r['disk_in']:6.3f} | {r['disk_out']:6.3f} | "
            f"{r['verdict']:<4} | {ratio:>6} | {to_opt:>6} |")


_HEAD = ("| row | cost | MIMO Ms | disk in | disk out | verdict | /published | /optimum |\n"
         "|---|---|---|---|---|---|---|---|")


def _plant_table(model: str, tuned_for: Sequence[str], args: argparse.Namespace) -> None:
    print(f"\n## {model}\n\n{_HEAD}", flush=True)
    for name, gains, kind in reference_rows(model):
        base = score(_with_type(model, kind), gains)
        print(_fmt(name + " (published)", base, None), flush=True)
        if name not in tuned_for:
            continue
        disk = min(base["disk_in"], base["disk_out"])
        ok = disk > 0  # the published row is stable here: tune at its own Ms and disk margin
        req = {"mimo_ms_max": round(base["ms"], 4), "disk_margin_min": round(disk, 4)} if ok else {}
        # backoff 0: the constraint is the reference's own figure, not a margin inside it
        spec = _with_type(model, "pi", True, **req, backoff=0)
        limits = f"Ms<={req.get('mimo_ms_max', '-')}, disk>={req.get('disk_margin_min', '-')}"
        opt = optimum(spec, f"{model} PI at {name}'s limits", args)
        if opt is not None:
            print(_fmt(f"  optimum, {opt['n_sims']} sims ({limits})", opt, base["cost"] if ok else None,
                       opt["cost"]), flush=True)
        for method, budget in (("cmaes", args.cmaes_budget), ("tune", args.rl_budget)):
            if budget <= 0:
                continue
            r = tuned_row(spec, method, budget, args.seed)
            print(_fmt(f"  gaintune {method} @{budget} ({limits})", r, base["cost"] if ok else None,
                       opt["cost"] if opt else None), flush=True)
            if args.verbose:
                print(f"    gains {r['gains']}; {r['wall_s']:.0f} s; {'; '.join(r['reasons'])}", flush=True)


def build_parser() -> argparse.ArgumentParser:
    ap = BenchParser(prog="gaintune bench mimo", description=__doc__.split("\n\n")[0])
    ap.add_argument("--cmaes-budget", type=int_range(0), default=1000,
                    help="CMA-ES simulations per tuned row (0: skip).")
    ap.add_argument("--rl-budget", type=int_range(0), default=1000,
                    help="`tune` (RL search + polish) simulations per tuned row (0: skip).")
    ap.add_argument("--seed", type=int_range(0), default=0)
    ap.add_argument("--plants", nargs="+", choices=["wood_berry", "quadruple_tank_min", "quadruple_tank_nmp"],
                    default=["wood_berry", "quadruple_tank_min", "quadruple_tank_nmp"])
    ap.add_argument("--ref-restarts", type=int_range(0), default=4,
                    help="CMA-ES restarts of the per-plant constrained optimum (0: no optimum column).")
    ap.add_argument("--ref-sims", type=int_range(100), default=3000, help="simulations per restart of the optimum.")
    ap.add_argument("--verbose", action="store_true", help="Print the tuned gains and wall time of each answer.")
    add_out_argument(ap)
    return ap


def main(argv: Sequence[str] | None = None) -> int:
    """Run the benchmark and print its tables."""
    args = build_parser().parse_args(argv)
    commit = subprocess.run(["git", "rev-parse", "--short", "HEAD"], capture_output=True, text=True,
                            cwd=os.path.dirname(__file__)).stdout.strip() or "unknown"
    print(f"command: gaintune bench mimo {' '.join(argv if argv is not None else sys.argv[1:])}".rstrip())
    print(f"commit {commit}; load average {' '.join(f'{x:.2f}' for x in os.getloadavg())}; {os.cpu_count()} cores")
    t0 = time.perf_counter()
    for model in args.plants:
        tuned_for = ("BLT", "Chen-Seborg") if model == "wood_berry" else ("Johansson PI",)
        _plant_table(model, tuned_for, args)
    print(f"\nwall time {time.perf_counter() - t0:.0f} s")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
