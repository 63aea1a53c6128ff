"""Reverse-acting loops (negative path gain): direction resolution, signed layout, mirror-exact simulation, tuning."""

from __future__ import annotations

import numpy as np
import pytest
from pydantic import ValidationError

from gaintune.classical import auto_bounds, tune_classical
from gaintune.controllers.direction import loop_directions, resolve_directions
from gaintune.controllers.layout import GainLayout
from gaintune.controllers.pid import pid_params
from gaintune.errors import GainError, SpecError
from gaintune.evaluation.search_box import search_box, search_layout
from gaintune.plants import build_plant
from gaintune.sim import Simulator
from gaintune.spec import load_spec

#: -2 e^{-10 s}/(60 s + 1): the thermal FOTD benchmark with its sign flipped (e.g. a cooler).
REVERSE_FOTD = {
    "name": "reverse_fotd",
    "plant": {"tf": {"num": [-2], "den": [60, 1]}, "delay": 10},
    "loops": [{"name": "main", "type": "pi"}],
    "actuator": {"limits": [-50, 50]},
    "scenarios": [
        {"name": "setpoint_step", "dt": 0.5, "horizon": 600, "reference": {"kind": "step", "amplitude": 5.0, "time": 10}},
        {
            "name": "load_step", "dt": 0.5, "horizon": 600, "reference": {"kind": "none"},
            "disturbance": {"kind": "step", "entry": "input", "amplitude": -10.0, "time": 10},
        },
    ],
    "objective": {"measure": "iae", "effort_weight": 0.001},
    "requirements": {"gm_min_db": 6, "pm_min_deg": 45, "ms_max": 1.6},
    "search": {"budget": 1500, "seed": 0, "n_envs": 32},
    "verify": {"robust_samples": 0},
}


def _spec(data: dict, **changes) -> object:
    return load_spec({**data, **changes})


def _tf_spec(num, den, loop: dict | None = None, **extra):
    return load_spec({"plant": {"tf": {"num": num, "den": den}}, "loops": [loop or {"type": "pi"}], **extra})


# ------------------------------------------------------------- resolution


@pytest.mark.parametrize(
    ("num", "den", "sign", "rule"),
    [
        ([-2], [60, 1], -1, "static_gain"),
        ([2], [60, 1], 1, "static_gain"),
        ([-3], [1, 0], -1, "velocity_gain"),  # integrating: the sign of K in K/s
        ([0.5], [2, 1, 0], 1, "velocity_gain"),
        ([-1, 1], [1, 2, 1], 1, "static_gain"),  # inverse response: the static gain decides
        ([1], [1, -1], 1, "unstable"),  # 1/(s-1): static gain -1, but only Kp > 1 stabilises
        ([1], [1, 0, -1], 1, "unstable"),
    ],
)
def test_direction_auto_matches_static_gain_sign(num, den, sign, rule):
    spec = _tf_spec(num, den)
    plant = build_plant(spec.plant)
    (d,) = resolve_directions(spec, plant)
    assert (d.sign, d.rule, d.source) == (sign, rule, "auto")
    assert loop_directions(spec, plant) == (sign,)
    # every layout of the spec resolves the same direction, with or without the plant
    assert GainLayout(spec, plant.states).directions == (sign,) == search_layout(spec, plant).directions


def test_direction_reason_names_the_rule_and_gain():
    (d,) = resolve_directions(_tf_spec([-2], [60, 1]))
    assert d.reason == "plant static gain -2" and d.gain == pytest.approx(-2.0)
    (d,) = resolve_directions(_tf_spec([-3], [1, 0]))
    assert "integrating plant, velocity gain -3" in d.reason and "-3/s" in d.reason


