"""Proven bounds on |L| above the analysis band (the "tail"), so the band can stop there.

This concerns the continuous analysis (``verify.sampled: false``; the sampled loop's band
simply ends at pi/dt, where its Nyquist curve ends). The loop is analysed in continuous time
with the sample-and-hold as dt/2 of delay, a model that only holds below the Nyquist frequency
pi/dt. Resolving the delay's phase spin far above it (up to where |L| < 1e-4, often 1e7 rad/s)
costs most of the grid and describes nothing physical.
:func:`gaintune.verification.analysis.analyse` therefore stops the band at a multiple of the
Nyquist frequency, *provided* this module proves that the frequencies above the band cannot
change any figure or the stability count:

* every break point's |L(jw)| stays below a level tau for all w >= w_cap, where tau is
  chosen from the band's own figures so that no gain crossing, no lower gain margin, no
  upper gain margin smaller than the band's, and no larger Ms, Mt or 1/alpha can hide there;
* the plant-input loop stays below 1 on the shifted contour Re s = -eps used by the
  argument principle, so the Nyquist count closes exactly at the band edge.

The delay e^{-sT} has |.| = 1 on the imaginary axis, so these are statements about
*delay-free rational* functions, proven with the Hamiltonian level-set test: for
G = C (sI - A)^-1 B + D and gamma > |D|, |G(jw)| = gamma exactly at the w where jw is an
eigenvalue of the Hamiltonian matrix M_gamma (Boyd, Balakrishnan and Kabamba 1989). No
eigenvalue on the axis above w_cap, |G(j w_cap)| < gamma and |D| < gamma imply
|G(jw)| < gamma for every w >= w_cap.

Outer loops of a cascade are not rational (the inner loops close around the delay):
with the notation of :mod:`gaintune.verification.cascade`, L_i = -g_i H_{i+1} and
H_{i+1} = Phi_{i+1} / (1 - g^{(i+1)}), where g_i = e^{-sT} G_i, g^{(i+1)} = e^{-sT} Gin_{i+1}
(the plant-input loop of loops i+1.. alone) and Phi_{i+1} the product of the inner setpoint
paths, all rational. Hence |L_i| <= |G_i Phi_{i+1}| / (1 - |Gin_{i+1}|), bounded by two
level tests. Any test that fails only means the band is widened (ultimately to the old,
uncapped analysis); it never changes a figure.
"""

from __future__ import annotations

import math

import numpy as np

from gaintune.plants.plant import LinearModel
from gaintune.verification.cascade import Cascade
from gaintune.verification.laws import LoopCtl, controller_state_index

__all__ = ["chain_ss", "series", "level_clear", "tail_levels"]

SS = tuple[np.ndarray, np.ndarray, np.ndarray, float]

#: Bound used for the inner loops' |Gin| in the outer-loop bound |G Phi| / (1 - |Gin|).
INNER_LEVEL = 0.5


#: An unbatched linear signal: its row over the states and its coefficient of the chain's input.
_Sig = tuple[np.ndarray, float]


def _comb(N: int, *terms: tuple[float, _Sig]) -> _Sig:
    """Sum of coefficient x signal."""
    rx, ru = np.zeros(N), 0.0
    for c, (tx, tu) in terms:
        rx = rx + c * tx
        ru = ru + c * tu
    return rx, ru


def _unit(N: int, j: int) -> _Sig:
    """State ``j`` itself."""
    r = np.zeros(N)
    r[j] = 1.0
    return r, 0.0


