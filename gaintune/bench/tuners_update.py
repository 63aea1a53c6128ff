"""``gaintune bench tuners --update``: learning on (``gaintune tuner update``) against a cold start.

The changed family is the FOTD family with a sensor lag added, ``e^{-tau s}/(((1-tau) s + 1)(LAG s + 1))``
in the time unit ``L + T`` (:func:`changed_spec`), PI, the same load-step problem and Ms limit, over the
same range of ``tau``. Both runs train on it with the same settings and seed, one from scratch and one
from the shipped tuner (``tuner update``: its actor and gain box, a lower starting exploration, and a
fresh critic trained alone for its first episodes). The figure is the number of training simulations
until the training curve's median cost / per-context optimum (on fixed contexts, each scored against
its own MIGO optimum) first reaches :data:`TARGET`, and their ratio.
"""

from __future__ import annotations

import math
import tempfile
import time
from pathlib import Path
from typing import Any

__all__ = ["LAG", "TARGET", "CURVE_EVERY", "CHUNK", "changed_spec", "sims_to", "measure_update",
           "main_update"]

#: The added sensor lag, in units of L + T.
LAG = 0.2
#: The curve's median cost / optimum both runs must reach.
TARGET = 1.01
#: Default episodes between curve points (``--update-curve-every``): a measurement only, the training is the same.
CURVE_EVERY = 64
#: Episodes of a training chunk (checkpoint, and step of the noise schedule) of both runs.
CHUNK = 256


def changed_spec(ms_max: float = 1.4) -> Any:
    """The changed family as a spec with ``randomize`` over ``tau`` (log-uniform, the FOTD tuners' range)."""
    from gaintune.spec import load_spec
    from gaintune.tuners.families import FAMILIES

    lo, hi = FAMILIES["fotd"].shape["tau"]
    return load_spec({
        "name": "fotd_sensor_lag",
        "plant": {"tf": {"num": [1], "den": f"((1 - tau)*s + 1)*({LAG}*s + 1)"}, "delay": "tau",
                  "params": {"tau": math.sqrt(lo * hi)}},
        "loops": [{"name": "main", "type": "pi"}],
        "scenarios": [{"name": "load", "reference": {"kind": "none"},
                       "disturbance": {"kind": "step", "entry": "input", "amplitude": 1.0, "time": 0.0}}],
        "objective": {"measure": "iae", "effort_weight": 0.0},
        "requirements": {"gm_min_db": None, "pm_min_deg": None, "ms_max": ms_max, "backoff": 0},
        "randomize": {"params": {"tau": {"dist": "loguniform", "low": lo, "high": hi}}},
    })


def sims_to(curve: list[dict[str, Any]], target: float = TARGET) -> int | None:
    """Training simulations at the first curve point with median ratio <= ``target`` (None: never)."""
    for p in curve:
        r = p.get("median_ratio")
        if r is not None and r <= target:
            return int(p["sims"])
    return None


def _base_with_agent(tmp: Path, seed: int) -> Path:
    """A tuner of the FOTD PI Ms 1.4 family trained as ``gaintune tuner train --family fotd`` does, with its agent
    (actor and critic) kept: what ``tuner update`` continues from a trained folder."""
    from gaintune.tuners.problems import FamilyProblem
    from gaintune.tuners.train import TrainSettings, train

    return train(FamilyProblem("fotd", "pi", 1.4), tmp / "base", TrainSettings(seed=seed, validation=4), resume=False)


