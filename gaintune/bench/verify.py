"""``gaintune bench verify``: how long verification takes, nominal and full, and the search estimate's batch.

Cases (models from ``models/``, not copies):

* the 3-loop DC-motor cascade (``models/dc_motor.yaml`` with J = 0.01, b = 0.001,
  Kt = Ke = 0.5: the parameters this benchmark has always used), position P -> speed PI
  -> current PI, dt 0.1 ms;
* one PI loop on 1/(s+1)^3, dt 10 ms;
* the REST benchmark's 2-loop speed cascade, full verification (nonlinear check on) with
  different gains on every call (``gaintune.bench.api.CASCADE_SPEC``);
* MIMO verification (``gaintune.verification.mimo.mimo_report``): the Wood-Berry column with
  Luyben's BLT PI gains, and a synthetic 18 x 18 diagonally dominant plant (first-order
  channels, input delays of 10-50 ms, 10 % coupling) with a decentralised PI loop per channel
  (:func:`synthetic_mimo`). Their rows also give the mean process CPU time, which a busy machine
  inflates less than the wall time.

For each: ``verify`` nominal with the plant and layout reused, ``verify`` including the
plant build, and the batched search estimate (``requirement_violation``, B = 64). Figures are
mean and p95 over ``--repeat`` calls after one warm-up call; the machine is shared, so
compare figures from one run. Written to ``--out`` (default ``bench/results``) as Markdown.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Sequence
from typing import TYPE_CHECKING, Any

import numpy as np

from gaintune.bench.arguments import BenchParser, add_out_argument, positive_int, resolve_out
from gaintune.bench.compare import md_table, write_outputs

if TYPE_CHECKING:  # pragma: no cover
    from gaintune.spec import Gains

__all__ = ["CASES", "main", "synthetic_mimo", "mimo_rows"]

#: name -> (spec dict, gains)
CASES: dict[str, tuple[dict[str, Any], Gains]] = {
    "3-loop DC-motor cascade": (
        {
            "name": "dc_motor_cascade",
            "plant": {"model": {"name": "dc_motor", "params": {"J": 0.01, "b": 0.001, "Kt": 0.5, "Ke": 0.5}}},
            "loops": [
                {"name": "position", "type": "p", "measure": "position"},
                {"name": "speed", "type": "pi", "measure": "speed"},
                {"name": "current", "type": "pi", "measure": "current"},
            ],
            "scenario": {"dt": 1e-4, "horizon": 1.0},
        },
        {"position": {"Kp": 10.0}, "speed": {"Kp": 2.0, "Ki": 40.0}, "current": {"Kp": 10.0, "Ki": 1000.0}},
    ),
    "1 PI loop, 1/(s+1)^3": (
        {"plant": {"tf": {"num": [1], "den": "(s+1)^3"}}, "loops": [{"type": "pi"}], "scenario": {"dt": 0.01}},
        {"loop0": {"Kp": 1.14, "Ki": 0.454}},
    ),
}


def _time(fn: Callable[[], object], repeat: int) -> tuple[float, float]:
    """(mean, p95) wall time in ms over ``repeat`` calls, after one warm-up call."""
    fn()
    ts = []
    for _ in range(repeat):
        t0 = time.perf_counter()
        fn()
        ts.append(time.perf_counter() - t0)
    ms = np.array(ts) * 1e3
    return float(ms.mean()), float(np.percentile(ms, 95))


def _case_rows(name: str, spec_d: dict[str, Any], gains: Gains, repeat: int) -> list[list[Any]]:
    """One case's rows: verify nominal (plant reused, then built per call) and the batched search estimate."""
    from gaintune.controllers.layout import GainLayout
    from gaintune.plants import build_plant
    from gaintune.spec import load_spec
    from gaintune.verification import requirement_violation, verify

    spec = load_spec(spec_d)
    plant = build_plant(spec.plant)
    layout = GainLayout(spec, plant.states, plant=plant)
    rep = verify(spec, gains, robust=False, nonlinear=False, plant=plant, layout=layout)
    rows: list[list[Any]] = []
    m, p = _time(lambda: verify(spec, gains, robust=False, nonlinear=False, plant=plant, layout=layout), repeat)
    rows.append([name, "verify, nominal", m, p, rep.verdict])
    m, p = _time(lambda: verify(spec, gains, robust=False, nonlinear=False, cache=False), repeat)
    rows.append([name, "verify, nominal, plant built per call", m, p, rep.verdict])
    rng = np.random.default_rng(0)
    full = np.tile(layout.from_dict(gains), (64, 1)) * np.exp(rng.normal(0, 0.3, (64, layout.n_gains)))
    lin = plant.linearize()
    m, p = _time(lambda: requirement_violation(spec, plant, layout, full, lin), repeat)
    rows.append([name, "search estimate, batch of 64", m, p, "-"])
    return rows


