"""pidtune's target crossover (``design.crossover``, issue 12): the tuned loop's crossover lies in
the requested band and the verdict checks it, like every other requirement."""

from __future__ import annotations

import numpy as np
import pytest

from gaintune.controllers.layout import GainLayout
from gaintune.plants.plant import build_plant
from gaintune.search.tuning import tune
from gaintune.spec import load_spec
from gaintune.verification import quick_margins, verify

BASE = {"plant": {"tf": {"num": [1], "den": "(s+1)^3"}}, "loops": [{"name": "main", "type": "pi"}]}


def test_tuned_gains_meet_the_target_crossover_band():
    spec = load_spec({**BASE, "design": {"crossover": 0.3, "focus": "disturbance_rejection", "dt": 0.05, "horizon": 40},
                      "search": {"budget": 1000, "seed": 0}})
    res = tune(spec)
    assert res.verdict == "pass"
    wc = res.verification.loops[0].pm_freq
    assert spec.requirements.wc_min <= wc <= spec.requirements.wc_max
    lines = {q.requirement for q in res.verification.requirements}
    assert {"wc_min", "wc_max", "pm_min_deg"} <= lines


@pytest.mark.parametrize("kp, ki", [(0.3, 0.1), (0.8, 0.3), (1.5, 0.5)])
def test_search_estimate_of_the_crossover_agrees_with_the_verdict(kp, ki):
    spec = load_spec({**BASE, "scenario": {"dt": 0.05, "horizon": 40}})
    plant = build_plant(spec.plant)
    layout = GainLayout(spec, plant.states)
    g = {"main": {"Kp": kp, "Ki": ki}}
    q = quick_margins(spec, plant, layout, layout.from_dict(g)[None, :])
    exact = verify(spec, g, nonlinear=False).loops[0].pm_freq
    assert q.wc[0, 0] == pytest.approx(exact, rel=2e-3)


def test_a_crossover_outside_the_band_fails_verification_with_the_reason():
    spec = load_spec({**BASE, "design": {"crossover": 2.0}})
    rep = verify(spec, {"main": {"Kp": 0.5, "Ki": 0.2}}, nonlinear=False)
    assert rep.verdict == "fail" and any(r.startswith("wc_min") for r in rep.reasons)
    assert np.isfinite(rep.loops[0].pm_freq)
