"""First-order-plus-dead-time (FOTD) models of a loop's plant path.

Classical tuning rules need a model ``K e^{-Ls}/(Ts + 1)`` (self-regulating) or
``Kv e^{-Ls}/s`` (integrating). :func:`fit_fotd` obtains one from a SISO
linear path (state space of the delay-free part, :class:`gaintune.lti.statespace.StateSpace`
or python-control's, plus a delay in seconds):

* **Half rule** (Skogestad 2003) when every pole is real (and stable),
  there are no left-half-plane zeros and no direct feedthrough: with the
  lags sorted ``tau_1 >= tau_2 >= ...`` and the right-half-plane zeros
  ``(-T_j s + 1)``::

      T = tau_1 + tau_2/2
      L = delay + tau_2/2 + sum_{i>=3} tau_i + sum_j T_j

  The second-order model used by SIMC PID keeps ``tau_1``, takes
  ``T2 = tau_2 + tau_3/2`` and ``L2 = delay + tau_3/2 + sum_{i>=4} tau_i + sum_j T_j``.
  For an integrating path the integrator is the dominant lag (``tau_1 = inf``),
  so ``Kv = lim s G(s)``, ``L = delay + tau_2/2 + sum_{i>=3} tau_i + sum_j T_j``
  and, for PID, ``T2 = tau_2`` (model ``Kv e^{-L2 s}/(s (T2 s + 1))``).
* **Step-response least squares** otherwise (the general method): ``K`` is the
  exact static gain; ``T`` and ``L`` minimise the squared error between the
  delay-free step response (sampled on 2,000 points over five times the sum of
  the plant's time constants) and the FOTD step response, started from the
  28 %/63 % two-point estimate ``T = 1.5 (t63 - t28)``, ``L = t63 - T``. The
  plant delay is added to ``L``. The second-order model is fitted the same way.
  Integrating paths fit the path without the integrator, ``Kv e^{-Lr s}/(Tr s+1)``,
  and use ``L = Lr + Tr/2`` (the half rule with the integrator as dominant lag).

``K`` (or ``Kv``) is negative for a reverse-acting path; every step above works
on the signed gain (the step response is normalised by ``K``).

The path is handled with :mod:`gaintune.lti.statespace` (the operations python-control performs,
without importing it: that import costs about a second of ``gaintune tune``).

No FOTD model applies (and :class:`NoModelError` is raised, naming why) to
unstable paths, double integrators, paths with zero static gain, and
oscillatory paths (step-response overshoot above :data:`OSCILLATION_LIMIT`).

Examples
--------
>>> import control
>>> s = control.tf("s")
>>> m = fit_fotd(control.ss(1 / (s + 1) ** 3), method="half_rule")
>>> round(m.K, 6), round(m.T, 6), round(m.L, 6)
(1.0, 1.5, 1.5)
"""

from __future__ import annotations

import math
import warnings
from dataclasses import asdict, dataclass
from typing import Any, Literal

import numpy as np

from gaintune.errors import GaintuneError
from gaintune.lti.pade import pade_tf
from gaintune.lti.statespace import StateSpace, as_state_space, ss_to_tf, step_response, tf_minreal, tf_to_ss

__all__ = ["Fotd", "NoModelError", "fit_fotd", "path_poles_zeros", "siso_minreal", "OSCILLATION_LIMIT"]

#: Largest relative step-response overshoot for which an FOTD model is still fitted.
OSCILLATION_LIMIT = 0.10

FitMethod = Literal["auto", "half_rule", "step_fit", "two_point"]


class NoModelError(GaintuneError):
    """No FOTD model (or no classical rule) applies to this loop; the message says why."""


