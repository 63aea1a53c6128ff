"""Benchmark: nominal verification time of a 3-loop DC-motor cascade and a 1-loop loop.

Run:  .venv/bin/python bench/bench_verify.py [--repeat 50]

Budget: one nominal 3-loop verify in at most 50 ms. Also times the batched cheap
penalty (B=64) used in the RL reward (budget 20 ms), and a full verify (nonlinear
check included, different gains each call) of the API benchmark's 2-loop cascade.
"""

from __future__ import annotations

import argparse
import time

import numpy as np

from gaintune.controllers.layout import GainLayout
from gaintune.plants.plant import build_plant
from gaintune.spec import load_spec
from gaintune.verify import requirement_violation, verify

R, Lm, J, b, Kt = 1.0, 0.01, 0.01, 0.001, 0.5

#: DC motor, states current i, speed w, angle th; cascade position -> speed -> current.
MOTOR_CASCADE = {
    "name": "dc_motor_cascade",
    "plant": {
        "ss": {
            "A": [[-R / Lm, -Kt / Lm, 0.0], [Kt / J, -b / J, 0.0], [0.0, 1.0, 0.0]],
            "B": [[1.0 / Lm], [0.0], [0.0]],
            "C": [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]],
            "states": ["i", "w", "th"],
            "outputs": ["i", "w", "th"],
        }
    },
    "loops": [
        {"name": "position", "type": "p", "measure": "th"},
        {"name": "speed", "type": "pi", "measure": "w"},
        {"name": "current", "type": "pi", "measure": "i"},
    ],
    "scenario": {"dt": 1e-4, "horizon": 1.0},
}
MOTOR_GAINS = {"position": {"Kp": 10.0}, "speed": {"Kp": 2.0, "Ki": 40.0}, "current": {"Kp": 10.0, "Ki": 1000.0}}

ONE_LOOP = {"plant": {"tf": {"num": [1], "den": "(s+1)^3"}}, "loops": [{"type": "pi"}], "scenario": {"dt": 0.01}}
ONE_GAINS = {"loop0": {"Kp": 1.14, "Ki": 0.454}}


def _time(fn, repeat: int) -> tuple[float, float]:
    fn()  # warm up (imports, caches)
    ts = []
    for _ in range(repeat):
        t0 = time.perf_counter()
        fn()
        ts.append(time.perf_counter() - t0)
    ts = np.array(ts) * 1e3
    return float(ts.mean()), float(np.percentile(ts, 95))


def _api_cascade(repeat: int) -> None:
    """The API benchmark's 2-loop cascade: full verify (nonlinear check on) with different gains each call."""
    from gaintune.bench.api import CASCADE_SPEC, NOMINAL_GAINS

    spec = load_spec(CASCADE_SPEC)
    rng = np.random.default_rng(1)

    def one():
        f = np.exp(rng.uniform(np.log(0.8), np.log(1.25), 4))
        g = {"speed": {"Kp": NOMINAL_GAINS["speed"]["Kp"] * f[0], "Ki": NOMINAL_GAINS["speed"]["Ki"] * f[1]},
             "current": {"Kp": NOMINAL_GAINS["current"]["Kp"] * f[2], "Ki": NOMINAL_GAINS["current"]["Ki"] * f[3]}}
        verify(spec, g)

    mean, p95 = _time(one, repeat)
    print(f"verify 2-loop API cascade, full, distinct gains: mean {mean:6.1f} ms  p95 {p95:6.1f} ms")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--repeat", type=int, default=50)
    args = ap.parse_args()
    _api_cascade(args.repeat)
    for label, spec_d, gains in (("3-loop cascade", MOTOR_CASCADE, MOTOR_GAINS), ("1-loop", ONE_LOOP, ONE_GAINS)):
        spec = load_spec(spec_d)
        plant = build_plant(spec.plant)
        layout = GainLayout(spec, plant.states)
        rep = verify(spec, gains, robust=False, nonlinear=False, plant=plant, layout=layout)
        mean, p95 = _time(lambda: verify(spec, gains, robust=False, nonlinear=False, plant=plant, layout=layout), args.repeat)
        print(f"verify {label:<15} nominal: mean {mean:6.1f} ms  p95 {p95:6.1f} ms  (verdict {rep.verdict})")
        mean, p95 = _time(lambda: verify(spec, gains, robust=False, nonlinear=False), args.repeat)
        print(f"verify {label:<15} incl. plant build: mean {mean:6.1f} ms  p95 {p95:6.1f} ms")
        full = np.tile(layout.from_dict(gains), (64, 1)) * np.exp(np.random.default_rng(0).normal(0, 0.3, (64, layout.n_gains)))
        lin = plant.linearize()
        mean, p95 = _time(lambda: requirement_violation(spec, plant, layout, full, lin), args.repeat)
        print(f"quick penalty B=64 {label:<15}: mean {mean:6.1f} ms  p95 {p95:6.1f} ms")


if __name__ == "__main__":
    main()
