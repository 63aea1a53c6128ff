"""Modes of a state-space model: eigenvalues, state responses through the complex Schur form, observability.

Nothing here knows about specs, loops or plants: it imports only numpy and scipy.linalg
(lazily), so every layer may use it.

* **State responses** X(s) = (sI - A)^-1 B through the complex Schur form A = Z T Z^H
  (:func:`complex_schur`, :func:`plant_state_response`) and the eigenvalues of A
  (:func:`plant_eigvals`), both remembered per model object (the cache key is its identity:
  a verification or a search changes the gains, not the model).
* **Observability**: :func:`observable_split` separates the modes the measured outputs see
  from those they do not.
"""

from __future__ import annotations

from typing import Protocol

import numpy as np

__all__ = ["StateMatrices", "plant_eigvals", "complex_schur", "plant_state_response", "observable_split"]


class StateMatrices(Protocol):
    """What the cached helpers need of a model: its state matrices A (n, n) and B (n, 1).

    Read-only properties, so a frozen model (``LinearModel``) satisfies it.
    """

    @property
    def A(self) -> np.ndarray: ...

    @property
    def B(self) -> np.ndarray: ...


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


#: Rounding floor of the Krylov rank test (the state matrix scaled to norm 1): a new direction's part outside
#: the subspace found so far counts above it, however small the coupling that reaches it.
_ROUNDING = 1e-12


def _orth(M: np.ndarray, tol: float) -> np.ndarray:
    if M.size == 0:
        return M
    U, sv, _ = np.linalg.svd(M, full_matrices=False)
    r = int(np.sum(sv > tol * max(1.0, sv[0] if sv.size else 1.0)))
    return U[:, :r]


def _new_directions(V: np.ndarray, M: np.ndarray, tol: float) -> np.ndarray:
    """Orthonormal directions of ``M``'s columns outside span(V) (V orthonormal): a part outside counts when
    it exceeds ``tol`` of M and the rounding floor. Judged against M, not against V's unit columns: a lag
    that an integrator sees through an entry of 1 beside 1/T = 2e9 couples by 5e-10 of the norm."""
    R = M - V @ (V.T @ M)
    R = R - V @ (V.T @ R)  # a second pass: one classical Gram-Schmidt pass leaves rounding in span(V)
    U, sv, _ = np.linalg.svd(R, full_matrices=False)
    floor = max(_ROUNDING, tol * float(np.linalg.norm(M, 2)))
    return U[:, : int(np.sum(sv > floor))]


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
    import scipy.linalg

    n = A.shape[0]
    # The rank test runs on the balanced model: x = D x_b with D diagonal (powers of 2, exact) changes no
    # mode's observability, and a companion form of lags of a microsecond (entries 1 and 3e12) otherwise
    # makes the coupling it observes through look like rounding (test_modes.py).
    Ab, D = scipy.linalg.matrix_balance(A, permute=False)
    d = np.diag(D)
    Cb = C * d[None, :]
    Ah = Ab / max(np.linalg.norm(Ab), 1e-300)
    # C's own scale says nothing about which modes it sees: a sensor gain of 1e-9 (a slow integrating
    # plant in small units) is a measurement, not the absence of one
    V = _orth(Cb.T / max(np.linalg.norm(Cb), 1e-300), tol)
    for _ in range(n):
        new = _new_directions(V, Ah.T @ V, tol) if V.size else V
        if not new.shape[1]:
            break
        V = np.hstack([V, new])
    r = V.shape[1]
    if r == n:
        return None
    # back to the model's coordinates: the observable row space is D^-1 times the balanced one
    U, _, _ = np.linalg.svd(V / d[:, None], full_matrices=True)
    return U[:, :r], U[:, r:]
