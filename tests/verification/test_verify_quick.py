"""The cheap batched margin estimate and requirement penalty (RL reward) against the exact verification."""

from __future__ import annotations

import math

import numpy as np
import pytest
from plant_fixtures import MOTOR

from gaintune.controllers.layout import GainLayout
from gaintune.controllers.pid import pid_params
from gaintune.plants.plant import build_plant
from gaintune.spec import load_spec
from gaintune.verification import quick_margins, requirement_violation, verify
from gaintune.verification.cascade import pid_arrays
from gaintune.verification.quick import UNSTABLE_VIOLATION

MOTOR_LOOPS = [
    {"name": "position", "type": "p", "measure": "th"},
    {"name": "speed", "type": "pi", "measure": "w"},
    {"name": "current", "type": "pi", "measure": "i"},
]
MOTOR_GAINS = {"position": {"Kp": 10.0}, "speed": {"Kp": 2.0, "Ki": 40.0}, "current": {"Kp": 10.0, "Ki": 1000.0}}

CASES = [
    ({"tf": {"num": [1], "den": "(s+1)^3"}}, [{"type": "pi"}], {"loop0": {"Kp": 1.14, "Ki": 0.454}}, 0.01),
    ({"tf": {"num": [1], "den": "(s+1)^3"}}, [{"type": "pid"}], {"loop0": {"Kp": 2.0, "Ki": 1.0, "Kd": 1.0}}, 0.01),
    ({"tf": {"num": [1], "den": [1, 0]}, "delay": 0.2}, [{"type": "p"}], {"loop0": {"Kp": 2.0}}, 0.01),
    ({"tf": {"num": [1], "den": [1, 1]}, "delay": 1.0}, [{"type": "pi"}], {"loop0": {"Kp": 0.5, "Ki": 0.4}}, 0.05),
    ({"tf": {"num": [1], "den": [1, -1]}}, [{"type": "p"}], {"loop0": {"Kp": 2.0}}, 0.01),
    (MOTOR, MOTOR_LOOPS, MOTOR_GAINS, 1e-4),
]


def setup(plant, loops, dt=0.01, sampled=True, **kw):
    """verify.sampled: the sampled loop (the default) or the continuous one plus dt/2 (false)."""
    kw["verify"] = {"sampled": sampled, **kw.get("verify", {})}
    spec = load_spec({"plant": plant, "loops": loops, "scenario": {"dt": dt, "horizon": 200 * dt}, **kw})
    p = build_plant(spec.plant)
    return spec, p, GainLayout(spec, p.states)


@pytest.mark.parametrize("sampled", [True, False])
@pytest.mark.parametrize("plant, loops, gains, dt", CASES)
def test_quick_estimate_agrees_with_exact_verify(plant, loops, gains, dt, sampled):
    spec, p, lay = setup(plant, loops, dt, sampled)
    rep = verify(spec, gains, nonlinear=False, plant=p, layout=lay)
    q = quick_margins(spec, p, lay, lay.from_dict(gains)[None, :])
    assert bool(q.stable[0]) == rep.stability.stable
    assert q.breaks == [(f.loop, f.break_point) for f in rep.loops]
    for r, f in enumerate(rep.loops):
        assert q.ms[0, r] == pytest.approx(f.ms, rel=0.03)
        assert q.mt[0, r] == pytest.approx(f.mt, rel=0.03)
        assert q.pm_deg[0, r] == pytest.approx(f.pm_deg, abs=max(1.0, 0.03 * abs(f.pm_deg)))
        if math.isinf(f.gm_db):
            assert math.isinf(q.gm_db[0, r])
        else:
            assert q.gm_db[0, r] == pytest.approx(f.gm_db, abs=max(0.3, 0.03 * f.gm_db))
        assert q.delay_margin[0, r] == pytest.approx(f.delay_margin, rel=0.03)


