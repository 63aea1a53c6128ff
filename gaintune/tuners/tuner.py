"""A trained tuner answers verified gains for one plant: NumPy forward pass, boundary move, verification.

:meth:`Tuner.query` takes a plant's parameters (``K``, ``T``, ``L`` for a FOTD tuner; the
randomised parameters of a spec tuner) and

1. maps them to the tuner's context (a family tuner reduces them to the dimensionless shape);
   a context outside the training ranges is refused, naming the value and the range;
2. evaluates the policy in NumPy (no torch is imported anywhere on this path);
3. moves the gains onto this plant's requirement boundary, inward or outward, where that lowers
   the cost (:func:`gaintune.evaluation.boundary_both.onto_boundary`);
4. optionally refines them with CMA-ES from there, with at most ``refine`` more simulations;
5. verifies them on this plant (:func:`gaintune.verification.verify`); gains that fail by the exact
   verification although the estimate held are pulled inside by it and verified again (:func:`settle`).
   As everywhere in gaintune, only a ``pass`` releases gains (:attr:`TunerAnswer.accepted_gains`).
"""

from __future__ import annotations

import threading
import time
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from gaintune.evaluation.boundary_both import onto_boundary
from gaintune.evaluation.evaluator import Evaluator
from gaintune.spec import Gains
from gaintune.tuners import artefact
from gaintune.tuners.artefact import Artefact
from gaintune.tuners.problems import FamilyProblem
from gaintune.verification import verify
from gaintune.verification.context import SpecContext
from gaintune.verification.report import VerificationReport

__all__ = ["Tuner", "TunerAnswer", "OutsideFamilyError", "settle", "evaluator_context"]


class OutsideFamilyError(ValueError):
    """The plant lies outside the family the tuner was trained on (a SpecError-like message)."""

    def __init__(self, field_name: str, message: str) -> None:
        super().__init__(f"{field_name}: {message}")
        self.field, self.message = field_name, message


@dataclass
class TunerAnswer:
    """One plant's answer. ``accepted_gains`` is None unless the verdict is ``pass``."""

    params: dict[str, float]
    context: dict[str, float]
    gains: Gains
    verdict: str
    cost: float
    policy_ms: float
    elapsed_ms: float
    n_sims: int
    refined: int = 0
    verification: VerificationReport | None = field(default=None, repr=False)

    @property
    def accepted_gains(self) -> Gains | None:
        return self.gains if self.verdict == "pass" else None

    def as_dict(self) -> dict[str, Any]:
        """JSON-ready: parameters, context, gains, verdict, cost, timings, simulations, and ``failures``: why the
        verdict failed (the verification's reasons, binding requirement first; empty on pass)."""
        v = self.verification
        return {
            "params": self.params, "context": self.context, "gains": self.gains, "verdict": self.verdict,
            "accepted_gains": self.accepted_gains, "cost": self.cost, "policy_ms": self.policy_ms,
            "elapsed_ms": self.elapsed_ms, "n_sims": self.n_sims, "refined_sims": self.refined,
            "failures": list(v.reasons) if v is not None else [],
        }


