"""Exact loop-at-a-time margins of one gain set on one linear model.

Everything is computed from frequency responses evaluated with numpy (no
python-control objects in the hot path): a log grid, every sign change located
and then zoomed in on (vectorised over all brackets at once), and peaks refined
the same way.

Definitions (L = open-loop response at a break point: L(jw) of the continuous loop, or
L(e^{jw dt}) of the sampled loop, :mod:`gaintune.verify.sampled`, for 0 < w <= pi/dt):

* gain crossover: |L(jw)| = 1; phase margin there PM = 180 + arg L wrapped to
  (-180, 180]; the reported PM is the one of smallest magnitude (as
  ``control.stability_margins``); delay margin = min over crossovers of the phase
  lag (PM mod 360, in rad) / w.
* phase crossover: L(jw) on the negative real axis (w = 0 included when L(0) is
  finite and negative); critical gain factor k = 1/|L|. Upper GM = smallest
  k > 1, lower GM = largest k < 1 (conditionally stable loops). The binding GM is
  the one of smaller |dB|. No crossover -> GM = inf (also when the phase only
  approaches -180 deg asymptotically, python-control issue #784). A crossing with
  |L| < 1e-4 (GM > 80 dB) counts as none. A sampled loop's L is real at the Nyquist
  frequency too (z = -1): a negative L(-1) is a phase crossing there, like w = 0.
* Ms = max |1/(1+L)|, Mt = max |L/(1+L)|; disk margin alpha = 1/max|S - 1/2|
  (balanced, skew 0), with disk GM/PM as in ``control.disk_margins``.

Closed-loop stability uses the argument principle on the characteristic
quasi-polynomial chi_ol(s) (1 + L_u(s)) along s = -eps + jw (the plant-input
cut L_u passes through every loop), which is exact for delays and counts
open-loop unstable poles; for delay-free loops the closed-loop eigenvalues
decide and the two are cross-checked. The sampled loop is finite-dimensional (its
delay is an input buffer): the eigenvalues of its transition matrix decide (|z| < 1),
cross-checked by the discrete Nyquist count on |z| = e^{-eps dt}; beyond
:data:`EIG_MAX` states (long delays) the count decides alone.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace

import numpy as np

from gaintune.plants.plant import LinearModel
from gaintune.verify.loops import (
    Cascade,
    _schur,
    observable_part,
    pade_response,
    plant_eigvals,
)
from gaintune.verify.sampled import SampledPlant
from gaintune.verify.tail import INNER_LEVEL, chain_ss, level_clear, series, tail_levels

__all__ = ["DelayModel", "BreakFigures", "Analysis", "analyse"]

#: |L| below this at a phase crossing counts as no crossing (GM > 80 dB is reported as inf).
MAG_FLOOR = 1e-4
GM_INF_LIMIT = 1.0 / MAG_FLOOR
_ZOOM = 24


@dataclass(frozen=True)
class DelayModel:
    """Total input delay and how it enters frequency responses."""

    T: float
    pade_order: int | None = None

    def factor(self, s: np.ndarray) -> np.ndarray:
        if self.T <= 0:
            return np.ones_like(s)
        if self.pade_order is None:
            return np.exp(-s * self.T)
        return pade_response(s, self.T, self.pade_order)

    def pade(self, default_order: int = 6) -> tuple[float, int] | None:
        """(T, order) for pole computations: the stated order, else ``default_order``."""
        if self.T <= 0:
            return None
        return (self.T, self.pade_order or default_order)


@dataclass
class Crossing:
    kind: str  # "gain" | "phase"
    omega: float
    value: float  # gain: PM deg; phase: GM dB (positive upper, negative lower)
    delay_margin: float | None = None  # gain crossings only
    binding: bool = False


@dataclass
class BreakFigures:
    loop: str
    break_point: str
    gm_db: float = math.inf
    gm_upper_db: float = math.inf
    gm_lower_db: float = math.inf  # dB the gain may be *reduced* by (positive)
    gm_freq: float | None = None
    pm_deg: float = math.inf
    pm_freq: float | None = None
    delay_margin: float = math.inf
    ms: float = 1.0
    ms_freq: float | None = None
    mt: float = 0.0
    mt_freq: float | None = None
    disk_alpha: float = math.inf
    disk_gm_db: float = math.inf
    disk_pm_deg: float = 90.0
    disk_freq: float | None = None
    crossings: list[Crossing] = field(default_factory=list)
    #: Valid phase crossings not refined and not in ``crossings`` (delay spirals give hundreds):
    #: each has a larger |GM| than every listed one beyond the first MAX_PHASE_LISTED.
    phase_omitted: int = 0


@dataclass
class Stability:
    stable: bool
    method: str
    rhp_count: int
    nyquist_rhp: int | None
    poles: np.ndarray
    poles_method: str
    max_real_pole: float
    notes: list[str] = field(default_factory=list)
    #: "s": continuous poles; "z": poles of the sampled loop (max_real_pole is then ln(max|z|)/dt)
    domain: str = "s"
    spectral_radius: float | None = None


@dataclass
class Analysis:
    figures: list[BreakFigures]
    stability: Stability
    omega_range: tuple[float, float]


# ------------------------------------------------------------------ helpers


def _plant_eig_abs(lin: LinearModel) -> list[float]:
    return list(np.abs(plant_eigvals(lin)))


def _char_freqs(cas: Cascade, lin: LinearModel, delay: DelayModel) -> np.ndarray:
    f = _plant_eig_abs(lin)
    for lp in cas.loops:
        if lp.kind == "pid":
            kp, ki, kd, tf = float(lp.Kp[0]), float(lp.Ki[0]), float(lp.Kd[0]), float(lp.Tf[0])
            # magnitudes: a reverse-acting loop has Kp, Ki, Kd all negative
            if lp.has_i and kp != 0:
                f.append(abs(ki / kp))
            if lp.has_d and kd != 0:
                f += [abs(kp / kd), 1.0 / tf]
    if delay.T > 0:
        f.append(1.0 / delay.T)
    f = np.array([x for x in f if np.isfinite(x) and x > 1e-12])
    return f if f.size else np.array([1.0])


_CHUNK = 4096


def _dot(c: np.ndarray, X: np.ndarray) -> np.ndarray:
    """c @ X for a short coefficient vector, without BLAS (whose threads only add latency here)."""
    if c.size > 8:
        return c @ X
    out = c[0] * X[0]
    for i in range(1, c.size):
        out = out + c[i] * X[i]
    return out


class _Evaluator:
    """L at arbitrary frequencies for one gain set (rows: break points).

    Same algebra as :meth:`Cascade.loop_responses` (the reference, used for batches > 1),
    specialised for one gain set: controller gains as Python scalars, the plant's complex
    Schur form and the output rows C Z precomputed, and only the measured outputs formed,
    so one call is a few dozen numpy operations over the frequency vector.

    ``sampled``: evaluate the sampled loop (:mod:`gaintune.verify.sampled`) at z = e^{s dt}
    instead of the continuous one (``delay`` is then unused).
    """

    def __init__(self, cas: Cascade, lin: LinearModel, delay: DelayModel | None, sampled: SampledPlant | None = None):
        self.cas, self.lin, self.delay, self.sampled = cas, lin, delay, sampled
        #: delay (s) whose phase spin e^{-jwT} the grids must resolve
        self.spin_T = sampled.total_delay if sampled is not None else max(delay.T, 0.0)
        self.calls = 0
        self.points = 0
        self.fast = cas.batch == 1
        if not self.fast:
            return
        if sampled is not None:
            n = sampled.n
            if n:
                T, Z, zb0, zb1, diag = sampled.schur()
                self._T, self._zb, self._zb1, self._diag = T, zb0, (zb1 if sampled.has_G1 else None), diag
                CZ = sampled.C.astype(complex) @ Z
            else:
                Z = None
                self._T = self._zb = self._zb1 = self._diag = None
                CZ = np.zeros((sampled.C.shape[0], 0), dtype=complex)
        else:
            n = lin.A.shape[0]
            self._zb1 = None
            if n:
                T, Z, zb = _schur(lin)
                self._T, self._zb = T, zb
                self._diag = np.diag(T).copy()
                CZ = lin.C.astype(complex) @ Z
            else:
                Z = None
                self._T = self._zb = self._diag = None
                CZ = np.zeros((lin.C.shape[0], 0), dtype=complex)
        self._n = n
        outs = sorted({lp.out_idx for lp in cas.loops})
        self._outs = {j: (CZ[j], complex(lin.D[j, 0])) for j in outs}
        self._ctl = []
        for lp in cas.loops:
            if lp.kind == "pid":
                self._ctl.append(("pid", lp.out_idx, lp.has_i, lp.has_d, float(lp.Kp[0]), float(lp.Ki[0]),
                                  float(lp.Kd[0]), float(lp.Tf[0]), float(lp.b), float(lp.c)))
            else:
                KZ = (np.asarray(lp.K[0], dtype=float) @ Z) if n else np.zeros(0, dtype=complex)
                self._ctl.append(("lq", lp.out_idx, lp.has_i, KZ, float(lp.Kint[0]) if lp.has_i else 0.0,
                                  float(lp.Nr[0])))

    def __call__(self, w: np.ndarray, shift: float = 0.0) -> np.ndarray:
        self.calls += 1
        w = np.asarray(w, dtype=float)
        self.points += w.size
        s = -shift + 1j * w
        with np.errstate(all="ignore"):
            if not self.fast:
                if self.sampled is not None:
                    return self.cas.loop_responses(s, self.lin, sampled=self.sampled)[:, 0, :]
                return self.cas.loop_responses(s, self.lin, self.delay.factor(s))[:, 0, :]
            if s.size <= _CHUNK:
                return self._eval(s)
            # chunks keep every temporary below glibc's mmap threshold (128 KiB): large
            # temporaries are fresh mappings, and their page faults cost more than the arithmetic
            out = np.empty((len(self.cas.loops) + 1, s.size), dtype=complex)
            for i in range(0, s.size, _CHUNK):
                out[:, i : i + _CHUNK] = self._eval(s[i : i + _CHUNK])
            return out

    def _eval(self, s: np.ndarray) -> np.ndarray:
        n = self._n
        sp = self.sampled
        if sp is not None:
            dt = sp.dt
            z = np.exp(s * dt)
            zi = 1.0 / z
            x_at = z  # the back-substitution runs in z
            d = np.exp(-s * (dt * sp.d)) if sp.d else 1.0  # z^-d
            dD = np.exp(-s * (dt * sp.dD)) if sp.dD else 1.0  # z^-dD (feedthrough)
            one_m = 1.0 - zi
        else:
            x_at = s
            d = dD = self.delay.factor(s)
            zi = None
        if n:
            T, zb, zb1, diag = self._T, self._zb, self._zb1, self._diag
            xs = np.empty((n, s.size), dtype=complex)
            for i in range(n - 1, -1, -1):
                acc = zb[i] if zb1 is None else zb[i] + zb1[i] * zi
                if i + 1 < n:
                    acc = acc + _dot(T[i, i + 1 :], xs[i + 1 :])
                xs[i] = acc / (x_at - diag[i])
        P = {}
        for j, (cz, dj) in self._outs.items():
            if sp is None:
                P[j] = (_dot(cz, xs) + dj) * d if n else dj * d
            else:
                P[j] = (_dot(cz, xs) * d + dj * dD) if n else dj * dD
        inv_s = None
        resp = []
        for c in self._ctl:
            if c[0] == "pid":
                _, oi, has_i, has_d, kp, ki, kd, tf, b, cw = c
                if has_i:
                    if inv_s is None:
                        inv_s = dt / one_m if sp is not None else 1.0 / s
                    I = ki * inv_s
                else:
                    I = 0.0
                if has_d:
                    Dd = kd * one_m / (tf + dt - tf * zi) if sp is not None else kd * s / (tf * s + 1.0)
                else:
                    Dd = 0.0
                C = kp + I + Dd
                F = b * kp + I + cw * Dd
                m = -C * P[oi]
            else:
                _, oi, has_i, KZ, kint, nr = c
                KX = (_dot(KZ, xs) * d) if n else np.zeros(s.size, dtype=complex)
                if has_i:
                    if inv_s is None:
                        inv_s = dt / one_m if sp is not None else 1.0 / s
                    I = kint * inv_s
                else:
                    I = 0.0
                m = -(KX + I * P[oi])
                F = nr + I
            resp.append((F, m))
        nl = len(resp)
        g = []
        prev = 0.0
        for F, m in resp:
            prev = F * prev + m
            g.append(prev)
        L = np.empty((nl + 1, s.size), dtype=complex)
        H = 1.0
        for k in range(nl - 1, -1, -1):
            L[k] = -g[k] * H
            F, m = resp[k]
            H = H * F / (1.0 - H * m)
        L[nl] = -g[nl - 1]
        return L


#: Convergence of the crossing refinement, in log w.
_ROOT_TOL = 1e-10


def _zoom_roots(ev: _Evaluator, lo: np.ndarray, hi: np.ndarray, rows: np.ndarray, fn, iters: int = 12,
                La: np.ndarray | None = None, Lb: np.ndarray | None = None):
    """Refine brackets [lo, hi] (per row) of a sign change of fn(L): vectorised modified regula
    falsi (Anderson-Bjorck) in log w, one evaluation of the unconverged brackets per iteration.

    ``La``/``Lb``: L at the bracket ends when known (grid values), else evaluated.
    ``fn`` maps (L values, bracket indices) to the function values. Returns (w, L at w).
    """
    if lo.size == 0:
        return lo, np.zeros(0, dtype=complex)
    a, b = np.log(lo), np.log(hi)
    k = np.arange(lo.size)
    if La is None or Lb is None:
        Lab = ev(np.concatenate([lo, hi]))
        La, Lb = Lab[rows, k], Lab[rows, k + lo.size]
    fa = fn(La, k)
    fb = fn(Lb, k)
    side = np.zeros(lo.size)
    c = 0.5 * (a + b)
    Lc = np.where(np.abs(fa) <= np.abs(fb), La, Lb)  # only used if no iteration runs
    act = np.arange(lo.size)
    for _ in range(iters):
        A, Bv, FA, FB = a[act], b[act], fa[act], fb[act]
        c_prev = c[act]
        with np.errstate(invalid="ignore", divide="ignore"):
            cc = np.where(FA != FB, (A * FB - Bv * FA) / (FB - FA), 0.5 * (A + Bv))
        bad = ~np.isfinite(cc) | (cc <= np.minimum(A, Bv)) | (cc >= np.maximum(A, Bv))
        cc = np.where(bad, 0.5 * (A + Bv), cc)
        Lcc = ev(np.exp(cc))[rows[act], np.arange(act.size)]
        fc = fn(Lcc, act)
        c[act] = cc
        Lc[act] = Lcc
        left = np.sign(fc) == np.sign(FA)  # root in [c, b]
        sd = side[act]
        # Anderson-Bjorck: when the same end is kept twice, scale its value by 1 - f(c)/f(replaced
        # end) (by 1/2, as Illinois, when that is not positive); converges faster than halving
        with np.errstate(invalid="ignore", divide="ignore"):
            mb = np.where(FA != 0, 1.0 - fc / FA, 0.5)
            ma = np.where(FB != 0, 1.0 - fc / FB, 0.5)
        FB = np.where(left & (sd == 1), FB * np.where(mb > 0, mb, 0.5), FB)
        FA = np.where(~left & (sd == -1), FA * np.where(ma > 0, ma, 0.5), FA)
        a[act], fa[act] = np.where(left, cc, A), np.where(left, fc, FA)
        b[act], fb[act] = np.where(left, Bv, cc), np.where(left, FB, fc)
        side[act] = np.where(left, 1, -1)
        # 1e-10 in log w: frequencies to 1e-10 relative; tighter only chases round-off
        # or a residual at round-off level (both functions are O(1): log|L| and sin(arg L))
        done = (np.abs(cc - c_prev) < _ROOT_TOL) | (np.abs(b[act] - a[act]) < _ROOT_TOL) | (np.abs(fc) < 1e-13)
        act = act[~done]
        if act.size == 0:
            break
    return np.exp(c), Lc


def _figure_values(S: np.ndarray, q: np.ndarray) -> np.ndarray:
    """Row i of S = 1/(1 + L): |S| (q_i = 0), |T| = |L S| = |1 - S| (1) or |S - 1/2| (2, 1/disk alpha); NaN -> inf."""
    with np.errstate(invalid="ignore"):
        V = np.abs(np.where((q == 0)[:, None], S, np.where((q == 1)[:, None], 1.0 - S, S - 0.5)))
    return np.where(V == V, V, np.inf)


def _peak_values(Z: np.ndarray, q: np.ndarray) -> np.ndarray:
    """:func:`_figure_values` of the loop responses Z (row i for figure q_i)."""
    with np.errstate(divide="ignore", invalid="ignore"):
        S = 1.0 / (1.0 + Z)
    return _figure_values(S, q)


def _zoom_peaks(ev: _Evaluator, lo: np.ndarray, hi: np.ndarray, rows: np.ndarray, q: np.ndarray, rounds: int = 3):
    """Refine the maximum of :func:`_peak_values` (figure q_i) inside [lo_i, hi_i] (row rows_i),
    all peaks in one evaluation per round. Returns (w, value)."""
    best_w = np.sqrt(lo * hi)
    best_v = np.full(lo.size, -np.inf)
    k = np.arange(lo.size)
    t = np.linspace(0.0, 1.0, _ZOOM)
    for _ in range(rounds):
        W = np.exp(np.log(lo)[:, None] + (np.log(hi) - np.log(lo))[:, None] * t[None, :])
        L = ev(W.ravel())
        f = _peak_values(L[rows[:, None], np.arange(W.size).reshape(W.shape)], q)
        j = np.argmax(f, axis=1)
        better = f[k, j] > best_v
        best_v = np.where(better, f[k, j], best_v)
        best_w = np.where(better, W[k, j], best_w)
        lo, hi = W[k, np.maximum(j - 1, 0)], W[k, np.minimum(j + 1, _ZOOM - 1)]
    return best_w, best_v


def _wrap180(deg: np.ndarray) -> np.ndarray:
    """Wrap to (-180, 180]."""
    return 180.0 - np.mod(180.0 - deg, 360.0)


def disk_from_alpha(alpha: float) -> tuple[float, float]:
    """Disk GM (dB) and PM (deg) for a balanced (skew 0) disk margin alpha, as control.disk_margins."""
    if not np.isfinite(alpha):
        return math.inf, 90.0
    gmin = (1 - 0.5 * alpha) / (1 + 0.5 * alpha)
    gmax = (1 + 0.5 * alpha) / (1 - 0.5 * alpha) if alpha != 2 else math.inf
    with np.errstate(all="ignore"):
        dgm = 20 * np.log10(np.minimum(1 / gmin, gmax))
    dgm = math.inf if (np.isnan(dgm) or alpha >= 2) else float(dgm)
    if np.isinf(gmax):
        dpm = 90.0
    else:
        c = (1 + gmin * gmax) / (gmin + gmax)
        dpm = math.inf if abs(c) >= 1 else float(np.degrees(np.arccos(c)))
    return dgm, dpm


# ------------------------------------------------------------------ margins


_COS_DPH = math.cos(0.5)


def _band_ends(ev: _Evaluator, cas, lin) -> tuple[float, float, np.ndarray]:
    """(lo, hi) of the full grid: every frequency where max|L| >= MAG_FLOOR (end probes in one
    call), and L(0) per row (the same call). A sampled loop's grid ends at the Nyquist frequency."""
    cf = _char_freqs(cas, lin, DelayModel(0.0))
    lo, hi = cf.min() * 1e-3, cf.max() * 1e3
    if ev.sampled is not None:
        wn = ev.sampled.nyquist
        lo = min(lo, wn * 1e-4)
        los = lo / 100.0 ** np.arange(3)
        Lp = ev(np.concatenate([los, [0.0]]))
        Plo = np.abs(Lp[:, :-1])
        ok_lo = np.all((Plo > 1e3) | (Plo < MAG_FLOOR), axis=0)
        lo = los[int(np.argmax(ok_lo))] if ok_lo.any() else lo / 1e6
        return float(lo), wn, Lp[:, -1]
    his = hi * 10.0 ** np.arange(8)
    los = lo / 100.0 ** np.arange(3)
    Lp = ev(np.concatenate([his, los, [0.0]]))
    L0 = Lp[:, -1]
    P = np.abs(Lp[:, :-1])
    ok_hi = np.all(P[:, :8] < MAG_FLOOR, axis=0)
    hi = his[int(np.argmax(ok_hi))] if ok_hi.any() else hi * 1e8
    Plo = P[:, 8:]
    ok_lo = np.all((Plo > 1e3) | (Plo < MAG_FLOOR), axis=0)
    lo = los[int(np.argmax(ok_lo))] if ok_lo.any() else lo / 1e6
    return float(lo), float(hi), L0


