"""MIGO: the PI reference optimum under a sensitivity-peak limit (Åström & Hägglund).

For ``C(jw) = kp + ki/(jw)`` and a frequency response ``G(jw)`` (delays exact), MIGO maximises
``ki`` (minimises ``IE = 1/ki`` for a unit load step at the plant input) subject to
``Ms = max_w 1/|1 + C G| <= ms_max`` and closed-loop stability (Åström, Panagopoulos & Hägglund,
Automatica 34(5), 1998). :func:`boundary_optimum` then moves along ``ki = ki_max(kp)`` to minimise
a user cost (e.g. load IAE, which differs from IE for oscillatory responses). AMIGO was fitted
under the stronger combined-sensitivity circle M = 1.4, so MIGO at ``ms_max = 1.4`` has a larger
``ki`` than AMIGO (see tests/classical/test_migo.py).

**Stability.** Supported: open-loop stable plants, or one integrator (``G1(s)/s``, ``G1`` stable),
with positive static (velocity) gain and ``L(j inf) = 0``. For fixed ``kp`` and ``ki -> 0+`` the
closed-loop poles are those of ``1 + kp G`` plus one near ``-ki G(0)/(1 + kp G(0))`` (``-ki/kp``
if integrating), so that loop is stable iff ``1 + kp G`` is. As ``ki`` grows the poles move
continuously and reach the imaginary axis only where ``1 + L(jw) = 0``, i.e. ``Ms = inf``: every
``ki`` below the FIRST ``Ms > ms_max`` crossing of a stable small-``ki`` loop is stable.
:func:`ki_max_on_boundary` scans ``ki`` upward on a log grid (:data:`KI_PER_DECADE` a decade,
1e-8 to 1e2 times ``w_c/|G(j w_c)|``), bisects between the last feasible and first infeasible
point, and applies the Nyquist criterion at the smallest ``ki`` (and, as a safeguard, at the
result): with ``k`` poles of ``L`` at 0 there are ``Z = k/2 - D/pi`` RHP closed-loop poles, ``D``
the phase change of ``1 + L(jw)`` from its ``w -> 0+`` asymptote ``-k pi/2`` to ``arg 1 = 0`` at
``w = inf``. Unstable plants raise ValueError: ``open_loop_rhp_poles > 0`` (the contract), or a
negative ``Z`` (a partial safeguard when the flag is not given).

**Grid.** ``w`` (rad/s, increasing) must start well below the slowest plant corner (integrators
are counted from the low-frequency slope of ``|G|``), end where ``|L| << 1`` and resolve the
Nyquist curve near -1. The coarse minimum of ``|1 + L|`` is refined by golden section in
``log w`` between its grid neighbours (new ``G`` evaluations), to far below 1e-4 relative.

``G`` may carry an ``integrator(w)`` attribute, the integral action's frequency response
(default ``1/(jw)``): a sampled loop with a backward-Euler integral passes ``dt/(1 - e^{-jw dt})``
and its plant's ZOH response, with the grid ending at ``pi/dt``.

>>> G = lambda w: 1 / (1j * w + 1) ** 3
>>> round(migo_pi(G, 1.4, np.geomspace(1e-3, 1e2, 1000)).ms, 4)
1.4
"""

from __future__ import annotations

import warnings
from collections.abc import Callable
from dataclasses import dataclass
from typing import NamedTuple

import numpy as np
from scipy.optimize import minimize_scalar

__all__ = ["PiPoint", "pi_sensitivity_peak", "ki_max_on_boundary", "migo_pi", "boundary_optimum", "KI_PER_DECADE"]

FreqResp = Callable[[np.ndarray], np.ndarray]
#: ki scan density of :func:`ki_max_on_boundary`, points per decade.
KI_PER_DECADE = 12
_KI_DECADES, _BISECT_RTOL, _N_GOLDEN = (-8.0, 2.0), 1e-6, 20
_GOLD = (np.sqrt(5.0) - 1.0) / 2.0
_CHUNK = 1 << 21  # complex elements per (gain x frequency) block


