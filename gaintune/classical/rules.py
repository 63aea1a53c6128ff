"""Classical PID tuning rules on an FOTD model (or on the ultimate gain and period).

Every rule returns an :class:`IdealPid` (``Kc``, ``Ti``, ``Td`` of the ideal,
non-interacting form ``Kc (1 + 1/(Ti s) + Td s)``; ``Ti = inf`` means no
integral action, ``Td = 0`` no derivative action) for a controller type
``p``, ``pi``, ``pd`` or ``pid``. :func:`to_loop_gains` converts it to the
loop's form: parallel ``Kp = Kc, Ki = Kc/Ti, Kd = Kc*Td`` or ideal.

Notation: the model is ``K e^{-Ls}/(Ts+1)``; integrating models are
``Kv e^{-Ls}/s`` (``Fotd.integrating``; K holds Kv). Formulas are listed in
``docs/baselines.md``; the ones from GUIDE.md section 4 are used verbatim.

Where a published rule has no P or PD variant we keep its proportional gain
(and derivative time) and drop the integral term; this is stated per rule.

Negative process gains (reverse-acting loops): every FOTD rule's ``Kc`` is
proportional to ``1/K`` (or ``1/Kv``) while ``Ti`` and ``Td`` do not depend on
``K``, so a model with ``K < 0`` gives the mirror-image controller: the same
magnitudes as for ``|K|`` and ``Kc < 0`` (so Kp, Ki, Kd < 0).
:func:`ultimate_gain` returns the magnitude ``Ku`` for either sign. The caller
(:func:`gaintune.classical.tuning.tune_classical`) gives ``Kc`` the sign of
the loop's direction.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np

from gaintune.classical.fotd import Fotd, NoModelError
from gaintune.lti.statespace import StateSpace, as_state_space
from gaintune.spec import GAIN_NAMES, LoopSpec

__all__ = [
    "IdealPid",
    "zn_step",
    "zn_ultimate",
    "simc",
    "amigo",
    "imc",
    "ultimate_gain",
    "series_to_ideal",
    "to_loop_gains",
    "with_direction",
    "FOTD_RULES",
]

CTYPES = ("p", "pi", "pd", "pid")


@dataclass(frozen=True)
class IdealPid:
    """Ideal-form PID parameters: Kc (1 + 1/(Ti s) + Td s)."""

    Kc: float
    Ti: float = math.inf
    Td: float = 0.0

    def parallel(self) -> tuple[float, float, float]:
        """(Kp, Ki, Kd)."""
        ki = self.Kc / self.Ti if math.isfinite(self.Ti) and self.Ti > 0 else 0.0
        return self.Kc, ki, self.Kc * self.Td


def series_to_ideal(Kc: float, tau_i: float, tau_d: float) -> IdealPid:
    """Series (interacting) ``Kc (tau_i s + 1)/(tau_i s) (tau_d s + 1)`` -> ideal form."""
    if not math.isfinite(tau_i):
        return IdealPid(Kc, math.inf, tau_d)
    f = 1.0 + tau_d / tau_i
    return IdealPid(Kc * f, tau_i + tau_d, tau_i * tau_d / (tau_i + tau_d))


def _check(m: Fotd, ctype: str, rule: str, need_delay: bool = True) -> None:
    if ctype not in CTYPES:
        raise NoModelError(rule, f"no {rule} rule for a {ctype!r} loop (classical rules cover p, pi, pd, pid)")
    if not (math.isfinite(m.K) and m.K != 0):
        raise NoModelError(rule, f"the loop's plant gain is {m.K:.3g}: a rule needs a finite, nonzero gain")
    if need_delay and not m.L > 0:
        raise NoModelError(
            rule, f"{rule} needs a positive apparent delay L (got {m.L:g}); give the plant's delay or sample time"
        )
    if not m.integrating and not m.T > 0:
        raise NoModelError(rule, f"{rule} needs a positive time constant T (got {m.T:g})")


# ------------------------------------------------------------ Ziegler-Nichols


def zn_step(m: Fotd, ctype: str) -> IdealPid:
    """Ziegler-Nichols step-response rule, a = K L / T (integrating: a = Kv L).

    P: Kc = 1/a. PI: 0.9/a, Ti = 3L. PID: 1.2/a, Ti = 2L, Td = L/2.
    PD (no published row): the PID row without integral action.
    """
    _check(m, ctype, "zn_step")
    a = m.K * m.L if m.integrating else m.K * m.L / m.T
    return {
        "p": IdealPid(1.0 / a),
        "pi": IdealPid(0.9 / a, 3.0 * m.L),
        "pd": IdealPid(1.2 / a, math.inf, 0.5 * m.L),
        "pid": IdealPid(1.2 / a, 2.0 * m.L, 0.5 * m.L),
    }[ctype]


def zn_ultimate(Ku: float, Pu: float, ctype: str) -> IdealPid:
    """Ziegler-Nichols ultimate-gain rule.

    P: 0.5 Ku. PI: 0.45 Ku, Ti = Pu/1.2. PID: 0.6 Ku, Ti = Pu/2, Td = Pu/8.
    PD: 0.8 Ku, Td = Pu/8 (the usual textbook PD row).
    """
    if ctype not in CTYPES:
        raise NoModelError("zn_ultimate", f"no rule for a {ctype!r} loop")
    if not (Ku > 0 and Pu > 0 and math.isfinite(Ku) and math.isfinite(Pu)):
        raise NoModelError("zn_ultimate", f"needs a finite positive ultimate gain and period, got Ku={Ku}, Pu={Pu}")
    return {
        "p": IdealPid(0.5 * Ku),
        "pi": IdealPid(0.45 * Ku, Pu / 1.2),
        "pd": IdealPid(0.8 * Ku, math.inf, Pu / 8.0),
        "pid": IdealPid(0.6 * Ku, Pu / 2.0, Pu / 8.0),
    }[ctype]


# ------------------------------------------------------------------- SIMC


def simc(m: Fotd, ctype: str, tau_c: float | None = None) -> IdealPid:
    """Skogestad's SIMC rules; tau_c defaults to the model's delay (tau_c = theta).

    * PI (and P, without the integral): Kc = T/(K (tau_c + L)), Ti = min(T, 4 (tau_c + L)).
      Integrating: Kc = 1/(Kv (tau_c + L)), Ti = 4 (tau_c + L).
    * PID on the second-order model K e^{-L2 s}/((T1 s+1)(T2 s+1)), series form:
      Kc = T1/(K (tau_c + L2)), tau_I = min(T1, 4 (tau_c + L2)), tau_D = T2, converted
      to the ideal form. When the second lag is small (T2 < L2/3) the improved SIMC
      rule for FOTD processes (Grimholt & Skogestad 2012) is used instead:
      Kc = (T + L/3)/(K (tau_c + L)), tau_I = min(T + L/3, 4 (tau_c + L)), tau_D = L/3.
      Integrating: Kc = 1/(Kv (tau_c + L2)), tau_I = 4 (tau_c + L2), tau_D = T2
      (T2 < L2/3: the PI values on (Kv, L) with tau_D = L/3).
    * PD: the PID's Kc and tau_D without the integral term (SIMC PD for second-order plants).
    """
    _check(m, ctype, "simc")
    if ctype in ("p", "pi"):
        tc = m.L if tau_c is None else tau_c
        if m.integrating:
            kc, ti = 1.0 / (m.K * (tc + m.L)), 4.0 * (tc + m.L)
        else:
            kc, ti = m.T / (m.K * (tc + m.L)), min(m.T, 4.0 * (tc + m.L))
        return IdealPid(kc) if ctype == "p" else IdealPid(kc, ti)
    second_order = m.T2 >= m.L2 / 3.0 and m.T2 > 0 and m.L2 > 0
    if second_order:
        tc = m.L2 if tau_c is None else tau_c
        if m.integrating:
            kc, t_i, t_d = 1.0 / (m.K * (tc + m.L2)), 4.0 * (tc + m.L2), m.T2
        else:
            kc, t_i, t_d = m.T1 / (m.K * (tc + m.L2)), min(m.T1, 4.0 * (tc + m.L2)), m.T2
    else:
        tc = m.L if tau_c is None else tau_c
        if m.integrating:
            kc, t_i, t_d = 1.0 / (m.K * (tc + m.L)), 4.0 * (tc + m.L), m.L / 3.0
        else:
            t1 = m.T + m.L / 3.0
            kc, t_i, t_d = t1 / (m.K * (tc + m.L)), min(t1, 4.0 * (tc + m.L)), m.L / 3.0
    if ctype == "pd":
        return IdealPid(kc, math.inf, t_d)
    return series_to_ideal(kc, t_i, t_d)


# ------------------------------------------------------------------ AMIGO


def amigo(m: Fotd, ctype: str) -> IdealPid:
    """AMIGO rules (Astrom & Hagglund), formulas as in GUIDE.md section 4.

    PI:  Kc = 0.15/K + (0.35 - L T/(L+T)^2) T/(K L), Ti = 0.35 L + 13 L T^2/(T^2 + 12 L T + 7 L^2).
    PID: Kc = (0.2 + 0.45 T/L)/K, Ti = L (0.4 L + 0.8 T)/(L + 0.1 T), Td = 0.5 L T/(0.3 L + T).
    Integrating (the T -> inf limits): PI Kc = 0.35/(Kv L), Ti = 13.4 L;
    PID Kc = 0.45/(Kv L), Ti = 8 L, Td = 0.5 L.
    P and PD (no published rows): the PI / PID rows without the integral term.
    """
    _check(m, ctype, "amigo")
    K, T, L = m.K, m.T, m.L
    if ctype in ("p", "pi"):
        if m.integrating:
            kc, ti = 0.35 / (K * L), 13.4 * L
        else:
            kc = 0.15 / K + (0.35 - L * T / (L + T) ** 2) * T / (K * L)
            ti = 0.35 * L + 13.0 * L * T**2 / (T**2 + 12.0 * L * T + 7.0 * L**2)
        return IdealPid(kc) if ctype == "p" else IdealPid(kc, ti)
    if m.integrating:
        kc, ti, td = 0.45 / (K * L), 8.0 * L, 0.5 * L
    else:
        kc = (0.2 + 0.45 * T / L) / K
        ti = L * (0.4 * L + 0.8 * T) / (L + 0.1 * T)
        td = 0.5 * L * T / (0.3 * L + T)
    return IdealPid(kc, math.inf, td) if ctype == "pd" else IdealPid(kc, ti, td)


# ------------------------------------------------------------ IMC / lambda


def default_lambda(m: Fotd) -> float:
    """Closed-loop time constant used by :func:`imc` when none is given: max(T, 2L).

    lambda = T keeps the open-loop speed for lag-dominant plants (classic lambda
    tuning); the floor 2L keeps the PI's gain margin >= 3*pi/2 ~ 4.7 on the FOTD
    model for delay-dominant ones. Integrating models use 2L.
    """
    return 2.0 * m.L if m.integrating else max(m.T, 2.0 * m.L)


def imc(m: Fotd, ctype: str, lam: float | None = None) -> IdealPid:
    """IMC / lambda tuning with closed-loop time constant ``lam`` (default :func:`default_lambda`).

    * PI (lambda tuning): Kc = T/(K (lam + L)), Ti = T. P: the same Kc.
    * PID (Rivera, Morari & Skogestad 1986, ideal form): Kc = (2T + L)/(K (2 lam + L)),
      Ti = T + L/2, Td = T L/(2T + L). PD: the same Kc and Td.
    * Integrating PI: Kc = (2 lam + L)/(Kv (lam + L)^2), Ti = 2 lam + L. Integrating PID
      (our extension): the PI values in series form with tau_D = max(T2, L/3).
    """
    _check(m, ctype, "imc", need_delay=False)
    lam = default_lambda(m) if lam is None else lam
    if not lam > 0:
        raise NoModelError("imc", f"needs lambda > 0 (got {lam:g}); the model has no delay and no lag")
    K, T, L = m.K, m.T, m.L
    if m.integrating:
        kc, ti = (2 * lam + L) / (K * (lam + L) ** 2), 2 * lam + L
        if ctype == "p":
            return IdealPid(kc)
        if ctype == "pi":
            return IdealPid(kc, ti)
        td = max(m.T2, L / 3.0)
        if not td > 0:
            raise NoModelError("imc", "integrating PID needs a lag or a delay to set Td")
        return IdealPid(kc, math.inf, td) if ctype == "pd" else series_to_ideal(kc, ti, td)
    if ctype in ("p", "pi"):
        kc = T / (K * (lam + L))
        return IdealPid(kc) if ctype == "p" else IdealPid(kc, T)
    kc = (2 * T + L) / (K * (2 * lam + L))
    td = T * L / (2 * T + L)
    if not td > 0:
        raise NoModelError("imc", "IMC PID needs a positive delay (Td = T L/(2T + L) is 0)")
    return IdealPid(kc, math.inf, td) if ctype == "pd" else IdealPid(kc, T + L / 2, td)


#: Rules that work on an FOTD model, by method name.
FOTD_RULES: dict[str, Callable[[Fotd, str], IdealPid]] = {
    "zn_step": zn_step,
    "simc": simc,
    "amigo": amigo,
    "imc": imc,
}


# -------------------------------------------------------- ultimate gain


#: Finer grids laid inside the -180 degree bracket by :func:`ultimate_gain`, and their points.
ZOOM_PASSES = 3
ZOOM_POINTS = 33


def ultimate_gain(sys: Any, delay: float = 0.0, n_grid: int = 4000) -> tuple[float, float]:
    """Ultimate gain Ku and period Pu of a SISO path with an exact delay e^{-j w delay}.

    The phase of G(jw) e^{-jw delay} is unwrapped on a log grid from low
    frequency; the first -180 degree crossing is refined by :data:`ZOOM_PASSES` finer grids
    inside its bracket and a final linear interpolation (~1e-14 relative: the bracket shrinks
    ~30,000-fold, and the phase is smooth across it). No root finder is imported: scipy.optimize
    (with scipy.sparse) cost 0.14 s of every tune's start for this one crossing.

    ``sys`` is a SISO state space (:class:`gaintune.lti.statespace.StateSpace`, python-control's, or
    a python-control transfer function), ``delay`` the path's dead time in seconds.

    A path with a negative gain (static gain, or velocity gain of an integrating path) is
    analysed as its negation: ``Ku`` is the magnitude of the ultimate gain either way.

    Raises
    ------
    NoModelError
        When the phase never reaches -180 degrees (Ku infinite) or the low-frequency gain
        is negative after that (open-loop unstable paths).
    """
    sys = as_state_space(sys)
    sgn = _path_sign(sys)

    def resp(x: Any) -> np.ndarray:
        return sgn * sys.freqresp(1j * np.atleast_1d(x)).reshape(-1)

    w = _frequency_grid(sys, delay, n_grid)
    g = resp(w)
    ph = np.unwrap(np.angle(g)) - w * delay
    k = _first_crossing(g, ph)
    wu = _zoom_crossing(resp, w, g, ph, k, delay)
    Ku = 1.0 / abs(resp(wu)[0])
    return float(Ku), float(2.0 * np.pi / wu)


def _path_sign(sys: StateSpace) -> float:
    """-1 for a stable-sign path with a negative (static or velocity) gain, else +1."""
    from gaintune.controllers.direction import path_gain

    if sys.nstates:
        d = float(np.asarray(sys.D)[0, 0])
        pg = path_gain(np.asarray(sys.A), np.asarray(sys.B)[:, 0], np.asarray(sys.C)[0], d)
        if pg is not None and pg.coef < 0 and pg.rhp_real == 0:
            return -1.0
    return 1.0


def _frequency_grid(sys: StateSpace, delay: float, n_grid: int) -> np.ndarray:
    """Log grid three decades either side of the path's pole magnitudes and 1/delay."""
    p = np.linalg.eigvals(sys.A) if sys.nstates else np.zeros(0)
    mags = np.abs(p[np.abs(p) > 1e-12])
    lo = min([*(mags.tolist()), 1.0 / delay if delay > 0 else np.inf, 1.0])
    hi = max([*(mags.tolist()), 1.0 / delay if delay > 0 else 0.0, 1.0])
    return np.logspace(np.log10(lo) - 3, np.log10(hi) + 3, n_grid)


