"""The pidtune-style ``design`` shortcut expands into requirements and scenarios."""

from __future__ import annotations

import pytest
from pydantic import ValidationError

from gaintune.spec import load_spec

BASE = {"plant": {"tf": {"num": [1], "den": "(s+1)^3"}}, "loops": [{"type": "pi"}]}


def test_design_default_is_pidtunes_60_degrees_balanced():
    spec = load_spec({**BASE, "design": {}})
    assert spec.requirements.pm_min_deg == 60.0
    assert [(s.name, s.weight) for s in spec.scenarios] == [("tracking", 0.5), ("load", 0.5)]
    load = spec.scenarios[1]
    assert load.reference.kind == "none" and load.disturbance.kind == "step" and load.disturbance.entry == "input"


@pytest.mark.parametrize("focus, names", [("reference_tracking", ["tracking"]), ("disturbance_rejection", ["load"])])
def test_design_focus_picks_the_scenario(focus, names):
    spec = load_spec({**BASE, "design": {"focus": focus, "phase_margin": 55, "dt": 0.05, "horizon": 30}})
    assert [s.name for s in spec.scenarios] == names
    assert spec.scenarios[0].dt == 0.05 and spec.scenarios[0].horizon == 30
    assert spec.requirements.pm_min_deg == 55


def test_design_keeps_explicit_scenarios_and_round_trips():
    spec = load_spec({**BASE, "design": {"phase_margin": 50}, "scenario": {"name": "mine", "dt": 0.02}})
    assert [s.name for s in spec.scenarios] == ["mine"] and spec.requirements.pm_min_deg == 50
    again = load_spec(spec.model_dump(mode="json"))
    assert again.content_hash() == spec.content_hash()


def test_design_phase_margin_given_twice_is_rejected_naming_both_fields():
    with pytest.raises(ValidationError, match="pm_min_deg.*design.phase_margin"):
        load_spec({**BASE, "design": {"phase_margin": 60}, "requirements": {"pm_min_deg": 45}})
    with pytest.raises(ValidationError, match="phase_margin"):
        load_spec({**BASE, "design": {"phase_margin": 95}})


def test_design_crossover_becomes_a_band_requirement_and_round_trips():
    spec = load_spec({**BASE, "design": {"crossover": 0.5}})
    assert spec.requirements.wc_min == pytest.approx(0.5 / 1.1) and spec.requirements.wc_max == pytest.approx(0.55)
    spec = load_spec({**BASE, "design": {"crossover": 0.5, "crossover_tolerance": 0.2}})
    assert spec.requirements.wc_max == pytest.approx(0.6)
    again = load_spec(spec.model_dump(mode="json"))
    assert again.content_hash() == spec.content_hash()


def test_design_crossover_given_twice_or_for_a_cascade_is_rejected():
    with pytest.raises(ValidationError, match="give it once"):
        load_spec({**BASE, "design": {"crossover": 0.5}, "requirements": {"wc_min": 0.1}})
    two = {**BASE, "plant": {"ss": {"A": [[-1, 0], [1, -2]], "B": [[1], [0]], "C": [[1, 0], [0, 1]], "outputs": ["a", "b"]}},
           "loops": [{"type": "pi", "measure": "b"}, {"type": "pi", "measure": "a"}]}
    with pytest.raises(ValidationError, match="single loop"):
        load_spec({**two, "design": {"crossover": 0.5}})


def test_design_scenarios_default_horizon_scaled_to_slow_fotd_plant():
    # issue 25 for the shortcut: design's scenarios were 0.01 s / 20 s whatever the plant
    from gaintune.classical.timescale import scenario_defaults

    fotd = {"plant": {"tf": {"num": [2], "den": "60*s + 1"}, "delay": 10}, "loops": [{"type": "pi"}], "design": {}}
    spec = load_spec(fotd)
    assert [(s.dt, s.horizon) for s in spec.scenarios] == [(None, None), (None, None)]
    resolved, records = scenario_defaults(spec)
    assert [(s.name, s.dt, s.horizon) for s in resolved.scenarios] == [("tracking", 0.35, 700.0), ("load", 0.35, 700.0)]
    assert [r.scenario for r in records] == ["tracking", "load"]
    assert load_spec(resolved.model_dump(mode="json")).content_hash() == resolved.content_hash()
    # explicit design.dt/horizon are kept; horizon alone: dt from the plant (at least 2,000 samples)
    given = scenario_defaults(load_spec({**fotd, "design": {"horizon": 100}}))[0]
    assert [(s.dt, s.horizon) for s in given.scenarios] == [(0.05, 100.0), (0.05, 100.0)]
