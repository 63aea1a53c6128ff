"""The ready-made families are self-similar: every plant of a family, whatever its units, gets a passing answer.

A plant's time scale and gain are units, not physics: the answer for K e^{-Ls}/(Ts+1) with T, L in
microseconds or in days is the unit plant's, scaled (gaintune.tuners.families). Absolute thresholds
broke that (a cost of 1e6 called divergence, a divergence bound of 1e6 on the states, the observability
test's tolerances): at 124a426, 86 of these 140 queries passed.
"""

from __future__ import annotations

import itertools
import warnings

import pytest

from gaintune.tuners.tuner import Tuner

SHAPES = {
    "fotd_pi_ms1.4": lambda s: {"T": 1.0 * s, "L": 1.0 * s},
    "fotd_pid_ms1.4": lambda s: {"T": 3.0 * s, "L": 0.5 * s},
    "sotd_pi_ms1.4": lambda s: {"T1": 1.0 * s, "T2": 0.3 * s, "L": 0.4 * s},
    "ipd_pi_ms1.4": lambda s: {"T": 1.0 * s, "L": 1.0 * s},
}
TIME_SCALES = (1e-6, 1e-4, 1e-2, 1.0, 1e2, 1e4, 1e6)
GAINS = (1e-8, 1e-4, 1.0, 1e4, 1e8)


@pytest.mark.parametrize("name", sorted(SHAPES))
def test_every_time_scale_and_gain_over_fourteen_decades_gets_a_passing_answer(name):
    tuner = Tuner.load(name)
    failed = []
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # the FOTD fit of a microsecond SOTD warns of its coefficients' conditioning
        for s, k in itertools.product(TIME_SCALES, GAINS):
            a = tuner.query({"K": k, **SHAPES[name](s)})
            if a.verdict != "pass":
                failed.append((s, k, a.as_dict()["failures"][:1]))
    assert not failed, failed


#: Two shapes per family at the ends of its training range, as functions of the time scale.
EDGE_SHAPES = {
    "fotd_pi_ms1.4": [lambda s: {"T": s / 1.05, "L": 0.05 * s / 1.05}, lambda s: {"T": s / 11, "L": 10 * s / 11}],
    "fotd_pid_ms1.4": [lambda s: {"T": s / 1.05, "L": 0.05 * s / 1.05}, lambda s: {"T": s / 11, "L": 10 * s / 11}],
    "sotd_pi_ms1.4": [lambda s: {"T1": s / 1.05 ** 2, "T2": 0.05 * s / 1.05 ** 2, "L": 0.05 * s / 1.05},
                      lambda s: {"T1": s / 22, "T2": s / 22, "L": 10 * s / 11}],
    "ipd_pi_ms1.4": [lambda s: {"T": s / 1.06, "L": 0.06 * s / 1.06}, lambda s: {"T": s / 20, "L": 19 * s / 20}],
}


@pytest.mark.parametrize("name", sorted(EDGE_SHAPES))
def test_the_corners_of_the_supported_gains_and_time_scales_get_a_passing_answer(name):
    """GAIN_RANGE x TIME_RANGE at both ends of each family's shape range: the range the tuners promise."""
    from gaintune.tuners.families import GAIN_RANGE, TIME_RANGE

    tuner = Tuner.load(name)
    failed = []
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        for k, s, shape in itertools.product(GAIN_RANGE, (TIME_RANGE[0], 0.999 * TIME_RANGE[1]), EDGE_SHAPES[name]):
            a = tuner.query({"K": k, **shape(s)})
            if a.verdict != "pass" or not a.cost < 1e29:  # the simulator's diverged cost is 1e30
                failed.append((k, s, a.cost, a.as_dict()["failures"][:1]))
    assert not failed, failed


@pytest.mark.parametrize("params, field, needle", [
    ({"K": 1.0, "T": 1e200, "L": 1e200}, "params", "time scale L + T = 2e+200 s is outside the 1e-09 to 1e+08 s"),
    ({"K": 1.0, "T": 1e-12, "L": 1e-12}, "params", "time scale L + T = 2e-12 s is outside"),
    ({"K": 1e30, "T": 1.0, "L": 1.0}, "params.K", "gain K = 1e+30 is outside the 1e-10 to 1e+10"),
    ({"K": 1e-308, "T": 1.0, "L": 1.0}, "params.K", "express the output or the input in other units"),
])
def test_a_plant_beyond_the_supported_scales_is_refused_naming_the_parameter_and_the_fix(params, field, needle):
    """Beyond them T = 1e200 s overflowed (a traceback), K = 1e308 named internal spec fields, K = 1e30 passed
    with the simulator's diverged cost."""
    from gaintune.errors import SpecError

    with pytest.raises(SpecError) as exc:
        Tuner.load("fotd_pi_ms1.4").query(params)
    assert exc.value.field == field and needle in exc.value.message
