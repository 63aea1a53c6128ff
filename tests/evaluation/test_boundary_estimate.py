"""The RL search's constraint projection (gaintune.evaluation.boundary_estimate), and the bug it fixes.

Bug (issue 12): with feasibility-first rewards, every policy sample across an active
requirement boundary scored far below every feasible one, so the PPO policy mean kept well
inside the boundary; the RL agent's own answer on PID problems was up to 24 % worse than the
constrained optimum (std_unstable_pid 1.238, std_integ_pid 1.206, std_fotd01_pid 1.151).
Samples beyond the boundary are now moved onto it along their loop-gain scale before scoring.
"""

from __future__ import annotations

import numpy as np
import pytest

from gaintune.envs.problem import GainProblem
from gaintune.evaluation.boundary import loop_gain_exponents
from gaintune.evaluation.boundary_estimate import TOL, onto_boundary_estimate
from gaintune.search import tune
from gaintune.spec import load_spec
from gaintune.verification import verify

LOAD = {"name": "load", "reference": {"kind": "none"}, "disturbance": {"kind": "step", "amplitude": 1.0, "entry": "input"}}


def _spec(loop="pid", budget=2000, repair_on=True, den="(s+1)^3", delay=None, ms=1.4, backoff=None):
    plant = {"tf": {"num": [1], "den": den}}
    if delay:
        plant["delay"] = delay
    req = {"gm_min_db": None, "pm_min_deg": None, "ms_max": ms}
    if backoff is not None:
        req["backoff"] = backoff
    return load_spec({
        "plant": plant, "loops": [{"name": "main", "type": loop}],
        "scenarios": [{**LOAD, "dt": 0.05, "horizon": 40.0}], "objective": {"measure": "iae", "effort_weight": 0},
        "requirements": req,
        "search": {"budget": budget, "seed": 0, "n_envs": 16, "repair": repair_on},
    })


def _exact_ms(spec, gp, tuned) -> float:
    rep = verify(spec, gp.layout.to_dict(gp.layout.full(tuned)), nonlinear=False, plant=gp.plant, layout=gp.layout)
    return max(f.ms for f in rep.loops)


def test_loop_gain_exponents_scale_every_gain_of_a_parallel_pid():
    gp = GainProblem(_spec())
    assert loop_gain_exponents(gp.evaluator).tolist() == [1.0, 1.0, 1.0]


def test_repair_moves_stable_infeasible_gains_onto_the_ms_boundary_keeping_their_ratios():
    spec = _spec(backoff=0)  # onto the exact limit (the default aim inside it: test_repair_lands_on_the_backoff_aim)
    gp = GainProblem(spec)
    base = gp.layout.initial_tuned()
    tuned = np.array([base * f for f in (1.6, 2.0, 2.4)])
    v0 = gp.evaluator.requirement_violation(tuned)
    assert np.all((v0 > 0) & (v0 < 10))  # infeasible but stable: what repair handles
    r = onto_boundary_estimate(gp.evaluator, tuned)
    assert r.repaired.all() and np.all(r.violation == 0) and np.all(r.alpha < 1)
    for row, orig in zip(r.tuned, tuned):
        ratio = row / orig
        assert ratio == pytest.approx(np.full(3, ratio[0]), rel=1e-12)  # one scale for the whole controller
        assert 1.4 * (1 - 2 * TOL) <= _exact_ms(spec, gp, row) <= 1.4  # on the boundary, by the exact check
    assert np.all(gp.evaluator.requirement_violation(r.tuned) == 0)


def test_repair_leaves_feasible_and_unstable_rows_alone():
    gp = GainProblem(_spec())
    base = gp.layout.initial_tuned()
    tuned = np.array([base * 0.5, base * 40.0])
    v0 = gp.evaluator.requirement_violation(tuned)
    assert v0[0] == 0 and v0[1] >= 10
    r = onto_boundary_estimate(gp.evaluator, tuned)
    assert not r.repaired.any()
    np.testing.assert_array_equal(r.tuned, tuned)
    np.testing.assert_array_equal(r.violation, v0)


def test_repair_lands_on_the_backoff_aim_never_between_it_and_the_limit():
    spec = _spec()  # the default back-off: the estimate aims at Ms 1.386
    gp = GainProblem(spec)
    aim = spec.requirements.backoff.aim("ms_max", 1.4)
    tuned = np.array([gp.layout.initial_tuned() * f for f in (1.6, 2.0, 2.4)])
    r = onto_boundary_estimate(gp.evaluator, tuned)
    assert r.repaired.all() and np.all(r.violation == 0)
    for row in r.tuned:
        assert aim * (1 - 5 * TOL) <= _exact_ms(spec, gp, row) <= aim + 1e-4  # by the exact check


def test_rl_policy_mean_kept_inside_an_active_ms_constraint_instead_of_on_it():
    """Same seed and budget, repair off and on: the RL agent's own answer (no polish) gets closer to the optimum."""
    costs = {}
    for on in (False, True):
        spec = _spec(budget=2500, repair_on=on, den=[10, 1], delay=1.0)
        spec = spec.model_copy(update={"search": spec.search.model_copy(update={"refine": False})})
        r = tune(spec)
        assert r.verdict == "pass"
        costs[on] = r.rl_cost
    assert costs[True] < costs[False] * 0.99
