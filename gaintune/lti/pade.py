"""Padé approximants of the delay e^{-sT}, and the controller canonical form of a SISO transfer function.

Nothing here knows about specs, loops or plants: it imports only numpy (and python-control in
:func:`pade_tf` alone), so every layer may use it.

* Padé approximation of order (n, n): :func:`pade_coeffs`, :func:`pade_response` (evaluated in
  the well-conditioned variable p = sT), :func:`pade_poles`, :func:`pade_ss` (a state-space
  realisation), all scaled from the unit-delay approximant; :func:`pade_monic` (python-control's
  ``pade``, computed for T directly) and :func:`pade_tf` (a python-control transfer function:
  imports python-control). The two normalisations agree to rounding but not bit for bit; the
  verification uses the first, the classical rules the second.
* :func:`canonical_form` realises a SISO transfer function as ``scipy.signal.tf2ss`` does,
  without importing scipy.signal (~0.7 s).
"""

from __future__ import annotations

import warnings
from functools import lru_cache

import numpy as np

__all__ = ["pade_coeffs", "pade_response", "pade_poles", "pade_ss", "pade_tf", "pade_monic", "canonical_form"]


# ------------------------------------------------------------------ Padé


@lru_cache(maxsize=32)
def _pade_unit(order: int) -> tuple[np.ndarray, np.ndarray, tuple]:
    """Padé (order, order) of e^{-p} (unit delay) and a state-space realisation of it."""
    num_l, den_l = pade_monic(1.0, order)
    num, den = np.asarray(num_l, dtype=float), np.asarray(den_l, dtype=float)
    Ad, Bd, Cd, Dd = canonical_form(num, den)
    return num, den, (Ad, Bd, Cd, float(Dd[0, 0]))


def pade_coeffs(T: float, order: int) -> tuple[np.ndarray, np.ndarray]:
    """(num, den) of the (order, order) Padé approximant of e^{-sT} (descending powers of s)."""
    if T <= 0:
        return np.array([1.0]), np.array([1.0])
    num, den, _ = _pade_unit(order)
    k = np.arange(num.size - 1, -1, -1)
    return num * T**k, den * T**k


def pade_response(s: np.ndarray, T: float, order: int) -> np.ndarray:
    """Padé approximant of e^{-sT} at s, evaluated in the well-conditioned variable p = sT."""
    num, den, _ = _pade_unit(order)
    p = s * T
    return np.polyval(num, p) / np.polyval(den, p)


def pade_poles(T: float, order: int) -> np.ndarray:
    """Poles of the (order, order) Padé approximant of e^{-sT} (T > 0)."""
    return np.roots(_pade_unit(order)[1]) / T


def pade_ss(T: float, order: int):
    """(Ad, Bd, Cd, Dd) of the Padé delay: the unit-delay realisation with time scaled by T."""
    Ad, Bd, Cd, Dd = _pade_unit(order)[2]
    return Ad / T, Bd / T, Cd, Dd


def pade_monic(T: float, order: int) -> tuple[list[float], list[float]]:
    """(num, den) of the (order, order) Padé approximant of e^{-sT}, monic denominator.

    ``control.pade(T, order)``'s numbers (Golub & van Loan, Alg. 11.3.1, the same operations
    in the same order) without importing python-control.

    Parameters
    ----------
    T
        Delay in seconds (>= 0; 0 gives 1/1).
    order
        Degree of numerator and denominator (both returned in descending powers of s).
    """
    if not T >= 0:
        raise ValueError("require T >= 0")
    if T == 0:
        return [1.0], [1.0]
    num, den = [0.0] * (order + 1), [0.0] * (order + 1)
    num[-1] = den[-1] = cn = cd = 1.0
    for k in range(1, order + 1):
        cn *= -T * (order - k + 1) / (order + order - k + 1) / k
        cd *= T * (order - k + 1) / (order + order - k + 1) / k
        num[order - k], den[order - k] = cn, cd
    return [c / den[0] for c in num], [c / den[0] for c in den]


def pade_tf(T: float, order: int):
    """``control.tf(*control.pade(T, order))``: imports python-control (the rules use :func:`pade_state_space`)."""
    import control

    return control.tf(*pade_monic(T, order))




def canonical_form(num: np.ndarray, den: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """(A, B, C, D) of num/den in controller canonical form: ``scipy.signal.tf2ss``'s operations, for SISO
    (without importing scipy.signal, ~0.7 s)."""
    den = np.trim_zeros(den, "f")
    num, den = num / den[0], den / den[0]
    lead = 0
    while lead < num.size and abs(num[lead]) <= 1e-14:
        lead += 1
    if lead:  # scipy warns (BadCoefficients, a UserWarning) and drops these columns
        warnings.warn("Badly conditioned filter coefficients (numerator): the results may be meaningless",
                      UserWarning, stacklevel=3)
        num = num[min(lead, num.size - 1):]
    M, K = num.size, den.size
    if M > K:
        raise ValueError("Improper transfer function. `num` is longer than `den`.")
    num = np.hstack((np.zeros((1, K - M)), num[np.newaxis, :]))
    D = np.atleast_2d(num[:, 0])
    if K == 1:
        return np.zeros((1, 1)), np.zeros((1, 1)), np.zeros((1, 1)), D
    A = np.r_[-np.array([den[1:]]), np.eye(K - 2, K - 1)]
    return A, np.eye(K - 1, 1), num[:, 1:] - np.outer(num[:, 0], den[1:]), D