@dataclass(frozen=True)
class Fotd:
    """``K e^{-Ls}/(Ts+1)``, or ``K e^{-Ls}/s`` when ``integrating`` (then K is the velocity gain)."""

    K: float
    T: float
    L: float
    integrating: bool = False
    method: str = ""
    #: Second-order model for SIMC PID: K e^{-L2 s}/((T1 s+1)(T2 s+1)), or Kv e^{-L2 s}/(s (T2 s+1)).
    T1: float = 0.0
    T2: float = 0.0
    L2: float = 0.0
    #: RMS step-response error of the FOTD model relative to |K| (step fits only).
    fit_error: float | None = None

    def with_extra_delay(self, dl: float) -> Fotd:
        """The same model with ``dl`` seconds more apparent delay (e.g. half a sample)."""
        d = asdict(self)
        d["L"] += dl
        d["L2"] += dl
        return Fotd(**d)

    def to_dict(self) -> dict[str, Any]:
        """The model's fields as a plain dict (JSON-serialisable)."""
        return asdict(self)

    def tf(self, pade: int | None = None):
        """python-control TF of the model (delay as a Pade approximation of order ``pade``, or omitted)."""
        import control

        s = control.tf("s")
        g = self.K / s if self.integrating else self.K / (self.T * s + 1)
        if pade and self.L > 0:
            g = g * pade_tf(self.L, pade)
        return g


# ---------------------------------------------------------------- helpers


def _siso_ss(sys) -> StateSpace:
    sys = as_state_space(sys)
    if sys.ninputs != 1 or sys.noutputs != 1:
        raise ValueError(f"need a SISO path, got {sys.noutputs}x{sys.ninputs}")
    return sys


def siso_minreal(sys, tol: float = 1e-6) -> StateSpace:
    """Minimal SISO state space: cancels (near-)coincident pole/zero pairs via the transfer function.

    Paths cut from a multi-output plant carry unobservable modes (e.g. the
    position integrator seen from a velocity output); they must go before poles
    are classified.

    Parameters
    ----------
    sys
        SISO state space (:class:`gaintune.lti.statespace.StateSpace`, python-control's, or a
        python-control transfer function).
    tol
        Largest distance between a cancelled zero and pole.

    Returns
    -------
    StateSpace
        Controller canonical form of the reduced transfer function (no states for a static gain).
    """
    sys = as_state_space(sys)
    if sys.nstates == 0:
        return sys
    num, den = ss_to_tf(sys)
    # Round-off in the ss -> tf conversion leaves tiny leading numerator terms
    # (spurious zeros near infinity): drop them relative to the coefficient scale.
    scale = max(np.abs(num).max(initial=0.0), 1e-300)
    num = np.where(np.abs(num) < 1e-10 * scale, 0.0, num)
    if np.any(num):
        num = np.trim_zeros(num, "f")
    num, den = tf_minreal(num, den, tol=tol)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        return tf_to_ss(num, den)


def path_poles_zeros(sys) -> tuple[np.ndarray, np.ndarray]:
    """Poles and (finite) transmission zeros of a SISO state-space path.

    Parameters
    ----------
    sys
        SISO state space (:class:`gaintune.lti.statespace.StateSpace` or python-control's).

    Returns
    -------
    tuple of ndarray
        Eigenvalues of A and the finite zeros.
    """
    sys = _siso_ss(sys)
    p = sys.poles()
    try:
        z = sys.zeros()
    except Exception:  # pragma: no cover - degenerate pencils
        z = np.zeros(0)
    z = z[np.isfinite(z)]
    return p, z


def _scale(p: np.ndarray) -> float:
    return max(1.0, float(np.max(np.abs(p)))) if p.size else 1.0


def _is_real(v: complex, rel: float = 0.05) -> bool:
    # Repeated real roots come out of eig() with a small imaginary scatter
    # (about eps^(1/n) for n-fold roots): accept that as real.
    return abs(v.imag) <= rel * max(abs(v), 1e-12)


def _dc_gain(sys) -> float:
    A, B, C, D = (np.asarray(m, dtype=float) for m in (sys.A, sys.B, sys.C, sys.D))
    if A.size == 0:
        return float(D[0, 0])
    return float((D - C @ np.linalg.solve(A, B))[0, 0])