def _grid(ev: _Evaluator, lo: float, hi: float, n_freq: int):
    """Log grid on [lo, hi], refined where the phase turns fast (delays). Returns (w, L, |L|).

    Each refinement round checks only the intervals created by the previous one (the
    others were already fine); the points are merged once at the end.
    """
    w = np.logspace(np.log10(lo), np.log10(hi), n_freq)
    w[0], w[-1] = lo, hi
    L = ev(w)
    aL = np.abs(L)
    ws, Ls, aLs = [w], [L], [aL]
    R = L.shape[0]
    # candidate intervals: the sub-intervals of a block of refined intervals (end points E (m, k+1),
    # responses LE (R, m, k+1)), then bad intervals left over by the cap (higher w, rarely any)
    E, LE, AE = w[None, :], L[:, None, :], aL[:, None, :]
    rest = (np.zeros(0), np.zeros(0), np.zeros((R, 0), complex), np.zeros((R, 0), complex), np.zeros((R, 0)), np.zeros((R, 0)))
    for _ in range(4):
        m, k = E.shape[0], E.shape[1] - 1
        with np.errstate(all="ignore"):
            z = LE[:, :, 1:] * LE[:, :, :-1].conj()
            zr = rest[3] * rest[2].conj()
            turn = z.real < _COS_DPH * np.abs(z)  # |arg(L_right/L_left)| > 0.5
            big = (AE[:, :, 1:] > MAG_FLOOR) | (AE[:, :, :-1] > MAG_FLOOR)
            turn_r = zr.real < _COS_DPH * np.abs(zr)
            big_r = (rest[5] > MAG_FLOOR) | (rest[4] > MAG_FLOOR)
        bad_all = np.concatenate([np.nonzero(np.any(turn & big, axis=0).ravel())[0],
                                  m * k + np.nonzero(np.any(turn_r & big_r, axis=0))[0]])
        if bad_all.size == 0:
            break

        def pick(idx):
            blk = idx[idx < m * k]
            bi, bj = np.divmod(blk, k)
            ri = idx[idx >= m * k] - m * k
            cat = np.concatenate
            return (cat([E[bi, bj], rest[0][ri]]), cat([E[bi, bj + 1], rest[1][ri]]),
                    cat([LE[:, bi, bj], rest[2][:, ri]], axis=1), cat([LE[:, bi, bj + 1], rest[3][:, ri]], axis=1),
                    cat([AE[:, bi, bj], rest[4][:, ri]], axis=1), cat([AE[:, bi, bj + 1], rest[5][:, ri]], axis=1))

        wl, wr, Ll, Lr, al, ar = pick(bad_all[:20000])
        rest = pick(bad_all[20000:])
        nb = wl.size
        new = np.exp(np.log(wl[:, None]) + np.log(wr / wl)[:, None] * np.linspace(0, 1, 8)[None, 1:-1])
        Ln = ev(new.ravel())
        an = np.abs(Ln)
        ws.append(new.ravel())
        Ls.append(Ln)
        aLs.append(an)
        E = np.concatenate([wl[:, None], new, wr[:, None]], axis=1)
        LE = np.concatenate([Ll[:, :, None], Ln.reshape(R, nb, 6), Lr[:, :, None]], axis=2)
        AE = np.concatenate([al[:, :, None], an.reshape(R, nb, 6), ar[:, :, None]], axis=2)
    if len(ws) > 1:
        w = np.concatenate(ws)
        o = np.argsort(w, kind="stable")  # a few sorted runs: a cheap merge
        w = w[o]
        L = np.concatenate(Ls, axis=1)[:, o]
        aL = np.concatenate(aLs, axis=1)[:, o]
    return w, L, aL


