"""``gaintune bench ablation``: RL agents and PPO settings side by side on 1/(s+1)^3 PID (IAE + 0.01 int u^2).

Usage: gaintune bench ablation [--budget 5000] [--seeds 0 1] [--reference 1.602535]
The problem states no requirement (the unconstrained optimum is the reference).
Prints RL-only and policy-mean cost ratios to the reference optimum (docs/search.md).
"""

from __future__ import annotations

import time
from typing import Any

from gaintune.bench.arguments import BenchParser, budget_int, positive_float, seed_int
from gaintune.search import tune
from gaintune.spec import load_spec

__all__ = ["CONFIGS", "main"]

#: name -> (algo, env, agent overrides)
CONFIGS: dict[str, tuple[str, str, dict[str, Any]]] = {
    "ppo (default)": ("ppo", "oneshot", {}),
    "ppo lr=1e-3": ("ppo", "oneshot", {"learning_rate": 1e-3}),
    "ppo lr=1e-2": ("ppo", "oneshot", {"learning_rate": 1e-2}),
    "ppo 20 epochs": ("ppo", "oneshot", {"n_epochs": 20}),
    "sac": ("sac", "oneshot", {}),
    "td3": ("td3", "oneshot", {}),
    "ppo iterative env": ("ppo", "iterative", {}),
}


def main(argv: list[str] | None = None) -> int:
    """``gaintune bench ablation``: run each configuration on each seed and print a Markdown table row."""
    ap = BenchParser(prog="gaintune bench ablation", description=__doc__.splitlines()[0])
    ap.add_argument("--budget", type=budget_int, default=5000, help="simulations per run (default 5000)")
    ap.add_argument("--seeds", type=seed_int, nargs="+", default=[0])
    ap.add_argument("--reference", type=positive_float, default=1.602535, help="reference optimum cost (> 0)")
    ap.add_argument("--configs", nargs="+", default=list(CONFIGS), choices=list(CONFIGS), metavar="CONFIG",
                    help="configurations to run, quoted, from: " + ", ".join(f"'{c}'" for c in CONFIGS)
                    + " (default: all)")
    a = ap.parse_args(argv)
    print("| config | seed | RL-only / optimum | policy / optimum | sims | wall s |")
    print("|---|---|---|---|---|---|")
    for name in a.configs:
        algo, env, over = CONFIGS[name]
        for seed in a.seeds:
            spec = load_spec({
                "plant": {"tf": {"num": [1], "den": "(s+1)^3"}}, "loops": [{"type": "pid"}],
                "requirements": {"gm_min_db": None, "pm_min_deg": None, "ms_max": None},
                "search": {"algo": algo, "env": env, "budget": a.budget, "seed": seed, "refine": False},
            })
            t0 = time.perf_counter()
            r = tune(spec, verify=False, agent_overrides=over or None)
            print(f"| {name} | {seed} | {r.rl_cost / a.reference:.4f} | {r.policy_cost / a.reference:.4f} | "
                  f"{r.sims} | {time.perf_counter() - t0:.1f} |", flush=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
