"""The query's fast path gives what the full path gives: the verification reuses the evaluator's plant,
layout, linearisation and simulator (``verify(..., context=...)``), and the boundary move reuses the
requirement estimate it computed; verdicts, reports and costs equal those of a plain :func:`verify`
and of a fresh evaluation of the answer."""

from __future__ import annotations

import numpy as np
import pytest

from gaintune.evaluation.boundary_both import onto_boundary
from gaintune.evaluation.evaluator import Evaluator
from gaintune.tuners.tuner import Tuner, evaluator_context
from gaintune.verification import verify

#: FOTD plants over the family's range (L/T 0.05 to 10, time scales from 0.3 s to 200 s), and one PID tuner's.
PLANTS = [("fotd_pi_ms1.4", {"K": 2.0, "T": 60.0, "L": 10.0}), ("fotd_pi_ms1.4", {"K": 0.3, "T": 1.0, "L": 0.05}),
          ("fotd_pi_ms1.4", {"K": 7.0, "T": 0.3, "L": 3.0}), ("fotd_pi_ms2", {"K": 1.0, "T": 200.0, "L": 40.0}),
          ("fotd_pid_ms1.4", {"K": 1.5, "T": 5.0, "L": 1.0}), ("fotd_pid_ms1.4", {"K": 4.0, "T": 2.0, "L": 0.2})]


def _plain(report) -> dict:
    """The report's content without its timing."""
    d = report.model_dump(mode="json")
    d.pop("elapsed_s")
    return d


@pytest.mark.parametrize(("name", "params"), PLANTS)
def test_fast_query_verdict_and_cost_equal_the_full_verify(name, params):
    tuner = Tuner.load(name)
    ans = tuner.query(params)
    spec = tuner.problem.physical_spec(params)
    full = verify(spec, ans.gains, cache=False)  # from the spec alone: nothing reused
    assert ans.verdict == full.verdict and ans.verification is not None
    assert ans.verification.reasons == full.reasons
    assert ans.verification.loops == full.loops and ans.verification.nonlinear == full.nonlinear
    ev = Evaluator(spec)
    lay = ev.layout
    fresh = ev.evaluate(np.asarray(lay.from_dict(ans.gains), dtype=float)[lay.tuned_idx][None, :])
    assert ans.cost == float(fresh.cost[0])
    assert float(fresh.violation[0]) == 0.0 or ans.verdict == "fail"


def test_verify_on_an_evaluators_context_gives_the_report_of_a_fresh_verify():
    tuner = Tuner.load("fotd_pi_ms1.4")
    spec = tuner.problem.physical_spec({"K": 2.0, "T": 60.0, "L": 10.0})
    ev = Evaluator(spec)
    gains = {"main": {"Kp": 0.2, "Ki": 0.02}}
    reused = verify(ev.spec, gains, context=evaluator_context(ev))
    assert _plain(reused) == _plain(verify(ev.spec, gains, cache=False))


@pytest.mark.parametrize("scale", [0.05, 0.5, 3.0])
def test_boundary_move_scores_equal_a_fresh_evaluation_of_its_answer(scale):
    tuner = Tuner.load("fotd_pi_ms1.4")
    spec = tuner.problem.physical_spec({"K": 1.0, "T": 10.0, "L": 2.0})
    ev = Evaluator(spec)
    start = np.array([[0.3 * scale, 0.05 * scale], [0.6 * scale, 0.02 * scale]])
    move = onto_boundary(ev, start)
    fresh = Evaluator(spec).evaluate(move.tuned)
    np.testing.assert_array_equal(move.scores.violation, fresh.violation)
    np.testing.assert_array_equal(move.scores.cost, fresh.cost)


@pytest.mark.parametrize("aot", [True, False], ids=["ahead_of_time", "jit"])
def test_query_loads_only_the_single_lane_kernel_variant(monkeypatch, aot):
    """A query's simulations (the move's two rows, the verification's runs) all run on the single-lane kernel:
    the ahead-of-time module where it is built (no JIT variant called), else the JIT single-lane variant, so a
    fresh process loads one compiled variant, not two."""
    import gaintune.sim.kernel as kernel
    from gaintune.sim.kernel import drivers
    from gaintune.sim.kernel_aot import load_single
    from gaintune.sim.precompile import build_single

    if aot:
        build_single()
        module = load_single()
        assert module is not None
        ran = []

        def counted_aot(*args):
            ran.append(1)
            return module(*args)

        monkeypatch.setattr(kernel, "load_single", lambda: counted_aot)
    else:
        monkeypatch.setattr(kernel, "load_single", lambda: None)
    calls = {"_single": 0, "_serial": 0}
    for name in calls:
        real = getattr(drivers, name)

        def counted(*args, _real=real, _name=name):
            calls[_name] += 1
            return _real(*args)

        monkeypatch.setattr(drivers, name, counted)
    for name, params in PLANTS[:3]:
        assert Tuner.load(name).query(params).verdict == "pass"
    if aot:
        assert calls == {"_single": 0, "_serial": 0} and len(ran) > 0
    else:
        assert calls["_serial"] == 0 and calls["_single"] > 0


@pytest.mark.parametrize(("name", "params"), PLANTS)
def test_rows_evaluated_one_at_a_time_equal_the_batched_evaluation(name, params):
    """The move of one candidate evaluates its rows one at a time (single-lane variant): the scores are those of
    one batched call (the CHUNK-lane variant), bit for bit."""
    from gaintune.evaluation.boundary_both import _evaluate

    tuner = Tuner.load(name)
    gains, _, _ = tuner.policy_gains(params)
    spec = tuner.problem.physical_spec(params)
    ev = Evaluator(spec)
    lay = ev.layout
    rows = np.asarray(lay.from_dict(gains), dtype=float)[lay.tuned_idx][None, :] * np.array([[1.0], [0.7], [1.3]])
    v = ev.requirement_violation(rows)
    one = _evaluate(ev, rows, v)
    batched = Evaluator(spec).evaluate(rows, violation=v)
    for field in ("cost", "violation", "diverged", "tripped"):
        np.testing.assert_array_equal(getattr(one, field), getattr(batched, field))
    assert one.metrics.keys() == batched.metrics.keys()
    for k in one.metrics:
        np.testing.assert_array_equal(one.metrics[k], batched.metrics[k])