def test_direction_of_a_nonlinear_plant_is_read_at_its_operating_point():
    # dh/dt = (q_out(h) - b u)/A: a drain valve u lowers the level -> reverse-acting level loop
    spec = load_spec({
        "plant": {
            "ode": {"states": ["h"], "input": "u", "rhs": {"h": "(2 - b*u - 0.5*sqrt(max(h, 0)))/10"},
                    "outputs": {"level": "h"}, "x0": {"h": 4}},
            "params": {"b": 1.0},
        },
        "loops": [{"type": "pi"}],
    })
    (d,) = resolve_directions(spec)
    assert d.sign == -1 and d.rule == "static_gain" and d.gain < 0


def test_explicit_direction_overrides_auto():
    spec = _tf_spec([-2], [60, 1], {"type": "pi", "direction": "direct"})
    assert loop_directions(spec) == (1,)
    (d,) = resolve_directions(spec)
    assert d.source == "set"
    spec = _tf_spec([2], [60, 1], {"type": "pi", "direction": "reverse"})
    assert loop_directions(spec) == (-1,)


def test_ambiguous_direction_raises_spec_error():
    # s/(s+1)^2: zero static gain, the sign cannot be read from the plant
    spec = _tf_spec([1, 0], [1, 2, 1])
    plant = build_plant(spec.plant)
    with pytest.raises(SpecError) as exc:
        GainLayout(spec, plant.states)
    assert exc.value.field == "loops[0].direction"
    assert "static gain" in exc.value.message and "zero" in exc.value.message
    assert "direction: direct" in exc.value.message and "direction: reverse" in exc.value.message
    # setting it resolves the ambiguity
    fixed = _tf_spec([1, 0], [1, 2, 1], {"type": "pi", "direction": "direct"})
    assert GainLayout(fixed, plant.states).directions == (1,)


def test_direction_changing_sign_over_the_randomised_box_raises():
    spec = load_spec({
        "plant": {"tf": {"num": ["K"], "den": [10, 1]}, "params": {"K": 1.0}},
        "loops": [{"type": "pi"}],
        "randomize": {"params": {"K": [-0.5, 2.0]}},
    })
    with pytest.raises(SpecError, match="changes sign over the randomize.params box") as exc:
        loop_directions(spec)
    assert exc.value.field == "loops[0].direction"
    ok = load_spec({**spec.model_dump(), "randomize": {"params": {"K": [0.5, 2.0]}}})
    assert loop_directions(ok) == (1,)


def test_reverse_on_an_lq_loop_is_rejected():
    with pytest.raises(ValidationError, match="direction: reverse does not apply"):
        _tf_spec([1], [1, 1], {"type": "lqr", "direction": "reverse"})
    spec = _tf_spec([-1], [1, 1], {"type": "lqr"})  # auto: LQ loops have no direction
    assert resolve_directions(spec)[0].rule == "lq"


# ------------------------------------------------------------------ layout


def test_layout_searches_magnitudes_and_gives_signed_gains():
    spec = _tf_spec([-2], [60, 1], {"name": "main", "type": "pid", "gains": {"Kp": {"bounds": [0.1, 10]}}})
    plant = build_plant(spec.plant)
    lay = GainLayout(spec, plant.states)
    t = lay.initial_tuned()
    assert np.all(t > 0)
    full = lay.full(t)
    assert np.all(full < 0)
    named = lay.to_dict(full)
    assert set(named["main"]) == {"Kp", "Ki", "Kd"} and all(v < 0 for v in named["main"].values())
    back = lay.from_dict(named)
    np.testing.assert_array_equal(back, full)
    # signed entries of a full vector map to the same gains (callers do full[tuned_idx])
    np.testing.assert_array_equal(lay.full(full[lay.tuned_idx]), full)
    np.testing.assert_array_equal(lay.tuned_of(full), t)
    np.testing.assert_allclose(lay.tuned_to_action(full[lay.tuned_idx]), lay.tuned_to_action(t))
    with pytest.raises(GainError) as exc:
        lay.from_dict({"main": {"Kp": 1.0, "Ki": -0.1, "Kd": -1.0}})
    assert exc.value.field == "gains.main.Kp"
    assert exc.value.message == (
        "must be < 0, got 1: this loop is reverse-acting (plant static gain -2); "
        "give a negative value or set loops[0].direction: direct"
    )