def _figures_for_row(row_name, gm_w, gm_k, pm_w, pm_deg, peaks, phase_omitted: int) -> BreakFigures:
    fig = BreakFigures(loop=row_name[0], break_point=row_name[1])
    crossings: list[Crossing] = []
    ups, lows = [], []
    with np.errstate(divide="ignore", invalid="ignore"):
        keep = np.isfinite(gm_k) & (gm_k <= GM_INF_LIMIT) & (gm_k >= 1.0 / GM_INF_LIMIT)
    for wc, k in zip(gm_w[keep].tolist(), gm_k[keep].tolist()):  # k: critical gain factor
        db = 20 * math.log10(k)
        crossings.append(Crossing("phase", wc, db))
        (ups if k > 1 else lows).append((db, wc, len(crossings) - 1))
    if ups:
        fig.gm_upper_db = min(ups)[0]
    if lows:
        fig.gm_lower_db = -max(lows)[0]
    cand = [(abs(d), wc, i) for d, wc, i in ups + lows]
    if cand:
        d, wc, i = min(cand)
        fig.gm_db, fig.gm_freq = float(d), float(wc)
        crossings[i].binding = True
    pms = []
    for wc, phase_deg in zip(np.asarray(pm_w).tolist(), np.asarray(pm_deg).tolist()):
        pm = 180.0 - ((180.0 - (180.0 + phase_deg)) % 360.0)
        lag = math.radians(pm % 360.0)
        dm = lag / wc if wc > 0 else math.inf
        crossings.append(Crossing("gain", wc, pm, delay_margin=float(dm)))
        pms.append((abs(pm), len(crossings) - 1))
        fig.delay_margin = min(fig.delay_margin, dm)
    if pms:
        _, i = min(pms)
        fig.pm_deg, fig.pm_freq = crossings[i].value, crossings[i].omega
        crossings[i].binding = True
    fig.crossings = sorted(crossings, key=lambda c: c.omega)
    fig.phase_omitted = int(phase_omitted)
    (fig.ms_freq, fig.ms), (fig.mt_freq, fig.mt), (fig.disk_freq, inv_alpha) = peaks
    fig.disk_alpha = 1.0 / inv_alpha if inv_alpha > 0 else math.inf
    fig.disk_gm_db, fig.disk_pm_deg = disk_from_alpha(fig.disk_alpha)
    return fig


