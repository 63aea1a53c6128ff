"""Safe parsing of user expressions (plant right-hand sides, coefficients).

Expressions are parsed with :mod:`ast` and walked node by node against a
whitelist: numbers, names, + - * / ** ^ (power, same precedence as **), unary minus, and calls to the
functions in :data:`FUNCTIONS`. Attribute access, subscripts, keywords,
lambdas, comprehensions and every other node are rejected. Nothing is ever
passed to ``eval``/``exec``.

The same parsed tree can be evaluated with casadi (symbolic ODEs), with plain
floats, or with :class:`numpy.polynomial.Polynomial` (transfer functions in s).

Work on an expression is bounded before it starts: the text length and nesting are
limited when it is parsed, numbers are floats (``10**10**10`` overflows at once instead
of growing a huge integer), and a polynomial's degree is bounded from the parsed tree
(:func:`degree_bound`) before anything is expanded. :func:`cpu_budget` adds a limit on
the CPU time a thread may spend evaluating expressions (the API builds specs under one).
"""

from __future__ import annotations

import ast
import math
import operator
import time
from collections.abc import Callable, Iterator, Mapping
from contextlib import contextmanager
from contextvars import ContextVar
from functools import lru_cache
from typing import TYPE_CHECKING, Any

import numpy as np

from gaintune.errors import SpecError
from gaintune.spec.base import MAX_ORDER

if TYPE_CHECKING:  # pragma: no cover
    import casadi as ca

__all__ = [
    "FUNCTIONS", "CONSTANTS", "parse", "names_in", "to_casadi", "to_float", "to_polynomial", "degree_bound",
    "cpu_budget", "MAX_DEGREE", "MAX_POWER",
]

MAX_LENGTH = 2000
MAX_DEPTH = 60
#: Highest degree in s any part of a polynomial expression may reach: a transfer function's
#: numerator and denominator cannot exceed the largest plant order, so nothing larger is expanded.
MAX_DEGREE = MAX_ORDER
#: Largest whole power a polynomial in s may be raised to.
MAX_POWER = 40


class _Casadi:
    """``casadi.<name>``, looked up when called: casadi is imported on purpose only once an
    expression is evaluated symbolically (ODE plants), not by every LTI run (~15 ms at start-up)."""

    __slots__ = ("name",)

    def __init__(self, name: str) -> None:
        self.name = name

    def __call__(self, *args: Any) -> Any:
        import casadi  # deferred: see the class docstring

        return getattr(casadi, self.name)(*args)

    def __repr__(self) -> str:
        return f"casadi.{self.name}"


#: Whitelisted functions: name -> (casadi implementation, float implementation).
FUNCTIONS: dict[str, tuple[Callable[..., Any], Callable[..., Any]]] = {
    "sin": (_Casadi("sin"), math.sin),
    "cos": (_Casadi("cos"), math.cos),
    "tan": (_Casadi("tan"), math.tan),
    "asin": (_Casadi("asin"), math.asin),
    "acos": (_Casadi("acos"), math.acos),
    "atan": (_Casadi("atan"), math.atan),
    "atan2": (_Casadi("atan2"), math.atan2),
    "sinh": (_Casadi("sinh"), math.sinh),
    "cosh": (_Casadi("cosh"), math.cosh),
    "tanh": (_Casadi("tanh"), math.tanh),
    "exp": (_Casadi("exp"), math.exp),
    "log": (_Casadi("log"), math.log),
    "sqrt": (_Casadi("sqrt"), math.sqrt),
    "abs": (_Casadi("fabs"), abs),
    "sign": (_Casadi("sign"), lambda x: float(np.sign(x))),
    "min": (_Casadi("fmin"), min),
    "max": (_Casadi("fmax"), max),
    "if_else": (_Casadi("if_else"), lambda c, a, b: a if c else b),
}
CONSTANTS = {"pi": math.pi, "e": math.e}
#: Argument counts that differ from 1. Checked at parse time so every evaluator (casadi, float,
#: polynomial) rejects a wrong count the same way instead of failing inside casadi or Python.
ARITY: dict[str, int] = {"atan2": 2, "min": 2, "max": 2, "if_else": 3}
_FLOAT_FUNCS = {k: v[1] for k, v in FUNCTIONS.items()}