def test_ideal_form_reverse_loop_has_negative_kp_and_positive_times():
    spec = _tf_spec([-2], [60, 1], {"name": "main", "type": "pid", "form": "ideal"})
    lay = GainLayout(spec, build_plant(spec.plant).states)
    g = lay.to_dict(lay.full(lay.initial_tuned()))["main"]
    assert g["Kp"] < 0 and g["Ti"] > 0 and g["Td"] > 0
    with pytest.raises(GainError, match="Ti is a time or weight"):
        lay.from_dict({"main": {"Kp": -1.0, "Ti": -5.0, "Td": 1.0}})
    p = pid_params(spec.loops[0], {"Kp": -1.0, "Ti": 20.0, "Td": 2.0})
    assert p.Ki == pytest.approx(-0.05) and p.Kd == pytest.approx(-2.0) and p.Tf == pytest.approx(0.2)


def test_fixed_and_initial_values_are_signed():
    loop = {"name": "main", "type": "pi", "gains": {"Kp": {"value": -1.0, "bounds": [0.1, 10]}, "Ki": {"tune": False, "value": -0.02}}}
    spec = _tf_spec([-2], [60, 1], loop)
    lay = GainLayout(spec, build_plant(spec.plant).states)
    assert lay.initial_tuned().tolist() == [1.0]
    assert lay.full(lay.initial_tuned()).tolist() == [-1.0, -0.02]
    bad = _tf_spec([-2], [60, 1], {**loop, "gains": {"Kp": {"value": 1.0, "bounds": [0.1, 10]}}})
    with pytest.raises(SpecError, match="reverse-acting") as exc:
        GainLayout(bad, build_plant(bad.plant).states)
    assert exc.value.field == "loops[0].gains.Kp.value"


def test_pid_params_times_are_positive_for_negative_gains():
    spec = _tf_spec([-2], [60, 1], {"type": "pid", "anti_windup": "back_calculation"})
    loop = spec.loops[0]
    pos = pid_params(loop, {"Kp": 2.0, "Ki": 0.1, "Kd": 4.0})
    neg = pid_params(loop, {"Kp": -2.0, "Ki": -0.1, "Kd": -4.0})
    assert neg.Tf == pos.Tf == pytest.approx(0.2)  # Td/N, Td = Kd/Kp = 2
    assert neg.Tt == pos.Tt == pytest.approx(np.sqrt(20.0 * 2.0))
    assert (neg.Kp, neg.Ki, neg.Kd) == (-pos.Kp, -pos.Ki, -pos.Kd)
    fixed_tf = _tf_spec([-2], [60, 1], {"type": "pid", "filter": {"Tf": 0.3}}).loops[0]
    assert pid_params(fixed_tf, {"Kp": -2.0, "Ki": -0.1, "Kd": -4.0}).Tf == 0.3


# -------------------------------------------------------------- simulation


