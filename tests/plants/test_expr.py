"""The safe expression parser: whitelist, rejections (naming the field), and evaluators agreeing."""

from __future__ import annotations

import math

import casadi as ca
import numpy as np
import pytest

from gaintune.errors import SpecError
from gaintune.plants import expr

FIELD = "plant.ode.rhs.x"


@pytest.mark.parametrize(
    "text, env, expected",
    [
        ("1 + 2*3", {}, 7.0),
        ("-a + +b", {"a": 1.0, "b": 5.0}, 4.0),
        ("a/b - 1", {"a": 3.0, "b": 2.0}, 0.5),
        ("2**3", {}, 8.0),
        ("2^3", {}, 8.0),
        ("pi", {}, math.pi),
        ("e", {}, math.e),
        ("sqrt(max(h, 0))", {"h": -4.0}, 0.0),
        ("sqrt(max(h, 0))", {"h": 4.0}, 2.0),
        ("min(a, b)", {"a": 1.0, "b": 2.0}, 1.0),
        ("abs(-3) + sign(-2)", {}, 2.0),
        ("sin(0) + cos(0) + tan(0) + exp(0) + log(1)", {}, 2.0),
        ("asin(1) + acos(1) + atan(1) + atan2(1, 1)", {}, math.pi / 2 + math.pi / 2),
        ("sinh(0) + cosh(0) + tanh(0)", {}, 1.0),
        ("if_else(x > 0, 1, 2)", {"x": 3.0}, 1.0),
        ("if_else(x <= 0, 1, 2)", {"x": 3.0}, 2.0),
        ("1e-3 * x", {"x": 2.0}, 2e-3),
    ],
)
def test_whitelist_evaluates(text: str, env: dict, expected: float) -> None:
    assert expr.to_float(text, env, FIELD) == pytest.approx(expected)


@pytest.mark.parametrize(
    "text, expected",
    [
        ("s^2 + 1", 2.0),  # not s^(2+1)
        ("2*3^2", 18.0),  # not (2*3)^2
        ("-2^2", -4.0),  # mathematical convention
        ("2^3^2", 512.0),  # right-associative like **
    ],
)
def test_caret_is_power_with_power_precedence(text: str, expected: float) -> None:
    # regression: '^' used to parse as XOR precedence, below + and *.
    assert expr.to_float(text, {"s": 1.0}, FIELD) == pytest.approx(expected)


def test_numbers_pass_through_to_float() -> None:
    assert expr.to_float(2.5, {}, FIELD) == 2.5


@pytest.mark.parametrize(
    "text, fragment",
    [
        ("__import__('os')", "__import__"),
        ("__import__", "underscore"),
        ("x.real", "attribute"),
        ("().__class__", "attribute"),
        ("(1).__class__.__bases__", "attribute"),
        ("x[0]", "Subscript"),
        ("lambda: 1", "Lambda"),
        ("[y for y in x]", "ListComp"),
        ("{y: 1 for y in x}", "DictComp"),
        ("open('/etc/passwd')", "open"),
        ("eval('1')", "eval"),
        ("exec('1')", "exec"),
        ("getattr(x, 'y')", "getattr"),
        ("sin(x=1)", "keyword"),
        ("'abc'", "numeric"),
        ("sin('x')", "numeric"),
        ("True", "numeric"),
        ("x if x else 1", "IfExp"),
        ("x and 1", "BoolOp"),
        ("not x", "UnaryOp"),
        ("a < b < c", "Compare"),
        ("a == b", "Compare"),
        ("x % 2", "BinOp"),
        ("x // 2", "BinOp"),
        ("sin(*x)", "Starred"),
        ("(x := 1)", "NamedExpr"),
        ("1 +", "cannot parse"),
        ("", "empty"),
        ("   ", "empty"),
    ],
)
def test_rejected_with_field_name(text: str, fragment: str) -> None:
    with pytest.raises(SpecError) as info:
        expr.parse(text, FIELD)
    assert info.value.field == FIELD
    assert fragment in str(info.value)


def test_rejected_even_when_evaluating() -> None:
    # to_float/to_casadi/to_polynomial all parse first, so nothing reaches an evaluator.
    for fn in (
        lambda: expr.to_float("__import__('os').system('true')", {}, "plant.delay"),
        lambda: expr.to_casadi("x.real", {"x": ca.SX.sym("x")}, "plant.delay"),
        lambda: expr.to_polynomial("open('f')", {}, "plant.delay"),
    ):
        with pytest.raises(SpecError) as info:
            fn()
        assert info.value.field == "plant.delay"


