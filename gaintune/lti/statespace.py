"""A python-control stand-in for the classical rules: state space, conversions, series, step response.

python-control costs about a second to import (it loads scipy.signal and matplotlib), too
much for every ``gaintune tune``, and the rules need only a few of its operations. Each one
here repeats python-control 0.10's own operations without slycot, so the rules' gains are the
same bit for bit (``tests/classical/test_control_free.py`` checks them against
python-control). Layer 0: numpy, scipy.linalg (lazily) and :mod:`gaintune.lti.pade`;
python-control is imported only to convert a model without state matrices
(:func:`as_state_space` given a python-control transfer function).

* :class:`StateSpace` (poles, transmission zeros, frequency response) and
  :func:`as_state_space`;
* :func:`ss_to_tf`, :func:`tf_to_ss`, :func:`tf_minreal`;
* :func:`series`, :func:`with_input_delay` (Padé, :func:`pade_state_space`);
* :func:`step_response` (exact at the samples, through the matrix exponential).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np

from gaintune.lti.pade import canonical_form, pade_monic

__all__ = ["StateSpace", "as_state_space", "ss_to_tf", "tf_to_ss", "tf_minreal", "series", "with_input_delay",
           "step_response", "pade_state_space", "one_stable_lag"]


def _mat(x: Any) -> np.ndarray:
    a = np.array(x, dtype=float)
    return a.reshape(0, 0) if a.size == 0 else np.atleast_2d(a)


@dataclass(frozen=True, eq=False)
class StateSpace:
    """Continuous-time model x' = A x + B u, y = C x + D u (read-only float copies).

    Stands in for python-control's StateSpace on the classical-rule path. Empty A, B or C
    (a static gain) take their shapes from D, as in python-control.

    Examples
    --------
    >>> g = StateSpace([[-1.0]], [[1.0]], [[2.0]], [[0.0]])
    >>> g.nstates, g.ninputs, g.noutputs, complex(g(0.0)[0, 0])
    (1, 1, 1, (2+0j))
    """

    A: np.ndarray
    B: np.ndarray
    C: np.ndarray
    D: np.ndarray

    def __post_init__(self) -> None:
        A, B, C, D = (_mat(x) for x in (self.A, self.B, self.C, self.D))
        n = A.shape[0] or B.shape[0] or C.shape[1]
        m = B.shape[1] if B.size else D.shape[1]
        p = C.shape[0] if C.size else D.shape[0]
        A, B, C, D = (x if x.size else np.zeros(shape) for x, shape in
                      ((A, (n, n)), (B, (n, m)), (C, (p, n)), (D, (p, m))))
        if A.shape != (n, n) or B.shape != (n, m) or C.shape != (p, n) or D.shape != (p, m):
            raise ValueError(f"inconsistent state-space shapes A{A.shape} B{B.shape} C{C.shape} D{D.shape}")
        for name, x in zip("ABCD", (A, B, C, D), strict=True):
            x.flags.writeable = False
            object.__setattr__(self, name, x)

    nstates = property(lambda self: self.A.shape[0], doc="Number of states.")
    ninputs = property(lambda self: self.D.shape[1], doc="Number of inputs.")
    noutputs = property(lambda self: self.D.shape[0], doc="Number of outputs.")

    def poles(self) -> np.ndarray:
        """Eigenvalues of A."""
        return np.linalg.eigvals(self.A) if self.nstates else np.zeros(0)

    def freqresp(self, s: Any) -> np.ndarray:
        """G(s) = C (sI - A)^-1 B + D at the points ``s``: (noutputs, ninputs, len(s)), complex; inf at a pole.

        One LU solve per point, as python-control without slycot (so the same ultimate gain).
        """
        x = np.atleast_1d(s).astype(complex, copy=False)
        A, B, C, D = self.A, self.B, self.C, self.D
        if self.nstates == 0:
            return D[:, :, np.newaxis] * np.ones_like(x, dtype=complex)
        if self.nstates == 1:
            with np.errstate(divide="ignore", invalid="ignore"):
                out = C[:, :, np.newaxis] / (x - A[0, 0]) * B[:, :, np.newaxis] + D[:, :, np.newaxis]
            out[np.isnan(out)] = complex(np.inf, np.nan)
            return out
        out = np.empty((self.noutputs, self.ninputs, x.size), dtype=complex)
        eye = np.eye(self.nstates)
        for k, xk in enumerate(x):
            try:
                out[:, :, k] = C @ np.linalg.solve(xk * eye - A, B) + D
            except np.linalg.LinAlgError:
                out[:, :, k] = complex(np.inf, np.nan)
        return out

    def __call__(self, s: Any) -> np.ndarray:
        """G(s): (noutputs, ninputs) at a scalar ``s``, (noutputs, ninputs, len(s)) at an array."""
        g = self.freqresp(s)
        return g[:, :, 0] if np.ndim(s) == 0 else g

    def zeros(self) -> np.ndarray:
        """Finite transmission zeros: generalized eigenvalues of the Rosenbrock pencil
        [[A, B], [C, D]] - s [[I, 0], [0, 0]] (square systems, as python-control without slycot)."""
        n, p, m = self.nstates, self.noutputs, self.ninputs
        if n == 0:
            return np.array([])
        if p != m:
            raise NotImplementedError("transmission zeros need as many inputs as outputs")
        import scipy.linalg  # deferred: only the paths that need zeros pay for scipy.linalg

        L = np.concatenate((np.concatenate((self.A, self.B), axis=1), np.concatenate((self.C, self.D), axis=1)), axis=0)
        M = np.pad(np.eye(n), ((0, p), (0, m)), "constant")
        return np.array([x for x in scipy.linalg.eigvals(L, M, overwrite_a=True) if not np.isinf(x)], dtype=complex)


def as_state_space(sys: Any) -> StateSpace:
    """``sys`` as a :class:`StateSpace`.

    Parameters
    ----------
    sys
        A StateSpace (returned as is), anything with ``A``, ``B``, ``C``, ``D`` (python-control's
        or scipy's state space), or anything else ``control.ss`` accepts (a python-control
        transfer function: the only case that imports python-control).
    """
    if isinstance(sys, StateSpace):
        return sys
    if all(hasattr(sys, a) for a in "ABCD"):
        return StateSpace(sys.A, sys.B, sys.C, sys.D)
    import control

    ss = control.ss(sys)
    return StateSpace(ss.A, ss.B, ss.C, ss.D)


def one_stable_lag(A: np.ndarray, B: np.ndarray, C: np.ndarray, D: np.ndarray) -> float | None:
    """The pole ``a`` of a SISO path that is one stable lag with a readable gain, else None.

    One state, no feedthrough, ``a`` clear of the origin (more than 1e-9 of max(1, |a|) to its left:
    closer, the FOTD fit reads an integrator) and a gain ``bc`` above 1e-9 |a| (below, a minimal
    realisation may cancel the state). For such a path the classical rules' general machinery (minimal
    realisation, zeros' pencil, low-frequency expansion) gives what ``a`` and ``bc`` give directly: its
    time scale (:mod:`gaintune.classical.timescale`) and its loop sign (:mod:`gaintune.controllers.direction`)
    read them without it.
    """
    A, B, C, D = (np.asarray(x, dtype=float) for x in (A, B, C, D))
    if A.shape != (1, 1) or D.size != 1 or D.ravel()[0] != 0.0:
        return None
    a, bc = float(A[0, 0]), float(B.ravel()[0] * C.ravel()[0])
    if not (math.isfinite(a) and math.isfinite(bc)) or -a <= 1e-9 * max(1.0, abs(a)) or abs(bc) <= 1e-9 * abs(a):
        return None
    return a


def _tf_clean(num: Any, den: Any) -> tuple[np.ndarray, np.ndarray]:
    """A SISO (num, den) as python-control stores it: zero numerator -> den 1, leading zeros cut."""
    num, den = np.atleast_1d(np.asarray(num, dtype=float)), np.atleast_1d(np.asarray(den, dtype=float))
    if not np.any(den):
        raise ValueError("the transfer function has a zero denominator")
    if not np.any(num):
        den = np.ones(1)
    num, den = (c[np.flatnonzero(c)[0]:] if np.any(c) else np.zeros(1) for c in (num, den))
    return num, den




def tf_to_ss(num: Any, den: Any) -> StateSpace:
    """Realisation of the SISO transfer function num/den, as ``control.ss(control.tf(num, den))``.

    Parameters
    ----------
    num, den
        Coefficients in descending powers of s (proper: ``len(num) <= len(den)``). The
        realisation is the controller canonical form (no states for a static gain).
    """
    num, den = _tf_clean(num, den)
    if num.size > den.size:
        raise ValueError("transfer function is non-proper; can't convert to StateSpace system")
    if num.size == 1 and den.size == 1:
        return StateSpace(np.zeros((0, 0)), np.zeros((0, 1)), np.zeros((1, 0)), np.array([[num[0] / den[0]]]))
    return StateSpace(*canonical_form(num, den))


def ss_to_tf(sys: Any) -> tuple[np.ndarray, np.ndarray]:
    """Transfer function of input 0 -> output 0, as ``control.tf(sys)`` without slycot.

    den = det(sI - A), num = det(sI - A + B C) + (D - 1) den (leading zeros cut).

    Parameters
    ----------
    sys
        State space (see :func:`as_state_space`). (num, den) come in descending powers of s.
    """
    sys = as_state_space(sys)
    if sys.nstates == 0:
        return _tf_clean([sys.D[0, 0]], [1.0])
    A, B, C, D = sys.A, sys.B[:, :1], sys.C[:1, :], sys.D[:1, :1]
    den = np.poly(A)
    return _tf_clean(np.poly(A - np.dot(B, C)) + (D[0] - 1) * den, den)


def tf_minreal(num: Any, den: Any, tol: float | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Cancel coincident pole/zero pairs of num/den, as ``control.minreal(control.tf(num, den), tol)``.

    Parameters
    ----------
    num, den
        Coefficients in descending powers of s.
    tol
        A zero cancels the first pole closer than this; default ``1000 max(eps, |z| sqrt(eps))``.
        The reduced (num, den) keeps the ratio of the leading coefficients as its gain.
    """
    num, den = _tf_clean(num, den)
    zeros, poles = np.roots(num), np.roots(den)
    eps = np.finfo(float).eps
    kept = []
    for z in zeros:
        idx = np.where(abs(z - poles) < (tol or 1000 * max(eps, abs(z) * math.sqrt(eps))))[0]
        if len(idx):
            poles = np.delete(poles, idx[0])
        else:
            kept.append(z)
    return _tf_clean(np.atleast_1d(num[0] / den[0] * np.real(np.poly(kept))), np.atleast_1d(np.real(np.poly(poles))))


