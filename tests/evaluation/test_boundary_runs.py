"""The move onto the boundary from both sides when the feasible loop-gain scales form several runs."""

from __future__ import annotations

import numpy as np

from gaintune.evaluation.boundary import loop_gain_exponents
from gaintune.evaluation.boundary_both import _ONE, SCAN, _scan, _start_points, onto_boundary
from gaintune.evaluation.evaluator import Evaluator
from gaintune.tuners.problems import FamilyProblem
from gaintune.verification import verify


def _ok(pattern: str) -> np.ndarray:
    assert len(pattern) == SCAN.size
    return np.array([c == "1" for c in pattern])


def test_start_points_put_the_given_gains_run_first_then_every_other_run_top():
    # the given gains (index 15) feasible: the top of their run first, then the other runs' tops
    assert _start_points(_ok("1111100000000111111000011100000")) == [18, 4, 25]
    # the given gains infeasible: the largest feasible scale below them first
    assert _start_points(_ok("1111111111110000000111000000000")) == [11, 21]
    # a run at the top of the scan (the box ceiling) is a start point too
    assert _start_points(_ok("0000000000000000000000000000111")) == [30]
    assert _start_points(_ok("0" * 31)) == []
    assert _ONE == 15


def test_move_finds_the_high_gain_island_of_a_lag_dominant_pid():
    """Regression: the move landed only next to the given gains, so a lag-dominant PID shape given at a gain
    inside the infeasible band (its box-centre scale, as a tuner's action gives it) was pulled down to the
    low-gain run, at ~35x the cost of the island of high gain where the shape's optimum lies. The reward
    of the PID tuners had a cliff beside the optimum there, and their answers stayed 15-18 % above it."""
    p = FamilyProblem("fotd", "pid", 1.4)
    ev = Evaluator(p.spec_at({"tau": 0.048}))
    given = np.array([[1.2087, 7.5664, 0.024223]])  # the optimum's shape (Ki/Kp 6.26) at 0.14x its gain
    d = loop_gain_exponents(ev)
    _, _, starts, _ = _scan(ev, given, d)
    assert len(starts[0]) == 2  # feasible at low gain and on an island of high gain; not at the given gain
    move = onto_boundary(ev, given)
    assert bool(move.scores.feasible[0]) and move.alpha[0] > 4.0
    low = given * SCAN[starts[0][0]]  # the top scan point of the low-gain run
    assert move.scores.cost[0] < ev.evaluate(low).cost[0] / 10
    lay = ev.layout
    assert verify(ev.spec, lay.to_dict(lay.full(move.tuned[0])), cache=False).verdict == "pass"


def test_the_landing_check_of_points_whose_margins_hold_is_the_full_estimate() -> None:
    """The move checks its landing points (feasible scan points and bracket ends) for stability alone: for any
    gain set, the full estimate's violation is the unstable grade where the loop is unstable, and the
    margins' violation where it is stable."""
    for ctype, context, given in [("pi", {"tau": 0.3}, [0.8, 1.1]), ("pid", {"tau": 0.048}, [1.2087, 7.5664, 0.024223]),
                                  ("pi", {"tau": 0.8}, [0.2, 0.15])]:
        ev = Evaluator(FamilyProblem("fotd", ctype, 1.4).spec_at(context))
        g = np.asarray(given)
        rows = g[None, :] * np.geomspace(1e-2, 1e2, 25)[:, None] ** loop_gain_exponents(ev)
        full = ev.requirement_scores(rows)[0]
        margins = ev.requirement_scores(rows, stability=False)[0]
        unstable = ev.unstable_violation(rows)
        assert (unstable > 0).any() and (unstable == 0).any() and (margins == 0).any()
        assert np.array_equal(full, np.where(unstable > 0, unstable, margins))