def measure_update(base: str = "fotd_pi_ms1.4", episodes: int = 8192, seed: int = 0,
                   with_agent: bool = True, curve_every: int = CURVE_EVERY) -> dict[str, Any]:
    """Train cold and warm on :func:`changed_spec`; the simulations each needed to reach :data:`TARGET`.

    Two warm runs: from ``base`` (a shipped tuner: its actor and, when the folder has ``critic.npz``, its
    critic; else a fresh critic) and, with ``with_agent``, from a folder trained here with its agent kept.
    ``curve_every``: episodes between the curves' points (:attr:`TrainSettings.curve_every`; both runs train
    in chunks of :data:`CHUNK` whatever it is). A run is counted at the first point that reaches the target, so
    the figure is read to within ``curve_every`` episodes: both runs cross inside their first few chunks.
    """
    from gaintune.tuners import artefact
    from gaintune.tuners.problems import SpecProblem
    from gaintune.tuners.train import TrainSettings, train

    common: dict[str, Any] = {"episodes": episodes, "seed": seed, "chunk": CHUNK, "curve_every": curve_every,
                              "validation": 8, "curve_contexts": 8}
    out: dict[str, Any] = {"base": base, "lag": LAG, "target": TARGET, "episodes": episodes, "seed": seed,
                           "curve_every": curve_every, "chunk": CHUNK}
    out["base_has_critic"] = artefact.critic_sha256(artefact.resolve(base)) is not None
    with tempfile.TemporaryDirectory() as tmp:
        starts: dict[str, Path | None] = {"cold": None, "update": artefact.resolve(base)}
        if with_agent:
            t0 = time.perf_counter()
            starts["update_with_agent"] = _base_with_agent(Path(tmp), seed)
            out["base_training_s"] = time.perf_counter() - t0
        for run, start in starts.items():
            t0 = time.perf_counter()
            folder = train(SpecProblem(changed_spec()), Path(tmp) / run, TrainSettings(**common), warm_start=start,
                           resume=False)
            doc = artefact.load(folder)
            curve = doc.training["curve"]
            out[run] = {"sims_to_target": sims_to(curve), "wall_s": time.perf_counter() - t0, "curve": curve,
                        "validation_median": doc.validation["median_ratio"],
                        "validation_worst": doc.validation["worst_ratio"]}
    c = out["cold"]["sims_to_target"]
    for run in [r for r in ("update", "update_with_agent") if r in out]:
        u = out[run]["sims_to_target"]
        out[f"ratio_{run}"] = c / u if c and u else (math.inf if c and u == 0 else None)
    out["ratio"] = out["ratio_update"]
    return out


def training_figures(name: str) -> dict[str, Any]:
    """The training record of a tuner folder or shipped tuner: wall time, episodes, simulations, validation."""
    from gaintune.tuners import artefact

    folder = artefact.resolve(name)
    art = artefact.load(folder)
    t, v = art.training, art.validation
    size = sum(p.stat().st_size for p in folder.iterdir() if p.is_file())
    return {"tuner": name, "algo": t.get("algo"), "episodes": t.get("episodes"), "sims": t.get("sims"),
            "wall_s": t.get("wall_s"), "resumed": t.get("resumed"), "validation_n": v.get("n"),
            "validation_median": v.get("median_ratio"), "validation_worst": v.get("worst_ratio"),
            "validation_passed": v.get("passed"), "size_kb": round(size / 1024, 1),
            "versions": art.meta.get("versions", {})}


def render_update(r: dict[str, Any], command: str) -> str:
    """The update measurement as Markdown."""
    from gaintune.bench.compare import md_table

    runs = [run for run in ("cold", "update", "update_with_agent") if run in r]
    rows = []
    for run in runs:
        x = r[run]
        rows.append([run, x["sims_to_target"] if x["sims_to_target"] is not None else "not reached",
                     f"{x['wall_s']:.0f}", f"{x['validation_median']:.4f}", f"{x['validation_worst']:.4f}"])
    shipped = "actor and critic arrays" if r.get("base_has_critic") else "actor only, a fresh critic"
    agent = (f" and from a folder trained here with its agent (actor and critic; its training took "
             f"{r['base_training_s']:.0f} s)" if "update_with_agent" in r else "")
    lines = [f"# {command}", "",
             f"Changed family: FOTD with a sensor lag {r['lag']} (L+T) added, PI, load step, Ms <= 1.4; cold start vs "
             f"`tuner update` from the shipped `{r['base']}` ({shipped}){agent}, {r['episodes']:,} "
             f"episodes each, seed {r['seed']}, " + _resolution(r)
             + (f" Load average: {r['loadavg']}." if r.get("loadavg") else ""), "",
             md_table(["run", f"training sims to median ratio <= {r['target']}", "wall s", "validation median",
                       "validation worst"], rows), ""]
    for run in runs[1:]:
        ratio = r[f"ratio_{run}"]
        lines.append(f"cold / {run} simulations: **{ratio:.1f}x**" if isinstance(ratio, float)
                     and math.isfinite(ratio) else f"cold / {run} simulations: {ratio}")
    lines += ["", "Curves (episodes, sims, median ratio):", ""]
    for run in runs:
        pts = ", ".join(f"({p['episodes']}, {p['sims']}, {p['median_ratio']:.4f})" for p in r[run]["curve"])
        lines.append(f"- {run}: {pts}")
    w = r.get("warm_start")
    if w:
        rows = [[run, w[run]["sims_to_target"] if w[run]["sims_to_target"] is not None else "not reached",
                 f"{w[run]['rl_ratio']:.4f}", f"{w[run]['final_ratio']:.4f}", f"{w[run]['wall_s']:.0f}"]
                for run in ("cold", "warm_start")]
        lines += ["", f"`tune --warm-start` on one changed plant (tau = {w['tau']}), budget {w['budget']}, seed "
                  f"{w['seed']}; the agent from `tune` on the plant without the lag:", "",
                  md_table(["search", f"sims to {w['target']} x optimum", "RL alone / optimum", "answer / optimum",
                            "wall s"], rows), "",
                  f"cold / warm-start simulations: {w['ratio']:.1f}x" if w["ratio"] else
                  "cold / warm-start simulations: not comparable (a run did not reach the target)"]
    return "\n".join(lines) + "\n"