#: Phase crossings refined per break point (those of smallest |GM| first); the rest are only counted.
MAX_PHASE_LISTED = 20
_PHASE_REFINE = 2 * MAX_PHASE_LISTED + 8
#: An unrefined crossing is classified from its bracket only when both ends' |L| are this factor
#: clear of a threshold (|L| hardly changes over a bracket; the root's lies between the ends').
_BAND = 1.25


def _crit_gain(z: np.ndarray) -> np.ndarray:
    """Critical gain factor 1/|L| at a refined phase crossing; NaN when L is not on the negative real axis."""
    with np.errstate(divide="ignore", invalid="ignore"):
        on_axis = np.abs(z.imag) <= 1e-6 * np.abs(z) + 1e-300
        k = np.where(on_axis, 1.0 / np.abs(z), 1.0 / np.abs(z.real))  # too flat to pin down: still a crossing
        return np.where(z.real < 0, k, np.nan)


def _margins(ev: _Evaluator, w: np.ndarray, L: np.ndarray, aL: np.ndarray, names, L0: np.ndarray,
             Lend: np.ndarray | None = None) -> list[BreakFigures]:
    """Figures per row from the grid (w, L, |L|); ``L0``: L at w = 0 per row. ``Lend``: a
    sampled loop's L at the grid's last point, the Nyquist frequency, where it is real: an end
    point of the Nyquist curve like w = 0 (its crossing is added from ``Lend``, not bracketed)."""
    R = L.shape[0]
    im, re = L.imag, L.real
    with np.errstate(invalid="ignore"):
        fin = np.isfinite(aL) & (aL > 0)
        sgn = np.sign(aL - 1.0)  # sign of log|L|
    # ---- gain crossings
    sc = (sgn[:, :-1] != sgn[:, 1:]) & fin[:, :-1] & fin[:, 1:]
    r_g, i_g = np.nonzero(sc)
    # ---- phase crossings (negative real axis)
    sp = (np.sign(im[:, :-1]) != np.sign(im[:, 1:])) & ((re[:, :-1] < 0) | (re[:, 1:] < 0))
    sp &= (aL[:, :-1] > 0.5 * MAG_FLOOR) | (aL[:, 1:] > 0.5 * MAG_FLOOR)
    sp &= (aL[:, :-1] < 2 * GM_INF_LIMIT) | (aL[:, 1:] < 2 * GM_INF_LIMIT)
    if Lend is not None:
        sp[:, -1] = False  # the end point itself is on the real axis: added below
    r_p, i_p = np.nonzero(sp)
    # Delays give hundreds of phase crossings; only those that can be listed (smallest |GM|)
    # or whose classification is not clear from the bracket are refined, the rest counted.
    Pa, Pb = L[r_p, i_p], L[r_p, i_p + 1]
    aa, ab = aL[r_p, i_p], aL[r_p, i_p + 1]
    lo_m, hi_m = np.minimum(aa, ab), np.maximum(aa, ab)
    with np.errstate(all="ignore"):
        zz = Pb * Pa.conj()
        amb = (Pa.real >= 0) | (Pb.real >= 0) | (zz.real <= 0.5 * np.abs(zz)) | ~np.isfinite(hi_m) | ~(lo_m > 0)
        # an interval the delay alone turns by > 0.5 rad may hide whole turns between its ends
        amb |= ev.spin_T * (w[i_p + 1] - w[i_p]) > 0.5
        amb |= (hi_m * _BAND > MAG_FLOOR) & (lo_m / _BAND < MAG_FLOOR)
        amb |= (hi_m * _BAND > GM_INF_LIMIT) & (lo_m / _BAND < GM_INF_LIMIT)
        score = np.abs(0.5 * (np.log(aa) + np.log(ab)))  # ~ |ln GM| of the crossing
        slack = 0.5 * np.abs(np.log(aa) - np.log(ab)) + math.log(1.5)
    score = np.where(np.isfinite(score), score, np.inf)
    refine = amb.copy()
    for r in range(R):
        idx = np.nonzero(r_p == r)[0]
        if idx.size > _PHASE_REFINE:
            refine[idx[np.argpartition(score[idx], _PHASE_REFINE)[:_PHASE_REFINE]]] = True
        else:
            refine[idx] = True
    # ---- zoom: gain and phase brackets together
    fn_gain = lambda Z: np.log(np.abs(Z))  # noqa: E731
    done = np.zeros(r_p.size, dtype=bool)
    wp = np.full(r_p.size, np.nan)
    kp_ = np.full(r_p.size, np.nan)
    first = True
    while True:
        todo = np.nonzero(refine & ~done)[0]
        ng = r_g.size if first else 0
        lo = np.concatenate([w[i_g] if first else np.zeros(0), w[i_p[todo]]])
        hi = np.concatenate([w[i_g + 1] if first else np.zeros(0), w[i_p[todo] + 1]])
        rows = np.concatenate([r_g if first else np.zeros(0, dtype=np.int64), r_p[todo]]).astype(np.int64)
        La = np.concatenate([L[r_g, i_g] if first else np.zeros(0, dtype=complex), Pa[todo]])
        Lb = np.concatenate([L[r_g, i_g + 1] if first else np.zeros(0, dtype=complex), Pb[todo]])

        def fn(Z, kk, ng=ng):
            with np.errstate(divide="ignore", invalid="ignore"):
                return np.where(kk < ng, fn_gain(Z), Z.imag / np.abs(Z))  # log|L|; sin(arg L)

        wz, Lz = _zoom_roots(ev, lo, hi, rows, fn, La=La, Lb=Lb)
        if first:
            wg, Lg = wz[:ng], Lz[:ng]
            first = False
        wp[todo] = wz[ng:]
        kp_[todo] = _crit_gain(Lz[ng:])
        done[todo] = True
        # every unrefined bracket must rank after the MAX_PHASE_LISTED-th refined crossing of its row
        more = False
        for r in range(R):
            un = np.nonzero((r_p == r) & ~done)[0]
            if un.size == 0:
                continue
            kr = kp_[(r_p == r) & done]
            with np.errstate(divide="ignore", invalid="ignore"):
                v = np.abs(np.log(kr[np.isfinite(kr) & (kr <= GM_INF_LIMIT) & (kr >= 1 / GM_INF_LIMIT)]))
            tau = np.sort(v)[MAX_PHASE_LISTED - 1] if v.size >= MAX_PHASE_LISTED else np.inf
            need = un[score[un] - slack[un] <= tau]
            if need.size:
                refine[need] = True
                more = True
        if not more:
            break
    # ---- per row: listed crossings and counts
    gm_w = [[] for _ in range(R)]
    gm_k = [[] for _ in range(R)]
    omitted = np.zeros(R, dtype=np.int64)
    for r in range(R):
        sel = (r_p == r) & done
        gm_w[r], gm_k[r] = wp[sel], kp_[sel]
        un = (r_p == r) & ~done
        # unrefined: clearly on the negative real axis, |L| clearly inside (MAG_FLOOR, GM_INF_LIMIT)
        omitted[r] = int(np.count_nonzero(un & (lo_m > MAG_FLOOR) & (hi_m < GM_INF_LIMIT)))
    # w = 0 (and a sampled loop's Nyquist frequency): a finite negative real L is a phase crossing too
    ends = [(0.0, L0)] + ([(float(w[-1]), Lend)] if Lend is not None else [])
    for r in range(R):
        for we, Le in ends:
            z = Le[r]
            if np.isfinite(z) and 0 < abs(z) < 1e8 and z.real < 0 and abs(z.imag) < 1e-9 * abs(z):
                o = np.argsort(np.concatenate([[we], gm_w[r]]), kind="stable")
                gm_w[r] = np.concatenate([[we], gm_w[r]])[o]
                gm_k[r] = np.concatenate([[1.0 / abs(z)], gm_k[r]])[o]
    pm_w = [wg[r_g == r] for r in range(R)]
    pm_deg = [np.degrees(np.angle(Lg[r_g == r])) for r in range(R)]
    # ---- peaks: Ms, Mt, 1/alpha (all rows and figures zoomed together)
    rows = np.tile(np.arange(R), 3)
    q = np.repeat(np.arange(3), R)
    with np.errstate(divide="ignore", invalid="ignore"):
        S = 1.0 / (1.0 + L)
    V = _figure_values(np.tile(S, (3, 1)), q)  # (3R, W), figure-major
    jj = np.argmax(V, axis=1)
    Vmax = V[np.arange(3 * R), jj]
    Vj = [Vmax[qi * R : (qi + 1) * R] for qi in range(3)]
    lo = w[np.maximum(jj - 1, 0)]
    hi = w[np.minimum(jj + 1, w.size - 1)]
    with np.errstate(divide="ignore", invalid="ignore"):
        pw, pv = _zoom_peaks(ev, lo, hi, rows, q)
    peaks = [[(float(pw[qi * R + r]), float(max(pv[qi * R + r], Vj[qi][r]))) for qi in range(3)] for r in range(R)]
    return [_figures_for_row(names[r], gm_w[r], gm_k[r], pm_w[r], pm_deg[r], peaks[r], omitted[r]) for r in range(R)]


