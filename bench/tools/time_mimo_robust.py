"""Time the MIMO verdict with its robust set (``gaintune.verify``, nonlinear check off) beside the nominal one.

Run from the repository root: ``python bench/tools/time_mimo_robust.py [wood_berry quadruple_tank]``.
Wood-Berry: the R -> xD gain written as the parameter K11, uniform on [10, 16], BLT PI. quadruple_tank:
gamma1 uniform on [0.65, 0.75] and k1 on [3.2, 3.4], PI Kp 3, Ki 0.1 / Kp 2.7, Ki 0.0675. The default robust
set: the 2^d box corners + ``verify.robust_samples`` (16) Monte-Carlo draws. Per case: the first call in
the process, then the second; ``plant=`` passes one built plant to both (its per-plant work cached), else each
call builds its own. Process CPU time beside wall time.
"""

from __future__ import annotations

import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
sys.path[:0] = [str(ROOT / "tests" / "verification")]

from test_mimo_robust import RANDOM_K11, wood_berry_k11  # noqa: E402
from test_mimo_verdict import blt  # noqa: E402

from gaintune.plants import build_plant  # noqa: E402
from gaintune.plants.library import load_model  # noqa: E402
from gaintune.spec import load_spec  # noqa: E402
from gaintune.verification import verify  # noqa: E402


def _quadruple_tank() -> tuple[dict, dict]:
    data = load_model("quadruple_tank").example_spec()
    data["randomize"] = {"params": {"gamma1": {"low": 0.65, "high": 0.75}, "k1": {"low": 3.2, "high": 3.4}}}
    return data, {"y1": {"Kp": 3.0, "Ki": 0.1}, "y2": {"Kp": 2.7, "Ki": 0.0675}}


CASES = {"wood_berry": lambda: (wood_berry_k11(randomize=RANDOM_K11), blt()), "quadruple_tank": _quadruple_tank}


def _timed(spec, gains, **kw) -> str:
    t, c = time.perf_counter(), time.process_time()
    rep = verify(spec, gains, nonlinear=False, **kw)
    n = rep.robust.n_samples if rep.robust is not None else 0
    return f"cpu={time.process_time() - c:.3f}s wall={time.perf_counter() - t:.3f}s verdict={rep.verdict} plants={n}"


def main(names: list[str]) -> None:
    """Print per model: nominal and robust, first and second call, without and with a shared plant."""
    for name in names or list(CASES):
        data, gains = CASES[name]()
        spec = load_spec(data)
        for robust in (False, True):
            first, second = _timed(spec, gains, robust=robust), _timed(spec, gains, robust=robust)
            print(f"{name:14s} robust={robust!s:5s} first: {first} | second: {second}", flush=True)
        plant = build_plant(spec.plant)
        first, second = _timed(spec, gains, plant=plant), _timed(spec, gains, plant=plant)
        print(f"{name:14s} robust=True  plant= first: {first} | second: {second}", flush=True)


if __name__ == "__main__":
    main(sys.argv[1:])
