"""Generic linear time-invariant (LTI) helpers: Padé delays, complex Schur responses, observability.

Nothing here knows about specs, loops or plants: it imports only numpy and scipy.linalg
(lazily), so every layer may use it. The python-control stand-in the classical rules use
(state space, conversions, series, step response) is :mod:`gaintune.statespace`.

* **Padé approximation** of the delay e^{-sT}, order (n, n): :func:`pade_coeffs`,
  :func:`pade_response` (evaluated in the well-conditioned variable p = sT),
  :func:`pade_poles`, :func:`pade_ss` (a state-space realisation), all scaled from the
  unit-delay approximant; :func:`pade_monic` (python-control's ``pade``, computed for T
  directly) and :func:`pade_tf` (a python-control transfer function: imports python-control).
  The two normalisations agree to rounding but not bit for bit; the verification uses the
  first, the classical rules the second. :func:`canonical_form` realises a SISO transfer
  function as ``scipy.signal.tf2ss`` does, without importing scipy.signal (~0.7 s).
* **State responses** X(s) = (sI - A)^-1 B through the complex Schur form A = Z T Z^H
  (:func:`complex_schur`, :func:`plant_state_response`) and the eigenvalues of A
  (:func:`plant_eigvals`), both remembered per model object (the cache key is its identity:
  a verification or a search changes the gains, not the model).
* **Observability**: :func:`observable_split` separates the modes the measured outputs see
  from those they do not.
"""

from __future__ import annotations

import warnings
from functools import lru_cache
from typing import Any, Protocol

import numpy as np

__all__ = [
    "StateMatrices", "pade_coeffs", "pade_response", "pade_poles", "pade_ss", "pade_tf", "pade_monic",
    "canonical_form", "plant_eigvals", "complex_schur", "plant_state_response", "observable_split",
]


class StateMatrices(Protocol):
    """What the cached helpers need of a model: its state matrices A (n, n) and B (n, 1)."""

    A: np.ndarray
    B: np.ndarray


# ------------------------------------------------------------------ Padé


@lru_cache(maxsize=32)
def _pade_unit(order: int) -> tuple[np.ndarray, np.ndarray, tuple]:
    """Padé (order, order) of e^{-p} (unit delay) and a state-space realisation of it."""
    num, den = pade_monic(1.0, order)
    num, den = np.asarray(num, dtype=float), np.asarray(den, dtype=float)
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


# ------------------------------------------------------------------ state responses


_EIGVALS_CACHE: dict[int, tuple[StateMatrices, np.ndarray]] = {}


def plant_eigvals(lin: StateMatrices) -> np.ndarray:
    """Eigenvalues of ``lin.A``, remembered per model object (only the gains change between verifications)."""
    hit = _EIGVALS_CACHE.get(id(lin))
    if hit is not None and hit[0] is lin:
        return hit[1]
    v = np.linalg.eigvals(lin.A) if lin.A.size else np.zeros(0, dtype=complex)
    if len(_EIGVALS_CACHE) > 512:
        _EIGVALS_CACHE.clear()
    _EIGVALS_CACHE[id(lin)] = (lin, v)
    return v


_SCHUR_CACHE: dict[int, tuple[StateMatrices, np.ndarray, np.ndarray, np.ndarray]] = {}


def complex_schur(lin: StateMatrices) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(T, Z, Z^H B) of the complex Schur form A = Z T Z^H (T upper triangular, Z unitary),
    remembered per model object."""
    hit = _SCHUR_CACHE.get(id(lin))
    if hit is not None and hit[0] is lin:
        return hit[1:]
    import scipy.linalg

    T, Z = scipy.linalg.schur(lin.A.astype(complex), output="complex")
    zb = Z.conj().T @ lin.B[:, 0].astype(complex)
    if len(_SCHUR_CACHE) > 512:
        _SCHUR_CACHE.clear()
    _SCHUR_CACHE[id(lin)] = (lin, T, Z, zb)
    return T, Z, zb


def plant_state_response(lin: StateMatrices, s: np.ndarray) -> np.ndarray:
    """X(s) = (sI - A)^-1 B for each s: (W, n).

    Uses the complex Schur form A = Z T Z^H (unitary, so robust for defective A):
    a vectorised back-substitution over the frequencies, O(n^2) numpy operations.
    """
    T, Z, zb = complex_schur(lin)
    n = T.shape[0]
    x = np.empty((n, s.size), dtype=complex)
    with np.errstate(all="ignore"):
        for i in range(n - 1, -1, -1):
            acc = np.full(s.size, zb[i])
            if i + 1 < n:
                acc = acc + T[i, i + 1 :] @ x[i + 1 :]
            x[i] = acc / (s - T[i, i])
    return (Z @ x).T


# ------------------------------------------------------------------ observability


def _orth(M: np.ndarray, tol: float) -> np.ndarray:
    if M.size == 0:
        return M
    U, sv, _ = np.linalg.svd(M, full_matrices=False)
    r = int(np.sum(sv > tol * max(1.0, sv[0] if sv.size else 1.0)))
    return U[:, :r]


def observable_split(A: np.ndarray, C: np.ndarray, tol: float = 1e-9) -> tuple[np.ndarray, np.ndarray] | None:
    """Orthonormal bases (V1, V2) of the observable subspace of (A, C) and of its complement.

    In the coordinates [V1 V2] the model is block triangular: ``V1^T A V1`` (with
    ``V1^T B`` and ``C V1``) is its observable part, and the eigenvalues of ``V2^T A V2``
    are the unobservable modes. None when every mode is observable.

    Parameters
    ----------
    A
        State matrix (n, n).
    C
        Rows of the outputs that are measured (q, n).
    tol
        Relative singular-value threshold of the Krylov rank test.
    """
    n = A.shape[0]
    scale = max(np.linalg.norm(A), 1e-300)
    Ah = A / scale
    V = _orth(C.T, tol)
    for _ in range(n):
        W = _orth(np.hstack([V, Ah.T @ V]), tol)
        if W.shape[1] == V.shape[1]:
            break
        V = W
    r = V.shape[1]
    if r == n:
        return None
    U, _, _ = np.linalg.svd(V, full_matrices=True)
    return U[:, :r], U[:, r:]
