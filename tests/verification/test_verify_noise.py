"""Noise sensitivity Mks (requirements.mks_max, issue 12): the figure against python-control and
hand-derived loop algebra, the plant-derived ``auto`` limit, the search estimate against the
verdict, and the requirement line."""

from __future__ import annotations

import control as ct
import numpy as np
import pytest
from pydantic import ValidationError

from gaintune.controllers.layout import GainLayout
from gaintune.plants.noise_limit import AUTO_SPEEDUP, noise_limits, path_relative_degree
from gaintune.plants.plant import build_plant
from gaintune.spec import load_spec
from gaintune.verification import quick_margins, verify

FIRST_ORDER = {"tf": {"num": [2.0], "den": [5.0, 1.0]}}


def spec_of(plant, loops, dt=0.01, **kw):
    return load_spec({"plant": plant, "loops": loops, "scenario": {"dt": dt, "horizon": 400 * dt}, **kw})


def _peak(f, w):
    return float(np.max(np.abs(f(w))))


def test_mks_of_a_continuous_pi_loop_matches_python_control():
    dt = 0.01
    spec = spec_of(FIRST_ORDER, [{"type": "pi"}], dt, verify={"sampled": False}, requirements={"mks_max": None})
    rep = verify(spec, {"loop0": {"Kp": 3.0, "Ki": 1.5}}, nonlinear=False)
    s = ct.tf("s")
    G = 2.0 / (5.0 * s + 1.0)
    C = 3.0 + 1.5 / s
    T = dt / 2  # the continuous analysis adds half a sample of delay
    w = np.logspace(-3, 5, 200_001)

    def CS(w):
        return C(1j * w) / (1.0 + C(1j * w) * G(1j * w) * np.exp(-1j * w * T))

    assert rep.loops[0].mks == pytest.approx(_peak(CS, w), rel=1e-6)
    assert rep.loops[1].mks is None  # the plant-input break point has no measurement of its own


def test_mks_of_the_sampled_loop_matches_python_control_c2d():
    dt = 0.2
    spec = spec_of(FIRST_ORDER, [{"type": "pi"}], dt, requirements={"mks_max": None})
    kp, ki = 3.0, 1.5
    rep = verify(spec, {"loop0": {"Kp": kp, "Ki": ki}}, nonlinear=False)
    Gd = ct.c2d(ct.tf([2.0], [5.0, 1.0]), dt, "zoh")
    z = ct.tf([1, 0], [1], dt)
    Cd = kp + ki * dt * z / (z - 1)  # the simulator's backward-Euler integral dt/(1 - z^-1)
    w = np.linspace(1e-4, np.pi / dt, 200_001)

    def CS(w):
        return Cd(np.exp(1j * w * dt)) / (1.0 + Cd(np.exp(1j * w * dt)) * Gd(np.exp(1j * w * dt)))

    assert rep.loops[0].mks == pytest.approx(_peak(CS, w), rel=1e-6)


def test_mks_of_a_cascade_outer_loop_is_noise_to_plant_input_with_the_inner_loop_closed():
    # two-output plant: u -> x1 (inner), x1 -> x2 (outer); continuous loop, T = dt/2 at u
    A = [[-2.0, 0.0], [1.0, -0.5]]
    plant = {"ss": {"A": A, "B": [[2.0], [0.0]], "C": [[1.0, 0.0], [0.0, 1.0]], "outputs": ["a", "b"]}}
    loops = [{"name": "outer", "type": "pi", "measure": "b"}, {"name": "inner", "type": "pi", "measure": "a"}]
    dt = 1e-3
    spec = spec_of(plant, loops, dt, verify={"sampled": False}, requirements={"mks_max": None})
    g = {"outer": {"Kp": 1.2, "Ki": 0.4}, "inner": {"Kp": 4.0, "Ki": 6.0}}
    rep = verify(spec, g, nonlinear=False)
    s = ct.tf("s")
    G1 = 2.0 / (s + 2.0)  # u -> a
    G2 = G1 / (s + 0.5)  # u -> b
    Ci, Co = 4.0 + 6.0 / s, 1.2 + 0.4 / s
    T = dt / 2

    def outer_noise(w):  # u = -Ci Co n / (1 + Ci G1 + Ci Co G2), plant delay e^{-sT} at u
        sw = 1j * w
        d = np.exp(-sw * T)
        return Ci(sw) * Co(sw) / (1 + Ci(sw) * G1(sw) * d + Ci(sw) * Co(sw) * G2(sw) * d)

    def inner_noise(w):  # noise on a: u = -Ci (n + G1 u) - Ci Co G2 u
        sw = 1j * w
        d = np.exp(-sw * T)
        return Ci(sw) / (1 + Ci(sw) * G1(sw) * d + Ci(sw) * Co(sw) * G2(sw) * d)

    w = np.logspace(-3, 6, 200_001)
    by_loop = {f.loop: f.mks for f in rep.loops if f.break_point == "controller_output"}
    assert by_loop["outer"] == pytest.approx(_peak(outer_noise, w), rel=1e-5)
    assert by_loop["inner"] == pytest.approx(_peak(inner_noise, w), rel=1e-5)