@pytest.mark.parametrize("sampled", [True, False])
def test_quick_batch_equals_one_by_one_and_stability_matches_exact(sampled):
    spec, p, lay = setup({"tf": {"num": [1], "den": "(s+1)^3"}}, [{"type": "pid"}], sampled=sampled)
    rng = np.random.default_rng(1)
    G = np.exp(rng.uniform(np.log([0.2, 0.05, 0.05]), np.log([10.0, 5.0, 5.0]), size=(24, 3)))
    q = quick_margins(spec, p, lay, G)
    for b in range(0, 24, 3):
        one = quick_margins(spec, p, lay, G[b : b + 1])
        assert one.stable[0] == q.stable[b]
        assert one.ms[0] == pytest.approx(q.ms[b], rel=0.02)
        rep = verify(spec, G[b], nonlinear=False, plant=p, layout=lay)
        assert rep.stability.stable == bool(q.stable[b])
    assert q.stable.any() and (~q.stable).any()


def test_penalty_zero_when_met_grows_with_violation_large_when_unstable():
    spec, p, lay = setup({"tf": {"num": [1], "den": "(s+1)^3"}}, [{"type": "pi"}],
                         requirements={"gm_min_db": 6, "pm_min_deg": 45, "ms_max": 1.7})
    G = np.array([[1.14, 0.454], [2.0, 0.8], [3.0, 1.5], [20.0, 10.0]])
    pen = requirement_violation(spec, p, lay, G)
    assert pen.shape == (4,) and np.all(pen >= 0)
    assert pen[0] == 0.0
    assert 0 < pen[1] < pen[2] < UNSTABLE_VIOLATION <= pen[3]
    # relative violation: PM 11.95 vs 45 -> 0.73, Ms 5.9 vs 1.7 -> 2.5, GM 3.1 vs 6 dB -> 0.48
    rep = verify(spec, {"loop0": {"Kp": 3.0, "Ki": 1.5}}, nonlinear=False)
    f = rep.loops[0]
    expect = (45 - f.pm_deg) / 45 + (f.ms - 1.7) / 1.7 + (6 - f.gm_db) / 6
    assert pen[2] == pytest.approx(expect, rel=0.05)
    # no requirements: only instability is penalised
    spec2, p2, lay2 = setup({"tf": {"num": [1], "den": "(s+1)^3"}}, [{"type": "pi"}],
                            requirements={"gm_min_db": None, "pm_min_deg": None, "ms_max": None})
    pen2 = requirement_violation(spec2, p2, lay2, G)
    assert list(pen2[:3]) == [0.0, 0.0, 0.0] and pen2[3] >= UNSTABLE_VIOLATION


def test_batched_three_loop_penalty_equals_one_at_a_time():
    # (its speed is a benchmark figure, gaintune bench verify, not a timed test)
    spec, p, lay = setup(MOTOR, MOTOR_LOOPS, 1e-4)
    lin = p.linearize()
    base = lay.from_dict(MOTOR_GAINS)
    G = base * np.exp(np.random.default_rng(0).normal(0, 0.3, size=(64, lay.n_gains)))
    pen = requirement_violation(spec, p, lay, G, lin)
    assert pen.shape == (64,) and np.all(np.isfinite(pen))
    for i in (0, 17, 63):
        assert requirement_violation(spec, p, lay, G[i:i + 1], lin)[0] == pytest.approx(pen[i], rel=1e-9, abs=1e-12)


def test_vectorised_pid_conversion_matches_pid_params():
    for loop_d, names, vals in [
        ({"type": "pid"}, ["Kp", "Ki", "Kd"], [2.0, 0.5, 0.3]),
        ({"type": "pid", "form": "ideal"}, ["Kp", "Ti", "Td"], [2.0, 4.0, 0.25]),
        ({"type": "pd", "filter": {"Tf": 0.02}}, ["Kp", "Kd"], [1.5, 0.2]),
        ({"type": "pi", "form": "ideal"}, ["Kp", "Ti"], [1.0, 2.0]),
    ]:
        spec = load_spec({"plant": {"tf": {"num": [1], "den": [1, 1]}}, "loops": [loop_d]})
        loop = spec.loops[0]
        ref = pid_params(loop, dict(zip(names, vals, strict=True)))
        got = pid_arrays(loop, np.array([vals]), names)
        for k in ("Kp", "Ki", "Kd", "Tf"):
            assert got[k][0] == pytest.approx(getattr(ref, k))