def _resolution(r: dict[str, Any]) -> str:
    """The curve's resolution and the training chunk, as the result records them (older results: chunk = curve)."""
    every = r.get("curve_every", 256)
    chunk = r.get("chunk", every)
    if chunk == every:
        return f"a curve point every {every} episodes (the training chunk)."
    return f"a curve point every {every} episodes, training chunks of {chunk} episodes."


def _sims_to_curve(curve: list[Any], target_cost: float) -> int | None:
    """Simulations at the first point of a search curve whose feasible best cost is within ``target_cost``."""
    for p in curve:
        if p.feasible and p.best_cost <= target_cost:
            return int(p.sims)
    return None


def measure_warm_start(tau: float = 0.3, budget: int = 3000, seed: int = 0) -> dict[str, Any]:
    """``tune --warm-start`` against a cold ``tune`` on one changed plant: simulations to :data:`TARGET` x optimum.

    The agent is trained by ``tune`` on the FOTD unit plant with this ``tau``; the changed plant is the
    same with the sensor lag (:func:`changed_spec` at ``tau``). Both searches on it have the same spec,
    budget and seed; the optimum is the changed plant's MIGO point (exact limit, as both specs aim).
    """
    from gaintune.baselines.migo_reference import migo_reference
    from gaintune.evaluation.evaluator import Evaluator
    from gaintune.search.tuning import tune
    from gaintune.tuners.families import FAMILIES, problem_spec
    from gaintune.tuners.problems import SpecProblem

    fam = FAMILIES["fotd"]
    search = {"budget": budget, "seed": seed}
    original = problem_spec(fam, fam.unit_params({"tau": tau})).model_copy(deep=True)
    original = original.model_copy(update={"search": original.search.model_copy(update=search)})
    changed = SpecProblem(changed_spec()).spec_at({"tau": tau})
    changed = changed.model_copy(update={"search": changed.search.model_copy(update=search)})
    ref = migo_reference(None, Evaluator(changed))
    assert ref is not None
    target = TARGET * float(ref["cost"])
    out: dict[str, Any] = {"tau": tau, "budget": budget, "seed": seed, "optimum": ref["cost"], "target": TARGET}
    with tempfile.TemporaryDirectory() as tmp:
        tune(original, out_dir=tmp, verify=False)
        for run, warm in (("cold", None), ("warm_start", Path(tmp) / "agent.zip")):
            t0 = time.perf_counter()
            r = tune(changed, verify=False, warm_start=warm)
            out[run] = {"sims_to_target": _sims_to_curve(r.curve, target), "final_ratio": r.cost / ref["cost"],
                        "rl_ratio": (r.rl_cost or math.inf) / ref["cost"], "wall_s": time.perf_counter() - t0}
    c, w = out["cold"]["sims_to_target"], out["warm_start"]["sims_to_target"]
    out["ratio"] = c / w if c and w else None
    return out


def main_update(args: Any, base: str, out: Path, command: str) -> int:
    """``gaintune bench tuners --update``: the learning-on figure alone (two trainings)."""
    from gaintune.bench.arguments import load_now, load_span
    from gaintune.bench.compare import publish

    load0 = load_now()
    r = measure_update(base, args.update_episodes, with_agent=not args.shipped_only,
                       curve_every=args.update_curve_every)
    if not args.shipped_only:
        r["warm_start"] = measure_warm_start()
    r["command"] = command
    r["loadavg"] = load_span(load0)
    # a --shipped-only run measures less: it must not overwrite the full run's results
    return publish(r, out, "tuners_update_shipped" if args.shipped_only else "tuners_update",
                   render_update(r, command))