def series(first: Any, second: Any) -> StateSpace:
    """``second`` driven by ``first`` (u -> first -> second -> y), as ``control.series(first, second)``.

    Parameters
    ----------
    first, second
        State spaces (see :func:`as_state_space`); ``first``'s outputs feed ``second``'s inputs.
        The result has the states of ``first``, then those of ``second``.
    """
    g1, g2 = as_state_space(first), as_state_space(second)
    if g1.noutputs != g2.ninputs:
        raise ValueError(f"cannot connect {g1.noutputs} outputs to {g2.ninputs} inputs")
    A = np.concatenate((np.concatenate((g1.A, np.zeros((g1.nstates, g2.nstates))), axis=1),
                        np.concatenate((g2.B @ g1.C, g2.A), axis=1)), axis=0)
    B = np.concatenate((g1.B, g2.B @ g1.D), axis=0)
    return StateSpace(A, B, np.concatenate((g2.D @ g1.C, g2.C), axis=1), g2.D @ g1.D)


def with_input_delay(sys: Any, delay: float, order: int) -> StateSpace:
    """``sys`` (one input, any outputs) behind an (order, order) Padé approximation of e^{-s delay}.

    Parameters
    ----------
    sys
        State space (see :func:`as_state_space`).
    delay
        Input delay in seconds; <= 0 returns ``sys``.
    order
        Padé order (:func:`pade_state_space`).
    """
    sys = as_state_space(sys)
    return sys if delay <= 0 else series(pade_state_space(delay, order), sys)