@pytest.mark.parametrize("anti_windup", ["none", "clamping", "back_calculation"])
@pytest.mark.parametrize("ctype", ["pi", "pid"])
def test_reverse_loop_mirrors_direct_loop_in_simulation(anti_windup, ctype):
    """A reverse loop on -G is the mirror image of the direct loop on G: same y, u negated (saturation mirrored)."""
    lo, hi = -3.0, 8.0  # asymmetric, so a wrong mirror would show; the step saturates the PI
    scenario = {
        "dt": 0.5, "horizon": 300, "reference": {"kind": "step", "amplitude": 5.0, "time": 5},
        "disturbance": {"kind": "step", "entry": "output", "amplitude": 1.0, "time": 150},
    }
    gains = {"Kp": 1.8, "Ki": 0.08} | ({"Kd": 3.0} if ctype == "pid" else {})
    runs = {}
    for sign in (1, -1):
        spec = load_spec({
            "plant": {"tf": {"num": [2 * sign], "den": [60, 1]}, "delay": 10},
            "loops": [{"name": "main", "type": ctype, "anti_windup": anti_windup}],
            "actuator": {"limits": [lo, hi] if sign > 0 else [-hi, -lo]},
            "scenario": scenario,
        })
        sim = Simulator(spec)
        assert sim.layout.directions == (sign,)
        full = sim.layout.from_dict({"main": {k: sign * v for k, v in gains.items()}})
        runs[sign] = sim.run(full[None], traces=True)
    d, r = runs[1], runs[-1]
    u = d.traces["u"][0]
    assert u.max() == pytest.approx(hi) and u.min() < hi  # the actuator saturates, then leaves saturation
    np.testing.assert_allclose(r.traces["y.main"], d.traces["y.main"], rtol=0, atol=1e-12)
    np.testing.assert_allclose(r.traces["u"], -d.traces["u"], rtol=0, atol=1e-12)
    for name in ("iae", "ise", "itae", "effort", "tv", "overshoot", "settling_time", "sat_frac", "load_iae", "y_final"):
        np.testing.assert_allclose(r.metrics[name], d.metrics[name], rtol=1e-12, atol=1e-12, err_msg=name)


def test_direct_gains_on_a_reverse_plant_diverge():
    spec = _spec(REVERSE_FOTD, loops=[{"name": "main", "type": "pi", "direction": "direct"}],
                 actuator={"limits": None})
    sim = Simulator(spec)
    res = sim.run(sim.layout.from_dict({"main": {"Kp": 1.0, "Ki": 0.02}})[None])
    assert bool(res.metrics["diverged"][0]) or float(res.metrics["iae"][0]) > 1e3


# ------------------------------------------------------------ classical rules


@pytest.mark.parametrize("method", ["zn_step", "zn_ultimate", "simc", "amigo", "imc"])
def test_classical_rules_give_mirror_gains_for_a_negative_plant(method):
    neg = _tf_spec([-2], [60, 1], {"name": "main", "type": "pid"}, scenario={"dt": 0.5, "horizon": 600})
    pos = _tf_spec([2], [60, 1], {"name": "main", "type": "pid"}, scenario={"dt": 0.5, "horizon": 600})
    gn = tune_classical(neg, build_plant(neg.plant), method).gains["main"]
    gp = tune_classical(pos, build_plant(pos.plant), method).gains["main"]
    assert gn == pytest.approx({k: -v for k, v in gp.items()}, rel=1e-6)


def test_auto_bounds_are_centred_on_magnitudes():
    spec = _spec(REVERSE_FOTD)
    plant = build_plant(spec.plant)
    g = tune_classical(spec, plant, "simc").gains
    b = auto_bounds(spec, g)
    for name, v in g["main"].items():
        assert v < 0
        lo, hi = b[("main", name)]
        assert np.sqrt(lo * hi) == pytest.approx(-v)
    box = search_box(spec, plant)
    lay = box.layout
    np.testing.assert_allclose(lay.full(lay.initial_tuned()), [box.centre["main"]["Kp"], box.centre["main"]["Ki"]])
    assert box.centre["main"]["Kp"] < 0 and box.centre["main"]["Ki"] < 0


# ------------------------------------------------------------------ cascade

#: Inner path u -> y1 = -1/(s+1) (negative), outer y1 -> y2 = 1/(5s+1) (so u -> y2 is negative too).
CASCADE = {
    "plant": {"ss": {"A": [[-1, 0], [0.2, -0.2]], "B": [[-1], [0]], "C": [[1, 0], [0, 1]], "outputs": ["y1", "y2"]}},
    "loops": [
        {"name": "outer", "measure": "y2", "type": "pi", "output_limits": [-5, 5]},
        {"name": "inner", "measure": "y1", "type": "pi"},
    ],
    "scenario": {"dt": 0.05, "horizon": 60, "reference": {"kind": "step", "amplitude": 1.0, "time": 1}},
}