# --------------------------------------------------------------- stability


#: Offsets (in units of the pole's distance to the contour) sampled around every open-loop pole.
_POLE_OFFSETS = np.concatenate([-(2.0 ** np.arange(9, -4, -1)), [0.0], 2.0 ** np.arange(-3, 10)])


def _contour(ev: _Evaluator, ol_poles_s: np.ndarray, w_hi: float, eps: float, n_freq: int):
    """1 + L_u (plant-input cut, row -1) sampled along s = -eps + jw, 0 <= w <= w_hi, finely enough
    to unwrap its phase. ``ol_poles_s``: open-loop poles as s-plane points (for a sampled loop,
    ln(z)/dt), around which the contour is sampled densely. Returns (w, 1 + L_u)."""
    # An open-loop pole p turns 1 + L within a few |Re p + eps| of Im p. A lightly damped one
    # (a resonance) can make 1 + L circle the origin between two log-grid points, which leaves
    # no trace in the phase steps checked below: sample around every pole.
    up = ol_poles_s[ol_poles_s.imag > 0]
    dist = np.maximum(np.abs(up.real + eps), eps)  # pole to contour
    extra = (up.imag[:, None] + dist[:, None] * _POLE_OFFSETS[None, :]).ravel()
    wl = np.logspace(np.log10(eps / 100), np.log10(w_hi), n_freq)
    wl[-1] = w_hi
    w = np.concatenate([[0.0], wl, extra])
    w = np.unique(w[(w >= 0) & (w <= w_hi)])
    phi = 1.0 + ev(w, shift=eps)[-1]
    # the delay alone turns L by T dw over an interval: where |L| is not small, a whole turn of
    # 1 + L could also hide between two points
    T = ev.spin_T
    for _ in range(10):
        d = np.abs(np.angle(phi[1:] / phi[:-1]))
        aL = np.abs(phi - 1.0)
        spin = (T * np.diff(w) > 1.0) & (np.maximum(aL[1:], aL[:-1]) > 0.5)
        bad = np.nonzero((d > 0.3) | spin)[0]
        if bad.size == 0:
            break
        bad = bad[:4000]
        new = (w[bad, None] + (w[bad + 1] - w[bad])[:, None] * np.linspace(0, 1, 10)[None, 1:-1]).ravel()
        wn = np.concatenate([w, new])
        phin = np.concatenate([phi, 1.0 + ev(new, shift=eps)[-1]])
        o = np.argsort(wn)
        w, phi = wn[o], phin[o]
    return w, phi