def _dc_gain_scale(sys) -> float:
    """The size the static gain's rounding is relative to: |C| |A^-1 B| + |D|. A gain below 1e-12 of it is a
    zero at s = 0; the path's own units do not decide (a process gain of 1e-15 read as zero against 1e-12)."""
    A, B, C, D = (np.asarray(m, dtype=float) for m in (sys.A, sys.B, sys.C, sys.D))
    lag = float(np.linalg.norm(C) * np.linalg.norm(np.linalg.solve(A, B))) if A.size else 0.0
    return lag + float(np.abs(D).max(initial=0.0))


def _remove_integrator(sys: StateSpace) -> tuple[float, StateSpace]:
    """(Kv, rest): the velocity gain Kv = lim s G(s) and a state space of s G(s), the path without its integrator."""
    num, den = ss_to_tf(sys)
    den = den / den[0]
    rest_den = den[:-1]  # drop the root at the origin (last coefficient ~ 0)
    # ss_to_tf leaves round-off (~1e-17) where a leading numerator coefficient is zero: scipy then
    # warns "badly conditioned filter coefficients" for a plain P-PI cascade; drop it
    num = np.asarray(num, dtype=float).ravel()
    num = np.where(np.abs(num) <= 1e-12 * np.max(np.abs(num), initial=0.0), 0.0, num)
    num = np.trim_zeros(num, "f") if np.any(num) else np.zeros(1)
    if rest_den.size == 1:
        rest = StateSpace(np.zeros((0, 0)), np.zeros((0, 1)), np.zeros((1, 0)), np.array([[num[-1] / rest_den[0]]]))
        return float(num[-1] / rest_den[-1]), rest
    return float(num[-1] / rest_den[-1]), tf_to_ss(num, rest_den)


# -------------------------------------------------------------- half rule


def _merge_clusters(v: np.ndarray, rel: float = 0.1) -> np.ndarray:
    """Replace clusters of scattered roots (a multiple root computed by eig()) by their mean.

    Only clusters that contain a complex member are merged: genuinely distinct real
    roots stay as they are. The mean of the scattered copies of an n-fold root is
    accurate to rounding, while each copy is off by about eps^(1/n).
    """
    v = np.asarray(v, dtype=complex).copy()
    n = v.size
    label = list(range(n))

    def find(i: int) -> int:
        while label[i] != i:
            label[i] = label[label[i]]
            i = label[i]
        return i

    for i in range(n):
        for j in range(i + 1, n):
            if abs(v[i] - v[j]) <= rel * max(abs(v[i]), abs(v[j]), 1e-300):
                label[find(i)] = find(j)
    groups: dict[int, list[int]] = {}
    for i in range(n):
        groups.setdefault(find(i), []).append(i)
    for members in groups.values():
        if len(members) > 1 and any(abs(v[i].imag) > 0 for i in members):
            v[members] = np.mean(v[members])
    return v


def _half_rule_parts(p: np.ndarray, z: np.ndarray, D: float):
    """Time constants and inverse-response times, or None when the half rule does not apply."""
    if abs(D) > 0:
        return None
    p, z = _merge_clusters(p), _merge_clusters(z)
    if not all(_is_real(v) for v in p) or not all(_is_real(v) for v in z):
        return None
    if np.any(z.real < 0):  # left-half-plane zeros: no half-rule approximation here
        return None
    taus = sorted((float(-1.0 / v.real) for v in p), reverse=True)
    inv = float(sum(1.0 / v.real for v in z if v.real > 0))
    return taus, inv


