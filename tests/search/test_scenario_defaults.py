"""Scenario dt and horizon left out are derived from the plant; an unsettled response and a Ti longer
than the horizon are flagged (gaintune issue 25: a fixed 0.01 s / 20 s hid a 60 s process's integral action)."""

from __future__ import annotations

import pytest

from gaintune.classical.timescale import STEP_CAP, plant_scale, scenario_defaults
from gaintune.classical.tuning import tune_classical
from gaintune.plants import build_plant
from gaintune.search import tune
from gaintune.search.diagnosis import integral_time_hints
from gaintune.sim import Simulator
from gaintune.sim.settling import unsettled_scenarios
from gaintune.spec import load_spec

#: The README's minimal spec on the FOTD 2 e^{-10 s}/(60 s + 1): no scenario given.
FOTD = {"plant": {"tf": {"num": [2], "den": "60*s + 1"}, "delay": 10}, "loops": [{"type": "pi"}]}
SMALL = {"budget": 300, "n_envs": 8, "seed": 0}

#: name -> plant: fast, slow (lag-dominant), integrating, delay-dominant.
PLANTS = {
    "fast": {"tf": {"num": [1], "den": "0.01*s + 1"}},
    "slow": {"tf": {"num": [1], "den": "1000*s + 1"}, "delay": 5},
    "integrating": {"tf": {"num": [1], "den": "s*(s + 1)"}},
    "delay_dominant": {"tf": {"num": [1], "den": "s + 1"}, "delay": 10},
}


def test_default_horizon_scaled_to_slow_fotd_plant_settles():
    result = tune(load_spec({**FOTD, "search": SMALL}))
    (sc,) = result.spec["scenarios"]
    # T + L = 70 s: the horizon covers ten of them, at 2,000 samples (dt <= L/20)
    assert sc["horizon"] == 700.0 and sc["dt"] == 0.35
    (d,) = result.scenario_defaults
    assert (d.scenario, d.dt, d.horizon, d.dt_from, d.horizon_from) == ("nominal", 0.35, 700.0, "plant", "plant")
    assert "T 60 s, L 10 s" in d.reason
    assert result.metrics["nominal"]["sse"] < 0.02  # was 0.29 at the fixed 20 s
    ti = result.gains["loop0"]["Kp"] / result.gains["loop0"]["Ki"]
    assert ti < 200.0  # was about 2,400 s, on the Ki lower bound
    assert any("horizon 700 s" in h and "derived from the plant" in h for h in result.diagnosis.hints)
    assert not any("bound" in h for h in result.diagnosis.hints)


@pytest.mark.parametrize("name, dt, horizon", [
    ("fast", 5e-5, 0.1),            # T 0.01 s, no delay: 10 T, 2,000 samples
    ("slow", 0.55, 11000.0),        # T 1000 s, L 5 s: 10 (T + L); L/20 would be 44,000 samples: capped at 20,000
    ("integrating", 0.02, 40.0),    # integrator + 1 s lag: L = 0.5 s (half rule), S = 8 L
    ("delay_dominant", 0.055, 110.0),  # T 1 s, L 10 s
])
def test_default_horizon_rule_on_fast_slow_integrating_and_delay_dominant_plants(name, dt, horizon):
    spec, (d,) = scenario_defaults(load_spec({"plant": PLANTS[name], "loops": [{"type": "pi"}]}))
    (sc,) = spec.scenarios
    assert (sc.dt, sc.horizon) == (d.dt, d.horizon) == (dt, horizon)
    assert 2 <= sc.n_steps <= STEP_CAP
    # the classical (SIMC) PI loop on this plant settles within the derived horizon; the fixed
    # 20 s of old did not for the slow plant
    plant = build_plant(spec.plant)
    sim = Simulator(spec, plant)
    gains = tune_classical(spec, plant, "simc").gains
    assert unsettled_scenarios(sim, sim.layout.from_dict(gains)) == []


def test_fixed_20s_horizon_leaves_the_slow_plant_unsettled():
    # the check above can fail: the same SIMC loop on the slow plant, at the former defaults
    spec = load_spec({"plant": PLANTS["slow"], "loops": [{"type": "pi"}], "scenario": {"dt": 0.01, "horizon": 20}})
    plant = build_plant(spec.plant)
    sim = Simulator(spec, plant)
    found = unsettled_scenarios(sim, sim.layout.from_dict(tune_classical(spec, plant, "simc").gains))
    assert [i for i, _ in found] == [0]


def test_cascade_horizon_from_outer_loop_dt_from_inner_loop():
    # inner: u -> v = 1/(0.1 s + 1); outer: v -> x = 1/(20 s + 1) (two outputs of one state space)
    spec = load_spec({
        "plant": {"ss": {"A": [[-10, 0], [0.05, -0.05]], "B": [[10], [0]], "C": [[0, 1], [1, 0]], "D": [[0], [0]],
                         "outputs": ["x", "v"]}},
        "loops": [{"name": "outer", "type": "pi", "measure": "x"}, {"name": "inner", "type": "pi", "measure": "v"}],
    })
    scale = plant_scale(spec, build_plant(spec.plant))
    outer, inner = scale.loops
    assert outer.settle > 100 * inner.settle
    assert scale.horizon >= 10 * outer.settle and scale.dt <= 10 * inner.settle / 2000


