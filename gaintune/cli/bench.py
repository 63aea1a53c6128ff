"""``gaintune bench``: the benchmark sub-app, one pass-through command per module of :mod:`gaintune.bench`.

:data:`BENCH` names every benchmark (with its one-line help); ``gaintune bench NAME
ARGS...`` imports ``gaintune.bench.NAME`` only when run and calls its ``main(argv)``
with the arguments unchanged, so ``--help`` shows the benchmark's own options.
"""

from __future__ import annotations

import importlib
from collections.abc import Callable

import typer

from gaintune.cli.common import EPILOG, err

__all__ = ["BENCH", "bench_app"]

bench_app = typer.Typer(help="Benchmarks (arguments after the command are passed through; --help shows each "
                             "benchmark's own options).",
                        no_args_is_help=True, epilog=EPILOG)

BENCH = {
    "sim": "Simulator throughput (simulations/s).",
    "search": "RL search vs baselines on the benchmark processes.",
    "verify": "Verification speed: nominal, full and the search estimate's batch.",
    "compare": "Compare gaintune with classical rules and optimisers.",
    "constraints": "Agreement of the searched requirement estimate with the verdict near the boundary.",
    "kernel": "The simulator kernel side by side with an earlier git revision of it.",
    "ablation": "RL agents and PPO settings side by side on 1/(s+1)^3 PID.",
    "scaling": "Budget-to-quality curves of the RL search and CMA-ES on suite problems, built-in models (quadrotor, "
               "robot_arm6, process_train) or any spec.",
    "startup": "End-to-end wall time of --help, import, verify and a 3,000-simulation tune, beside python -c pass.",
    "tuners": "Trained tuners on held-out FOTD plants against the per-plant optimum and AMIGO/SIMC, with their "
              "answer time.",
    "quick": "`tune --quick` on the standard suite's SISO problems against the cached reference and AMIGO/SIMC, with "
             "its wall time.",
    "sweep": "Fleet sweeps: local processes vs Ray (overhead), 1 vs 2 workers, a Ray worker and the driver killed, "
             "a 10,000-loop cluster projection.",
    "mimo": "Wood-Berry and quadruple-tank decentralised PI: tuned against the published rows at their own MIMO Ms "
            "and multiloop disk margin.",
    "api": "REST API load test.",
    "chaos": "Chaos campaign against a real API server: worker/server kills, freezes, storage faults, reused "
             "connections.",
}


def _bench_runner(name: str) -> Callable:
    def run(ctx: typer.Context) -> None:
        try:
            mod = importlib.import_module(f"gaintune.bench.{name}")
        except ModuleNotFoundError as exc:
            err.print(f"error: benchmark '{name}' is not available (module gaintune.bench.{name} is missing: {exc})",
                      markup=False)
            raise typer.Exit(1) from None
        main = getattr(mod, "main", None)
        if main is None:
            err.print(f"error: gaintune.bench.{name} has no main(argv)", markup=False)
            raise typer.Exit(1)
        rc = main(list(ctx.args))
        raise typer.Exit(int(rc or 0))

    run.__doc__ = BENCH[name]
    return run


for _name in BENCH:
    bench_app.command(
        _name,
        context_settings={"allow_extra_args": True, "ignore_unknown_options": True, "help_option_names": []},
        add_help_option=False,
    )(_bench_runner(_name))