def test_cascade_with_reverse_inner_and_direct_outer():
    spec = load_spec(CASCADE)
    plant = build_plant(spec.plant)
    outer, inner = resolve_directions(spec, plant)
    assert inner.sign == -1 and inner.reason == "plant static gain -1"
    assert outer.sign == 1 and "inner loop closed" in outer.reason  # y2/y1 at s = 0 is +1
    res = tune_classical(spec, plant, "simc")
    assert all(v < 0 for v in res.gains["inner"].values())
    assert all(v > 0 for v in res.gains["outer"].values())
    assert res.fotd["outer"].K > 0  # the outer loop sees the correctly closed (reverse) inner loop
    sim = Simulator(spec)
    out = sim.run(sim.layout.from_dict(res.gains)[None], traces=True)
    assert not bool(out.metrics["diverged"][0])
    assert out.traces["y.outer"][0, -1] == pytest.approx(1.0, abs=1e-3)


def test_integrating_outer_loop_around_a_reverse_inner_loop():
    # u -> speed = -1/(s+1) (reverse), speed -> position = 1/s: the outer path is integrating, positive
    spec = load_spec({
        "plant": {"ss": {"A": [[-1, 0], [1, 0]], "B": [[-1], [0]], "C": [[1, 0], [0, 1]], "outputs": ["speed", "pos"]}},
        "loops": [{"name": "pos", "measure": "pos", "type": "p"}, {"name": "speed", "measure": "speed", "type": "pi"}],
    })
    pos, speed = resolve_directions(spec)
    assert speed.sign == -1 and speed.rule == "static_gain"  # the unobservable position integrator is ignored
    assert pos.sign == 1 and pos.rule == "velocity_gain"


# --------------------------------------------------------------------- tune


@pytest.fixture(scope="module")
def reverse_tuned():
    from gaintune.search import tune

    return tune(_spec(REVERSE_FOTD))


def test_reverse_acting_fotd_is_tuned_and_passes(reverse_tuned):
    from gaintune.verification import verify

    r = reverse_tuned
    g = r.gains["main"]
    assert g["Kp"] < 0 and g["Ki"] < 0
    assert r.verification is not None and r.verification.verdict == "pass", r.verification.reasons
    assert r.accepted_gains == r.gains
    # independent check: the signed gains simulate stable and settle on the setpoint
    spec = _spec(REVERSE_FOTD)
    sim = Simulator(spec)
    step = sim.run(sim.layout.from_dict(r.gains)[None], scenario=0, traces=True)
    assert not bool(step.metrics["diverged"][0])
    assert step.traces["y.main"][0, -1] == pytest.approx(5.0, abs=0.05)
    assert verify(spec, r.gains).verdict == "pass"


def test_direction_override_direct_on_negative_plant_fails_verification_with_reason():
    from gaintune.verification import verify

    spec = _spec(REVERSE_FOTD, loops=[{"name": "main", "type": "pi", "direction": "direct"}])
    plant = build_plant(spec.plant)
    g = tune_classical(spec, plant, "simc").gains["main"]
    assert g["Kp"] > 0 and g["Ki"] > 0  # the user forced direct: the rule gives direct gains
    rep = verify(spec, {"main": g})
    assert rep.verdict == "fail"
    assert any("unstable" in reason for reason in rep.reasons)


def test_forced_wrong_direction_is_named_in_the_diagnosis():
    """Regression: forcing direction: direct on a negative plant said only 'no stabilising gains were found'."""
    from gaintune.search.diagnosis import direction_hints

    spec = _spec(REVERSE_FOTD, loops=[{"name": "main", "type": "pi", "direction": "direct"}])
    (hint,) = direction_hints(spec, build_plant(spec.plant))
    assert "direction: direct" in hint and "-2" in hint and "set direction: reverse or auto" in hint
    ok = _spec(REVERSE_FOTD, loops=[{"name": "main", "type": "pi", "direction": "reverse"}])
    assert direction_hints(ok, build_plant(ok.plant)) == []