def step_response(sys: Any, t: np.ndarray) -> np.ndarray:
    """Response of every output to a unit step on input 0, from rest, as python-control's ``step_response``.

    Exact at the samples: x_{k+1} = Ad x_k + (Bd0 + Bd1) u, from the matrix exponential of the
    system augmented with its input (the same recursion, and rounding, as python-control).

    Parameters
    ----------
    sys
        State space (see :func:`as_state_space`).
    t
        Equally spaced times, starting at the step.

    Returns
    -------
    ndarray
        (noutputs, len(t)).
    """
    import scipy.linalg  # deferred: scipy.linalg costs ~0.2 s to import

    sys = as_state_space(sys)
    A, B, C, D = sys.A, sys.B[:, :1], sys.C, sys.D[:, :1]
    t = np.asarray(t, dtype=float)
    n, k = A.shape[0], t.size
    dt = (t[-1] - t[0]) / (k - 1)
    U = np.ones((1, k))
    M = np.block([[A * dt, B * dt, np.zeros((n, 1))], [np.zeros((1, n + 1)), np.identity(1)], [np.zeros((1, n + 2))]])
    expM = scipy.linalg.expm(M)
    Ad, Bd1 = expM[:n, :n], expM[:n, n + 1:]
    Bd0 = expM[:n, n:n + 1] - Bd1
    x = np.zeros((n, k))
    for i in range(1, k):
        x[:, i] = Ad @ x[:, i - 1] + Bd0 @ U[:, i - 1] + Bd1 @ U[:, i]
    return C @ x + D @ U


def pade_state_space(T: float, order: int) -> StateSpace:
    """The Padé delay of :func:`pade_monic` realised as ``control.ss(pade_tf(T, order))`` does."""
    return tf_to_ss(*pade_monic(T, order))