_BINOPS = (ast.Add, ast.Sub, ast.Mult, ast.Div, ast.Pow, ast.BitXor)
_CMPOPS = (ast.Lt, ast.LtE, ast.Gt, ast.GtE)
# what _evaluate applies for each; any other whitelisted binary operator (**, ^) is a power
_ARITH: dict[type[ast.operator], Callable[[Any, Any], Any]] = {
    ast.Add: operator.add, ast.Sub: operator.sub, ast.Mult: operator.mul, ast.Div: operator.truediv,
}
_COMPARE: dict[type[ast.cmpop], Callable[[Any, Any], Any]] = {
    ast.Lt: operator.lt, ast.LtE: operator.le, ast.Gt: operator.gt, ast.GtE: operator.ge,
}


@lru_cache(maxsize=4096)
def parse(text: str, field: str = "expression") -> ast.expr:
    """Parse and validate ``text``; raise :class:`SpecError` naming ``field`` if it is not allowed."""
    if not isinstance(text, str) or not text.strip():
        raise SpecError(field, "empty expression")
    if len(text) > MAX_LENGTH:
        raise SpecError(field, f"expression longer than {MAX_LENGTH} characters")
    try:
        # '^' means power with the precedence of '**' (s^2 + 1 is s**2 + 1), not Python's XOR.
        tree = ast.parse(text.strip().replace("^", "**"), mode="eval")
    except SyntaxError as exc:
        raise SpecError(field, f"cannot parse {text!r}: {exc.msg}") from None
    _check(tree.body, field, 0)
    return tree.body


def _check(node: ast.AST, field: str, depth: int) -> None:
    if depth > MAX_DEPTH:
        raise SpecError(field, "expression nested too deeply")
    if isinstance(node, ast.Constant):
        if isinstance(node.value, bool) or not isinstance(node.value, (int, float)):
            raise SpecError(field, f"only numeric constants are allowed, got {node.value!r}")
        return
    if isinstance(node, ast.Name):
        if node.id.startswith("_"):
            raise SpecError(field, f"name {node.id!r} is not allowed (leading underscore)")
        return
    if isinstance(node, ast.BinOp) and isinstance(node.op, _BINOPS):
        _check(node.left, field, depth + 1)
        _check(node.right, field, depth + 1)
        return
    if isinstance(node, ast.UnaryOp) and isinstance(node.op, (ast.USub, ast.UAdd)):
        _check(node.operand, field, depth + 1)
        return
    if isinstance(node, ast.Compare) and len(node.ops) == 1 and isinstance(node.ops[0], _CMPOPS):
        _check(node.left, field, depth + 1)
        _check(node.comparators[0], field, depth + 1)
        return
    if isinstance(node, ast.Call):
        if not isinstance(node.func, ast.Name) or node.func.id not in FUNCTIONS:
            what = ast.unparse(node.func)
            raise SpecError(
                field, f"call to {what!r} is not allowed; allowed functions: {', '.join(sorted(FUNCTIONS))}"
            )
        if node.keywords:
            raise SpecError(field, "keyword arguments are not allowed")
        name, want = node.func.id, ARITY.get(node.func.id, 1)
        if len(node.args) != want:
            plural = "argument" if want == 1 else "arguments"
            raise SpecError(field, f"{name}() takes {want} {plural}, got {len(node.args)}")
        for arg in node.args:
            _check(arg, field, depth + 1)
        return
    if isinstance(node, ast.Attribute):
        raise SpecError(field, "attribute access ('.') is not allowed")
    raise SpecError(field, f"{type(node).__name__} is not allowed in expressions")