def _first_crossing(g: np.ndarray, ph: np.ndarray) -> int:
    """Index of the first grid point at or below -180 degrees; NoModelError when there is none to bracket."""
    g0 = g[0]
    if g0.real <= 0 and abs(g0.imag) < abs(g0.real):
        raise NoModelError(
            "zn_ultimate", "the path's low-frequency gain is negative: needs a reverse-acting controller"
        )
    below = np.nonzero(ph <= -np.pi)[0]
    if below.size == 0:
        raise NoModelError(
            "zn_ultimate", "the phase never reaches -180 degrees: the ultimate gain is infinite (no delay, order <= 2)"
        )
    k = int(below[0])
    if k == 0:
        raise NoModelError("zn_ultimate", "phase is below -180 degrees at the lowest frequency: cannot find Ku")
    return k


def _zoom_crossing(
    resp: Callable[[Any], np.ndarray], w: np.ndarray, g: np.ndarray, ph: np.ndarray, k: int, delay: float
) -> float:
    """The -180 degree frequency inside ``w[k-1] .. w[k]``: :data:`ZOOM_PASSES` finer grids, then interpolation."""
    w1 = w[k - 1]
    g1 = g[k - 1]

    def phase(x: np.ndarray) -> np.ndarray:
        """Phase + pi at ``x`` inside the bracket (continuous from ``w1``: the bracket is narrow)."""
        return ph[k - 1] + np.angle(resp(x) / g1) - (x - w1) * delay + np.pi

    lo_w, hi_w = float(w[k - 1]), float(w[k])
    f_lo, f_hi = float(ph[k - 1] + np.pi), float(ph[k] + np.pi)
    for _ in range(ZOOM_PASSES):
        x = np.linspace(lo_w, hi_w, ZOOM_POINTS)
        f = phase(x)
        f[0], f[-1] = f_lo, f_hi  # the bracket's ends keep their values: the crossing stays inside
        j = int(np.argmax(f <= 0.0))
        lo_w, hi_w, f_lo, f_hi = float(x[j - 1]), float(x[j]), float(f[j - 1]), float(f[j])
    return lo_w + f_lo * (hi_w - lo_w) / (f_lo - f_hi) if f_lo != f_hi else hi_w


