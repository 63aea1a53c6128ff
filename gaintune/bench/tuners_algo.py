"""``gaintune bench tuners --algo-compare``: TD3 (the default learner) against PPO on one family, equal episodes.

Both train a tuner for the same ready-made family, controller and Ms limit with the default
:class:`gaintune.tuners.train.TrainSettings` except ``algo``, the episode count and the held-out set,
from the same seed. Each is scored as the shipped tuners are: on held-out contexts (never trained
on, the same for both), each answer moved onto its plant's boundary and verified, its cost divided
by that context's own optimum (:func:`gaintune.tuners.validation.validate`). The default is small
(4,096 episodes, 16 contexts) so the comparison runs in minutes; the shipped tuners train 36,000.
"""

from __future__ import annotations

import tempfile
import time
from pathlib import Path
from typing import Any

__all__ = ["ALGOS", "measure_algo_compare", "render_algo_compare", "main_algo"]

#: The learners compared, the default first.
ALGOS = ("td3", "ppo")


def measure_algo_compare(family: str = "fotd", ctype: str = "pi", ms_max: float = 1.4, episodes: int = 4096,
                         contexts: int = 16, seed: int = 0, log: Any = None) -> dict[str, Any]:
    """Train one tuner per algorithm (:data:`ALGOS`) at ``episodes`` and score each on ``contexts`` held-out contexts.

    Returns per algorithm the held-out median and worst cost / optimum, the passes, the training
    simulations and wall time, and the training curve's last median ratio.
    """
    from gaintune.tuners import artefact
    from gaintune.tuners.problems import FamilyProblem
    from gaintune.tuners.train import TrainSettings, train

    out: dict[str, Any] = {"family": family, "ctype": ctype, "ms_max": ms_max, "episodes": episodes,
                           "contexts": contexts, "seed": seed}
    with tempfile.TemporaryDirectory() as tmp:
        for algo in ALGOS:
            t0 = time.perf_counter()
            settings = TrainSettings(episodes=episodes, seed=seed, algo=algo, validation=contexts,
                                     chunk=min(4096, episodes))
            folder = train(FamilyProblem(family, ctype, ms_max), Path(tmp) / algo, settings, keep_agent=False)
            art = artefact.load(folder)
            v, t = art.validation, art.training
            out[algo] = {"median_ratio": v["median_ratio"], "worst_ratio": v["worst_ratio"], "passed": v["passed"],
                         "n": v["n"], "sims": t["sims"], "episodes": t["episodes"],
                         "wall_s": time.perf_counter() - t0, "curve_last": t["curve"][-1]["median_ratio"]}
            if log is not None:
                log(f"{algo}: held-out median {v['median_ratio']:.4f}, worst {v['worst_ratio']:.4f}, "
                    f"{v['passed']}/{v['n']} pass, {t['sims']:,} sims, {out[algo]['wall_s']:.0f} s")
    return out


def render_algo_compare(r: dict[str, Any], command: str) -> str:
    """The comparison as Markdown."""
    from gaintune.bench.compare import md_table

    rows = [[a, f"{r[a]['median_ratio']:.4f}", f"{r[a]['worst_ratio']:.4f}", f"{r[a]['passed']}/{r[a]['n']}",
             f"{r[a]['sims']:,}", f"{r[a]['wall_s']:.0f}"] for a in ALGOS]
    return "\n".join([
        f"# {command}", "",
        f"Family {r['family']}, {r['ctype'].upper()}, Ms <= {r['ms_max']:g}; {r['episodes']:,} training episodes each, "
        f"seed {r['seed']}, default settings otherwise; {r['contexts']} held-out contexts (the same for both), "
        "cost / that context's optimum after the boundary move and the verification."
        + (f" Load average: {r['loadavg']}." if r.get("loadavg") else ""), "",
        md_table(["algo", "held-out median", "held-out worst", "pass", "training sims", "wall s"], rows), "",
    ]) + "\n"


def main_algo(args: Any, out: Path, command: str) -> int:
    """``gaintune bench tuners --algo-compare``: TD3 vs PPO at equal episodes on one family."""
    import sys

    from gaintune.bench.arguments import load_now, load_span
    from gaintune.bench.compare import publish

    load0 = load_now()
    r = measure_algo_compare(args.algo_family, args.ctype, 1.4, args.algo_episodes, args.algo_contexts,
                             log=lambda m: print(m, file=sys.stderr, flush=True))
    r["command"] = command
    r["loadavg"] = load_span(load0)
    return publish(r, out, "tuners_algo", render_algo_compare(r, command))
