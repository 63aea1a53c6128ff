"""Time the search's per-candidate MIMO requirement check (``mimo_requirement_scores``: the exact sampled
loop's lean report at the search's aim) on built-in models.

Run from the repository root: ``python bench/tools/time_mimo_check.py [-n N] [--profile] [--repair] [wood_berry
wood_berry_k11 robot_arm6 process_train]``. ``wood_berry_k11`` is the Wood-Berry example with its R -> xD gain K11
uniform on [10, 16] (``randomize.params``; ``tests/verification/test_mimo_robust.py``): the check judges the
nominal plant and the 2 box corners. Candidates: the hand gains of ``tests/plants/test_big_models.py`` (BLT PI on
Wood-Berry) scaled by exp(N(0, 0.3)) per gain (seed 3), as a search's neighbourhood. One warm-up candidate first
(plant-only work, imports); then each candidate is checked on its own (the memo cleared), process CPU
time beside wall time. ``--profile`` prints the cProfile of the timed candidates (top 25 by cumulative time).
``--repair`` also moves the n candidates onto the requirement boundary as one batch
(:func:`gaintune.evaluation.boundary_estimate.onto_boundary_estimate`, every loop together, as the search's
default) and counts the MIMO checks that costs: evaluations (memo misses) and rows asked for.
"""

from __future__ import annotations

import argparse
import cProfile
import pstats
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[2]
sys.path[:0] = [str(ROOT / "tests" / "plants"), str(ROOT / "tests" / "verification")]

from test_big_models import _arm_gains, _process_gains  # noqa: E402
from test_mimo_robust import RANDOM_K11, wood_berry_k11  # noqa: E402

from gaintune.evaluation.evaluator import Evaluator, mimo_requirement_scores  # noqa: E402
from gaintune.plants.library import load_model  # noqa: E402
from gaintune.spec import TuningSpec, load_spec  # noqa: E402


def _blt() -> dict:
    return {"xD": {"Kp": 0.375, "Ki": 0.375 / 8.29}, "xB": {"Kp": -0.075, "Ki": -0.075 / 23.6}}


CASES = {"wood_berry": _blt, "wood_berry_k11": _blt, "robot_arm6": _arm_gains, "process_train": _process_gains}


def case_spec(name: str) -> TuningSpec:
    """The spec of case ``name``: the model's example, or the randomised Wood-Berry."""
    if name == "wood_berry_k11":
        return load_spec(wood_berry_k11(randomize=RANDOM_K11))
    return load_spec(load_model(name).example_spec())


def candidates(ev: Evaluator, gains: dict, n: int, seed: int = 3, scale: float = 1.0) -> np.ndarray:
    """n tuned gain vectors near ``gains`` times ``scale``: each gain times exp(N(0, 0.3))."""
    base = scale * ev.layout.tuned_of(ev.layout.from_dict(gains))
    rng = np.random.default_rng(seed)
    return base[None] * np.exp(rng.normal(0.0, 0.3, (n, base.size)))


def time_model(name: str, n: int, profile: bool = False) -> tuple[float, float, np.ndarray]:
    """(CPU ms, wall ms) per candidate over n candidates, and their violations."""
    ev = Evaluator(case_spec(name))
    rows = candidates(ev, CASES[name](), n + 1)
    mimo_requirement_scores(ev, rows[:1])  # warm-up: plant-only work, imports
    prof = cProfile.Profile() if profile else None
    viol = np.zeros(n)
    cpu = wall = 0.0
    for b in range(n):
        ev._mimo_memo.clear()
        c, t = time.process_time(), time.perf_counter()
        if prof is not None:
            prof.enable()
        viol[b] = mimo_requirement_scores(ev, rows[1 + b : 2 + b])[0][0]
        if prof is not None:
            prof.disable()
        cpu += time.process_time() - c
        wall += time.perf_counter() - t
    if prof is not None:
        pstats.Stats(prof).sort_stats("cumulative").print_stats(25)
    return 1e3 * cpu / n, 1e3 * wall / n, viol


def count_repair(name: str, n: int, per_loop: bool = False, scale: float = 1.0) -> dict:
    """Check calls of one repaired batch of n candidates: rows asked for, checks evaluated, CPU."""
    from gaintune.evaluation.boundary_estimate import onto_boundary_estimate
    from gaintune.verification import mimo_sampled_report as msr

    ev = Evaluator(case_spec(name))
    rows = candidates(ev, CASES[name](), n + 1, scale=scale)
    mimo_requirement_scores(ev, rows[:1])  # warm-up
    ev._mimo_memo.clear()
    v, _ = mimo_requirement_scores(ev, rows[1:])  # which rows the repair moves (stable, infeasible)
    eligible = int(np.sum((v > 0) & (v < 10.0)))
    ev._mimo_memo.clear()
    real, asked = msr.sampled_margins, [0]
    calls = [0]

    def counted(*a: object, **k: object) -> object:
        calls[0] += 1
        return real(*a, **k)  # type: ignore[arg-type]

    import gaintune.evaluation.evaluator as evmod

    real_scores = evmod.mimo_requirement_scores

    def scores(e: Evaluator, tuned: np.ndarray, stability: bool = True) -> tuple[np.ndarray, np.ndarray]:
        asked[0] += len(tuned)
        return real_scores(e, tuned, stability)

    msr.sampled_margins, evmod.mimo_requirement_scores = counted, scores  # type: ignore[assignment]
    try:
        c = time.process_time()
        move = onto_boundary_estimate(ev, rows[1:], per_loop=per_loop)
        cpu = time.process_time() - c
    finally:
        msr.sampled_margins, evmod.mimo_requirement_scores = real, real_scores  # type: ignore[assignment]
    v0 = move.violation  # after; the eligible rows are those the first estimate found stable and infeasible
    return {"candidates": n, "eligible": eligible, "repaired": int(move.repaired.sum()),
            "infeasible_after": int((v0 > 0).sum()), "rows_asked": asked[0], "checks": calls[0], "cpu_s": cpu}


def main() -> None:
    """Print one line per model: CPU and wall ms per candidate, and the candidates' violations."""
    ap = argparse.ArgumentParser()
    ap.add_argument("models", nargs="*", default=list(CASES))
    ap.add_argument("-n", type=int, default=5)
    ap.add_argument("--profile", action="store_true")
    ap.add_argument("--repair", action="store_true")
    ap.add_argument("--scale", type=float, default=1.0, help="every base gain times this (--repair)")
    args = ap.parse_args()
    for name in args.models:
        if args.repair:
            r = count_repair(name, args.n, scale=args.scale)
            print(f"{name:13s} scale={args.scale:g} repair of {r['candidates']} candidates ({r['eligible']} stable "
                  f"and infeasible): {r['repaired']} moved, "
                  f"{r['infeasible_after']} still infeasible; {r['checks']} checks evaluated "
                  f"({r['checks'] / r['candidates']:.1f} a candidate), {r['rows_asked']} rows asked "
                  f"({r['rows_asked'] / r['candidates']:.1f} a candidate); cpu={r['cpu_s']:.2f}s "
                  f"({1e3 * r['cpu_s'] / r['candidates']:.0f} ms a candidate)", flush=True)
            continue
        cpu, wall, viol = time_model(name, args.n, args.profile)
        print(f"{name:13s} n={args.n} cpu={cpu:8.1f} ms/candidate wall={wall:8.1f} ms/candidate "
              f"violations={np.array2string(viol, precision=6)}", flush=True)


if __name__ == "__main__":
    main()