@pytest.mark.parametrize("kp", [0.5, 2.0, 8.0])
def test_search_estimate_of_mks_agrees_with_the_verdict_figure(kp):
    spec = spec_of(FIRST_ORDER, [{"type": "pid"}], 0.05)
    plant = build_plant(spec.plant)
    layout = GainLayout(spec, plant.states)
    gains = {"loop0": {"Kp": kp, "Ki": 0.5 * kp, "Kd": 0.3 * kp}}
    full = layout.from_dict(gains)
    q = quick_margins(spec, plant, layout, full[None, :])
    exact = verify(spec, gains, nonlinear=False).loops[0].mks
    assert q.mks[0, 0] == pytest.approx(exact, rel=1e-3)


def test_auto_limit_is_ten_over_the_static_gain_for_a_delay_free_first_order_path():
    spec = spec_of(FIRST_ORDER, [{"type": "pi"}])
    lim = noise_limits(spec, build_plant(spec.plant).linearize())[0]
    assert lim.limit == pytest.approx(AUTO_SPEEDUP / 2.0)
    assert lim.source.startswith("auto:")


@pytest.mark.parametrize("plant, why", [
    ({"tf": {"num": [2.0], "den": [5.0, 1.0]}, "delay": 0.5}, "dead time"),
    ({"tf": {"num": [1.0], "den": "(s+1)^2"}}, "phase lag"),
    ({"tf": {"num": [1.0], "den": [1.0, 0.0]}}, "integrating"),
    ({"tf": {"num": [1.0], "den": [1.0, -1.0]}}, "unstable"),
])
def test_auto_sets_no_limit_where_the_plant_bounds_the_speed_or_has_no_static_gain(plant, why):
    spec = spec_of(plant, [{"type": "pi"}])
    lim = noise_limits(spec, build_plant(spec.plant).linearize())[0]
    assert lim.limit is None and why in lim.source


def test_relative_degree_from_markov_parameters():
    A = np.array([[-1.0, 0.0], [1.0, -2.0]])
    B = np.array([[1.0], [0.0]])
    assert path_relative_degree(A, B, np.array([1.0, 0.0]), 0.0) == 1
    assert path_relative_degree(A, B, np.array([0.0, 1.0]), 0.0) == 2
    assert path_relative_degree(A, B, np.array([0.0, 1.0]), 0.3) == 0


def test_explicit_and_per_loop_limits_and_an_unknown_loop_name():
    spec = spec_of(FIRST_ORDER, [{"name": "a", "type": "pi"}], requirements={"mks_max": 3.0})
    assert noise_limits(spec, build_plant(spec.plant).linearize())[0].limit == 3.0
    spec = spec_of(FIRST_ORDER, [{"name": "a", "type": "pi"}], requirements={"mks_max": {"a": 4.0}})
    assert noise_limits(spec, build_plant(spec.plant).linearize())[0].limit == 4.0
    with pytest.raises(ValidationError, match=r"requirements.mks_max\n  unknown loop\(s\)"):
        spec_of(FIRST_ORDER, [{"name": "a", "type": "pi"}], requirements={"mks_max": {"b": 4.0}})
    with pytest.raises(ValidationError, match="finite and > 0"):
        spec_of(FIRST_ORDER, [{"name": "a", "type": "pi"}], requirements={"mks_max": 0.0})


def test_mks_requirement_line_fails_above_the_limit_and_names_the_loop():
    spec = spec_of(FIRST_ORDER, [{"name": "a", "type": "pi"}], requirements={"mks_max": 2.0})
    rep = verify(spec, {"a": {"Kp": 3.0, "Ki": 1.0}}, nonlinear=False)
    line = next(q for q in rep.requirements if q.requirement == "mks_max")
    assert not line.passed and line.loop == "a" and line.limit == 2.0 and line.value > 3.0
    assert rep.verdict == "fail" and any(r.startswith("mks_max") for r in rep.reasons)
    ok = verify(spec, {"a": {"Kp": 1.0, "Ki": 0.3}}, nonlinear=False)
    assert next(q for q in ok.requirements if q.requirement == "mks_max").passed


def test_integrating_delay_free_loop_notes_that_auto_sets_no_noise_limit():
    spec = spec_of({"tf": {"num": [1.0], "den": [1.0, 0.0]}}, [{"name": "a", "type": "pi"}])
    rep = verify(spec, {"a": {"Kp": 1.0, "Ki": 0.1}}, nonlinear=False)
    assert not any(q.requirement == "mks_max" for q in rep.requirements)
    assert any("no automatic noise-sensitivity limit" in n for n in rep.notes)