def _half_rule(taus: list[float], inv: float, delay: float, K: float, integrating: bool) -> Fotd:
    t = list(taus) + [0.0, 0.0, 0.0]
    if integrating:
        L = delay + t[0] / 2 + sum(taus[1:]) + inv
        L2 = delay + t[1] / 2 + sum(taus[2:]) + inv
        return Fotd(K, 0.0, L, True, "half_rule", T1=0.0, T2=t[0], L2=L2)
    T = t[0] + t[1] / 2
    L = delay + t[1] / 2 + sum(taus[2:]) + inv
    T1, T2 = t[0], t[1] + t[2] / 2
    L2 = delay + t[2] / 2 + sum(taus[3:]) + inv
    return Fotd(K, T, L, False, "half_rule", T1=T1, T2=T2, L2=L2)


# ------------------------------------------------------ step-response fit


def _step(sys: StateSpace, horizon: float, n: int = 2000) -> tuple[np.ndarray, np.ndarray]:
    t = np.linspace(0.0, horizon, n)
    return t, np.asarray(step_response(sys, t)[0], dtype=float).ravel()


def _fotd_step(t: np.ndarray, K: float, T: float, L: float) -> np.ndarray:
    tt = np.maximum(t - L, 0.0)
    return K * (1.0 - np.exp(-tt / max(T, 1e-12)))


def _sotd_step(t: np.ndarray, K: float, T1: float, T2: float, L: float) -> np.ndarray:
    tt = np.maximum(t - L, 0.0)
    T1 = max(T1, 1e-12)
    if abs(T1 - T2) < 1e-6 * T1:
        return K * (1.0 - (1.0 + tt / T1) * np.exp(-tt / T1))
    return K * (1.0 - (T1 * np.exp(-tt / T1) - T2 * np.exp(-tt / max(T2, 1e-12))) / (T1 - T2))


def _crossing(t: np.ndarray, y: np.ndarray, level: float) -> float:
    k = int(np.argmax(y >= level))
    if k == 0:
        return float(t[0])
    return float(t[k - 1] + (level - y[k - 1]) * (t[k] - t[k - 1]) / (y[k] - y[k - 1]))


def _step_fit(sys, K: float, method: str) -> Fotd:
    """Fit (T, L) (and the SOPDT model) to the delay-free unit step response."""
    from scipy.optimize import least_squares

    p, _ = path_poles_zeros(sys)
    slow = [1.0 / abs(v.real) for v in p if abs(v.real) > 1e-12]
    horizon = 5.0 * sum(slow) if slow else 1.0
    t, y = _step(sys, horizon)
    yn = y / K
    overshoot = float(np.max(yn) - 1.0)
    if overshoot > OSCILLATION_LIMIT:
        raise NoModelError(
            "fotd",
            f"the step response overshoots by {100 * overshoot:.0f} % (oscillatory path); "
            "an FOTD model does not apply: use an optimiser baseline instead",
        )
    t28, t63 = _crossing(t, yn, 0.283), _crossing(t, yn, 0.632)
    T0 = max(1.5 * (t63 - t28), 1e-6 * horizon)
    L0 = max(t63 - T0, 0.0)
    if method == "two_point":
        err = float(np.sqrt(np.mean((_fotd_step(t, 1.0, T0, L0) - yn) ** 2)))
        return Fotd(K, T0, L0, method="two_point", T1=T0, T2=0.0, L2=L0, fit_error=err)
    lo_t = 1e-9 * horizon
    r1 = least_squares(
        lambda v: _fotd_step(t, 1.0, v[0], v[1]) - yn,
        x0=[T0, min(L0, horizon)],
        bounds=([lo_t, 0.0], [10 * horizon, horizon]),
        x_scale=[horizon, horizon],
    )
    T, L = (float(v) for v in r1.x)
    err = float(np.sqrt(np.mean(r1.fun**2)))
    r2 = least_squares(
        lambda v: _sotd_step(t, 1.0, v[0], v[0] * v[1], v[2]) - yn,
        x0=[T, 0.1, L],
        bounds=([lo_t, 0.0, 0.0], [10 * horizon, 1.0, horizon]),
        x_scale=[horizon, 1.0, horizon],
    )
    T1, ratio, L2 = (float(v) for v in r2.x)
    return Fotd(K, T, L, method="step_fit", T1=T1, T2=T1 * ratio, L2=L2, fit_error=err)