class Tuner:
    """A loaded tuner (see the module docstring). Thread-safe: a query holds no shared state."""

    def __init__(self, art: Artefact, folder: Path | None = None) -> None:
        self.artefact = art
        self.problem = art.problem
        self.policy = art.policy
        self.folder = folder
        self._lock = threading.Lock()

    @classmethod
    def load(cls, name_or_dir: str | Path) -> Tuner:
        """A tuner folder, or a shipped tuner by name (``gaintune tuner list``)."""
        folder = artefact.resolve(name_or_dir)
        return cls(artefact.load(folder), folder)

    @property
    def name(self) -> str:
        return self.artefact.name

    def context(self, params: Mapping[str, float]) -> dict[str, float]:
        """The context of ``params``; OutsideFamilyError when it lies outside the training ranges."""
        ctx = self.problem.context_of(params)
        for v in self.problem.variables:
            x = ctx[v.name]
            if not v.contains(x):
                raise OutsideFamilyError(f"params.{v.name}", self._outside_text(v.name, x, v.lo, v.hi, params))
        return ctx

    def _outside_text(self, name: str, x: float, lo: float, hi: float, params: Mapping[str, float]) -> str:
        if isinstance(self.problem, FamilyProblem) and name == "tau":
            def ratio(t: float) -> float:
                return t / (1.0 - t) if t < 1 else float("inf")

            lags = sum(float(params[p]) for p in self.problem.family.params[1:] if p != "L")  # L/T from the params
            value = float(params["L"]) / lags if lags > 0 else float("inf")
            lo_r, hi_r = ratio(lo), ratio(hi)
            return (f"L/T = {_apart(value, hi_r if value > hi_r else lo_r)} is outside the family this tuner was "
                    f"trained on (L/T from {lo_r:.3g} to {hi_r:.3g}); use 'gaintune tune' for this plant")
        return (f"{name} = {_apart(x, hi if x > hi else lo)} is outside the family this tuner was trained on "
                f"({lo:g} to {hi:g}); use 'gaintune tune' for this plant, or 'gaintune tuner update' with a wider "
                "range")

    def policy_gains(self, params: Mapping[str, float]) -> tuple[Gains, dict[str, float], float]:
        """The policy's raw gains for ``params`` (before the boundary move), the context, and the forward-pass ms."""
        ctx = self.context(params)
        assert self.problem.box is not None
        t0 = time.perf_counter()
        action = self.policy(self.problem.features(ctx)[None, :])[0]
        ms = 1e3 * (time.perf_counter() - t0)
        unit = self.problem.box.to_gains(self.problem.box.to_tuned(action)[0])
        return self.problem.scale_answer(unit, params), ctx, ms

    def query(self, params: Mapping[str, float], refine: int = 0, seed: int = 0) -> TunerAnswer:
        """Verified gains for the plant at ``params`` (see the module docstring)."""
        t0 = time.perf_counter()
        gains, ctx, policy_ms = self.policy_gains(params)
        ev = Evaluator(self.problem.physical_spec(params))
        lay = ev.layout
        tuned = np.asarray(lay.from_dict(gains), dtype=float)[lay.tuned_idx]
        move = onto_boundary(ev, tuned[None, :])
        tuned, cost = move.tuned[0], float(move.scores.cost[0])
        spent = 0
        if refine > 0:
            tuned, cost, spent = _refine(ev, tuned, float(move.scores.merit[0]), cost, refine, seed)
        tuned, report, settled_cost = settle(ev, tuned)
        cost = cost if settled_cost is None else settled_cost
        gains = lay.to_dict(lay.full(tuned))
        return TunerAnswer(params={k: float(v) for k, v in params.items()}, context=ctx, gains=gains,
                           verdict=report.verdict, cost=cost, policy_ms=policy_ms,
                           elapsed_ms=1e3 * (time.perf_counter() - t0), n_sims=ev.n_sims, refined=spent,
                           verification=report)


def _apart(x: float, bound: float) -> str:
    """``x`` with as many digits as it takes not to read as ``bound`` (L/T = 10.02 was printed as 10, beside
    a range ending at 10)."""
    for digits in range(3, 17):
        text = f"{x:.{digits}g}"
        if text != f"{bound:.{digits}g}":
            return text
    return repr(x)


def evaluator_context(ev: Evaluator) -> SpecContext:
    """The verification context of ``ev``'s (resolved) spec: its plant, layout, linearisation and simulator.

    :func:`verify` then analyses and simulates on the objects the evaluator built (its simulator's
    discretisation and the sampled plant are warm) instead of building them again: the same checks.
    """
    return SpecContext(ev.spec.content_hash(), ev.plant, ev.layout, ev.plant.linearize(), _sim=ev.sim)


def settle(ev: Evaluator, tuned: np.ndarray) -> tuple[np.ndarray, VerificationReport, float | None]:
    """Verify ``tuned``; an answer that fails is pulled inside by the exact verification and verified again.

    The boundary move works on the search estimate, which agrees with the exact verification to
    ~1e-5 in Ms on smooth loops but less on some PID loops; where the two disagree the exact one
    decides (:func:`gaintune.evaluation.boundary_exact.onto_boundary_exact`). Returns the gains, their
    report and their new cost (None when unchanged).
    """
    lay, ctx = ev.layout, evaluator_context(ev)
    report = verify(ev.spec, lay.to_dict(lay.full(tuned)), context=ctx)
    if report.verdict == "pass":
        return tuned, report, None
    from gaintune.evaluation.boundary_exact import onto_boundary_exact  # only for an answer that fails

    exact = onto_boundary_exact(ev, tuned)
    if exact.action != "pulled_inside":
        return tuned, report, None
    report = verify(ev.spec, lay.to_dict(lay.full(exact.tuned)), context=ctx)
    return exact.tuned, report, float(ev.evaluate(exact.tuned[None, :]).cost[0])


def _refine(ev: Evaluator, tuned: np.ndarray, merit: float, cost: float, budget: int,
            seed: int) -> tuple[np.ndarray, float, int]:
    """CMA-ES from the answer with at most ``budget`` simulations, then the boundary move; the better answer."""
    from gaintune.baselines.optimizers import optimize

    if budget < 2:  # one CMA-ES simulation and the move's evaluation of it need two: '--refine 1' spent 2
        return tuned, cost, 0
    n0 = ev.n_sims
    # a few simulations stay for the boundary move of the refined point (it evaluates both sides once)
    res = optimize(ev, "cmaes", max(budget - 3, 1), seed=seed, x0=tuned, sigma0=0.05)
    x = np.asarray(res.tuned, dtype=float)
    move = onto_boundary(ev, x[None, :])
    spent = ev.n_sims - n0
    if float(move.scores.merit[0]) < merit:
        return move.tuned[0], float(move.scores.cost[0]), spent
    return tuned, cost, spent