def _argument_principle(ev: _Evaluator, ol_poles: np.ndarray, w_hi: float, eps: float, n_freq: int,
                        tail_proven: bool = False):
    """Number of closed-loop roots right of Re s = -eps (plant-input cut, row -1).

    The contour runs on the grid up to ``w_hi``; above it |L| < 1 keeps 1 + L in the right
    half-plane, so the rest of the contour adds the principal angle from 1 + L(w_hi) to
    1 + L(inf). ``tail_proven``: that bound is proven (:mod:`gaintune.verify.tail`) rather
    than checked at one far point.
    """
    w, phi = _contour(ev, ol_poles, w_hi, eps, n_freq)
    ang = np.unwrap(np.angle(phi))
    d_one_plus_L = ang[-1] - ang[0]
    # tail to infinity: |L| < 1 there keeps 1 + L in the right half-plane
    far = 1.0 + ev(np.array([w_hi * 1e4]), shift=eps)[-1, 0]
    tail_ok = tail_proven or abs(far - 1.0) < 1.0
    d_one_plus_L += np.angle(far / phi[-1])
    c = -eps - ol_poles.real
    y0 = -ol_poles.imag
    with np.errstate(divide="ignore", invalid="ignore"):
        d_ol = np.where(c != 0, np.sign(c) * (np.pi / 2 - np.arctan(y0 / np.abs(c))), 0.0)
    total = d_ol.sum() + d_one_plus_L
    n = ol_poles.size
    z_real = (n * np.pi / 2 - total) / np.pi
    z = int(round(z_real))
    return z, abs(z_real - z), tail_ok, float(np.abs(far - 1.0))


