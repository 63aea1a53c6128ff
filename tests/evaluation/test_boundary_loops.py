"""The per-loop repair (gaintune.evaluation.boundary_loops and ``onto_boundary_estimate(per_loop=True)``).

Scaling every loop together charges a sample for one loop's excess with all of its loops: a cascade
sample whose inner loop breaks Ms <= 1.6 had its well-behaved outer loop scaled down by the same 0.73.
The per-loop repair moves only the loop that misses a requirement at its own break point.
"""

from __future__ import annotations

import numpy as np
import pytest

from gaintune.controllers.layout import GainLayout
from gaintune.evaluation.boundary_estimate import onto_boundary_estimate
from gaintune.evaluation.boundary_loops import loop_directions, loop_names, loop_shortfalls
from gaintune.evaluation.evaluator import Evaluator
from gaintune.plants import build_plant
from gaintune.sim import Simulator
from gaintune.spec import load_spec

#: outer PI on the slow lag (y2), inner PI on the fast one (y1); Ms <= 1.6 at every break point
CASCADE = {
    "plant": {"ss": {"A": [[-10.0, 0.0], [1.0, -1.0]], "B": [[10.0], [0.0]], "C": [[1.0, 0.0], [0.0, 1.0]],
                     "outputs": ["y1", "y2"], "states": ["x1", "x2"]}},
    "loops": [{"name": "outer", "measure": "y2", "type": "pi"}, {"name": "inner", "measure": "y1", "type": "pi"}],
    "scenarios": [{"name": "step", "dt": 0.01, "horizon": 10.0, "reference": {"kind": "step", "amplitude": 1.0}}],
    "requirements": {"gm_min_db": None, "pm_min_deg": None, "ms_max": 1.6},
    "search": {"budget": 300, "n_envs": 8, "seed": 0},
}
#: (outer Kp, Ki, inner Kp, Ki): the outer loop well inside Ms 1.6, the inner loop far past it
INNER_TOO_HOT = [0.5, 0.3, 8.0, 200.0]
#: both loops inside the limit
GOOD = [0.5, 0.3, 1.0, 10.0]


@pytest.fixture(scope="module")
def ev() -> Evaluator:
    spec = load_spec(CASCADE)
    plant = build_plant(spec.plant)
    layout = GainLayout(spec, plant.states, plant=plant)
    return Evaluator(spec, Simulator(spec, plant, layout))


def test_loop_directions_follow_the_layouts_loops(ev):
    assert loop_names(ev) == ["outer", "inner"]
    assert loop_directions(ev).tolist() == [[1.0, 1.0, 0.0, 0.0], [0.0, 0.0, 1.0, 1.0]]


def test_loop_shortfalls_blame_the_loop_that_misses_the_requirement(ev):
    s = loop_shortfalls(ev, np.array([INNER_TOO_HOT, GOOD]))
    assert s[0, 0] < 0 < s[0, 1]  # only the inner loop misses Ms
    assert np.all(s[1] < 0)
    # the whole-loop estimate's shortfall is the worst loop's
    assert ev.requirement_scores(np.array([INNER_TOO_HOT]))[1][0] == pytest.approx(s[0, 1], rel=1e-9)


def test_per_loop_repair_moves_only_the_loop_that_violates(ev):
    t = np.array([INNER_TOO_HOT])
    r = onto_boundary_estimate(ev, t, per_loop=True)
    assert r.repaired[0] and r.violation[0] == 0 and r.alpha[0] < 1
    np.testing.assert_array_equal(r.tuned[0, :2], t[0, :2])  # the outer loop is untouched
    ratio = r.tuned[0, 2:] / t[0, 2:]
    assert ratio == pytest.approx(np.full(2, r.alpha[0]), rel=1e-12)  # the inner controller scaled as a whole
    assert ev.requirement_violation(r.tuned)[0] == 0


def test_repair_of_every_loop_together_scales_the_outer_loop_too(ev):
    """The default move, for contrast: one scale on all four gains."""
    t = np.array([INNER_TOO_HOT])
    r = onto_boundary_estimate(ev, t)
    assert r.repaired[0]
    assert r.tuned[0] / t[0] == pytest.approx(np.full(4, r.alpha[0]), rel=1e-12)


def test_per_loop_repair_leaves_feasible_rows_alone(ev):
    t = np.array([GOOD, INNER_TOO_HOT])
    r = onto_boundary_estimate(ev, t, per_loop=True)
    np.testing.assert_array_equal(r.tuned[0], t[0])
    assert r.repaired.tolist() == [False, True]