# ------------------------------------------------------------------ public


def fit_fotd(sys, delay: float = 0.0, method: FitMethod = "auto") -> Fotd:
    """FOTD model of a SISO path ``sys`` (delay-free state space) with ``delay`` seconds of dead time.

    Parameters
    ----------
    sys
        SISO path: a :class:`gaintune.lti.statespace.StateSpace`, anything with ``A``, ``B``, ``C``,
        ``D`` (python-control's StateSpace), or anything else ``control.ss`` accepts
        (TransferFunction; only then is python-control imported).
    delay
        Pure time delay of the path in seconds (added to the model's L).
    method
        ``"auto"`` (half rule when it applies, else the step-response fit),
        ``"half_rule"`` (raises NoModelError when it does not apply),
        ``"step_fit"`` (least squares) or ``"two_point"`` (28 %/63 %).

    Raises
    ------
    NoModelError
        For unstable, oscillatory, double-integrating or zero-gain paths, or when
        ``method="half_rule"`` is requested for a path it does not cover.
    """
    sys = siso_minreal(_siso_ss(sys))
    p, z = path_poles_zeros(sys)
    sc = _scale(p)
    at_origin = np.abs(p) <= 1e-9 * sc
    n_int = int(np.sum(at_origin))
    if np.any(p[~at_origin].real > 0) or np.any(np.abs(p[~at_origin].real) <= 1e-12 * sc):
        raise NoModelError(
            "fotd",
            "the path is unstable (a pole in the right half plane or on the imaginary axis); "
            "classical FOTD rules do not apply: use an optimiser baseline",
        )
    if n_int > 1:
        raise NoModelError("fotd", f"the path has {n_int} integrators; FOTD rules cover at most one")
    D = float(np.asarray(sys.D)[0, 0])
    if n_int == 1:
        Kv, rest = _remove_integrator(sys)
        if not math.isfinite(Kv) or abs(Kv) < 1e-300:
            raise NoModelError("fotd", "the integrating path has zero velocity gain")
        rp, rz = path_poles_zeros(rest)
        parts = _half_rule_parts(rp, rz, float(np.asarray(rest.D)[0, 0])) if rest.nstates else ([], 0.0)
        if method in ("auto", "half_rule") and parts is not None:
            return _half_rule(parts[0], parts[1], delay, Kv, True)
        if method == "half_rule":
            raise NoModelError("fotd", "half rule needs real poles, no left-half-plane zeros and no feedthrough")
        if rest.nstates == 0:
            return Fotd(Kv, 0.0, delay, True, method, T2=0.0, L2=delay)
        m = _step_fit(rest, _dc_gain(rest), "step_fit" if method == "auto" else method)
        return Fotd(Kv, 0.0, delay + m.L + m.T / 2, True, m.method, T2=m.T, L2=delay + m.L, fit_error=m.fit_error)
    K = _dc_gain(sys)
    if not math.isfinite(K) or abs(K) <= 1e-12 * _dc_gain_scale(sys):
        raise NoModelError("fotd", "the path has zero static gain; an FOTD model does not apply")
    parts = _half_rule_parts(p, z, D)
    if method in ("auto", "half_rule") and parts is not None:
        return _half_rule(parts[0], parts[1], delay, K, False)
    if method == "half_rule":
        raise NoModelError("fotd", "half rule needs real poles, no left-half-plane zeros and no feedthrough")
    m = _step_fit(sys, K, "step_fit" if method == "auto" else method)
    return Fotd(m.K, m.T, m.L + delay, False, m.method, T1=m.T1, T2=m.T2, L2=m.L2 + delay, fit_error=m.fit_error)
