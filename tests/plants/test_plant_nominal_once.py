"""build_plant checks the nominal matrices once and keeps them as the nominal linearisation: the model equals
one linearised afresh, and the matrices are built once per plant (a tuner query builds a plant per answer)."""

from __future__ import annotations

import numpy as np
import pytest

from gaintune.plants import plant as plant_mod
from gaintune.plants.plant import build_plant
from gaintune.spec import PlantSpec

SPECS = [
    {"tf": {"num": ["K"], "den": "T*s + 1"}, "delay": "L", "params": {"K": 2.0, "T": 60.0, "L": 10.0}},
    {"tf": {"num": [1, 2], "den": "(s + 1)*(0.5*s + 1)*(0.1*s + 1)"}, "delay": 0.3},
    {"ss": {"A": [[0, 1], [-2, -3]], "B": [[0], [1]], "C": [[1, 0]], "states": ["pos", "vel"]}},
]


@pytest.mark.parametrize("data", SPECS)
def test_nominal_linearisation_kept_by_build_equals_one_built_afresh(data):
    p = build_plant(PlantSpec.model_validate(data))
    kept = p.linearize()
    p._cache.clear()
    fresh = p.linearize()
    for name in ("A", "B", "C", "D", "x0", "y0"):
        np.testing.assert_array_equal(getattr(kept, name), getattr(fresh, name))
    assert (kept.delay, kept.states, kept.outputs, kept.u0) == (fresh.delay, fresh.states, fresh.outputs, fresh.u0)


def test_build_plant_builds_the_nominal_matrices_once(monkeypatch):
    calls = []
    real = plant_mod._lti_matrices

    def counted(spec, p):
        calls.append(dict(p))
        return real(spec, p)

    monkeypatch.setattr(plant_mod, "_lti_matrices", counted)
    p = build_plant(PlantSpec.model_validate(SPECS[0]))
    p.linearize()
    assert len(calls) == 1
    p.linearize({"K": 3.0})  # other parameters: built for them
    assert len(calls) == 2
