"""Cost arithmetic of gaintune.evaluation.evaluator against hand-computed values."""

from __future__ import annotations

import numpy as np
import pytest

from gaintune.evaluation.evaluator import (
    DIVERGED_COST,
    DIVERGED_VIOLATION,
    INFEASIBLE_MERIT,
    Evaluator,
    aggregate,
    merit,
    scenario_cost,
)
from gaintune.sim import Simulator
from gaintune.sim import draws as draws_mod
from gaintune.spec import ObjectiveSpec, ScenarioSpec, load_spec


def metrics(**kw) -> dict[str, np.ndarray]:
    base = dict(iae=1.0, ise=0.5, itae=3.0, effort=10.0, tv=2.0, overshoot=30.0, settling_time=4.0, diverged=False)
    base.update(kw)
    return {k: np.atleast_1d(np.asarray(v, dtype=bool if k == "diverged" else float)) for k, v in base.items()}


def test_scenario_cost_weights_and_penalties() -> None:
    obj = ObjectiveSpec(measure="iae", effort_weight=0.01, tv_weight=0.5, overshoot_limit=20.0, overshoot_weight=0.1, settling_weight=0.2)
    sc = ScenarioSpec(horizon=20.0)
    c = scenario_cost(metrics(), obj, sc)
    # 1 + 0.01*10 + 0.5*2 + 0.1*(30 - 20) + 0.2*4
    assert c[0] == pytest.approx(1.0 + 0.1 + 1.0 + 1.0 + 0.8)


@pytest.mark.parametrize("measure, value", [("iae", 1.0), ("ise", 0.5), ("itae", 3.0)])
def test_scenario_cost_measure(measure: str, value: float) -> None:
    obj = ObjectiveSpec(measure=measure, effort_weight=0.0)
    assert scenario_cost(metrics(), obj, ScenarioSpec(dt=0.01, horizon=20.0))[0] == pytest.approx(value)


def test_overshoot_below_the_limit_is_free_and_nan_overshoot_is_zero() -> None:
    obj = ObjectiveSpec(effort_weight=0.0, overshoot_limit=40.0, overshoot_weight=5.0)
    c = scenario_cost(metrics(overshoot=[30.0, 45.0, np.nan]), obj, ScenarioSpec(dt=0.01, horizon=20.0))
    np.testing.assert_allclose(c, [1.0, 1.0 + 5.0 * 5.0, 1.0])


def test_unsettled_run_is_charged_the_horizon() -> None:
    obj = ObjectiveSpec(effort_weight=0.0, settling_weight=2.0)
    c = scenario_cost(metrics(settling_time=[3.0, np.nan]), obj, ScenarioSpec(horizon=15.0))
    np.testing.assert_allclose(c, [1.0 + 6.0, 1.0 + 30.0])


def test_diverged_and_non_finite_costs_are_capped() -> None:
    obj = ObjectiveSpec()
    c = scenario_cost(metrics(iae=[1.0, np.inf, 1.0, 5e6, 1e31], diverged=[True, False, False, False, False]), obj,
                      ScenarioSpec(dt=0.01, horizon=20.0))
    assert c[0] == DIVERGED_COST and c[1] == DIVERGED_COST and c[4] == DIVERGED_COST
    assert c[2] == pytest.approx(1.0 + 0.01 * 10.0)
    assert c[3] == pytest.approx(5e6 + 0.01 * 10.0)  # a large real cost is a cost, not divergence


BIG_GAIN = {"plant": {"tf": {"num": [1e4], "den": "100*s + 1"}, "delay": 100}, "loops": [{"name": "main", "type": "pi"}],
            "scenarios": [{"name": "load", "reference": {"kind": "none"},
                           "disturbance": {"kind": "step", "entry": "input", "amplitude": 1.0, "time": 0.0}}],
            "objective": {"measure": "iae", "effort_weight": 0.0},
            "requirements": {"gm_min_db": None, "pm_min_deg": None, "ms_max": 1.4}}


