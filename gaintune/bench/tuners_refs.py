"""The held-out plants of ``gaintune bench tuners``, their reference optima and the classical rules on them.

* :func:`held_out_plants`: FOTD plants ``K e^{-Ls}/(Ts+1)`` drawn with the held-out seed
  (:data:`HELD_OUT_SEED`; no tuner may be trained on plants drawn with it): L/T log-uniform over
  0.05..10, T log-uniform over 1..100 s, K log-uniform over 0.5..5.
* :func:`reference_for_plant`: the per-plant constrained optimum, on the exact limit. PI: the MIGO
  boundary optimum (:func:`gaintune.bench.standard.migo_reference`: max ki subject to Ms <= limit,
  then the load IAE along the boundary, on the loop verification analyses). PID (no MIGO): the
  multistart reference search (2 x 3,000 simulations, seed 0) or the best rule, whichever is better,
  the verdict first. Cached in ``<out>/reference_tuners.json`` keyed by :func:`reference_key` and
  re-scored on load, as :mod:`gaintune.bench.references` does, so a changed cost invalidates the entry.
* :func:`rule_gains`, :func:`judge`: AMIGO and SIMC on the plant's exact FOTD model, and any gains'
  plain cost (the bench's own :class:`~gaintune.evaluation.evaluator.Evaluator`) and verdict.
"""

from __future__ import annotations

import hashlib
import json
import math
import time
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from gaintune.bench.compare import ratio
from gaintune.bench.references import RESCORE_RTOL, read_cache
from gaintune.files import write_atomic

__all__ = [
    "HELD_OUT_SEED",
    "RANGES",
    "RULES",
    "CACHE_FILE",
    "Case",
    "held_out_plants",
    "make_case",
    "score",
    "judge",
    "rule_gains",
    "reference_key",
    "reference_for_plant",
]

#: Seed of the held-out plants. Reserved for this benchmark: no tuner is trained on plants drawn with it.
HELD_OUT_SEED = 12345
#: Log-uniform ranges of the held-out plants: L/T, T (s), K.
RANGES: dict[str, tuple[float, float]] = {"L/T": (0.05, 10.0), "T": (1.0, 100.0), "K": (0.5, 5.0)}
#: The classical rules compared, in table order.
RULES = ("amigo", "simc")
#: The reference cache in ``--out``.
CACHE_FILE = "reference_tuners.json"
#: Multistart reference search of a PID plant (no MIGO optimum for PID).
PID_REFERENCE: dict[str, Any] = {"restarts": 2, "sims_per_restart": 3000, "polish": False}


def held_out_plants(n: int, seed: int = HELD_OUT_SEED) -> list[dict[str, float]]:
    """``n`` FOTD plants ``{"K", "T", "L"}``, the same list for the same seed (plant i does not depend on n)."""
    rng = np.random.default_rng(seed)

    def logu(lo: float, hi: float) -> float:
        return float(np.exp(rng.uniform(math.log(lo), math.log(hi))))

    plants = []
    for _ in range(n):
        r, T, K = logu(*RANGES["L/T"]), logu(*RANGES["T"]), logu(*RANGES["K"])
        plants.append({"K": K, "T": T, "L": r * T})
    return plants


@dataclass
class Case:
    """One held-out plant: its parameters, its tuning problem and the bench's exact-limit evaluator."""

    index: int
    values: dict[str, float]
    spec: Any
    ev: Any


def make_case(index: int, values: Mapping[str, float], ctype: str, ms_max: float) -> Case:
    """The plant's problem (:func:`gaintune.tuners.families.problem_spec`) and its exact-limit evaluator."""
    from gaintune.evaluation.search_box import make_evaluator
    from gaintune.tuners.families import family, problem_spec

    spec = problem_spec(family("fotd"), values, ctype, ms_max)
    return Case(index, dict(values), spec, make_evaluator(spec, exact=True))


def score(ev: Any, gains: Mapping[str, Mapping[str, float]]) -> float:
    """The plain cost of ``gains`` (one simulation; not counted in ``ev.n_sims``)."""
    layout = ev.layout
    tuned = np.asarray(layout.from_dict(gains))[layout.tuned_idx]
    n0 = ev.n_sims
    cost = float(ev.evaluate(tuned[None, :]).cost[0])
    ev.n_sims = n0
    return cost


def judge(case: Case, gains: Mapping[str, Mapping[str, float]] | None, ref_cost: float | None) -> dict[str, Any]:
    """``{"gains", "cost", "ratio", "verdict", "ms"}`` of ``gains`` on the case, scored and verified here."""
    from gaintune.verification import verify

    if gains is None:
        return {"gains": None, "cost": None, "ratio": None, "verdict": "n/a", "ms": None}
    out: dict[str, Any] = {"gains": {k: dict(v) for k, v in gains.items()}}
    try:
        out["cost"] = score(case.ev, gains)
        report = verify(case.spec, gains)
        out["verdict"] = report.verdict
        out["ms"] = max((f.ms for f in report.loops), default=None)
    except Exception as exc:  # gains the layout or verification refuses are a fail, shown with the reason
        out.update(cost=None, verdict="fail", ms=None, error=f"{type(exc).__name__}: {exc}")
    out["ratio"] = ratio(out["cost"], ref_cost)
    return out


