"""The default search box (gaintune.search_box): rules first, a Sobol sample where no rule applies."""

from __future__ import annotations

import numpy as np

from gaintune.plants import build_plant
from gaintune.search_box import GRID_POINTS, search_box
from gaintune.spec import load_spec

UNSTABLE = {"plant": {"tf": {"num": [1], "den": [1, -1]}, "delay": 0.1}, "loops": [{"name": "main", "type": "pid"}],
            "scenario": {"dt": 0.005, "horizon": 15.0, "reference": {"kind": "none"},
                         "disturbance": {"kind": "step", "entry": "input", "amplitude": 1.0}},
            "objective": {"measure": "iae", "effort_weight": 0.0},
            "requirements": {"gm_min_db": None, "pm_min_deg": None, "ms_max": 2.0}}


def test_unstable_pid_without_a_rule_searched_the_whole_default_box():
    """Regression (issue 12): no classical rule applies to e^{-0.1s}/(s-1), so the box was the fixed
    1e-3 .. 1e3 of every gain, centred on gains that do not stabilise the loop (RL-only ratio 2.99)."""
    spec = load_spec(UNSTABLE)
    box = search_box(spec, build_plant(spec.plant))
    assert box.source is not None and box.source.startswith("grid")
    assert box.feasible  # the start gains stabilise the loop and meet Ms <= 2
    assert len(box.candidates) == GRID_POINTS
    kp = box.centre["main"]["Kp"]
    assert kp > 1.0  # an unstable pole at 1 needs Kp K > 1
    lo, hi = np.exp(box.layout.log_lo), np.exp(box.layout.log_hi)
    assert np.all(hi / lo < 1e6 * 0.999)  # a box around the centre, narrower than the six decades of the default


def test_sobol_centre_is_reproducible_for_a_seed():
    spec = load_spec(UNSTABLE)
    plant = build_plant(spec.plant)
    assert search_box(spec, plant).centre == search_box(spec, plant).centre