# ------------------------------------------------------------ conversion


def with_direction(pid: IdealPid, direction: int) -> IdealPid:
    """The same controller magnitudes with ``Kc`` of sign ``direction`` (+1 direct, -1 reverse)."""
    return IdealPid(math.copysign(abs(pid.Kc), direction), pid.Ti, pid.Td)


def to_loop_gains(pid: IdealPid, loop: LoopSpec) -> dict[str, float]:
    """Ideal-form parameters -> the loop's gain names (parallel Kp/Ki/Kd or ideal Kp/Ti/Td).

    Kp, Ki and Kd take the sign of ``Kc`` (negative: a reverse-acting loop); Ti and Td are positive.
    """
    names = GAIN_NAMES[(loop.type, loop.form)]
    kp, ki, kd = pid.parallel()
    values = {"Kp": kp, "Ki": ki, "Kd": kd, "Ti": pid.Ti, "Td": pid.Td}
    out = {n: float(values[n]) for n in names}
    sign = 1.0 if pid.Kc > 0 else -1.0
    for n, v in out.items():
        want = sign if n in ("Kp", "Ki", "Kd") else 1.0
        if not (math.isfinite(v) and v * want > 0):
            what = "positive" if want > 0 else "negative"
            raise NoModelError(f"{loop.name}.{n}", f"the rule gives {n} = {v:g}; it must be finite and {what}")
    return out
