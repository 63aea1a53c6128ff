"""Odd but valid inputs must not print numpy/scipy/matplotlib warnings on a user's terminal (fuzzing, W01-W03)."""

from __future__ import annotations

import warnings

import numpy as np

from gaintune.classical import rule_candidates
from gaintune.evaluation.evaluator import DIVERGED_COST, scenario_cost
from gaintune.plants import build_plant
from gaintune.spec import load_spec


def test_p_pi_cascade_rules_print_no_badly_conditioned_coefficients_warning() -> None:
    # ss_to_tf left ~1e-17 where the velocity path's leading numerator coefficient is 0: scipy warned twice
    spec = load_spec({"plant": {"ss": {"A": [[0, 1], [0, -2]], "B": [[0], [1]], "C": [[1, 0], [0, 1]],
                                       "outputs": ["pos", "vel"]}},
                      "loops": [{"type": "p", "measure": "pos"}, {"type": "pi", "measure": "vel"}],
                      "scenario": {"dt": 0.05, "horizon": 5}})
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        rules = rule_candidates(spec, build_plant(spec.plant))
    assert rules


def test_huge_effort_weight_costs_as_diverged_without_an_overflow_warning() -> None:
    spec = load_spec({"plant": {"tf": {"num": [1], "den": [1, 1]}}, "loops": [{"type": "pi"}],
                      "scenario": {"dt": 0.05, "horizon": 5}, "objective": {"effort_weight": 1e300}})
    m = {k: np.array([1.0, 2.0]) for k in ("iae", "ise", "itae", "effort", "tv", "overshoot", "settling_time")}
    m["effort"] = np.array([1e10, 0.0])
    m["diverged"] = np.array([False, False])
    with np.errstate(all="raise"):
        cost = scenario_cost(m, spec.objective, spec.scenarios[0])
    assert cost[0] == DIVERGED_COST and cost[1] < DIVERGED_COST
