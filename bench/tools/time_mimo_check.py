"""Time the search's per-candidate MIMO requirement check (``mimo_requirement_scores``: the exact sampled
loop's lean report at the search's aim) on built-in models.

Run from the repository root: ``python bench/tools/time_mimo_check.py [-n N] [--profile] [wood_berry robot_arm6
process_train]``. Candidates: the hand gains of ``tests/plants/test_big_models.py`` (BLT PI on Wood-Berry)
scaled by exp(N(0, 0.3)) per gain (seed 3), as a search's neighbourhood. One warm-up candidate first
(plant-only work, imports); then each candidate is checked on its own (the memo cleared), process CPU
time beside wall time. ``--profile`` prints the cProfile of the timed candidates (top 25 by cumulative time).
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

from gaintune.evaluation.evaluator import Evaluator, mimo_requirement_scores  # noqa: E402
from gaintune.plants.library import load_model  # noqa: E402
from gaintune.spec import load_spec  # noqa: E402


def _blt() -> dict:
    return {"xD": {"Kp": 0.375, "Ki": 0.375 / 8.29}, "xB": {"Kp": -0.075, "Ki": -0.075 / 23.6}}


CASES = {"wood_berry": _blt, "robot_arm6": _arm_gains, "process_train": _process_gains}


def candidates(ev: Evaluator, gains: dict, n: int, seed: int = 3) -> np.ndarray:
    """n tuned gain vectors near ``gains``: each gain times exp(N(0, 0.3))."""
    base = ev.layout.tuned_of(ev.layout.from_dict(gains))
    rng = np.random.default_rng(seed)
    return base[None] * np.exp(rng.normal(0.0, 0.3, (n, base.size)))


def time_model(name: str, n: int, profile: bool = False) -> tuple[float, float, np.ndarray]:
    """(CPU ms, wall ms) per candidate over n candidates, and their violations."""
    ev = Evaluator(load_spec(load_model(name).example_spec()))
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


def main() -> None:
    """Print one line per model: CPU and wall ms per candidate, and the candidates' violations."""
    ap = argparse.ArgumentParser()
    ap.add_argument("models", nargs="*", default=list(CASES))
    ap.add_argument("-n", type=int, default=5)
    ap.add_argument("--profile", action="store_true")
    args = ap.parse_args()
    for name in args.models:
        cpu, wall, viol = time_model(name, args.n, args.profile)
        print(f"{name:13s} n={args.n} cpu={cpu:8.1f} ms/candidate wall={wall:8.1f} ms/candidate "
              f"violations={np.array2string(viol, precision=6)}", flush=True)


if __name__ == "__main__":
    main()