def test_a_large_real_cost_is_not_divergence_and_the_search_still_finds_the_boundary() -> None:
    """Regression: a process gain of 1e4 (a pressure in Pa per valve fraction, say) gives a load IAE of ~2.7e6.
    Costs from 1e6 up counted as divergence, so every candidate "diverged" at the same cost, the search was
    blind, and `tune` handed out a PASS at Ms 1.03 under a 1.4 limit, its response unsettled at the horizon.
    The same problem in units where K = 1 must give the same answer, scaled."""
    from gaintune.evaluation.boundary_both import onto_boundary

    answers = []
    for k in (1.0, 1e4):
        data = {**BIG_GAIN, "plant": {**BIG_GAIN["plant"], "tf": {"num": [k], "den": "100*s + 1"}}}
        ev = Evaluator(load_spec(data))
        move = onto_boundary(ev, np.array([[0.1 / k, 0.001 / k]]))  # a timid PI: the move goes out to Ms 1.4
        assert not move.scores.diverged[0] and move.scores.violation[0] == 0
        answers.append((move.tuned[0] * k, float(move.scores.cost[0]) / k))
    (g1, c1), (g2, c2) = answers
    np.testing.assert_allclose(g2, g1, rtol=1e-6)
    assert c1 == pytest.approx(c2, rel=1e-6) and 200 < c1 < 400  # IAE ~2.7e6 at K = 1e4


def test_aggregate_mean_worst_cvar() -> None:
    costs = np.array([[1.0, 2.0, 3.0, 4.0, 5.0], [5.0, 5.0, 5.0, 5.0, 0.0]])
    np.testing.assert_allclose(aggregate(costs, "mean"), [3.0, 4.0])
    np.testing.assert_allclose(aggregate(costs, "worst"), [5.0, 5.0])
    np.testing.assert_allclose(aggregate(costs, "cvar", 0.2), [5.0, 5.0])  # ceil(0.2*5) = 1 worst draw
    np.testing.assert_allclose(aggregate(costs, "cvar", 0.4), [4.5, 5.0])  # the 2 worst
    np.testing.assert_allclose(aggregate(costs, "cvar", 0.5), [4.0, 5.0])  # ceil(2.5) = 3
    np.testing.assert_allclose(aggregate(costs, "cvar", 1.0), [3.0, 4.0])  # all draws: the mean


SPEC = {
    "plant": {"tf": {"num": ["K"], "den": "(T*s + 1)^3"}, "params": {"K": 1.0, "T": 1.0}},
    "loops": [{"type": "pi"}],
    "scenarios": [
        {"name": "a", "dt": 0.05, "horizon": 20.0, "weight": 0.3},
        {"name": "b", "dt": 0.05, "horizon": 30.0, "weight": 2.0, "reference": {"kind": "none"},
         "disturbance": {"kind": "step", "amplitude": 0.5, "time": 2.0}},
    ],
    "objective": {"measure": "ise", "effort_weight": 0.05, "tv_weight": 0.1, "overshoot_limit": 5.0, "overshoot_weight": 0.02,
                  "settling_weight": 0.1},
}


def test_evaluator_weights_scenarios_by_hand() -> None:
    spec = load_spec(SPEC)
    ev = Evaluator(spec)
    tuned = np.array([[1.0, 0.4], [0.5, 0.2], [30.0, 30.0]])  # the last one diverges
    scores = ev.evaluate(tuned)
    cost = scores.cost
    sim = Simulator(spec)
    expect = np.zeros(3)
    for sc in spec.scenarios:
        m = sim.run(sim.layout.full(tuned), scenario=spec.scenarios.index(sc)).metrics
        settle = np.where(np.isnan(m["settling_time"]), sc.horizon, m["settling_time"])
        part = (m["ise"] + 0.05 * m["effort"] + 0.1 * m["tv"] + 0.02 * np.maximum(0.0, np.nan_to_num(m["overshoot"]) - 5.0)
                + 0.1 * settle)
        part = np.where(m["diverged"], DIVERGED_COST, part)
        expect += sc.weight * part
    expect = np.minimum(expect, DIVERGED_COST)
    np.testing.assert_allclose(cost[:2], expect[:2], rtol=1e-12)
    assert cost[2] == DIVERGED_COST
    assert scores.diverged.tolist() == [False, False, True] and scores.violation[2] >= DIVERGED_VIOLATION
    assert ev.n_sims == 3 * 2


