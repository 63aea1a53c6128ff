"""Warnings about the plant: open-loop unstable, non-equilibrium operating point (issue 12)."""

from __future__ import annotations

import math

import pytest

from gaintune.plants import build_plant
from gaintune.plants.advice import plant_warnings
from gaintune.spec import PlantSpec

TANK = {"ode": {"states": ["h"], "input": "u", "rhs": {"h": "(b*u - a*sqrt(max(h, 0)))/A"},
                "outputs": {"level": "h"}, "x0": {"h": 10.0}}, "params": {"A": 20.0, "a": 2.0, "b": 5.0}}


def test_open_loop_unstable_plant_is_named_with_the_delay_bound():
    w = plant_warnings(build_plant(PlantSpec.model_validate({"tf": {"num": [1], "den": [1, -1]}, "delay": 0.5})))
    assert len(w) == 1 and "open-loop unstable" in w[0] and "pole(s) 1" in w[0]
    assert f"{math.exp(0.5):.4g}" in w[0]  # Mt >= e^(p theta) = 1.649


def test_stable_and_integrating_plants_give_no_warning():
    assert plant_warnings(build_plant(PlantSpec.model_validate({"tf": {"num": [1], "den": "(s+1)^3"}}))) == []
    assert plant_warnings(build_plant(PlantSpec.model_validate({"tf": {"num": [1], "den": "s*(s+1)"}}))) == []


def test_operating_point_that_is_not_an_equilibrium_is_reported_not_accepted_silently():
    assert plant_warnings(build_plant(PlantSpec.model_validate(TANK))) == []  # u0 solved: an equilibrium
    off = {**TANK, "ode": {**TANK["ode"], "u0": 3.0}}  # the equilibrium input at h = 10 is 2*sqrt(10)/5 = 1.265
    (w,) = plant_warnings(build_plant(PlantSpec.model_validate(off)))
    assert "not an equilibrium" in w and "dh/dt" in w
    assert float(w.split("dh/dt = ")[1].split()[0]) == pytest.approx((5 * 3.0 - 2 * math.sqrt(10)) / 20, rel=1e-3)