@dataclass(frozen=True)
class PiPoint:
    """A PI design: gains, sensitivity peak Ms (refined to well below 1e-4 relative), optional cost."""

    kp: float
    ki: float
    ms: float
    cost: float | None = None


class _Plant(NamedTuple):
    w: np.ndarray
    Gw: np.ndarray
    n_int: int  # plant integrators (0 or 1)
    kp_scale: float  # 1/|G(j w_c)|
    w_c: float  # w180, else the -135 deg or half-power frequency
    kp_top: float  # default kp_range = (1e-3, kp_top) * kp_scale


def _resp(G: FreqResp, w) -> np.ndarray:
    return np.asarray(G(np.asarray(w, float)), complex)


def _integrator(G: FreqResp, w) -> np.ndarray:
    """The integral action's response: ``G.integrator(w)`` when G carries one, else ``1/(jw)``.

    A sampled loop (backward-Euler PI at sample time dt) passes ``dt/(1 - e^{-jw dt})``.
    """
    f = getattr(G, "integrator", None)
    w = np.asarray(w, float)
    return np.asarray(f(w), complex) if f is not None else 1.0 / (1j * w)


def _wrap(x):
    return (x + np.pi) % (2 * np.pi) - np.pi


def _chunk(G, w, Gw, kp, ki, k):
    """Refined Ms (and the Nyquist count Z when k is not None) for 1-D gain arrays."""
    Gi = Gw * _integrator(G, w)  # 1 + L = 1 + kp G + ki G I(w), in real arithmetic
    re = 1.0 + kp[:, None] * Gw.real + ki[:, None] * Gi.real
    im = kp[:, None] * Gw.imag + ki[:, None] * Gi.imag
    a2 = re * re + im * im
    i = np.argmin(a2, axis=1)
    amin, lw = np.sqrt(a2[np.arange(kp.size), i]), np.log(w)
    lo, hi = lw[np.maximum(i - 1, 0)], lw[np.minimum(i + 1, w.size - 1)]

    def f(x):
        return np.abs(1.0 + (kp + ki * _integrator(G, np.exp(x))) * _resp(G, np.exp(x)))

    x1, x2 = hi - _GOLD * (hi - lo), lo + _GOLD * (hi - lo)
    f1, f2 = f(x1), f(x2)
    for _ in range(_N_GOLDEN):  # golden-section minimisation of |1 + L|, all gains at once
        left = f1 < f2
        lo, hi = np.where(left, lo, x1), np.where(left, x2, hi)
        xn = np.where(left, hi - _GOLD * (hi - lo), lo + _GOLD * (hi - lo))
        fn = f(xn)
        x1, x2, f1, f2 = np.where(left, xn, x2), np.where(left, x1, xn), np.where(left, fn, f2), np.where(left, f1, fn)
    with np.errstate(divide="ignore"):
        ms = 1.0 / np.minimum(amin, np.minimum(f1, f2))
    if k is None:
        return ms, 0
    F = re + 1j * im
    ph0 = np.angle(F[:, 0])
    ph1 = ph0 + np.angle(F[:, 1:] * F[:, :-1].conj()).sum(axis=1)  # unwrapped arg(1 + L) at w[-1]
    total = _wrap(ph0 + k * np.pi / 2) + ph1 - ph0 + _wrap(-ph1)
    return ms, np.rint(k / 2 - total / np.pi).astype(int)