def test_overly_long_expression_rejected() -> None:
    text = "+".join(["x"] * (expr.MAX_LENGTH // 2 + 1))
    assert len(text) > expr.MAX_LENGTH
    with pytest.raises(SpecError, match="longer than") as info:
        expr.parse(text, FIELD)
    assert info.value.field == FIELD


def test_deeply_nested_expression_rejected() -> None:
    text = "(" * (expr.MAX_DEPTH + 5) + "x" + ")" * (expr.MAX_DEPTH + 5)
    # Parentheses alone add no depth; nested calls do.
    expr.parse(text, FIELD)
    nested = "sin(" * (expr.MAX_DEPTH + 5) + "x" + ")" * (expr.MAX_DEPTH + 5)
    with pytest.raises(SpecError, match="nested too deeply") as info:
        expr.parse(nested, FIELD)
    assert info.value.field == FIELD


def test_parser_nesting_limit_is_a_spec_error() -> None:
    # Python's own parser limit (too many nested parentheses) must not escape as SyntaxError.
    text = "(" * 300 + "1" + ")" * 300
    with pytest.raises(SpecError) as info:
        expr.parse(text, FIELD)
    assert info.value.field == FIELD


def test_unknown_name_names_field_and_known_names() -> None:
    with pytest.raises(SpecError, match="unknown name 'q'.*known: a") as info:
        expr.to_float("a + q", {"a": 1.0}, "plant.tf.num[0]")
    assert info.value.field == "plant.tf.num[0]"


def test_math_domain_error_is_spec_error() -> None:
    with pytest.raises(SpecError) as info:
        expr.to_float("sqrt(-1)", {}, FIELD)
    assert info.value.field == FIELD
    with pytest.raises(SpecError):
        expr.to_float("1/x", {"x": 0.0}, FIELD)


def test_names_in_excludes_functions_and_constants() -> None:
    assert expr.names_in("a*sin(theta) + pi*max(h, 0)") == {"a", "theta", "h"}


@pytest.mark.parametrize(
    "text",
    [
        "(F + m*sin(th)*(l*w^2 - g*cos(th))) / (M + m*sin(th)^2)",
        "(b*u - a*sqrt(max(h, 0)))/A",
        "if_else(h > 1, atan2(h, u), tanh(u) - abs(h))",
        "exp(-h/2)*log(1 + u^2) + sign(u)*min(h, u)",
    ],
)
def test_casadi_and_float_agree(text: str) -> None:
    env = {"F": 0.7, "m": 0.1, "th": 0.3, "l": 0.5, "w": -1.2, "g": 9.81, "M": 1.0,
           "b": 5.0, "u": 1.3, "a": 2.0, "h": 3.7, "A": 20.0}  # fmt: skip
    syms = {k: ca.SX.sym(k) for k in env}
    fun = ca.Function("f", list(syms.values()), [expr.to_casadi(text, syms, FIELD)])
    got = float(fun(*env.values()))
    assert np.isfinite(got)
    assert got == pytest.approx(expr.to_float(text, env, FIELD), rel=1e-12, abs=1e-12)


def test_to_polynomial_expands() -> None:
    np.testing.assert_array_equal(expr.to_polynomial("(s+1)^3", {}), [1, 3, 3, 1])
    np.testing.assert_array_equal(expr.to_polynomial("(s+1)**3", {}), [1, 3, 3, 1])
    np.testing.assert_allclose(expr.to_polynomial("(T*s + 1)^n", {"T": 2.0, "n": 2.0}), [4, 4, 1])
    np.testing.assert_allclose(expr.to_polynomial("K", {"K": 3.0}), [3.0])
    np.testing.assert_allclose(expr.to_polynomial("s*(s + a) + 0*s^4", {"a": 2.0}), [1, 2, 0])


@pytest.mark.parametrize(
    "text, fragment",
    [
        ("(s^2 + 1)/s", "not a polynomial"),
        ("1/s", "not a polynomial"),
        ("sin(s)", "bad call"),
        ("(s+1)^n", "whole power"),
        ("(s+1)^-1", "whole power"),
        ("(s+1)^41", "whole power"),
    ],
)
def test_to_polynomial_rejects_non_polynomials(text: str, fragment: str) -> None:
    with pytest.raises(SpecError, match=fragment) as info:
        expr.to_polynomial(text, {"n": 2.5}, "plant.tf.den")
    assert info.value.field == "plant.tf.den"