def _discrete_nyquist(ev: _Evaluator, ol_z: np.ndarray, eps: float, n_freq: int):
    """Closed-loop roots of the sampled loop on or outside |z| = rho = e^{-eps dt} (discrete Nyquist).

    With chi_cl = chi_ol (1 + L_u) and the contour |z| = rho run counter-clockwise, the roots
    inside are the open-loop poles inside plus the turns of 1 + L_u; by conjugate symmetry
    the upper half (w from 0 to the Nyquist frequency, both ends real) gives half the turn.
    Returns (count, distance of the raw count from an integer).
    """
    dt = ev.sampled.dt
    rho = math.exp(-eps * dt)
    nz = ol_z[np.abs(ol_z) > 0]
    w, phi = _contour(ev, np.log(nz.astype(complex)) / dt, ev.sampled.nyquist, eps, n_freq)
    ang = np.unwrap(np.angle(phi))
    turns = (ang[-1] - ang[0]) / np.pi  # full turns of 1 + L_u around the closed contour
    p_out = int(np.sum(np.abs(ol_z) >= rho))
    z_real = p_out - turns
    z = int(round(z_real))
    return z, abs(z_real - z)


def _stability(ev: _Evaluator, cas: Cascade, lin: LinearModel, delay: DelayModel, w_hi: float, n_freq: int,
               capped: bool = False, g_u=None) -> Stability | None:
    """Closed-loop stability. ``capped``: the grid stops at ``w_hi``, short of where |L| is
    negligible; the Nyquist contour is then closed with a proven bound |L_u| < 1 above
    ``w_hi``, and None is returned when that bound cannot be proven. ``g_u``: the delay-free
    plant-input realisation on the observable part, when already built."""
    notes: list[str] = []
    has_delay = delay.T > 0
    exact_delay = has_delay and delay.pade_order is None
    cf = _char_freqs(cas, lin, DelayModel(0.0))
    # pole list of an exact-delay loop: Padé of order 6, or 2 when the delay is tiny for the loop
    pade = delay.pade(6 if delay.T * float(cf.max()) > 0.05 else 2) if has_delay else None
    # modes no loop measures are untouched by feedback: judge them separately
    meas = cas.measured
    lin_full = lin
    unobs = np.zeros(0, dtype=complex)
    if meas is not None:
        lin, unobs = observable_part(lin, meas)
    A = cas.closed_loop_A(lin, pade)[0]
    poles = np.linalg.eigvals(A) if A.size else np.zeros(0, dtype=complex)
    scale = max(1.0, float(np.max(np.abs(poles))) if poles.size else 1.0)
    eps = 1e-7 * float(_char_freqs(cas, lin, delay).min())
    max_re = float(np.max(poles.real)) if poles.size else -math.inf
    rhp_poles = int(np.sum(poles.real > -1e-12 * scale))
    ol = cas.open_loop_poles(lin, pade if not exact_delay else None)[0]
    proven = False
    if capped:
        # |L_u(-eps + jw)| < 1 above the band. On this contour the delay factor (exact or Padé)
        # has modulus 1 + O(eps T), with eps T < 1e-6 in practice: 0.999 leaves room for it.
        if g_u is None:
            g_u = chain_ss(cas, lin, 0, len(cas.loops) - 1, "u")
        proven = level_clear(g_u, 0.999 * math.exp(-2.0 * eps * max(delay.T, 0.0)), w_hi, shift=eps)
        if not proven:
            return None
    nyq, frac_err, tail_ok, l_inf = _argument_principle(ev, ol, w_hi, eps, n_freq, proven)
    if exact_delay:
        method = "nyquist"
        rhp = nyq
        if not tail_ok:
            notes.append(f"|L(jw)| does not fall below 1 at high frequency (|L| -> {l_inf:.3g}): neutral delay loop, unstable")
            rhp = max(rhp, 1)
        if frac_err > 0.25:
            notes.append("argument-principle count is not close to an integer; grid may be too coarse")
        poles_method = f"pade{pade[1]}" if pade else "exact"
    else:
        method = "poles"
        rhp = rhp_poles
        poles_method = "exact" if not has_delay else f"pade{delay.pade_order}"
        if nyq != rhp_poles:
            notes.append(f"Nyquist count ({nyq}) differs from the pole count ({rhp_poles}); poles decide")
    if unobs.size:
        tol = 1e-9 * max(1.0, float(np.max(np.abs(plant_eigvals(lin_full)))))
        bad = unobs[unobs.real > tol]
        marginal = unobs[np.abs(unobs.real) <= tol]
        if bad.size:
            rhp += int(bad.size)
            notes.append(f"unstable plant mode(s) {np.round(bad, 6).tolist()} not measured by any loop: cannot be stabilised")
        if marginal.size:
            notes.append(
                f"marginal plant mode(s) {np.round(marginal, 6).tolist()} not measured by any loop (e.g. an integrator "
                "such as position under speed control): left out of the stability verdict"
            )
    return Stability(rhp == 0, method, int(rhp), int(nyq), poles, poles_method, max_re, notes)


#: Largest closed-loop state dimension of a sampled loop whose eigenvalues are computed (a long
#: delay is a long input buffer); beyond it the discrete Nyquist criterion decides alone. (LAPACK's
#: eigenvalue solver turns multi-threaded near 80 states, and then costs 100x more on a busy machine.)
EIG_MAX = 64


