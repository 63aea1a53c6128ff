"""Rebuild the ready-made tuners shipped with gaintune: ``python -m gaintune.tuners.build_shipped [NAME ...]``.

Each entry of :data:`SHIPPED` is a family tuner (:class:`gaintune.tuners.problems.FamilyProblem`)
or, for ``family = "spec"``, a spec tuner over the spec file ``gaintune/tuners/specs/<ctype>``
(the water tank over its operating level, for gain schedules), trained with the default
:class:`gaintune.tuners.train.TrainSettings` (seed 0) into ``gaintune/tuners/shipped/<name>``.
The folders are small (the policy's and the critic's arrays and tuner.json; no torch agent:
``gaintune tuner update`` starts the actor and the critic from the arrays) and kept in the repository;
``tests/tuners/test_shipped.py`` checks that every one loads with the code that reads it and answers a plant
of its family.
"""

from __future__ import annotations

import argparse
import sys
import time
from collections.abc import Sequence

from gaintune.tuners.artefact import SHIPPED_DIR

__all__ = ["SHIPPED", "main"]

#: name -> (family, controller, Ms limit, training episodes)
SHIPPED: dict[str, tuple[str, str, float, int]] = {
    "fotd_pi_ms1.4": ("fotd", "pi", 1.4, 36_000),
    "fotd_pi_ms2": ("fotd", "pi", 2.0, 36_000),
    "fotd_pid_ms1.4": ("fotd", "pid", 1.4, 36_000),
    "fotd_pid_ms2": ("fotd", "pid", 2.0, 36_000),
    "sotd_pi_ms1.4": ("sotd", "pi", 1.4, 36_000),
    "ipd_pi_ms1.4": ("ipd", "pi", 1.4, 24_000),
    "water_tank_h0": ("spec", "water_tank_h0.yaml", 0.0, 12_000),
}
#: Validation contexts of the spec tuners (their optimum is a reference search, not MIGO).
SPEC_VALIDATION = 8


def build(name: str, log=print) -> None:
    """Train one shipped tuner into ``SHIPPED_DIR/name``."""
    from pathlib import Path

    from gaintune.spec import load_spec
    from gaintune.tuners.problems import FamilyProblem, SpecProblem, TunerProblem
    from gaintune.tuners.train import TrainSettings, train

    fam, ctype, ms, episodes = SHIPPED[name]
    settings = TrainSettings(episodes=episodes)
    problem: TunerProblem
    if fam == "spec":
        text = (Path(__file__).resolve().parent / "specs" / ctype).read_text(encoding="utf-8")
        problem = SpecProblem(load_spec(text))
        settings = TrainSettings(episodes=episodes, validation=SPEC_VALIDATION, curve_contexts=4)
    else:
        problem = FamilyProblem(fam, ctype, ms)
    t0 = time.perf_counter()

    def progress(done: int, total: int, info: dict) -> None:
        if "median_ratio" in info:
            log(f"{name}: {done:,}/{total:,} episodes, {info['sims']:,} sims, {info['elapsed_s']:.0f} s, "
                f"curve median ratio {info['median_ratio']:.4f}")

    # no agent.zip: the folders stay small; 'tuner update' then starts from policy.npz and critic.npz
    train(problem, SHIPPED_DIR / name, settings, name=name, on_progress=progress, keep_agent=False)
    log(f"{name}: done in {time.perf_counter() - t0:.0f} s")


def main(argv: Sequence[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="python -m gaintune.tuners.build_shipped", description=__doc__.splitlines()[0])
    ap.add_argument("names", nargs="*", help=f"tuners to rebuild (default: all of {', '.join(SHIPPED)})")
    args = ap.parse_args(argv)
    unknown = [n for n in args.names if n not in SHIPPED]
    if unknown:
        print(f"error: unknown shipped tuner {unknown[0]!r}; known: {', '.join(SHIPPED)}", file=sys.stderr)
        return 2
    for name in args.names or list(SHIPPED):
        build(name)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