def names_in(text: str, field: str = "expression") -> set[str]:
    """Free variable names used by an expression (constants and functions excluded)."""
    tree = parse(text, field)
    out = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.Name) and node.id not in FUNCTIONS and node.id not in CONSTANTS:
            out.add(node.id)
    return out


def _whole_power(b: Any, field: str) -> int:
    """The exponent ``b`` of a polynomial in s as an int, or SpecError."""
    if isinstance(b, float) and b.is_integer() and 0 <= b <= MAX_POWER:
        return int(b)
    raise SpecError(field, f"a polynomial in s can only be raised to a whole power 0..{MAX_POWER}")


def degree_bound(node: ast.expr, scope: Mapping[str, Any], field: str = "expression") -> int:
    """An upper bound of the degree in ``s`` of a parsed polynomial expression, from its tree alone.

    The degree of ``a**n`` is n times the degree of ``a``, of ``a*b`` the sum, of ``a+b`` and
    ``a-b`` the larger one, of ``a/b`` that of ``a`` (a divisor holding s is refused when evaluated);
    a number, a parameter and a function's value have degree 0. Only the exponents of powers whose
    base holds s are evaluated (``scope``: the names, ``s`` included), each after its own subtree
    has been bounded, so nothing of a higher degree is ever built.

    Raises
    ------
    SpecError
        When any part of the expression can reach a degree above :data:`MAX_DEGREE`, or a
        polynomial in s is raised to anything but a whole power 0..:data:`MAX_POWER`.
    """
    if isinstance(node, ast.Name):
        return 1 if node.id == "s" else 0
    if isinstance(node, ast.UnaryOp):
        return degree_bound(node.operand, scope, field)
    if isinstance(node, ast.BinOp):
        a, b = degree_bound(node.left, scope, field), degree_bound(node.right, scope, field)
        if isinstance(node.op, (ast.Add, ast.Sub)):
            d = max(a, b)
        elif isinstance(node.op, ast.Mult):
            d = a + b
        elif isinstance(node.op, ast.Div):
            d = a
        elif a == 0 or b > 0:  # a number to a power; an exponent holding s fails when evaluated
            d = 0
        else:
            d = a * _whole_power(_evaluate(node.right, scope, _FLOAT_FUNCS, field), field)
        if d > MAX_DEGREE:
            raise SpecError(field, f"the polynomial can reach degree {d} (degrees add up in products and multiply "
                                   f"in powers), which exceeds the limit of {MAX_DEGREE}, the largest plant order; "
                                   f"write one of degree <= {MAX_DEGREE}")
        return d
    for child in ast.iter_child_nodes(node):  # calls and comparisons: bound their operands, value of degree 0
        if isinstance(child, ast.expr):
            degree_bound(child, scope, field)
    return 0


# ------------------------------------------------------------------ CPU budget

_BUDGET: ContextVar[tuple[float, float] | None] = ContextVar("gaintune_expr_cpu_budget", default=None)


@contextmanager
def cpu_budget(seconds: float) -> Iterator[None]:
    """Inside the block, evaluating an expression raises SpecError once the calling thread has
    spent ``seconds`` of CPU time since the block began.

    A cooperative limit, checked at every node evaluated: the work between two checks is one
    operation on floats, casadi expressions or polynomials of degree <= :data:`MAX_DEGREE`, so
    it stays small. Thread CPU time, not wall time, so a loaded machine does not trip it.
    """
    token = _BUDGET.set((time.thread_time() + seconds, seconds))
    try:
        yield
    finally:
        _BUDGET.reset(token)


def _check_budget(field: str) -> None:
    budget = _BUDGET.get()
    if budget is not None and time.thread_time() >= budget[0]:
        raise SpecError(field, f"evaluating the expressions took more than the limit of {budget[1]:g} s of CPU "
                               "time; simplify them")