def test_explicit_scenarios_are_kept_bit_for_bit():
    spec = load_spec({**FOTD, "scenarios": [{"dt": 0.01, "horizon": 20}, {"name": "b", "dt": 0.5, "horizon": 600}]})
    same, records = scenario_defaults(spec)
    assert same is spec and records == []
    assert Simulator(spec).spec is spec


def test_derived_horizon_starts_after_the_last_event():
    spec, (d,) = scenario_defaults(load_spec({**FOTD, "scenario": {"reference": {"kind": "step", "time": 50}}}))
    assert d.horizon == 750.0 and "after the last event at 50 s" in d.reason


def test_a_step_far_beyond_the_plants_settling_window_is_refused_not_simulated_to_its_own_time():
    """Regression: a step at 1 s on a plant of 1e-12 s got the horizon 1 s (rounding up to two digits swallowed the
    1e-11 s window after it), so the step was never simulated and 'tune --quick' passed with cost 0."""
    from gaintune.errors import SpecError

    spec = load_spec({"plant": {"tf": {"num": [1], "den": "1e-12*s + 1"}}, "loops": [{"type": "pi"}],
                      "scenarios": [{"name": "late", "reference": {"kind": "step", "amplitude": 1.0, "time": 1.0}}]})
    with pytest.raises(SpecError) as e:
        scenario_defaults(spec)
    assert e.value.field == "scenarios[0]" and "put the event nearer t = 0" in e.value.message
    near = spec.model_copy(update={"scenarios": [spec.scenarios[0].model_copy(
        update={"reference": spec.scenarios[0].reference.model_copy(update={"time": 0.0})})]})
    (sc,) = scenario_defaults(near)[0].scenarios
    assert sc.horizon / sc.dt >= 50


def test_a_late_step_that_would_raise_dt_past_the_loops_time_scale_is_refused():
    """Regression: a step at 1e9 s on a 1 s plant got dt = 51,000 s (20,000 steps to reach it, the horizon rounded up
    to 1.1e9 s so 1,960 samples followed it), and the loop was simulated and verified at that sample time."""
    from gaintune.errors import SpecError

    def spec(t):
        return load_spec({"plant": {"tf": {"num": [1], "den": "s + 1"}}, "loops": [{"type": "pi"}],
                          "scenarios": [{"name": "late", "reference": {"kind": "step", "amplitude": 1.0, "time": t}}]})

    with pytest.raises(SpecError) as e:
        scenario_defaults(spec(1e9))
    assert e.value.field == "scenarios[0]" and "dt 51000 s" in e.value.message
    (sc,) = scenario_defaults(spec(2e3))[0].scenarios  # 200 settling windows late: still resolved
    assert 10.0 / sc.dt >= 50


def test_unsettled_explicit_scenario_warns_naming_scenario_and_horizon():
    spec = load_spec({**FOTD, "scenario": {"name": "short", "dt": 0.1, "horizon": 20}, "search": SMALL})
    result = tune(spec)
    assert result.spec["scenarios"][0]["horizon"] == 20 and result.scenario_defaults == []  # kept as given
    (hint,) = [h for h in result.diagnosis.hints if "has not settled" in h]
    assert "scenario 'short'" in hint and "error left is" in hint
    assert "scenarios[0].horizon: 700" in hint  # at least the horizon derived from the plant
    # the verification report says it too
    assert any("scenario 'short' has not settled" in n for n in result.verification.notes)


def test_integral_time_longer_than_horizon_flagged():
    # the trap's answer: Ki on a bound far below the rule, Ti about 2,400 s on a 20 s horizon
    spec = load_spec({**FOTD, "loops": [{"type": "pi", "gains": {"Ki": {"bounds": [1e-4, 1e-3]}}}],
                      "scenario": {"dt": 0.1, "horizon": 20}, "search": SMALL})
    result = tune(spec)
    (hint,) = [h for h in result.diagnosis.hints if "integral time" in h]
    assert hint.startswith("loops[0] (loop0): the integral time Ti = Kp/Ki") and "horizon (20 s)" in hint
    # the lower-bound hint on Ki would point the wrong way (widen the bounds): it is left out
    assert not any("Ki" in h and "lower search bound" in h for h in result.diagnosis.hints)
    # Ti = 51 s: flagged on the 20 s horizon, not on 600 s
    assert len(integral_time_hints(spec, {"loop0": {"Kp": 1.37, "Ki": 0.027}})) == 1
    long = load_spec({**FOTD, "scenario": {"dt": 0.5, "horizon": 600}})
    assert integral_time_hints(long, {"loop0": {"Kp": 1.37, "Ki": 0.027}}) == []