def test_nonlinear_check_runs_the_simulator():
    pytest.importorskip("gaintune.sim")
    spec = load_spec({
        "plant": {"tf": {"num": [1], "den": "(s+1)^3"}},
        "loops": [{"type": "pi"}],
        "actuator": {"limits": [-2, 2], "rate_limit": 10},
        "scenarios": [{"name": "step", "horizon": 20}, {"name": "load", "horizon": 20, "reference": {"kind": "none"},
                                                       "disturbance": {"kind": "step", "amplitude": 0.5, "time": 1}}],
    })
    ok = verify(spec, {"loop0": {"Kp": 1.14, "Ki": 0.454}})
    assert ok.nonlinear is not None and ok.nonlinear.ran and ok.nonlinear.passed
    assert ok.nonlinear.metrics["scenarios"] == 2 and ok.verdict == "pass"
    tight = spec.model_copy(update={"safety": spec.safety.model_copy(update={"max_abs_output": 0.5})})
    bad = verify(tight, {"loop0": {"Kp": 1.14, "Ki": 0.454}})
    assert bad.nonlinear.tripped and bad.verdict == "fail"
    assert any("nonlinear" in r for r in bad.reasons)


def test_a_stable_loop_past_the_divergence_bound_is_told_to_raise_safety_divergence_bound():
    """A process gain of 1e7 takes the output past the default bound of 1e6 on a stable loop: the failure names
    the field and its value, and the fix; with the bound raised the same gains pass."""
    data = {"plant": {"tf": {"num": [1e7], "den": "100*s + 1"}, "delay": 100},
            "loops": [{"name": "main", "type": "pi"}],
            "scenarios": [{"name": "load", "reference": {"kind": "none"},
                           "disturbance": {"kind": "step", "entry": "input", "amplitude": 1.0, "time": 0.0}}],
            "objective": {"measure": "iae", "effort_weight": 0.0},
            "requirements": {"gm_min_db": None, "pm_min_deg": None, "ms_max": 1.4}}
    gains = {"main": {"Kp": 3.5e-8, "Ki": 3.6e-10}}  # the K = 1 answer divided by 1e7
    report = verify(load_spec(data), gains)
    assert report.verdict == "fail" and report.stability.stable
    assert "safety.divergence_bound = 1e+06" in report.nonlinear.note and "raise safety.divergence_bound" in \
        report.nonlinear.note
    assert verify(load_spec({**data, "safety": {"divergence_bound": 1e13}}), gains).verdict == "pass"


def test_the_unstable_grade_counts_a_negative_max_pole_as_zero_and_nan_as_huge() -> None:
    """Regression: the grade once took a negative max Re pole as it came (a loop unstable through a mode no
    loop measures has a stable measured part): log1p of a value below -1 is NaN, and the violation of that
    unstable loop fell below UNSTABLE_VIOLATION. It is np.clip's grade: the max pole clipped to [0, 1e300]."""
    from gaintune.verification.quick import UNSTABLE_VIOLATION, _unstable_grade

    w = np.array([1e-3, 1.0, 1e3])
    max_re = np.array([-5.0, -1e-9, 0.0, 2.0, np.nan, np.inf, -np.inf])
    expect = UNSTABLE_VIOLATION + np.minimum(np.log1p(np.clip(np.nan_to_num(max_re, nan=1e300, posinf=1e300),
                                                             0.0, 1e300) / 1.0), 100.0)
    got = _unstable_grade(max_re, w)
    assert np.array_equal(got, expect)
    assert got[0] == got[1] == got[2] == UNSTABLE_VIOLATION and got[4] == got[5] == UNSTABLE_VIOLATION + 100.0
