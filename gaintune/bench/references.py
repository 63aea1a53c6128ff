"""Reference optima of the benchmark problems, and their on-disk cache.

Every benchmark result is scored against a reference optimum of its problem:
the best of a multistart search (``run_baseline(spec, "reference")``) and,
when known, the exact optimum (:func:`exact_optimum`: the discrete Riccati
gain of the LQ problems, the MIGO boundary optimum of the ``standard`` suite).
References are expensive, so :func:`reference_for` caches them in
``<out>/reference_<suite>.json`` keyed by :func:`reference_key` (a hash of
everything the optimum depends on) and re-scores a cached entry before using it.

The problems themselves are defined in :mod:`gaintune.bench.suite`.
"""

from __future__ import annotations

import hashlib
import json
import math
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

from gaintune.bench.suite import BenchCase
from gaintune.spec import Gains, TuningSpec

__all__ = [
    "RESCORE_RTOL",
    "reference_key",
    "exact_optimum",
    "reference_for",
    "compute_reference",
    "default_out_dir",
    "reference_summary",
    "read_cache",
]


def reference_key(problem: BenchCase) -> str:
    """Hash of everything the reference optimum depends on.

    The spec's non-default fields (so that schema additions and default-preserving
    refactors keep the key) without its name, description, search budget/seed/agent
    settings and verification settings (none of which change the constrained
    problem), with its requirements (they are constraints), plus the search box (which a rule change may move), the
    reference options and exactness. :func:`reference_for` also re-scores a cached
    answer, so a changed cost function is caught even when the key is unchanged.
    """
    spec = problem.tuning_spec()
    d = spec.model_dump(mode="json", exclude_defaults=True)
    for k in ("name", "description", "verify", "search"):
        d.pop(k, None)
    d["_requirements"] = spec.requirements.model_dump(mode="json")
    d["_robust"] = spec.search.robust.model_dump(mode="json")
    d["_box"] = _search_box(spec)
    d["_reference"] = {"options": problem.reference, "exact": problem.exact}
    return hashlib.sha256(json.dumps(d, sort_keys=True).encode()).hexdigest()[:16]


def _search_box(spec: TuningSpec) -> list[list[float]]:
    """Log-scale bounds of the tuned gains as the searches see them (rounded for a stable hash)."""
    import warnings

    from gaintune.evaluation.search_box import search_layout
    from gaintune.plants import build_plant

    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # FOTD fits of stiff paths warn about conditioning
        layout = search_layout(spec, build_plant(spec.plant))
    return [[float(f"{lo:.9g}"), float(f"{hi:.9g}")] for lo, hi in (s.bounds for s in layout.tuned_slots)]


def exact_optimum(problem: BenchCase, evaluator: Any) -> dict[str, Any] | None:
    """Known exact optimum of ``problem`` as ``{"gains", "cost", "method"}``, or None.

    ``dlqr``: the discrete Riccati gain for Q = C'C dt, R = effort_weight dt on
    the exact ZOH model of the plant at the scenario's dt; the simulated cost of
    ``u = -K x`` after an input impulse is x1' P_K x1 (x1 = Bd/dt), which that
    gain minimises over all K for every x1 (up to the horizon truncation).
    """
    if problem.exact == "migo":
        from gaintune.bench.standard import migo_reference

        return migo_reference(problem, evaluator)
    if problem.exact != "dlqr":
        return None
    from scipy.linalg import expm, solve_discrete_are

    spec = problem.tuning_spec()
    loop = spec.loops[-1]
    dt = spec.scenarios[0].dt
    assert dt is not None  # the dlqr problems give their scenario's dt
    lin = evaluator.plant.linearize()
    n = lin.A.shape[0]
    m = lin.output_index(loop.measure) if loop.measure else 0
    M = np.zeros((n + 1, n + 1))
    M[:n, :n] = lin.A * dt
    M[:n, n:] = lin.B * dt
    E = expm(M)
    Ad, Bd = E[:n, :n], E[:n, n:]
    C = lin.C[m : m + 1]
    w = spec.objective.effort_weight
    Q = C.T @ C * dt
    R = np.array([[w * dt]])
    P = solve_discrete_are(Ad, Bd, Q, R)
    K = np.linalg.solve(R + Bd.T @ P @ Bd, Bd.T @ P @ Ad).ravel()
    gains = {loop.name: {f"k_{s}": float(k) for s, k in zip(lin.states, K, strict=True)}}
    layout = evaluator.layout
    tuned = np.asarray(layout.from_dict(gains))[layout.tuned_idx]
    scores = evaluator.evaluate(tuned[None, :])
    cost = float(scores.cost[0])
    x1 = Bd[:, 0] / dt
    return {
        "gains": gains,
        "cost": cost if math.isfinite(cost) else None,
        "feasible": bool(scores.feasible[0]),
        "riccati_cost": float(x1 @ P @ x1),
        "method": "dlqr (discrete Riccati on the exact ZOH model)",
    }


# ------------------------------------------------------------ reference cache


def default_out_dir() -> Path:
    """``bench/results`` relative to the working directory (every benchmark's ``--out`` default)."""
    return Path("bench") / "results"


def read_cache(path: Path) -> dict[str, Any]:
    """A JSON cache of reference entries by key; empty when the file is missing or unreadable."""
    try:
        data = json.loads(path.read_text())
    except (OSError, ValueError):
        return {}
    return data if isinstance(data, dict) else {}


