"""Absurd but finite gains, plant coefficients and sample times (fuzzer findings).

Rule: verify() never crashes with a raw ZeroDivisionError/ValueError/OverflowError from deep
inside, and never passes because a number overflowed. It returns a failing report or raises
GainError/SpecError naming the field.
"""

from __future__ import annotations

import math
import warnings
from typing import Any

import numpy as np
import pytest

from gaintune.errors import GainError, SpecError
from gaintune.spec import load_spec
from gaintune.verification import verify
from gaintune.verification.margins import disk_from_alpha
from gaintune.verification.report import VerificationReport

BASE: dict[str, Any] = {"plant": {"tf": {"num": [1], "den": "(s+1)^2"}}, "loops": [{"type": "pi"}],
                        "scenario": {"dt": 0.05, "horizon": 5}}
PI = {"loop0": {"Kp": 1.0, "Ki": 1.0}}
GaintuneErrorLike = GainError | SpecError


def spec_with(sampled: bool = True, **over: Any):
    return load_spec({**BASE, **over, "verify": {"sampled": sampled}})


def outcome(spec, gains, **kw) -> VerificationReport | GaintuneErrorLike:
    """The report, or the GainError/SpecError raised; any other exception fails the test."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # overflow RuntimeWarnings are expected here
        try:
            return verify(spec, gains, **kw)
        except (GainError, SpecError) as exc:
            return exc


def assert_not_passed(res: VerificationReport | GaintuneErrorLike) -> None:
    if isinstance(res, VerificationReport):
        assert res.verdict == "fail" and res.reasons, res.reasons
        assert res.accepted_gains is None
    else:
        assert res.field  # names the field


both = pytest.mark.parametrize("sampled", [True, False], ids=["sampled", "continuous"])


# ---------------------------------------------------------------- bug 1: 1/gmin in disk_from_alpha


def test_disk_alpha_of_two_gives_infinite_gain_margin_not_zero_division():
    assert disk_from_alpha(2.0) == (math.inf, 90.0)


@both
@pytest.mark.parametrize("gains", [{"loop0": {"Kp": 1.0, "Ki": 1e200}}, {"loop0": {"Kp": 1e200, "Ki": 1.0}}],
                         ids=["Ki", "Kp"])
def test_huge_integral_gain_gives_a_fail_verdict_not_zero_division(gains, sampled):
    assert_not_passed(outcome(spec_with(sampled), gains, nonlinear=False))


@both
@pytest.mark.parametrize("plant", [
    {"tf": {"num": [1], "den": [1e308, 1e308]}},
    {"tf": {"num": [1e-320], "den": "(s+1)^2"}},
    {"ss": {"A": [[0, 1], [-1, -2]], "B": [[0], [1e-300]], "C": [[1, 0]], "D": [[0]]}},
], ids=["den1e308", "num1e-320", "B1e-300"])
def test_vanishing_plant_gain_gives_a_fail_verdict_not_zero_division(plant, sampled):
    assert_not_passed(outcome(spec_with(sampled, plant=plant), PI, nonlinear=False))


def test_tiny_ideal_integral_time_gives_a_fail_verdict_not_zero_division():
    spec = spec_with(loops=[{"type": "pi", "form": "ideal"}])
    assert_not_passed(outcome(spec, {"loop0": {"Kp": 1.0, "Ti": 1e-300}}, nonlinear=False))


def test_sub_attosecond_sample_time_does_not_crash_the_sampled_analysis():
    # dt = 1e-300: every pole is e^{p dt} = 1 to rounding, nothing can be certified
    assert_not_passed(outcome(spec_with(scenario={"dt": 1e-300, "horizon": 1e-298}), PI, nonlinear=False))


# ---------------------------------------------------------------- bug 2: NaN Nyquist count


@both
def test_max_float_gains_give_a_fail_verdict_not_nan_nyquist_count(sampled):
    res = outcome(spec_with(sampled), {"loop0": {"Kp": 1e308, "Ki": 1e308}}, nonlinear=False)
    assert_not_passed(res)
    if isinstance(res, VerificationReport):
        assert any("too large to analyse" in r for r in res.reasons)


def test_picosecond_sample_time_gives_a_fail_verdict_not_nan_nyquist_count():
    # |z| = e^{-eps dt} rounds to 1: the contour runs through the integrator's pole
    assert_not_passed(outcome(spec_with(scenario={"dt": 1e-12, "horizon": 1e-10}), PI, nonlinear=False))


@both
def test_huge_setpoint_weight_does_not_poison_the_loop_response(sampled):
    """c only weights the setpoint (never in L): c = 1e308 once made inf * 0 = NaN in every response.
    The figures are those of c = 1, so the verdict is the one the loop earns (not a NaN crash)."""
    gains = {"loop0": {"Kp": 1.0, "Ki": 1.0, "Kd": 1.0}}
    ref = verify(spec_with(sampled, loops=[{"type": "pid", "c": 1.0}]), gains, nonlinear=False)
    res = outcome(spec_with(sampled, loops=[{"type": "pid", "c": 1e308}]), gains, nonlinear=False)
    assert isinstance(res, VerificationReport)
    assert [f.model_dump() for f in res.loops] == [f.model_dump() for f in ref.loops]
    assert res.stability.stable == ref.stability.stable and res.verdict == ref.verdict


# ---------------------------------------------------------------- bug 3: non-finite sampled plant (schur)


def test_absurdly_fast_plant_pole_raises_spec_error_naming_the_plant_not_schur_value_error():
    res = outcome(spec_with(plant={"tf": {"num": [1], "den": [1e-308, 1]}}), PI, nonlinear=False)
    assert isinstance(res, SpecError) and res.field == "plant"


def test_astronomical_sample_time_raises_spec_error_naming_dt_not_schur_value_error():
    res = outcome(spec_with(scenario={"dt": 1e300, "horizon": 1e302}), PI, nonlinear=False)
    assert isinstance(res, SpecError) and res.field == "scenario.dt"


@pytest.mark.parametrize("over", [
    {"plant": {"tf": {"num": [1], "den": [1e-308, 1]}}},
    {"scenario": {"dt": 1e300, "horizon": 1e302}},
], ids=["den1e-308", "dt1e300"])
def test_non_finite_continuous_closed_loop_fails_as_not_certified(over):
    res = outcome(spec_with(False, **over), PI, nonlinear=False)
    assert_not_passed(res)
    if isinstance(res, VerificationReport):
        assert not res.stability.stable


# ---------------------------------------------------------------- robust samples


@both
@pytest.mark.parametrize("rng", [[0.5, 1e300], [1e-300, 1.0]], ids=["huge", "tiny"])
def test_absurd_robust_parameter_range_fails_not_crashes(rng, sampled):
    spec = load_spec({**BASE, "plant": {"tf": {"num": ["K"], "den": "(s+1)^2"}, "params": {"K": 1.0}},
                      "randomize": {"params": {"K": rng}}, "verify": {"robust_samples": 2, "sampled": sampled}})
    assert_not_passed(outcome(spec, PI, nonlinear=False))


def test_normal_gains_still_pass():
    rep = verify(spec_with(), PI, nonlinear=False)
    assert rep.verdict == "pass" and rep.stability.stable
    assert np.isfinite(rep.loops[0].pm_deg)


def test_verify_of_a_dict_or_a_spec_file_loads_it_instead_of_attribute_error(tmp_path) -> None:
    """``verify({...}, gains)`` raised AttributeError: 'dict' object has no attribute 'content_hash'."""
    import json

    from gaintune import load_spec, verify

    data = {"plant": {"tf": {"num": [1], "den": "(s+1)^2"}}, "loops": [{"type": "pi"}],
            "scenario": {"dt": 0.05, "horizon": 5}}
    gains = {"loop0": {"Kp": 1.0, "Ki": 0.5}}
    path = tmp_path / "pi.json"
    path.write_text(json.dumps(data))
    want = verify(load_spec(data), gains).verdict
    assert verify(data, gains).verdict == want
    assert verify(str(path), gains).verdict == want
    assert verify(path, gains).verdict == want


def test_delay_written_as_a_parameter_expression_is_bounded_where_it_gets_a_value() -> None:
    """``delay: "T"`` with ``T: 1e300``: the spec cannot evaluate it, so the sampled plant (verify) and
    the simulator's plant arrays check delay/dt against MAX_DELAY_STEPS (it overflowed a buffer size)."""
    from gaintune import load_spec, verify
    from gaintune.errors import SpecError
    from gaintune.plants import build_plant
    from gaintune.sim import Simulator

    spec = load_spec({"plant": {"tf": {"num": [1], "den": [1, 1]}, "params": {"T": 1e300}, "delay": "T"},
                      "loops": [{"type": "pi"}], "scenario": {"dt": 0.05, "horizon": 5}})
    with pytest.raises(SpecError, match="plant.delay.*over the limit"):
        verify(spec, {"loop0": {"Kp": 1.0, "Ki": 0.5}})
    with pytest.raises(SpecError, match="plant.delay.*over the limit"):
        sim = Simulator(spec, build_plant(spec.plant))
        sim.run(sim.layout.from_dict({"loop0": {"Kp": 1.0, "Ki": 0.5}})[None, :])
