"""The repair's ladder on a MIMO spec scores its rungs one at a time, only on rows still infeasible: the same
bracket as scoring every rung in one batch, from fewer loop checks (issue 28: the 110-gain process train
spent most of its search in the repair's trial checks)."""

from __future__ import annotations

import numpy as np
import pytest

import gaintune.verification.mimo_sampled_report as sampled_report
from gaintune.evaluation import boundary_estimate
from gaintune.evaluation.boundary import loop_gain_exponents
from gaintune.evaluation.evaluator import Evaluator
from gaintune.plants.library import load_model
from gaintune.spec import load_spec


def _ladder_and_checks(monkeypatch: pytest.MonkeyPatch, batched: bool) -> tuple[object, int]:
    ev = Evaluator(load_spec(load_model("wood_berry").example_spec()))
    base = ev.layout.initial_tuned()
    # from feasible (x1) to far beyond the boundary (x8): rows stop at different rungs, or at none
    tuned = np.array([base * f for f in (1.0, 1.5, 2.5, 4.0, 8.0)])
    d = loop_gain_exponents(ev)
    _, g0 = ev.requirement_scores(tuned)
    calls = []
    real = sampled_report.sampled_margins
    monkeypatch.setattr(sampled_report, "sampled_margins", lambda *a, **k: calls.append(1) or real(*a, **k))
    if batched:  # the single-loop way: every rung of every row in one call
        monkeypatch.setattr(Evaluator, "is_mimo", property(lambda self: False))
    br = boundary_estimate._ladder(ev, tuned, d, g0)
    return br, len(calls)


def test_mimo_ladder_scores_rungs_one_at_a_time_with_the_same_bracket_and_fewer_checks(
        monkeypatch: pytest.MonkeyPatch) -> None:
    with monkeypatch.context() as m:
        batched, n_batched = _ladder_and_checks(m, batched=True)
    with monkeypatch.context() as m:
        rungs, n_rungs = _ladder_and_checks(m, batched=False)
    for field in ("xg", "gg", "xb", "gb", "found"):
        assert np.array_equal(getattr(rungs, field), getattr(batched, field)), field
    assert n_batched == 5 * len(boundary_estimate.LADDER)
    assert n_rungs < n_batched
