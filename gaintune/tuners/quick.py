"""``gaintune tune SPEC --quick``: verified gains for one SISO PI/PID loop without a search.

The pidtune-style path, for the common case:

1. **Model.** Fit the loop's FOTD, SOTD or integrating model (:mod:`gaintune.tuners.quick_model`).
2. **Tuner.** Ask the ready-made tuner of that family, controller type and Ms limit for its
   policy's gains (a NumPy forward pass, scaled to the model's gain and time scale). The tuner's
   own query would settle and verify them on the *model*; here the next steps do that on the
   true plant instead.
3. **Settle and verify on the true plant.** In one batched move, the tuner's gains and the AMIGO
   and SIMC designs are moved onto the true spec's requirement boundary from both sides
   (:func:`gaintune.evaluation.boundary_both.onto_boundary`: a conservative answer outward, an
   infeasible one inward, each along its loop-gain scale); the best of them, feasibility first,
   is settled with the exact verification as every search's last step
   (:func:`gaintune.evaluation.boundary_exact.onto_boundary_exact`) and verified
   (:func:`gaintune.verification.verify`). The rules are candidates so that the answer never
   loses to a rule moved onto the boundary; :attr:`QuickResult.source` says which one won.
4. **Compare.** AMIGO and SIMC as the rules give them (cost and verdict on the true plant) and,
   with ``compare_search=N``, the RL search at N simulations (:func:`gaintune.search.tuning.tune`).
   The answer's time (``result.wall_time``) ends before this step; ``timing["compare_s"]`` is its time.

The answer is a :class:`~gaintune.search.result.TuneResult` (``algo`` ``"quick"``), so
``gaintune report`` and ``gaintune export`` read it as any tune's; the model, the tuner and the
comparison are in :class:`QuickResult`. As everywhere, only a ``pass`` releases gains.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from gaintune.baselines import optimize, run_baseline
from gaintune.classical import BOUNDS_FACTOR, auto_bounds
from gaintune.classical.fotd import NoModelError
from gaintune.classical.timescale import scenario_defaults
from gaintune.classical.tuning import tune_classical
from gaintune.controllers.layout import GainLayout
from gaintune.errors import SpecError
from gaintune.evaluation.boundary_both import onto_boundary
from gaintune.evaluation.boundary_exact import onto_boundary_exact, violation_after
from gaintune.evaluation.evaluator import Evaluator
from gaintune.plants import build_plant
from gaintune.plants.checks import validate_against_plant
from gaintune.plants.plant import Plant
from gaintune.provenance import versions
from gaintune.search.diagnosis import budget_hints, diagnose
from gaintune.search.result import Provenance, SettleInfo, TuneResult
from gaintune.sim import Simulator
from gaintune.spec import Gains, TuningSpec
from gaintune.tuners.quick_model import SEARCH_HINT, LoopModel, TunerInfo, tuner_start
from gaintune.verification import verify

__all__ = ["QuickResult", "quick_tune", "RULES", "DEFAULT_REFINE"]

#: The classical rules reported beside the answer (and tried as candidates).
RULES = ("amigo", "simc")
#: Simulations of the local refinement after the settling, by default (``--refine``).
DEFAULT_REFINE = 300


@dataclass
class QuickResult:
    """The quick answer (:attr:`result`, a TuneResult), how it was reached and what it compares with.

    Attributes
    ----------
    result
        The verified answer, written and read as any tune's ``result.json``.
    model
        The loop's fitted model (:class:`~gaintune.tuners.quick_model.LoopModel`).
    tuner
        The tuner asked: name, folder, family, controller type, Ms limit (None when no tuner of the
        model's family and controller type exists: the rules are the only candidates then).
    source
        Which candidate won the settling: ``tuner``, ``amigo`` or ``simc`` (moved onto the boundary).
    refined, refine_sims
        Whether the refinement (``refine``) improved the answer, and the simulations it spent.
    tuner_cost
        Cost of the tuner's own candidate after the move onto the boundary (None when infeasible).
    comparison
        One row per method: ``method``, ``gains``, ``cost``, ``verdict``, ``ratio`` (cost / the answer's).
    notes
        What the user should know (a shape outside the tuner's range, a requirement the tuner was not
        trained for).
    timing
        Wall time of each step (s): ``model_and_tuner_s``, ``settle_and_verify_s`` (together the answer's
        time, ``result.wall_time``) and ``compare_s`` (the rules' verdicts and the comparison search).
    """

    result: TuneResult
    model: LoopModel
    tuner: TunerInfo | None
    source: str
    tuner_cost: float | None
    refined: bool = False
    refine_sims: int = 0
    comparison: list[dict[str, Any]] = field(default_factory=list)
    notes: list[str] = field(default_factory=list)
    timing: dict[str, float] = field(default_factory=dict)

    @property
    def verdict(self) -> str | None:
        return self.result.verdict

    def as_dict(self) -> dict[str, Any]:
        """JSON-ready summary (``quick.json`` of ``--out``): everything but the full result."""
        t = self.tuner
        return {"model": self.model.as_dict(),
                "tuner": None if t is None else {"name": t.name, "folder": str(t.folder), "family": t.family,
                                                 "ctype": t.ctype, "ms_max": t.ms_max},
                "source": self.source, "refined": self.refined, "refine_sims": self.refine_sims,
                "tuner_cost": self.tuner_cost, "gains": self.result.gains,
                "cost": self.result.cost, "verdict": self.verdict, "accepted_gains": self.result.accepted_gains,
                "comparison": self.comparison, "notes": self.notes, "timing": self.timing,
                "wall_time": self.result.wall_time}


# ------------------------------------------------------------------ checks


def _check_loop(spec: TuningSpec) -> None:
    """One SISO PI/PID loop, else a SpecError naming ``loops`` and the search to run."""
    if len(spec.loops) != 1:
        raise SpecError("loops", f"--quick tunes a single PI or PID loop; this spec has {len(spec.loops)} loops "
                        f"(cascades and multi-loop designs need the search): {SEARCH_HINT}")
    loop = spec.loops[0]
    if loop.type not in ("pi", "pid"):
        raise SpecError("loops[0].type", f"--quick has ready-made tuners for PI and PID loops, not {loop.type!r}; "
                        f"{SEARCH_HINT}")


# ------------------------------------------------------------------ steps


def _rule_gains(spec: TuningSpec, plant: Plant) -> dict[str, Gains]:
    """The gains of every rule of :data:`RULES` that applies to the loop."""
    out = {}
    for method in RULES:
        try:
            out[method] = tune_classical(spec, plant, method).gains
        except (NoModelError, ValueError):
            continue
    return out


def _box_start(spec: TuningSpec, plant: Plant) -> Gains:
    """The start of the default search box (:func:`gaintune.evaluation.search_box.search_box`): a classical
    rule detuned until feasible where one applies, else the box's geometric middle."""
    from gaintune.evaluation.search_box import search_box

    sb = search_box(spec, plant)
    if sb.centre is not None:
        return sb.centre
    lay = sb.layout
    return lay.to_dict(lay.full(np.exp(0.5 * (lay.log_lo + lay.log_hi))))


def _evaluator(spec: TuningSpec, plant: Plant, starts: list[Gains]) -> Evaluator:
    """The true spec's evaluator; where the spec gives no bounds, its box spans every start gain set by
    ``BOUNDS_FACTOR`` each way (as a search's box spans its start)."""
    box: dict[tuple[str, str], tuple[float, float]] = {}
    for g in starts:
        for k, (lo, hi) in auto_bounds(spec, g, BOUNDS_FACTOR).items():
            lo0, hi0 = box.get(k, (lo, hi))
            box[k] = (min(lo, lo0), max(hi, hi0))
    layout = GainLayout(spec, plant.states, auto_bounds=box, plant=plant)
    layout.require_tuned()
    return Evaluator(spec, Simulator(spec, plant, layout))


def _tuned(ev: Evaluator, gains: Gains) -> np.ndarray:
    """The tuned magnitudes of ``gains``, inside the evaluator's box."""
    lay = ev.layout
    t = np.abs(np.asarray(lay.from_dict(gains), dtype=float)[lay.tuned_idx])
    return np.exp(np.clip(np.log(t), lay.log_lo, lay.log_hi))


def _rule_rows(spec: TuningSpec, ev: Evaluator) -> dict[str, dict[str, Any]]:
    """AMIGO and SIMC as the rules give them: gains, cost on the true plant and verdict (None: no gains)."""
    rows = {}
    for method in RULES:
        r = run_baseline(spec, method, evaluator=ev)
        row = r.model_dump(mode="json")
        if r.gains is not None:
            row["details"]["verdict"] = verify(spec, r.gains, plant=ev.plant, layout=ev.layout, cache=False).verdict
        rows[method] = row
    return rows


@dataclass
class _Settled:
    """The outcome of :func:`_settle`."""

    source: str
    tuned: np.ndarray
    exact: Any
    costs: dict[str, float | None]
    refined: bool = False
    refine_sims: int = 0


def _settle(ev: Evaluator, cands: dict[str, np.ndarray], refine: int, seed: int) -> _Settled:
    """Move every candidate onto the boundary from both sides, keep the best, refine it, settle it exactly.

    ``costs`` are each candidate's costs after the move (None when it stays infeasible); ``refined``
    says whether the refinement improved the winner.
    """
    names = list(cands)
    move = onto_boundary(ev, np.vstack([cands[n] for n in names]))
    k = int(np.argmin(move.scores.merit))
    costs = {n: (float(move.scores.cost[i]) if move.scores.feasible[i] else None) for i, n in enumerate(names)}
    source, tuned = names[k], move.tuned[k]
    merit, cost, feasible = float(move.scores.merit[k]), float(move.scores.cost[k]), bool(move.scores.feasible[k])
    n0, refined = ev.n_sims, False
    if refine > 0:
        # as a tuner's query --refine: CMA-ES from the answer, a few simulations kept for the boundary move
        res = optimize(ev, "cmaes", max(refine - 3, 1), seed=seed, x0=tuned, sigma0=0.05)
        again = onto_boundary(ev, np.asarray(res.tuned, dtype=float)[None, :])
        if float(again.scores.merit[0]) < merit:
            refined, tuned = True, again.tuned[0]
            cost, feasible = float(again.scores.cost[0]), bool(again.scores.feasible[0])
    spent = ev.n_sims - n0
    settled = onto_boundary_exact(ev, tuned, cost=cost if feasible else None)
    if settled.action in ("pulled_inside", "pushed_to_boundary"):
        tuned = settled.tuned
    return _Settled(source, tuned, settled, costs, refined, spent)


def _compare_search(spec: TuningSpec, budget: int) -> dict[str, Any]:
    """The RL search at ``budget`` simulations, as a comparison row (its cost and verdict)."""
    from gaintune.search.tuning import tune

    s = spec.search.model_copy(update={"budget": int(budget)})
    res = tune(spec.model_copy(update={"search": s}), verify=True)
    return {"method": "search", "gains": res.gains, "cost": res.cost, "feasible": res.violation <= 0,
            "n_sims": res.sims, "wall_time": res.wall_time,
            "reason": f"{spec.search.algo}, budget {budget}",
            "details": {"verdict": res.verdict, "algo": res.algo}}


# ------------------------------------------------------------------ entry


def quick_tune(spec: TuningSpec, *, tuners_dir: str | Path | None = None, refine: int = DEFAULT_REFINE,
               compare_search: int = 0, command: str = "") -> QuickResult:
    """Verified gains for ``spec``'s single SISO PI/PID loop from a ready-made tuner (module docstring).

    Parameters
    ----------
    spec
        A spec with one PI or PID loop on a SISO path with a FOTD, SOTD or integrating model.
    tuners_dir
        A folder of tuner folders to choose from (default: the tuners shipped with gaintune).
    refine
        When > 0, continue from the best candidate with CMA-ES for at most this many simulations
        (as ``gaintune tuner query --refine``), kept only when it ranks better; 0: the settled
        candidate as it is.
    compare_search
        When > 0, also run the RL search with this budget and show its answer in the comparison.
    command
        The command line, for the result's provenance.

    Raises
    ------
    SpecError
        Naming ``loops`` for more than one loop (or a P/PD/LQ loop), ``plant`` when no model applies
        (unstable, oscillatory), ``loops[0].type`` when no tuner fits; each says to run the search.
    """
    t0 = time.perf_counter()
    _check_loop(spec)
    plant = build_plant(spec.plant)
    validate_against_plant(spec, plant)
    spec, defaults = scenario_defaults(spec, plant)
    start = tuner_start(spec, plant, tuners_dir)
    timing = {"model_and_tuner_s": time.perf_counter() - t0}
    rule_gains = _rule_gains(spec, plant) if start.model.fotd is not None else {}
    starts = ({"tuner": start.gains} if start.gains is not None else {}) | rule_gains
    if start.model.fotd is None:
        starts["search box"] = _box_start(spec, plant)
    if not starts:
        raise SpecError("loops[0].type", f"no ready-made tuner fits this {start.model.family.upper()} "
                        f"{spec.loops[0].type.upper()} loop and neither AMIGO nor SIMC applies; {SEARCH_HINT}")
    ev = _evaluator(spec, plant, list(starts.values()))
    cands = {name: _tuned(ev, g) for name, g in starts.items()}
    policy_cost = float(ev.evaluate(cands["tuner"][None]).cost[0]) if "tuner" in cands else None
    st = _settle(ev, cands, refine, spec.search.seed)
    result = _result(spec, defaults, ev, st, start.gains, policy_cost, command)
    result.verification = verify(spec, result.gains, plant=plant, layout=ev.layout)
    _diagnose(result, ev, st.tuned, plant)
    result.wall_time = time.perf_counter() - t0  # the answer's time; the comparison below is not part of it
    timing["settle_and_verify_s"] = result.wall_time - timing["model_and_tuner_s"]
    result.baselines = list(_rule_rows(spec, ev).values())
    if compare_search > 0:
        result.baselines.append(_compare_search(spec, compare_search))
    timing["compare_s"] = time.perf_counter() - t0 - result.wall_time
    q = QuickResult(result, start.model, start.tuner, st.source, st.costs.get("tuner"), refined=st.refined,
                    refine_sims=st.refine_sims, notes=start.notes, timing=timing)
    q.comparison = comparison_rows(result)
    return q


def _result(spec: TuningSpec, defaults: list, ev: Evaluator, st: _Settled, start: Gains | None,
            policy_cost: float | None, command: str) -> TuneResult:
    """The unverified TuneResult of the quick answer."""
    lay, settled, tuner_cost = ev.layout, st.exact, st.costs.get("tuner")
    final = ev.evaluate(st.tuned[None])
    metrics = {r.scenario: {k: (float(v[0]) if np.isfinite(v[0]) else None) for k, v in r.metrics.items()}
               for r in final.results}
    return TuneResult(
        spec=spec.model_dump(mode="json"), scenario_defaults=defaults, algo="quick",
        gains=lay.to_dict(lay.full(st.tuned)),
        gains_source="refined" if st.refined else ("policy" if st.source == "tuner" else "start"),
        policy_gains=start, cost=float(final.cost[0]), violation=violation_after(settled, final),
        rl_cost=tuner_cost, rl_feasible=tuner_cost is not None, policy_cost=policy_cost,
        settle=SettleInfo(action=settled.action, alpha=settled.alpha, loop=settled.loop, margin=settled.margin,
                          checks=settled.checks),
        metrics=metrics, sims=ev.n_sims, stopped="quick",
        provenance=Provenance(spec_hash=spec.content_hash(), seed=spec.search.seed, versions=versions(),
                              command=command))


def _diagnose(result: TuneResult, ev: Evaluator, tuned: np.ndarray, plant: Plant) -> None:
    """The search's diagnosis without its budget hints (no search ran), and the search as the fix of a fail."""
    diag = diagnose(result, ev.layout, tuned, plant)
    drop = set(budget_hints(result))
    diag.hints = [h for h in diag.hints if h not in drop and "search.budget" not in h]
    if diag.status == "fail":
        diag.hints.insert(0, f"the quick answer does not meet the requirements on this plant; {SEARCH_HINT}")
    result.diagnosis = diag


def comparison_rows(result: TuneResult) -> list[dict[str, Any]]:
    """The answer and every baseline of ``result``: method, gains, cost, verdict and cost / the answer's."""
    rows = [{"method": "quick", "gains": result.gains, "cost": result.cost, "verdict": result.verdict, "ratio": 1.0}]
    for b in result.baselines:
        cost = b.get("cost")
        ratio = cost / result.cost if cost is not None and result.cost and result.cost > 0 else None
        rows.append({"method": b.get("method"), "gains": b.get("gains"), "cost": cost,
                     "verdict": (b.get("details") or {}).get("verdict"), "ratio": ratio,
                     "note": b.get("reason")})
    return rows