def _pid_rows(lp: LoopCtl, r: _Sig, y: _Sig, ii: int | None, di: int | None, A: np.ndarray,
              Bv: np.ndarray) -> _Sig:
    """A PID loop of the chain: its states' rows of (A, B) are written, its output returned."""
    N = A.shape[0]
    kp, ki, kd, tf = float(lp.Kp[0]), float(lp.Ki[0]), float(lp.Kd[0]), float(lp.Tf[0])
    terms = [(kp * lp.b, r), (-kp, y)]
    if ii is not None:
        A[ii], Bv[ii] = _comb(N, (1.0, r), (-1.0, y))
        terms.append((ki, _unit(N, ii)))
    if di is not None:
        ed = _comb(N, (lp.c, r), (-1.0, y), (-1.0, _unit(N, di)))  # c r - y - xd
        A[di], Bv[di] = _comb(N, (1.0 / tf, ed))
        terms.append((kd / tf, ed))
    return _comb(N, *terms)


def _lq_rows(lp: LoopCtl, r: _Sig, y: _Sig, ii: int | None, n: int, A: np.ndarray, Bv: np.ndarray) -> _Sig:
    """An LQ loop of the chain (state feedback over the ``n`` plant states, 0 when the plant is at rest)."""
    N = A.shape[0]
    fx = np.zeros(N)
    if n:
        fx[:n] = -np.asarray(lp.K[0], dtype=float)
    terms = [(1.0, (fx, 0.0)), (float(lp.Nr[0]), r)]
    if ii is not None:
        A[ii], Bv[ii] = _comb(N, (1.0, r), (-1.0, y))
        terms.append((float(lp.Kint[0]), _unit(N, ii)))
    return _comb(N, *terms)


def chain_ss(cas: Cascade, lin: LinearModel, j0: int, j1: int, drive: str) -> SS:
    """Delay-free state space of the open controller chain, loops j0..j1, member 0 of ``cas``.

    ``drive = "u"``: input u enters the plant, r_{j0} = 0, output v_{j1} (that is G_{j1} for
    j0 = 0, Gin_{j0} for j1 = n-1). ``drive = "r"``: input r_{j0}, plant at rest (u = 0),
    output v_{j1} (the product of the setpoint paths F_{j0} ... F_{j1}).
    """
    plant = drive == "u"
    n = lin.A.shape[0] if plant else 0
    loops = cas.loops[j0 : j1 + 1]
    ctl, N = controller_state_index(loops, n)
    zero = (np.zeros(N), 0.0)

    def output(j: int) -> _Sig:
        if not plant:
            return zero
        rx = np.zeros(N)
        rx[:n] = lin.C[j]
        return rx, float(lin.D[j, 0])

    A = np.zeros((N, N))
    Bv = np.zeros(N)
    if plant:
        A[:n, :n] = lin.A
        Bv[:n] = lin.B[:, 0]
    r = zero if plant else (np.zeros(N), 1.0)
    for lp, (ii, di) in zip(loops, ctl, strict=True):
        y = output(lp.out_idx)
        r = _pid_rows(lp, r, y, ii, di, A, Bv) if lp.kind == "pid" else _lq_rows(lp, r, y, ii, n, A, Bv)
    return A, Bv[:, None], r[0][None, :], float(r[1])


def series(g1: SS, g2: SS) -> SS:
    """g2 after g1 (SISO)."""
    A1, B1, C1, D1 = g1
    A2, B2, C2, D2 = g2
    n1, n2 = A1.shape[0], A2.shape[0]
    A = np.zeros((n1 + n2, n1 + n2))
    A[:n1, :n1] = A1
    A[n1:, n1:] = A2
    A[n1:, :n1] = B2 @ C1
    B = np.vstack([B1, B2 * D1])
    C = np.hstack([D2 * C1, C2])
    return A, B, C, D2 * D1


def _response(g: SS, s: complex) -> complex:
    A, B, C, D = g
    if A.shape[0] == 0:
        return complex(D)
    M = -A.astype(complex)
    M.flat[:: A.shape[0] + 1] += s
    try:
        x = np.linalg.solve(M, B[:, 0].astype(complex))
    except np.linalg.LinAlgError:  # s is a pole
        return complex(math.inf)
    return complex(C[0] @ x + D)


#: An eigenvalue of M_gamma within this relative distance of the imaginary axis counts as on it.
_AXIS_TOL = 1e-6