def rule_gains(rule: str, case: Case) -> tuple[dict[str, dict[str, float]] | None, str | None]:
    """``(gains, None)`` of AMIGO or SIMC on the plant's exact FOTD model, or ``(None, reason)``."""
    from gaintune.classical import rules
    from gaintune.classical.fotd import Fotd, NoModelError

    v, loop = case.values, case.spec.loops[0]
    try:
        pid = getattr(rules, rule)(Fotd(K=v["K"], T=v["T"], L=v["L"]), loop.type)
        return {loop.name: rules.to_loop_gains(pid, loop)}, None
    except NoModelError as exc:
        return None, str(exc)


# ------------------------------------------------------------ reference and its cache


def reference_key(case: Case) -> str:
    """Hash of what the reference depends on: the problem (not its name), the search box, the method."""
    d = case.spec.model_dump(mode="json", exclude_defaults=True)
    d.pop("name", None)
    d["_requirements"] = case.spec.requirements.model_dump(mode="json")
    d["_box"] = [[float(f"{lo:.9g}"), float(f"{hi:.9g}")] for lo, hi in (s.bounds for s in case.ev.layout.tuned_slots)]
    d["_method"] = "migo" if case.spec.loops[0].type == "pi" else {"search": PID_REFERENCE, "rules": list(RULES)}
    return hashlib.sha256(json.dumps(d, sort_keys=True).encode()).hexdigest()[:16]


def _write_cache(path: Path, key: str, entry: dict[str, Any]) -> None:
    data = read_cache(path)
    data[key] = entry
    write_atomic(path, json.dumps(data, indent=1, sort_keys=True) + "\n")  # a reader never sees half a file


def _still_valid(case: Case, entry: Mapping[str, Any]) -> bool:
    """The cached gains still score the cached cost (the cost function or the plant may have changed)."""
    gains, cost = entry.get("gains"), entry.get("cost")
    if not isinstance(gains, dict) or not isinstance(cost, (int, float)):
        return False
    try:
        now = score(case.ev, gains)
    except Exception:  # gains no longer fit the layout
        return False
    return math.isfinite(now) and abs(now - cost) <= RESCORE_RTOL * max(abs(cost), 1e-300)


def _compute(case: Case, rules: Mapping[str, Mapping[str, Any]]) -> dict[str, Any]:
    """The reference entry of ``case`` (``rules``: the judged rule answers, candidates for PID)."""
    from gaintune.baselines import run_baseline
    from gaintune.bench.standard import migo_reference

    t0 = time.perf_counter()
    cands: list[tuple[str, dict[str, Any], int]] = []  # (source, judged answer, simulations)
    if case.spec.loops[0].type == "pi":
        m = migo_reference(None, case.ev)  # uses only the evaluator (its spec, plant and layout)
        if m is not None:
            cands.append(("migo", judge(case, m["gains"], None), 0))
    else:
        r = run_baseline(case.spec, "reference", seed=0, evaluator=case.ev, **PID_REFERENCE)
        cands.append(("search", judge(case, r.gains, None), int(r.n_sims)))
        cands += [(name, dict(a), 0) for name, a in rules.items() if a.get("cost") is not None]
    cands = [c for c in cands if c[1].get("cost") is not None and math.isfinite(c[1]["cost"])]
    if not cands:
        return {"cost": None, "gains": None, "passes": False, "source": "none", "n_sims": 0,
                "wall_time": time.perf_counter() - t0}
    src, best, _ = min(cands, key=lambda c: (c[1]["verdict"] != "pass", c[1]["cost"]))  # verdict first
    return {"cost": best["cost"], "gains": best["gains"], "passes": best["verdict"] == "pass", "ms": best["ms"],
            "source": src, "n_sims": sum(c[2] for c in cands),
            "wall_time": time.perf_counter() - t0}


def reference_for_plant(case: Case, rules: Mapping[str, Mapping[str, Any]], out_dir: Path,
                        log: Callable[[str], None] | None = None) -> dict[str, Any]:
    """The case's reference, from ``<out_dir>/reference_tuners.json`` when it still scores, else computed.

    Returns the cache entry plus ``"cached"`` (True when read from the cache) and ``"key"``.
    """
    path = Path(out_dir) / CACHE_FILE
    key = reference_key(case)
    entry = read_cache(path).get(key)
    if isinstance(entry, dict) and _still_valid(case, entry):
        return {**entry, "key": key, "cached": True}
    if entry is not None and log:
        log(f"cached reference of plant {case.index} no longer scores {entry.get('cost')}: recomputing")
    entry = {"plant": case.values, "ctype": case.spec.loops[0].type, "ms_max": case.spec.requirements.ms_max,
             **_compute(case, rules)}
    _write_cache(path, key, entry)
    return {**entry, "key": key, "cached": False}