@pytest.mark.parametrize("how, alpha", [("mean", 0.2), ("worst", 0.2), ("cvar", 0.25)])
def test_evaluator_robust_aggregate_over_draws(how: str, alpha: float) -> None:
    data = dict(SPEC, scenarios=SPEC["scenarios"][:1], randomize={"params": {"K": [0.5, 1.5], "T": [0.7, 1.3]}},
                search={"robust": {"samples": 8, "aggregate": how, "alpha": alpha}})
    spec = load_spec(data)
    ev = Evaluator(spec)
    assert len(ev.draws) == 8 and len(np.unique(ev.draws.params[:, 0])) == 8
    tuned = np.array([[1.0, 0.4], [0.6, 0.3]])
    cost = ev.evaluate(tuned).cost  # the plain objective
    sim = Simulator(spec)
    sc = spec.scenarios[0]
    for i in range(2):
        full = np.repeat(sim.layout.full(tuned[i : i + 1]), 8, axis=0)
        per_draw = sc.weight * scenario_cost(sim.run(full, ev.draws).metrics, spec.objective, sc)
        ref = {"mean": per_draw.mean(), "worst": per_draw.max(), "cvar": np.sort(per_draw)[-2:].mean()}[how]
        assert cost[i] == pytest.approx(ref, rel=1e-12)
    # common random numbers: the same tuned gains always cost the same
    np.testing.assert_array_equal(ev.evaluate(tuned).cost, cost)
    # feasible gain sets rank by their plain cost: the merit is the cost itself
    s = ev.evaluate(tuned)
    np.testing.assert_array_equal(ev(tuned)[s.feasible], cost[s.feasible])


def test_merit_ranks_every_feasible_candidate_above_every_infeasible_one() -> None:
    cost = np.array([2.0, 500.0, 1.0, 0.5, DIVERGED_COST])
    violation = np.array([0.0, 0.0, 0.01, 3.0, DIVERGED_VIOLATION])
    m = merit(cost, violation)
    assert list(np.argsort(m)) == [0, 1, 2, 3, 4]  # feasible by cost, then infeasible by violation
    # a loose loop meets the requirements (violation 0); an aggressive one does not
    ev = Evaluator(load_spec(dict(SPEC, loops=[{"type": "pi"}], requirements={"gm_min_db": 6, "pm_min_deg": 45})))
    v = ev.requirement_violation(np.array([[0.3, 0.1], [6.0, 5.0]]))
    assert v[0] == 0.0 and v[1] > 0.0
    s = ev.evaluate(np.array([[0.3, 0.1], [6.0, 5.0]]))
    assert s.feasible.tolist() == [True, False] and s.merit[1] > INFEASIBLE_MERIT
    # the violation's order survives the magnitude of an infeasible merit
    assert merit(np.ones(3), np.array([1e-9, 2e-9, 0.5])).tolist() == sorted(merit(np.ones(3), np.array([1e-9, 2e-9, 0.5])))
    assert len(set(merit(np.ones(3), np.array([1e-9, 2e-9, 0.5])).tolist())) == 3


def test_cost_of_action_maps_through_log_bounds() -> None:
    data = dict(SPEC, loops=[{"type": "pi", "gains": {"Kp": {"bounds": [0.1, 10.0]}, "Ki": {"bounds": [0.01, 1.0]}}}])
    ev = Evaluator(load_spec(data))
    c = ev.cost_of_action(np.array([[0.0, 0.0]]))  # the geometric centres: Kp = 1, Ki = 0.1
    np.testing.assert_allclose(c, ev(np.array([[1.0, 0.1]])), rtol=1e-12)


def test_diverged_draw_costs_the_cap_whatever_the_scenario_weight() -> None:
    """Regression: a diverged run in a scenario of weight 0.3 used to cost only 0.3*DIVERGED_COST."""
    data = dict(SPEC, scenarios=SPEC["scenarios"][:1], randomize={"params": {"K": [0.2, 8.0]}},
                search={"robust": {"samples": 2, "aggregate": "worst"}})
    spec = load_spec(data)
    sim = Simulator(spec)
    ev = Evaluator(spec, sim, draws=draws_mod.corners(spec, sim.plant))  # K = 0.2 and K = 8
    tuned = np.array([[20.0, 1.0]])  # stable at K = 0.2 (loop gain 4 < 8), unstable at K = 8
    s = ev.evaluate(tuned)
    res = s.results[0]
    assert res.metrics["diverged"].any() and not res.metrics["diverged"].all()
    assert s.cost[0] == DIVERGED_COST and s.violation[0] >= DIVERGED_VIOLATION
