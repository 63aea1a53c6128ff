"""The hot paths' array helpers: integer powers past NumPy's fast range and the NaN replacement."""

from __future__ import annotations

import numpy as np
import pytest

from gaintune.lti.arrays import finite, int_power


@pytest.mark.parametrize("n", [0, 1, 2, 3, 36, 99, 100, 101, 130, 178, 1000])
def test_int_power_matches_the_exact_power_on_and_inside_the_unit_circle(n: int) -> None:
    w = np.linspace(0.0, np.pi, 501)
    s = -1e-3 + 1j * w
    z = np.exp(-s)
    exact = np.exp(-n * s)
    assert np.allclose(int_power(z, n), exact, rtol=0.0, atol=1e-12 * max(n, 1))
    assert np.allclose(int_power(z, n), z**n, rtol=1e-12, atol=1e-13 * max(n, 1))


def test_int_power_takes_one_exponent_per_channel() -> None:
    z = np.exp(1j * np.linspace(0.1, 3.0, 7))[:, None]
    d = np.array([[0, 5, 120, 5]])
    out = int_power(z, d)
    assert out.shape == (7, 4)
    for c in range(4):
        assert np.allclose(out[:, c], z[:, 0] ** int(d[0, c]), rtol=1e-12)
    with pytest.raises(ValueError, match="exponents must be >= 0"):
        int_power(z, np.array([-1]))


def test_int_power_returns_a_new_array_for_an_exponent_of_one() -> None:
    z = np.array([1.0 + 1.0j, 2.0])
    out = int_power(z, 1)
    out[0] = 0.0
    assert z[0] == 1.0 + 1.0j


def test_finite_gives_nan_to_nums_values_and_a_copy() -> None:
    x = np.array([[1.5, np.nan, np.inf], [-np.inf, -2.0, 0.0]])
    for nan, posinf, neginf in [(9.0, 8.0, 7.0), (1e300, 1e300, 0.0), (5.0, 5.0, float(np.finfo(float).min))]:
        got = finite(x, nan, posinf, neginf)
        assert np.array_equal(got, np.nan_to_num(x, nan=nan, posinf=posinf, neginf=neginf))
    clean = np.array([1.0, 2.0])
    out = finite(clean, 0.0, 0.0, 0.0)
    out[0] = 3.0
    assert clean[0] == 1.0


def test_below_numpys_threshold_int_power_is_numpys_power_to_the_bit() -> None:
    """Below an exponent of 100 NumPy multiplies repeatedly and is as fast: its values are kept, so a loop
    whose delay buffer is shorter than 100 samples is analysed as before to the last bit."""
    z = np.exp((-1e-3 + 1j) * np.linspace(0.0, np.pi, 777))
    for n in (0, 1, 7, 36, 99):
        assert int_power(z, n).tobytes() == (z**n).tobytes()
    d = np.array([[0, 3, 12, 99]])
    assert int_power(z[:, None], d).tobytes() == (z[:, None] ** d).tobytes()


def test_mixed_exponents_keep_numpys_values_below_100_and_square_above() -> None:
    z = np.exp((-1e-3 + 1j) * np.linspace(0.0, np.pi, 301))[:, None]
    d = np.array([[5, 150, 5, 99, 230]])
    out = int_power(z, d)
    small = np.array([0, 2, 3])
    assert out[:, small].tobytes() == (z ** d[:, small]).tobytes()
    assert np.allclose(out[:, [1, 4]], np.exp(d[0, [1, 4]] * np.log(z)), rtol=0.0, atol=1e-12)