def _evaluate(G, w, Gw, kp, ki, k=None):
    """(Ms, Z) for broadcast gains, in blocks of at most _CHUNK complex elements (Z = 0 if k is None)."""
    kp, ki = np.broadcast_arrays(np.asarray(kp, float), np.asarray(ki, float))
    shape, kp, ki = kp.shape, kp.ravel(), ki.ravel()
    ms, z = np.empty(kp.size), np.zeros(kp.size, int)
    step = max(1, _CHUNK // w.size)
    for s in range(0, kp.size, step):
        ms[s : s + step], z[s : s + step] = _chunk(G, w, Gw, kp[s : s + step], ki[s : s + step], k)
    return ms.reshape(shape), z.reshape(shape)


def _check_w(w) -> np.ndarray:
    w = np.asarray(w, float)
    if w.ndim != 1 or w.size < 3 or w[0] <= 0 or np.any(np.diff(w) <= 0):
        raise ValueError("w must be a 1-D increasing grid of at least 3 positive frequencies (rad/s)")
    return w


def _plant(G: FreqResp, w, ms_max: float, open_loop_rhp_poles: int) -> _Plant:
    """Validate the problem; integrator count and natural kp/ki scales."""
    if not (np.isfinite(ms_max) and ms_max > 1.0):
        raise ValueError(f"ms_max must be finite and > 1 (Ms >= 1 whenever L(j inf) = 0), got {ms_max}")
    if open_loop_rhp_poles > 0:
        raise ValueError(f"open-loop unstable plant ({open_loop_rhp_poles} RHP poles): MIGO here supports open-loop "
                         "stable and integrating plants only (the small-ki argument needs a stable kp-only loop)")
    w = _check_w(w)
    Gw = _resp(G, w)
    if Gw.shape != w.shape or not np.all(np.isfinite(Gw)):
        raise ValueError("G(w) must return one finite complex value per frequency")
    n_int = int(np.rint(-np.log(abs(Gw[1]) / abs(Gw[0])) / np.log(w[1] / w[0])))
    if n_int not in (0, 1):
        raise ValueError(f"low-frequency slope of |G| suggests {n_int} poles at s = 0; PI supports 0 or 1")
    if (Gw[0] * (1j * w[0]) ** n_int).real <= 0:
        raise ValueError("static (velocity) gain of G must be positive: flip the plant's sign (or it is unstable)")
    ph, lw = np.unwrap(np.angle(Gw)), np.log(w)
    cross = np.flatnonzero(ph <= -np.pi)
    if cross.size and cross[0] > 0:  # phase crossover w180, interpolated in log w
        i, kp_top = cross[0], 1.0
        w_c = float(np.exp(np.interp(-np.pi, [ph[i], ph[i - 1]], [lw[i], lw[i - 1]])))
    else:
        c135 = np.flatnonzero(ph <= -0.75 * np.pi)
        half = np.flatnonzero(np.abs(Gw) * w**n_int <= abs(Gw[0]) * w[0] ** n_int / np.sqrt(2))
        w_c = float(w[c135[0]] if c135.size else w[half[0]] if half.size else np.sqrt(w[0] * w[-1]))
        kp_top = 1e2
    return _Plant(w, Gw, n_int, float(1.0 / abs(_resp(G, [w_c])[0])), w_c, kp_top)


def _ki_max(G: FreqResp, P: _Plant, kp, ms_max: float) -> np.ndarray:
    """ki_max for an array of kp: first-crossing scan on a log ki grid, then log bisection."""
    kp = np.atleast_1d(np.asarray(kp, float))
    grid = P.kp_scale * P.w_c * np.logspace(*_KI_DECADES, int((_KI_DECADES[1] - _KI_DECADES[0]) * KI_PER_DECADE) + 1)
    k = 1 + P.n_int
    z0 = _evaluate(G, P.w, P.Gw, kp, grid[0], k)[1]  # the small-ki loop: stable iff 1 + kp G is
    if np.any(z0 < 0):
        raise ValueError("negative Nyquist count: the plant has open-loop RHP poles (not supported)")
    good = _evaluate(G, P.w, P.Gw, kp[:, None], grid[None, :])[0] <= ms_max
    good[:, 0] &= z0 == 0
    bad, all_good = np.argmax(~good, axis=1), good.all(axis=1)  # first infeasible ki on the grid
    lo, hi = np.where(bad > 0, grid[np.maximum(bad - 1, 0)], 0.0), grid[bad]
    act = (bad > 0) & ~all_good
    for _ in range(int(np.ceil(np.log2(np.log(grid[1] / grid[0]) / _BISECT_RTOL))) + 1):
        if not act.any():
            break
        mid = np.sqrt(lo[act] * hi[act])
        ok = _evaluate(G, P.w, P.Gw, kp[act], mid)[0] <= ms_max
        lo[act], hi[act] = np.where(ok, mid, lo[act]), np.where(ok, hi[act], mid)
    lo = np.where(all_good, grid[-1], lo)
    if np.any(_evaluate(G, P.w, P.Gw, kp[lo > 0], lo[lo > 0], k)[1] != 0):  # the continuity argument, checked
        raise RuntimeError("a boundary point fails the Nyquist check: refine or widen the frequency grid w")
    return lo


def pi_sensitivity_peak(G: FreqResp, kp: float | np.ndarray, ki: float | np.ndarray, w: np.ndarray) -> np.ndarray:
    """Sensitivity peak ``Ms = max_w 1/|1 + (kp + ki/(jw)) G(jw)|`` for (broadcast arrays of) PI gains.

    Parameters
    ----------
    G : callable
        ``G(w) -> G(jw)``, complex, vectorised over a 1-D array of frequencies (rad/s).
    kp, ki : float or ndarray
        PI gains, broadcast against each other.
    w : ndarray
        Increasing frequency grid; the coarse peak on it is refined by golden section.

    Returns
    -------
    ndarray
        Ms, shape of the broadcast gains; ``inf`` where ``1 + L`` vanishes. Stability is not checked.
    """
    w = _check_w(w)
    return _evaluate(G, w, _resp(G, w), kp, ki)[0]


def ki_max_on_boundary(G: FreqResp, kp: float, ms_max: float, w: np.ndarray, *, open_loop_rhp_poles: int = 0) -> float:
    """Largest ``ki`` with a stable loop and ``Ms <= ms_max`` for all ``ki' in (0, ki]`` (at scan resolution).

    Parameters
    ----------
    G, w
        As in :func:`pi_sensitivity_peak` (see the module notes on the grid).
    kp : float
        Proportional gain, > 0.
    ms_max : float
        Sensitivity-peak limit, > 1.
    open_loop_rhp_poles : int
        RHP poles of G; > 0 raises ValueError (unsupported).

    Returns
    -------
    float
        ``ki_max`` to 1e-6 relative, on the feasible side; 0.0 when even the small-``ki`` loop is infeasible.
    """
    if not kp > 0:
        raise ValueError(f"kp must be positive, got {kp}")
    return float(_ki_max(G, _plant(G, w, ms_max, open_loop_rhp_poles), [kp], ms_max)[0])


def _kp_range(P: _Plant, kp_range) -> tuple[float, float]:
    lo, hi = kp_range if kp_range is not None else (1e-3 * P.kp_scale, P.kp_top * P.kp_scale)
    if not 0 < lo < hi:
        raise ValueError(f"kp_range must satisfy 0 < low < high, got {kp_range}")
    return float(lo), float(hi)


def migo_pi(G: FreqResp, ms_max: float, w: np.ndarray, kp_range: tuple[float, float] | None = None, *,
            open_loop_rhp_poles: int = 0) -> PiPoint:
    """MIGO PI design: maximise ``ki`` subject to ``Ms <= ms_max`` and closed-loop stability.

    Parameters
    ----------
    G, ms_max, w, open_loop_rhp_poles
        As in :func:`ki_max_on_boundary`.
    kp_range : (float, float), optional
        Default ``[1e-3, 1]/|G(j w180)|`` (up to the ultimate gain), or ``[1e-3, 100]/|G(j w_c)|``
        without phase crossover (``w_c`` at -135 deg, else the half-power frequency).

    Returns
    -------
    PiPoint
        From a 41-point log scan of ``kp`` and bounded Brent on ``log kp`` between the best point's
        neighbours; ``cost`` is None. ValueError when nothing is feasible; a warning at the range's top.
    """
    P = _plant(G, w, ms_max, open_loop_rhp_poles)
    kps = np.geomspace(*_kp_range(P, kp_range), 41)
    return _migo(G, P, ms_max, kps, _ki_max(G, P, kps, ms_max))


def _migo(G: FreqResp, P: _Plant, ms_max: float, kps: np.ndarray, kis: np.ndarray) -> PiPoint:
    """MIGO from a kp scan: bounded Brent on log kp between the best scan point's neighbours."""
    j = int(np.argmax(kis))
    if kis[j] <= 0:
        raise ValueError(f"no stable PI gains with Ms <= {ms_max} for kp in [{kps[0]:.4g}, {kps[-1]:.4g}]")
    if j == kps.size - 1:
        warnings.warn("MIGO kp is at the top of kp_range: widen it", stacklevel=3)
    res = minimize_scalar(lambda x: -_ki_max(G, P, np.exp(x), ms_max)[0], method="bounded", options={"xatol": 1e-5},
                          bounds=(np.log(kps[max(j - 1, 0)]), np.log(kps[min(j + 1, kps.size - 1)])))
    kp, ki = (float(np.exp(res.x)), float(-res.fun)) if -res.fun > kis[j] else (float(kps[j]), float(kis[j]))
    return PiPoint(kp, ki, float(_evaluate(G, P.w, P.Gw, kp, ki)[0]))


def boundary_optimum(G: FreqResp, ms_max: float, w: np.ndarray, cost: Callable[[np.ndarray, np.ndarray], np.ndarray],
                     kp_range: tuple[float, float] | None = None, n_scan: int = 41, *, rounds: int = 4,
                     open_loop_rhp_poles: int = 0) -> tuple[PiPoint, PiPoint]:
    """MIGO and the lowest-cost point on the constraint boundary ``ki = ki_max(kp)``.

    Parameters
    ----------
    G, ms_max, w, kp_range, open_loop_rhp_poles
        As in :func:`migo_pi`.
    cost : callable
        ``cost(kp, ki) -> costs`` over 1-D arrays (non-finite is stored as inf). The scan points
        with ``ki_max > 0`` and MIGO go to ONE call; each refinement round makes one more.
    n_scan : int
        kp scan points (log grid over ``kp_range``).
    rounds : int
        Refinement rounds, each a 9-point log grid between the best point's neighbours.

    Returns
    -------
    (PiPoint, PiPoint)
        ``(migo, best)`` with costs, ``best`` the lower-cost of MIGO and the scan/refine result;
        both satisfy ``Ms <= ms_max``.
    """
    if n_scan < 3 or rounds < 0:
        raise ValueError(f"need n_scan >= 3 and rounds >= 0, got {n_scan}, {rounds}")
    P = _plant(G, w, ms_max, open_loop_rhp_poles)
    kps = np.geomspace(*_kp_range(P, kp_range), n_scan)
    kis = _ki_max(G, P, kps, ms_max)
    migo = _migo(G, P, ms_max, kps, kis)

    def costs(kp, ki):
        c = np.asarray(cost(kp, ki), float).reshape(kp.shape)
        return np.where(np.isfinite(c), c, np.inf)

    m = kis > 0
    c_all = costs(np.append(kps[m], migo.kp), np.append(kis[m], migo.ki))
    migo = PiPoint(migo.kp, migo.ki, migo.ms, float(c_all[-1]))
    c = np.full(n_scan, np.inf)
    c[m] = c_all[:-1]
    for _ in range(rounds):
        j = int(np.argmin(c))
        if not np.isfinite(c[j]):
            break
        kps = np.geomspace(kps[max(j - 1, 0)], kps[min(j + 1, kps.size - 1)], 9)  # contains kps[j]
        kis = _ki_max(G, P, kps, ms_max)
        m, c = kis > 0, np.full(9, np.inf)
        if m.any():
            c[m] = costs(kps[m], kis[m])
    j = int(np.argmin(c))
    if not c[j] < migo.cost:
        return migo, migo
    kp, ki = float(kps[j]), float(kis[j])
    return migo, PiPoint(kp, ki, float(_evaluate(G, P.w, P.Gw, kp, ki)[0]), float(c[j]))