def synthetic_mimo(n: int = 18, seed: int = 0):
    """An n x n diagonally dominant plant (channel i: a_i/(s + a_i), a_i in [0.5, 5], coupling up to
    10 %, input delays 10-50 ms) and a PI loop per channel (Kp 2, Ki 2 a_i): (plant, loops)."""
    from gaintune.lti.mimo import DelayedSS
    from gaintune.verification.mimo_loop import PidLoop

    rng = np.random.default_rng(seed)
    a = rng.uniform(0.5, 5.0, n)
    B = np.diag(a) + 0.1 * rng.uniform(-1.0, 1.0, (n, n)) * a[:, None]
    plant = DelayedSS(-np.diag(a), B, np.eye(n), np.zeros((n, n)), inputs=tuple(f"u{i}" for i in range(n)),
                      outputs=tuple(f"y{i}" for i in range(n)), input_delays=rng.uniform(0.01, 0.05, n))
    return plant, [PidLoop(f"loop{i}", f"y{i}", f"u{i}", Kp=2.0, Ki=2.0 * a[i]) for i in range(n)]


def _wood_berry_blt():
    """The Wood-Berry column (minutes) and Luyben's BLT PI loops."""
    from gaintune.lti.mimo import TfEntry, TfMatrix
    from gaintune.verification.mimo_loop import PidLoop

    def e(num: list[float], den: list[float], delay: float) -> TfEntry:
        return TfEntry(np.array(num), np.array(den), delay)

    plant = TfMatrix(((e([12.8], [16.7, 1], 1), e([-18.9], [21, 1], 3)), (e([6.6], [10.9, 1], 7),
                                                                          e([-19.4], [14.4, 1], 3))),
                     inputs=("reflux", "steam"), outputs=("xD", "xB"))
    return plant, [PidLoop("top", "xD", "reflux", Kp=0.375, Ki=0.375 / 8.29),
                   PidLoop("bottom", "xB", "steam", Kp=-0.075, Ki=-0.075 / 23.6)]


def mimo_rows(repeat: int) -> list[list[Any]]:
    """Rows for MIMO verification: Wood-Berry BLT and the synthetic 18-loop plant."""
    from gaintune.verification.mimo import mimo_report
    from gaintune.verification.mimo_loop import decentralised_pid

    rows: list[list[Any]] = []
    for name, (plant, loops) in (("Wood-Berry, BLT PI (2 loops)", _wood_berry_blt()),
                                 ("synthetic 18 x 18, decentralised PI (18 loops)", synthetic_mimo())):
        K = decentralised_pid(plant, loops)
        rep = mimo_report(plant, K, loops)
        cpu: list[float] = []

        def one(plant=plant, K=K, loops=loops, cpu=cpu) -> None:
            c0 = time.process_time()
            mimo_report(plant, K, loops)
            cpu.append(time.process_time() - c0)

        m, p = _time(one, repeat)
        verdict = (f"{'stable' if rep.stability.stable else 'UNSTABLE'}, Ms {rep.ms:.3f}, "
                   f"disk alpha {rep.disk_alpha:.4f}, CPU {1e3 * float(np.mean(cpu[1:] or cpu)):.0f} ms")
        rows.append([name, "mimo_report (stability, loop-at-a-time, multiloop disk, sigma peaks)", m, p, verdict])
    return rows


def measure(repeat: int) -> list[list[Any]]:
    """Rows ``[case, what, mean ms, p95 ms, verdict]``."""
    from gaintune.bench.api import CASCADE_SPEC, NOMINAL_GAINS
    from gaintune.spec import load_spec
    from gaintune.verification import verify

    rows = [row for name, (spec_d, gains) in CASES.items() for row in _case_rows(name, spec_d, gains, repeat)]
    spec = load_spec(CASCADE_SPEC)
    rng = np.random.default_rng(1)

    def one() -> None:
        f = np.exp(rng.uniform(np.log(0.8), np.log(1.25), 4))
        g = {"speed": {"Kp": NOMINAL_GAINS["speed"]["Kp"] * f[0], "Ki": NOMINAL_GAINS["speed"]["Ki"] * f[1]},
             "current": {"Kp": NOMINAL_GAINS["current"]["Kp"] * f[2], "Ki": NOMINAL_GAINS["current"]["Ki"] * f[3]}}
        verify(spec, g)

    m, p = _time(one, repeat)
    rows.append(["REST 2-loop speed cascade", "verify, full (nonlinear check), distinct gains", m, p, "-"])
    return rows + mimo_rows(repeat)


def main(argv: Sequence[str] | None = None) -> int:
    """``gaintune bench verify``: time every case, print the table and write it to ``--out``."""
    ap = BenchParser(prog="gaintune bench verify", description=(__doc__ or "").splitlines()[0])
    ap.add_argument("--repeat", type=positive_int, default=50, help="timed calls per figure (default 50)")
    add_out_argument(ap)
    args = ap.parse_args(argv)
    out = resolve_out(args.out)
    rows = measure(args.repeat)
    table = md_table(["case", "what", "mean ms", "p95 ms", "verdict"], rows)
    print(table)
    _, md = write_outputs({"rows": rows, "repeat": args.repeat}, out, "verify",
                          f"# gaintune bench verify --repeat {args.repeat}\n\n{table}\n")
    print(f"wrote {md}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
