"""Expression work is bounded before it starts: the degree of a polynomial in s from its tree (issue 24, defect 5),
numbers that overflow instead of growing, and a CPU-time budget for the API's spec checks."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path
from typing import Any

import numpy as np
import pytest

import gaintune
from gaintune.errors import SpecError
from gaintune.plants import build_plant, expr

NESTED = "((((s+1)**40)**40)**40)**40"  # degree 40^4 = 2,560,000 if expanded


def _scope(**params: float) -> dict[str, Any]:
    return {**params, "s": np.polynomial.Polynomial([0.0, 1.0])}


@pytest.fixture
def no_expansion(monkeypatch: pytest.MonkeyPatch) -> None:
    """Any polynomial power or product fails the test: a refusal must come before expanding."""

    def expanded(*args: Any) -> None:
        raise AssertionError("a polynomial was expanded before the degree bound refused it")

    monkeypatch.setattr(np.polynomial.Polynomial, "__pow__", expanded)
    monkeypatch.setattr(np.polynomial.Polynomial, "__mul__", expanded)
    monkeypatch.setattr(np.polynomial.Polynomial, "__rmul__", expanded)


@pytest.mark.parametrize("den", [NESTED, "((((s+1)**40)**40)**40)**10"])
def test_nested_power_expression_refused_fast(den: str, no_expansion: None) -> None:
    """The API took 129 CPU-seconds (and the CLI hung) expanding this; ``...**10`` was refused after 11 s."""
    spec = gaintune.load_spec({"plant": {"tf": {"num": [1], "den": den}}, "loops": [{"type": "pi"}]})
    with pytest.raises(SpecError) as info:
        build_plant(spec.plant)
    assert info.value.field == "plant.tf.den"
    # the innermost power already exceeds the limit: the tree's bound (40), no polynomial built
    assert "can reach degree 40" in info.value.message and f"limit of {expr.MAX_DEGREE}" in info.value.message


@pytest.mark.parametrize(
    "text, degree",
    [
        ("K", 0),
        ("s", 1),
        ("(s+1)^3", 3),
        ("(s+1)^3 * (s^2 + 1)^2", 7),  # products add
        ("(s+1)^15 + (s+1)^15 - s", 15),  # sums take the larger
        ("(T*s + 1)^n", 3),  # an exponent from a parameter (n = 3)
        ("(s^2 + 1)/2", 2),  # a division by a number keeps the degree
        ("2^10 * s", 1),  # a number to a power has degree 0
        ("sin(1) * s^2", 2),
    ],
)
def test_degree_bound_comes_from_the_tree(text: str, degree: int) -> None:
    assert expr.degree_bound(expr.parse(text), _scope(K=1.0, T=2.0, n=3.0)) == degree


@pytest.mark.parametrize("text, degree", [("(s+1)^15 * (s+1)^15", 30), ("((s^2+1)^5)^3", 30), ("sin((s+1)^40)", 40)])
def test_degree_over_the_limit_anywhere_in_the_tree_is_refused(text: str, degree: int, no_expansion: None) -> None:
    with pytest.raises(SpecError, match=f"can reach degree {degree}") as info:
        expr.to_polynomial(text, {}, "plant.tf.num")
    assert info.value.field == "plant.tf.num"


def test_degree_at_the_limit_is_expanded() -> None:
    coefs = expr.to_polynomial(f"(s+1)^{expr.MAX_DEGREE}", {}, "plant.tf.den")
    assert len(coefs) == expr.MAX_DEGREE + 1 and coefs[0] == 1 and coefs[-1] == 1


@pytest.mark.parametrize(
    "plant, field",
    [
        ({"tf": {"num": ["10**10**10"], "den": [1, 1]}}, "plant.tf.num[0]"),
        ({"tf": {"num": [1], "den": "(s+1)**(10**10**10)"}}, "plant.tf.den"),
        ({"tf": {"num": [1], "den": "s + K**K**K**K"}, "params": {"K": 10.0}}, "plant.tf.den"),
        ({"tf": {"num": [1], "den": [1, 1]}, "delay": "9**9**9"}, "plant.delay"),
        ({"ode": {"states": ["x"], "rhs": {"x": "-x + u*(10**10**10)"}, "outputs": {"y": "x"}}}, "plant.ode.rhs.x"),
    ],
)
def test_number_power_tower_is_refused_not_computed(plant: dict[str, Any], field: str) -> None:
    """Numbers are floats: 10**10**10 overflows at once (a Python int would take memory and time without end)."""
    spec = gaintune.load_spec({"plant": plant, "loops": [{"type": "pi"}]})
    with pytest.raises(SpecError, match="cannot evaluate") as info:
        build_plant(spec.plant)
    assert info.value.field == field


def test_cpu_budget_refuses_expression_work_over_the_limit() -> None:
    with expr.cpu_budget(0.0):  # a budget already spent: the first node evaluated is refused
        with pytest.raises(SpecError, match="limit of 0 s of CPU time") as info:
            expr.to_polynomial("(s+1)^3", {}, "plant.tf.den")
    assert info.value.field == "plant.tf.den"
    with expr.cpu_budget(60.0):
        np.testing.assert_array_equal(expr.to_polynomial("(s+1)^3", {}, "plant.tf.den"), [1, 3, 3, 1])
    assert expr.to_float("2*3", {}, "x") == 6.0  # outside any budget: no limit


def test_nested_power_expression_is_exit_2_from_the_cli(tmp_path: Path) -> None:
    """The CLI hung on this spec; now it names the field and exits 2. The timeout only stops a hang."""
    spec = tmp_path / "nested.yaml"
    spec.write_text(f'plant: {{tf: {{num: [1], den: "{NESTED}"}}}}\nloops: [{{type: pi}}]\n')
    p = subprocess.run([sys.executable, "-m", "gaintune", "verify", str(spec), "--gains", '{"loop0": {"Kp": 1, "Ki": 1}}'],
                       capture_output=True, text=True, timeout=300)
    assert p.returncode == 2, p.stderr
    assert "plant.tf.den" in p.stderr and "limit of 20" in p.stderr and "Traceback" not in p.stderr