def reference_for(
    problem: BenchCase, suite: str, out_dir: str | Path | None = None, *, refresh: bool = False,
    evaluator: Any = None, log: Callable[[str], None] | None = None,
) -> dict[str, Any]:
    """Reference optimum of ``problem``, from ``reference_<suite>.json`` in ``out_dir`` or computed and cached.

    The entry is keyed by :func:`reference_key`; any ``reference_*.json`` in the
    folder is searched, so suites sharing a problem share its reference. Returns
    ``{"problem", "key", "cost", "gains", "source", "n_sims", "wall_time", "search": {...}, "exact": {...}|None}``:
    ``cost`` is the best of the multistart search (``run_baseline(spec, "reference")``)
    and, when known, the exact optimum.
    """
    out = Path(out_dir) if out_dir is not None else default_out_dir()
    key = reference_key(problem)
    path = out / f"reference_{suite}.json"
    if not refresh:
        files = [path] + sorted(p for p in out.glob("reference_*.json") if p != path)
        for f in files:
            entry = read_cache(f).get(key)
            if entry is not None and _still_valid(problem, entry, evaluator):
                if f != path:
                    _write_entry(path, key, entry)
                return entry
            if entry is not None and log:
                log(f"cached reference of {problem.name} no longer scores {entry.get('cost')}: recomputing")
    entry = compute_reference(problem, evaluator=evaluator, log=log)
    entry["key"] = key
    _write_entry(path, key, entry)
    return entry


#: Relative difference between a cached reference cost and its re-scored gains that invalidates the entry.
RESCORE_RTOL = 1e-6


def _still_valid(problem: BenchCase, entry: dict[str, Any], evaluator=None) -> bool:
    """Re-score the cached reference gains (one simulation): the cost function may have changed."""
    gains, cost = entry.get("gains"), entry.get("cost")
    if gains is None or cost is None:
        return True  # nothing to check (no finite reference was found)
    try:
        if evaluator is None:
            from gaintune.envs.problem import GainProblem

            evaluator = GainProblem(problem.tuning_spec()).evaluator
        layout = evaluator.layout
        tuned = np.asarray(layout.from_dict(gains))[layout.tuned_idx]
        n0 = getattr(evaluator, "n_sims", 0)
        now = float(evaluator.evaluate(tuned[None, :]).cost[0])
        if hasattr(evaluator, "n_sims"):
            evaluator.n_sims = n0
    except Exception:  # gains no longer fit the layout, etc.
        return False
    return math.isfinite(now) and abs(now - cost) <= RESCORE_RTOL * max(abs(cost), 1e-300)


def _write_entry(path: Path, key: str, entry: dict[str, Any]) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    data = read_cache(path)
    # one entry per problem and suite file: an older key of the same problem is stale
    data = {k: v for k, v in data.items()
            if k == key or not isinstance(v, dict) or v.get("problem") != entry.get("problem")}
    data[key] = entry
    tmp = path.with_suffix(".json.tmp")
    tmp.write_text(json.dumps(data, indent=1, sort_keys=True) + "\n")
    tmp.replace(path)


def _passes(spec: TuningSpec, gains: Gains | None) -> bool:
    """The reference is judged by the verdict itself, not by the search's estimate."""
    if gains is None:
        return False
    from gaintune.verification import verify

    try:
        return verify(spec, gains).verdict == "pass"
    except Exception:  # gains verification rejects outright (e.g. out of range) never pass
        return False


def compute_reference(
    problem: BenchCase, *, evaluator: Any = None, log: Callable[[str], None] | None = None
) -> dict[str, Any]:
    """Run the reference optimum (and the exact optimum when known) for ``problem``, on the exact limits.

    No ``requirements.backoff``: the searches aim inside the limits, the reference is the exact-limit optimum.
    """
    import time

    from gaintune.baselines import run_baseline
    from gaintune.evaluation.search_box import make_evaluator

    spec = problem.tuning_spec()
    # the exact-limit optimum: the searches aim requirements.backoff inside the limits, the reference does not
    ev = evaluator if evaluator is not None else make_evaluator(spec, exact=True)
    if log:
        log(f"reference optimum of {problem.name} (cached afterwards) ...")
    t0 = time.perf_counter()
    r = run_baseline(spec, "reference", seed=0, evaluator=ev, **problem.reference)
    ex = exact_optimum(problem, ev)
    entry: dict[str, Any] = {
        "problem": problem.name,
        "search": {"cost": r.cost, "feasible": r.feasible, "gains": r.gains, "n_sims": r.n_sims,
                   "wall_time": r.wall_time, "winner": r.details.get("winner"), "options": problem.reference},
        "exact": ex,
    }
    cands = [("search", r.cost, _passes(spec, r.gains), r.gains)]
    if ex is not None:
        cands.append(("exact", ex["cost"], _passes(spec, ex["gains"]), ex["gains"]))
    cands = [c for c in cands if c[1] is not None]
    if cands:  # the verdict first, then the plain cost
        src, cost, passes, gains = min(cands, key=lambda c: (not c[2], c[1]))
    else:
        src, cost, passes, gains = "none", None, False, None
    entry.update(cost=cost, passes=passes, gains=gains, source=src, n_sims=r.n_sims,
                 wall_time=time.perf_counter() - t0)
    return entry


def reference_summary(ref: dict[str, Any], *extra: str) -> dict[str, Any]:
    """The fields of a reference entry stored with a benchmark result (plus ``extra`` ones)."""
    return {k: ref.get(k) for k in ("cost", "source", "key", "n_sims", *extra)}