def _stability_sampled(ev: _Evaluator, cas: Cascade, lin: LinearModel, sp: SampledPlant, n_freq: int) -> Stability:
    """Closed-loop stability of the sampled loop: the eigenvalues of its transition matrix decide
    (|z| < 1), the discrete Nyquist count is the cross-check (it decides alone for closed loops
    with more than :data:`EIG_MAX` states)."""
    notes: list[str] = []
    meas = cas.measured
    lin_r, unobs = lin, np.zeros(0, dtype=complex)
    if meas is not None:
        lin_r, unobs = observable_part(lin, meas)
    spr = sp.for_model(lin_r)
    ol = cas.open_loop_poles_sampled(spr)[0]
    N = spr.n + spr.buffer_len + sum(lp.n_states() for lp in cas.loops)
    eps = 1e-7 * float(_char_freqs(cas, lin_r, DelayModel(sp.total_delay)).min())
    nyq, frac_err = _discrete_nyquist(ev, ol, eps, n_freq)
    if N <= EIG_MAX:
        A = cas.closed_loop_sampled(spr)[0]
        poles = np.linalg.eigvals(A) if A.size else np.zeros(0, dtype=complex)
        rad = float(np.max(np.abs(poles))) if poles.size else 0.0
        rhp = int(np.sum(np.abs(poles) > 1.0 - 1e-10))
        method, poles_method = "poles", "exact"
        if nyq != rhp:
            notes.append(f"discrete Nyquist count ({nyq}) differs from the pole count ({rhp}); poles decide")
    else:
        poles = np.zeros(0, dtype=complex)
        rad = math.nan
        rhp = nyq
        method, poles_method = "nyquist", "none"
        notes.append(f"{N} closed-loop states (input buffer of {spr.buffer_len} samples): the discrete Nyquist "
                     "criterion decides; poles not listed")
        if frac_err > 0.25:
            notes.append("discrete Nyquist count is not close to an integer; grid may be too coarse")
    if unobs.size:
        zu = np.abs(sp.mode_factor(unobs))
        bad = unobs[zu > 1.0 + 1e-9]
        marginal = unobs[np.abs(zu - 1.0) <= 1e-9]
        if bad.size:
            rhp += int(bad.size)
            notes.append(f"unstable plant mode(s) {np.round(bad, 6).tolist()} not measured by any loop: cannot be stabilised")
        if marginal.size:
            notes.append(
                f"marginal plant mode(s) {np.round(marginal, 6).tolist()} not measured by any loop (e.g. an integrator "
                "such as position under speed control): left out of the stability verdict"
            )
    with np.errstate(divide="ignore"):
        max_re = math.log(rad) / sp.dt if math.isfinite(rad) and rad > 0 else (-math.inf if rad == 0 else math.nan)
    return Stability(rhp == 0, method, int(rhp), int(nyq), poles, poles_method, max_re, notes, "z",
                     rad if math.isfinite(rad) else None)


def _analyse_sampled(cas: Cascade, lin: LinearModel, sp: SampledPlant, n_freq: int) -> Analysis:
    """:func:`analyse` of the sampled loop: the band is [lo, pi/dt] and both ends are end points
    of the Nyquist curve (L is real at z = 1 and z = -1)."""
    ev = _Evaluator(cas, lin, None, sp)
    lo, hi, L0 = _band_ends(ev, cas, lin)
    w, L, aL = _grid(ev, lo, hi, n_freq)
    Lend = L[:, -1].real + 0j
    L[:, -1] = Lend
    figs = _all_margins(ev, w, L, aL, cas, L0, Lend)
    stab = _stability_sampled(ev, cas, lin, sp, max(400, n_freq // 2))
    return Analysis(figs, stab, (float(w[0]), float(w[-1])))


def _all_margins(ev: _Evaluator, w, L, aL, cas: Cascade, L0, Lend=None) -> list[BreakFigures]:
    """Figures of every break point. The plant-input row is the innermost loop's controller-output
    row (L_{n-1} = -g_{n-1} H_n with H_n = 1, bit for bit): analysed once, copied."""
    n = len(cas.loops)
    names = cas.break_names
    figs = _margins(ev, w, L[:n], aL[:n], names[:n], L0[:n], None if Lend is None else Lend[:n])
    inner = figs[n - 1]
    figs.append(replace(inner, loop=names[n][0], break_point=names[n][1],
                        crossings=[replace(c) for c in inner.crossings]))
    return figs


#: Band widenings tried (x10 each) when the tail above the band cannot be proven harmless.
_BAND_TRIES = 3


def _tail_clear(cas: Cascade, lin: LinearModel, figs: list[BreakFigures], w_cap: float):
    """Proven: above ``w_cap`` no break point's |L| can change its figures (see :mod:`gaintune.verify.tail`).

    Returns the plant-input realisation G_u (reused by the stability test) when proven, else None."""
    n = len(cas.loops)
    if cas.measured is not None:
        lin = observable_part(lin, cas.measured)[0]
    g_u = chain_ss(cas, lin, 0, n - 1, "u")  # rows n-1 (innermost) and n (plant input): |L| = |G_u|
    if not level_clear(g_u, min(tail_levels(figs[n - 1], MAG_FLOOR), tail_levels(figs[n], MAG_FLOOR)), w_cap):
        return None
    for i in range(n - 1):  # outer rows: |L_i| <= |G_i Phi_{i+1}| / (1 - |Gin_{i+1}|)
        tau = tail_levels(figs[i], MAG_FLOOR)
        g_in = chain_ss(cas, lin, i + 1, n - 1, "u")
        if not level_clear(g_in, INNER_LEVEL, w_cap):
            return None
        g_i = series(chain_ss(cas, lin, 0, i, "u"), chain_ss(cas, lin, i + 1, n - 1, "r"))
        if not level_clear(g_i, tau * (1.0 - INNER_LEVEL), w_cap):
            return None
    return g_u


def analyse(cas: Cascade, lin: LinearModel, delay: DelayModel | None, n_freq: int = 2000, band: float | None = None,
            sampled: SampledPlant | None = None) -> Analysis:
    """Margins at every break point and closed-loop stability for a one-member cascade.

    ``sampled``: analyse the sampled loop (the plant as the simulator steps it, the controllers'
    discrete laws; :mod:`gaintune.verify.sampled`) on [lo, pi/dt]; ``delay`` and ``band`` are then unused.

    ``band``: upper end (rad/s) of the analysis band, normally a multiple of the controller's
    Nyquist frequency. The grid stops there only when the frequencies above are proven unable
    to change any figure or the stability count (:mod:`gaintune.verify.tail`); otherwise the
    band is widened x10 (a few times), and finally the grid runs to where |L| < MAG_FLOOR, as
    without ``band``. Crossings above the band are neither listed nor counted.
    """
    if sampled is not None:
        return _analyse_sampled(cas, lin, sampled, n_freq)
    ev = _Evaluator(cas, lin, delay)
    lo, hi, L0 = _band_ends(ev, cas, lin)
    caps = []
    if band is not None and cas.batch == 1 and math.isfinite(band) and band > 0:
        c = max(float(band), lo * 10.0)
        while c < hi and len(caps) < _BAND_TRIES:
            caps.append(c)
            c *= 10.0
    n_ap = max(400, n_freq // 2)
    for cap in caps:
        w, L, aL = _grid(ev, lo, cap, n_freq)
        figs = _all_margins(ev, w, L, aL, cas, L0)
        g_u = _tail_clear(cas, lin, figs, cap)
        if g_u is None:
            continue
        stab = _stability(ev, cas, lin, delay, cap, n_ap, capped=True, g_u=g_u)
        if stab is not None:
            return Analysis(figs, stab, (float(w[0]), float(w[-1])))
    w, L, aL = _grid(ev, lo, hi, n_freq)
    figs = _all_margins(ev, w, L, aL, cas, L0)
    stab = _stability(ev, cas, lin, delay, float(w[-1]), n_ap)
    return Analysis(figs, stab, (float(w[0]), float(w[-1])))
