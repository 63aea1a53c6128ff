"""Fuzzer-found bad inputs to plant expressions: each must be a SpecError naming the field, never a crash."""

from __future__ import annotations

from typing import Any

import pytest

import gaintune
from gaintune.errors import SpecError
from gaintune.plants import build_plant, expr

GAINS = {"loop0": {"Kp": 1, "Ki": 0.5}}


def _spec(plant: dict[str, Any]) -> dict[str, Any]:
    return {"plant": plant, "loops": [{"type": "pi"}], "scenario": {"dt": 0.05, "horizon": 5}}


def _ode(rhs: str, **extra: Any) -> dict[str, Any]:
    return {"ode": {"states": ["h"], "rhs": {"h": rhs}, "outputs": {"y": "h"}, **extra}}


def _build_error(plant: dict[str, Any]) -> SpecError:
    spec = gaintune.load_spec(_spec(plant))  # the schema accepts these: they fail numerically
    with pytest.raises(SpecError) as info:
        build_plant(spec.plant)
    return info.value


@pytest.mark.parametrize(
    "plant, field",
    [
        ({"tf": {"num": ["(-8)^0.5"], "den": [1, 1]}}, "plant.tf.num[0]"),
        ({"tf": {"num": ["K^0.5"], "den": [1, 1]}, "params": {"K": -4}}, "plant.tf.num[0]"),
        ({"tf": {"num": [1], "den": [1, 1]}, "delay": "(-1)^0.5"}, "plant.delay"),
        # used to be accepted with the imaginary part silently dropped (ComplexWarning)
        ({"tf": {"num": [1], "den": "s + (-1)^0.5"}}, "plant.tf.den"),
        ({"tf": {"num": "(-1)^0.5", "den": "s + 1"}}, "plant.tf.num"),
        (_ode("u - h", u0="(-1)^0.5"), "plant.ode.u0"),
        (_ode("u - h", x0={"h": "(-1)^0.5"}), "plant.ode.x0.h"),
        (_ode("u - h + (-1)^0.5"), "plant.ode.rhs.h"),
    ],
)
def test_complex_valued_expression_is_a_spec_error_naming_the_field(plant: dict[str, Any], field: str) -> None:
    err = _build_error(plant)
    assert err.field == field
    assert "complex" in err.message and "real" in err.message


@pytest.mark.parametrize(
    "rhs, fragment",
    [
        ("min(u) - h", "min() takes 2 arguments, got 1"),
        ("sin(u, h)", "sin() takes 1 argument, got 2"),
        ("if_else(u)", "if_else() takes 3 arguments, got 1"),
        ("if_else(u > 0, u, h, 1)", "if_else() takes 3 arguments, got 4"),
        ("atan2(u)", "atan2() takes 2 arguments, got 1"),
    ],
)
def test_ode_call_with_wrong_argument_count_is_a_spec_error_naming_the_field(rhs: str, fragment: str) -> None:
    err = _build_error(_ode(rhs))
    assert err.field == "plant.ode.rhs.h"
    assert fragment in err.message


def test_wrong_argument_count_is_rejected_by_every_evaluator() -> None:
    # checked at parse time, so the float and polynomial paths agree with the casadi one
    with pytest.raises(SpecError, match=r"plant.tf.num\[0\]: max\(\) takes 2 arguments, got 3"):
        expr.to_float("max(1, 2, 3)", {}, "plant.tf.num[0]")
    with pytest.raises(SpecError, match=r"plant.tf.den: sqrt\(\) takes 1 argument, got 0"):
        expr.to_polynomial("s + sqrt()", {}, "plant.tf.den")


@pytest.mark.parametrize("rhs", ["u - h + 1/0", "u - h + 0^-1", "u - h + 10^400"])
def test_ode_constant_division_by_zero_is_a_spec_error_naming_the_field(rhs: str) -> None:
    err = _build_error(_ode(rhs))
    assert err.field == "plant.ode.rhs.h"
    assert "cannot evaluate" in err.message


@pytest.mark.parametrize(
    "rhs, x0",
    [
        ("u - log(h)", {}),  # x0 defaults to 0
        ("u - sqrt(h)", {"h": -1}),
        ("u - exp(h)", {"h": 800}),
        ("u - h^2", {"h": 1e200}),
    ],
)
def test_ode_not_finite_at_x0_without_u0_is_a_spec_error_naming_x0(rhs: str, x0: dict[str, float]) -> None:
    err = _build_error(_ode(rhs, x0=x0))
    assert err.field == "plant.ode.x0"
    assert "not finite" in err.message and "u0" in err.message


def test_ode_non_finite_operating_point_values_name_the_field() -> None:
    assert _build_error(_ode("u - h", u0="1e400")).field == "plant.ode.u0"
    assert _build_error(_ode("u - h", x0={"h": "1e400"})).field == "plant.ode.x0.h"


@pytest.mark.parametrize(
    "plant",
    [
        {"tf": {"num": ["(-8)^0.5"], "den": [1, 1]}},
        _ode("min(u) - h"),
        _ode("u - h + 1/0"),
        _ode("u - log(h)"),
    ],
)
def test_verify_reports_bad_plant_expressions_as_spec_errors(plant: dict[str, Any]) -> None:
    spec = gaintune.load_spec(_spec(plant))
    with pytest.raises(SpecError) as info:
        gaintune.verify(spec, GAINS)
    assert info.value.field.startswith("plant.")


def test_valid_ode_still_finds_its_operating_input() -> None:
    spec = gaintune.load_spec(_spec(_ode("max(u, 0) - sqrt(h)", x0={"h": 4})))
    lin = build_plant(spec.plant).linearize()
    assert lin.u0 == pytest.approx(2.0, abs=1e-6)