def _evaluate(node: ast.expr, env: Mapping[str, Any], funcs: Mapping[str, Callable[..., Any]], field: str) -> Any:
    _check_budget(field)
    if isinstance(node, ast.Constant):
        assert isinstance(node.value, (int, float))  # _check let only numbers through
        return float(node.value)
    if isinstance(node, ast.Name):
        if node.id in env:
            return env[node.id]
        if node.id in CONSTANTS:
            return CONSTANTS[node.id]
        raise SpecError(field, f"unknown name {node.id!r}; known: {', '.join(sorted(env)) or 'none'}")
    if isinstance(node, ast.UnaryOp):
        val = _evaluate(node.operand, env, funcs, field)
        return -val if isinstance(node.op, ast.USub) else val
    if isinstance(node, ast.BinOp):
        a = _evaluate(node.left, env, funcs, field)
        b = _evaluate(node.right, env, funcs, field)
        arith = _ARITH.get(type(node.op))
        return arith(a, b) if arith is not None else _power(a, b, field)
    if isinstance(node, ast.Compare):
        a = _evaluate(node.left, env, funcs, field)
        b = _evaluate(node.comparators[0], env, funcs, field)
        return _COMPARE[type(node.ops[0])](a, b)
    assert isinstance(node, ast.Call) and isinstance(node.func, ast.Name)
    args = [_evaluate(a, env, funcs, field) for a in node.args]
    try:
        return funcs[node.func.id](*args)
    except (TypeError, ValueError, NotImplementedError) as exc:  # NotImplementedError: casadi's bad-type error
        raise SpecError(field, f"bad call {node.func.id}(...): {exc}") from None


def _power(a: Any, b: Any, field: str) -> Any:
    if isinstance(a, np.polynomial.Polynomial):
        return a ** _whole_power(b, field)
    out = a**b
    # Python turns a negative float to a fractional power into a complex number; models are real.
    if isinstance(out, complex):
        raise SpecError(
            field,
            f"value is complex, not real: ({a:g})^{b:g} is a negative number to a fractional power; give a real value",
        )
    return out


def to_casadi(text: str, symbols: Mapping[str, Any], field: str = "expression") -> ca.SX:
    """Evaluate an expression into a casadi SX over the given symbols."""
    import casadi as ca  # deferred (see _Casadi)

    funcs = {k: v[0] for k, v in FUNCTIONS.items()}
    try:
        # Constant sub-expressions (1/0, 0^-1, 10^400) are evaluated with Python floats here too.
        return ca.SX(_evaluate(parse(text, field), symbols, funcs, field))
    except (ZeroDivisionError, OverflowError) as exc:
        raise SpecError(field, f"cannot evaluate {text!r}: {exc}") from None


def to_float(value: float | str, env: Mapping[str, float], field: str = "expression") -> float:
    """A number as is, or an expression evaluated over numeric parameters."""
    if not isinstance(value, str):
        return float(value)
    try:
        out = _evaluate(parse(value, field), env, _FLOAT_FUNCS, field)
    except (ZeroDivisionError, OverflowError, ValueError) as exc:
        raise SpecError(field, f"cannot evaluate {value!r}: {exc}") from None
    return float(out)


def to_polynomial(text: str, env: Mapping[str, float], field: str = "expression") -> np.ndarray:
    """Evaluate a polynomial expression in ``s``; return coefficients in descending powers."""
    scope: dict[str, Any] = dict(env)
    scope["s"] = np.polynomial.Polynomial([0.0, 1.0])
    try:
        tree = parse(text, field)
        degree_bound(tree, scope, field)  # before anything is expanded
        out = _evaluate(tree, scope, _FLOAT_FUNCS, field)
    except (ZeroDivisionError, OverflowError) as exc:
        raise SpecError(field, f"cannot evaluate {text!r}: {exc}") from None
    except TypeError:
        raise SpecError(field, f"{text!r} is not a polynomial in s (no division by s, no functions of s)") from None
    if isinstance(out, np.polynomial.Polynomial):
        coefs = out.coef[::-1].astype(float)
    else:
        coefs = np.array([float(out)])
    return np.trim_zeros(coefs, "f") if np.any(coefs) else np.array([0.0])
