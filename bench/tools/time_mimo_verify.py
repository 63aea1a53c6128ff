"""Time the MIMO verdict (``gaintune.verify``, nonlinear check off) on built-in models, sampled loop
(the default) against the continuous loop plus dt/2 (``verify.sampled: false``).

Run from the repository root: ``python bench/tools/time_mimo_verify.py [wood_berry quadrotor robot_arm6]``.
Gains: BLT PI on Wood-Berry, the hand gains of ``tests/plants/test_big_models.py`` on the others. Each
figure is the second call (imports and caches warm), process CPU time beside wall time.
"""

from __future__ import annotations

import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
sys.path[:0] = [str(ROOT / "tests" / "plants"), str(ROOT / "tests" / "verification")]

from test_big_models import _arm_gains, _quad_gains  # noqa: E402
from test_mimo_verdict import blt  # noqa: E402

from gaintune.plants.library import load_model  # noqa: E402
from gaintune.spec import load_spec  # noqa: E402
from gaintune.verification import verify  # noqa: E402

CASES = {"wood_berry": blt, "quadrotor": _quad_gains, "robot_arm6": _arm_gains}


def main(names: list[str]) -> None:
    """Print one line per model and loop: verdict, stability, grid size, CPU and wall seconds."""
    for name in names or list(CASES):
        for sampled in (True, False):
            data = load_model(name).example_spec()
            data.setdefault("verify", {})["sampled"] = sampled
            spec, gains = load_spec(data), CASES[name]()
            verify(spec, gains, nonlinear=False)
            t, c = time.perf_counter(), time.process_time()
            rep = verify(spec, gains, nonlinear=False)
            assert rep.mimo is not None
            print(f"{name:11s} sampled={sampled!s:5s} verdict={rep.verdict} stable={rep.stability.stable} "
                  f"grid={rep.mimo.grid_points} cpu={time.process_time() - c:.2f}s wall={time.perf_counter() - t:.2f}s "
                  f"ms={rep.mimo.ms:.4g} first reason: {rep.reasons[0] if rep.reasons else '-'}", flush=True)


if __name__ == "__main__":
    main(sys.argv[1:])