def _balance(A: np.ndarray) -> np.ndarray:
    """Diagonal scaling d (powers of 2) with D^-1 A D balanced (LAPACK gebal, no permutation); ones if it fails.

    (LAPACK directly rather than ``scipy.linalg.matrix_balance``: only the scaling is needed, per call.)
    """
    from scipy.linalg.lapack import dgebal  # deferred: scipy.linalg costs ~0.2 s at import

    _, _, _, d, info = dgebal(A, scale=1, permute=0)
    if info == 0 and np.all(np.isfinite(d)) and np.all(d > 0):
        return d
    return np.ones(A.shape[0])


def level_clear(g: SS, gamma: float, w_lo: float, shift: float = 0.0) -> bool:
    """True when |G(-shift + jw)| < gamma is proven for every w >= w_lo (False: not proven)."""
    A, B, C, D = g
    if not (gamma > 0 and math.isfinite(gamma)) or not abs(D) < gamma:
        return False
    n = A.shape[0]
    if n == 0:
        return True
    # (non-finite A, B or C give a NaN response or a non-finite H below: not proven)
    if not abs(_response(g, complex(-shift, w_lo))) < gamma:
        return False
    # frequency in units of w_lo (tail: p >= 1), contour shift folded into A; B and C balanced
    As = A / w_lo
    if shift:
        As.flat[:: n + 1] += shift / w_lo
    d = _balance(As)
    As = As * (1.0 / d)[:, None] * d[None, :]
    Bs = B[:, 0] / (w_lo * d)
    Cs = C[0] * d
    nb, nc = float(np.sqrt(Bs @ Bs)), float(np.sqrt(Cs @ Cs))
    if nb == 0.0 or nc == 0.0:
        return True  # G = D
    k = math.sqrt(nc / nb)
    Bs, Cs = Bs * k, Cs / k
    R = gamma * gamma - D * D
    H = np.empty((2 * n, 2 * n))
    top = As + (D / R) * np.outer(Bs, Cs)
    H[:n, :n] = top
    H[:n, n:] = np.outer(Bs, Bs) / R
    H[n:, :n] = -(1.0 + D * D / R) * np.outer(Cs, Cs)
    H[n:, n:] = -top.T
    if not np.all(np.isfinite(H)):
        return False
    lam = np.linalg.eigvals(H)
    scale = max(1.0, float(np.max(np.abs(lam))))
    on_axis = np.abs(lam.real) <= _AXIS_TOL * scale
    return not bool(np.any(on_axis & (np.abs(lam.imag) >= 1.0 - 1e-6)))


def tail_levels(fig, floor: float) -> float:
    """Largest tau such that |L| < tau above the band cannot change this row's figures.

    ``fig``: the band's :class:`~gaintune.verification.margins.BreakFigures`; ``floor``: the |L|
    below which a phase crossing counts as none (MAG_FLOOR).
    """
    t = 1.0  # no gain crossing, no lower gain margin
    if math.isfinite(fig.gm_upper_db):
        t = min(t, 10.0 ** (-fig.gm_upper_db / 20.0))  # a tail crossing's upper GM is larger
    else:
        t = min(t, floor)  # no upper crossing in the band: none may count above it
    if math.isfinite(fig.ms):
        t = min(t, 1.0 - 1.0 / fig.ms) if fig.ms > 1.0 else 0.0  # |S| <= 1/(1 - tau) <= Ms
    if math.isfinite(fig.mt):
        t = min(t, fig.mt / (1.0 + fig.mt))  # |T| <= tau/(1 - tau) <= Mt
    inv_alpha = 1.0 / fig.disk_alpha if fig.disk_alpha > 0 else math.inf
    if math.isfinite(inv_alpha):
        t = min(t, (2.0 * inv_alpha - 1.0) / (2.0 * inv_alpha + 1.0))  # |S - 1/2| <= (1+tau)/(2(1-tau))
    return t
