"""Exact loop-at-a-time margins of one gain set on one linear model.

Everything is computed from frequency responses evaluated with numpy (no
python-control objects in the hot path): a log grid, every sign change located
and then zoomed in on (vectorised over all brackets at once), and peaks refined
the same way.

Definitions (L = open-loop response at a break point):

* gain crossover: |L(jw)| = 1; phase margin there PM = 180 + arg L wrapped to
  (-180, 180]; the reported PM is the one of smallest magnitude (as
  ``control.stability_margins``); delay margin = min over crossovers of the phase
  lag (PM mod 360, in rad) / w.
* phase crossover: L(jw) on the negative real axis (w = 0 included when L(0) is
  finite and negative); critical gain factor k = 1/|L|. Upper GM = smallest
  k > 1, lower GM = largest k < 1 (conditionally stable loops). The binding GM is
  the one of smaller |dB|. No crossover -> GM = inf (also when the phase only
  approaches -180 deg asymptotically, python-control issue #784). A crossing with
  |L| < 1e-10 (GM > 200 dB) counts as none.
* Ms = max |1/(1+L)|, Mt = max |L/(1+L)|; disk margin alpha = 1/max|S - 1/2|
  (balanced, skew 0), with disk GM/PM as in ``control.disk_margins``.

Closed-loop stability uses the argument principle on the characteristic
quasi-polynomial chi_ol(s) (1 + L_u(s)) along s = -eps + jw (the plant-input
cut L_u passes through every loop), which is exact for delays and counts
open-loop unstable poles; for delay-free loops the closed-loop eigenvalues
decide and the two are cross-checked.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from gaintune.plants.plant import LinearModel
from gaintune.verify.loops import Cascade, observable_part, pade_response

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


@dataclass
class Analysis:
    figures: list[BreakFigures]
    stability: Stability
    omega_range: tuple[float, float]


# ------------------------------------------------------------------ helpers


def _char_freqs(cas: Cascade, lin: LinearModel, delay: DelayModel) -> np.ndarray:
    f = [abs(x) for x in np.linalg.eigvals(lin.A)] if lin.A.size else []
    for lp in cas.loops:
        if lp.kind == "pid":
            kp, ki, kd, tf = float(lp.Kp[0]), float(lp.Ki[0]), float(lp.Kd[0]), float(lp.Tf[0])
            if lp.has_i and kp > 0:
                f.append(ki / kp)
            if lp.has_d and kd > 0:
                f += [kp / kd, 1.0 / tf]
    if delay.T > 0:
        f.append(1.0 / delay.T)
    f = np.array([x for x in f if np.isfinite(x) and x > 1e-12])
    return f if f.size else np.array([1.0])


class _Evaluator:
    """L at arbitrary frequencies for one gain set (rows: break points)."""

    def __init__(self, cas: Cascade, lin: LinearModel, delay: DelayModel):
        self.cas, self.lin, self.delay = cas, lin, delay
        self.calls = 0

    def __call__(self, w: np.ndarray, shift: float = 0.0) -> np.ndarray:
        self.calls += 1
        s = -shift + 1j * np.asarray(w, dtype=float)
        with np.errstate(all="ignore"):
            return self.cas.loop_responses(s, self.lin, self.delay.factor(s))[:, 0, :]


def _zoom_roots(ev: _Evaluator, lo: np.ndarray, hi: np.ndarray, rows: np.ndarray, fn, iters: int = 12):
    """Refine brackets [lo, hi] (per row) of a sign change of fn(L): vectorised Illinois
    (modified regula falsi) in log w, one evaluation of all brackets per iteration."""
    if lo.size == 0:
        return lo
    a, b = np.log(lo), np.log(hi)
    k = np.arange(lo.size)
    fa = fn(ev(np.exp(a))[rows, k])
    fb = fn(ev(np.exp(b))[rows, k])
    side = np.zeros(lo.size)
    c = 0.5 * (a + b)
    for _ in range(iters):
        c_prev = c
        with np.errstate(invalid="ignore", divide="ignore"):
            c = np.where(fa != fb, (a * fb - b * fa) / (fb - fa), 0.5 * (a + b))
        bad = ~np.isfinite(c) | (c <= np.minimum(a, b)) | (c >= np.maximum(a, b))
        c = np.where(bad, 0.5 * (a + b), c)
        fc = fn(ev(np.exp(c))[rows, k])
        left = np.sign(fc) == np.sign(fa)  # root in [c, b]
        # Illinois: halve the retained end's value when the same side is kept twice
        fb = np.where(left & (side == 1), fb * 0.5, fb)
        fa = np.where(~left & (side == -1), fa * 0.5, fa)
        a, fa = np.where(left, c, a), np.where(left, fc, fa)
        b, fb = np.where(left, b, c), np.where(left, fb, fc)
        side = np.where(left, 1, -1)
        if np.all((np.abs(c - c_prev) < 1e-12) | (np.abs(b - a) < 1e-12) | (fc == 0)):
            break
    return np.exp(c)


def _zoom_peaks(ev: _Evaluator, lo: np.ndarray, hi: np.ndarray, rows: np.ndarray, fn, rounds: int = 2):
    """Refine the maximum of fn(L) inside [lo, hi] per row. Returns (w, value)."""
    best_w = np.sqrt(lo * hi)
    best_v = np.full(lo.size, -np.inf)
    for _ in range(rounds):
        t = np.linspace(0.0, 1.0, _ZOOM)
        W = np.exp(np.log(lo)[:, None] + (np.log(hi) - np.log(lo))[:, None] * t[None, :])
        L = ev(W.ravel())
        Lr = L[rows[:, None], np.arange(W.size).reshape(W.shape)]
        f = fn(Lr)
        j = np.argmax(f, axis=1)
        k = np.arange(lo.size)
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


def _grid(ev: _Evaluator, cas, lin, delay, n_freq: int):
    """Log grid covering every frequency where max|L| >= MAG_FLOOR, refined where the
    phase turns fast (delays)."""
    cf = _char_freqs(cas, lin, DelayModel(0.0))
    lo, hi = cf.min() * 1e-3, cf.max() * 1e3
    for _ in range(8):
        if np.all(np.abs(ev(np.array([hi]))) < MAG_FLOOR):
            break
        hi *= 10.0
    for _ in range(3):
        Llo = np.abs(ev(np.array([lo])))
        if np.all((Llo > 1e3) | (Llo < MAG_FLOOR)):
            break
        lo /= 100.0
    w = np.logspace(np.log10(lo), np.log10(hi), n_freq)
    L = ev(w)
    for _ in range(4):
        with np.errstate(all="ignore"):
            dph = np.abs(np.angle(L[:, 1:] / L[:, :-1]))
            big = (np.abs(L[:, 1:]) > MAG_FLOOR) | (np.abs(L[:, :-1]) > MAG_FLOOR)
        bad = np.nonzero(np.any((dph > 0.5) & big, axis=0))[0][:20000]
        if bad.size == 0:
            break
        new = np.exp(np.log(w[bad, None]) + np.log(w[bad + 1] / w[bad])[:, None] * np.linspace(0, 1, 8)[None, 1:-1]).ravel()
        o = np.argsort(np.concatenate([w, new]))
        w = np.concatenate([w, new])[o]
        L = np.concatenate([L, ev(new)], axis=1)[:, o]
    return w, L


def _figures_for_row(row_name, Lrow, w, gm_list, pm_list, peaks) -> BreakFigures:
    fig = BreakFigures(loop=row_name[0], break_point=row_name[1])
    crossings: list[Crossing] = []
    ups, lows = [], []
    for wc, k in gm_list:  # k: critical gain factor
        if not np.isfinite(k) or k > GM_INF_LIMIT or k < 1.0 / GM_INF_LIMIT:
            continue
        db = 20 * math.log10(k)
        crossings.append(Crossing("phase", float(wc), float(db)))
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
    for wc, phase_deg in pm_list:
        pm = float(_wrap180(np.array(180.0 + phase_deg)))
        lag = math.radians(pm % 360.0)
        dm = lag / wc if wc > 0 else math.inf
        crossings.append(Crossing("gain", float(wc), pm, delay_margin=float(dm)))
        pms.append((abs(pm), len(crossings) - 1))
        fig.delay_margin = min(fig.delay_margin, dm)
    if pms:
        _, i = min(pms)
        fig.pm_deg, fig.pm_freq = crossings[i].value, crossings[i].omega
        crossings[i].binding = True
    fig.crossings = sorted(crossings, key=lambda c: c.omega)
    (fig.ms_freq, fig.ms), (fig.mt_freq, fig.mt), (fig.disk_freq, inv_alpha) = peaks
    fig.disk_alpha = 1.0 / inv_alpha if inv_alpha > 0 else math.inf
    fig.disk_gm_db, fig.disk_pm_deg = disk_from_alpha(fig.disk_alpha)
    return fig


def _margins(ev: _Evaluator, w: np.ndarray, L: np.ndarray, names) -> list[BreakFigures]:
    R = L.shape[0]
    with np.errstate(divide="ignore", invalid="ignore"):
        logmag = np.log(np.abs(L))
    # ---- gain crossings
    sc = (np.sign(logmag[:, :-1]) != np.sign(logmag[:, 1:])) & np.isfinite(logmag[:, :-1]) & np.isfinite(logmag[:, 1:])
    r_g, i_g = np.nonzero(sc)
    wg = _zoom_roots(ev, w[i_g], w[i_g + 1], r_g, lambda Z: np.log(np.abs(Z)))
    # ---- phase crossings (negative real axis)
    im, re = L.imag, L.real
    aL = np.abs(L)
    sp = (np.sign(im[:, :-1]) != np.sign(im[:, 1:])) & ((re[:, :-1] < 0) | (re[:, 1:] < 0))
    sp &= (aL[:, :-1] > 0.5 * MAG_FLOOR) | (aL[:, 1:] > 0.5 * MAG_FLOOR)
    sp &= (aL[:, :-1] < 2 * GM_INF_LIMIT) | (aL[:, 1:] < 2 * GM_INF_LIMIT)
    r_p, i_p = np.nonzero(sp)
    wp = _zoom_roots(ev, w[i_p], w[i_p + 1], r_p, lambda Z: Z.imag)
    # ---- evaluate at the roots
    pts = np.concatenate([wg, wp])
    Lpts = ev(pts) if pts.size else np.zeros((R, 0), dtype=complex)
    gm_lists = [[] for _ in range(R)]
    pm_lists = [[] for _ in range(R)]
    for k, (r, wc) in enumerate(zip(r_g, wg)):
        pm_lists[r].append((wc, math.degrees(np.angle(Lpts[r, k]))))
    for k, (r, wc) in enumerate(zip(r_p, wp)):
        z = Lpts[r, wg.size + k]
        if z.real < 0 and abs(z.imag) <= 1e-6 * abs(z) + 1e-300:
            gm_lists[r].append((wc, 1.0 / abs(z)))
        elif z.real < 0:  # crossing too flat to pin down: still a crossing of the real axis
            gm_lists[r].append((wc, 1.0 / abs(z.real)))
    # w = 0: finite negative real DC gain is a phase crossing too
    L0 = ev(np.array([0.0]))[:, 0]
    for r in range(R):
        z = L0[r]
        if np.isfinite(z) and 0 < abs(z) < 1e8 and z.real < 0 and abs(z.imag) < 1e-9 * abs(z):
            gm_lists[r].append((0.0, 1.0 / abs(z)))
    # ---- peaks: Ms, Mt, 1/alpha
    with np.errstate(divide="ignore", invalid="ignore"):
        S = 1.0 / (1.0 + L)
        fns = [
            lambda Z: np.abs(1.0 / (1.0 + Z)),
            lambda Z: np.abs(Z / (1.0 + Z)),
            lambda Z: np.abs(1.0 / (1.0 + Z) - 0.5),
        ]
        vals = [np.abs(S), np.abs(L * S), np.abs(S - 0.5)]
    peaks = [[None] * 3 for _ in range(R)]
    rows = np.arange(R)
    for q, (fn, V) in enumerate(zip(fns, vals)):
        V = np.nan_to_num(V, nan=np.inf)
        j = np.argmax(V, axis=1)
        lo = w[np.maximum(j - 1, 0)]
        hi = w[np.minimum(j + 1, w.size - 1)]
        with np.errstate(divide="ignore", invalid="ignore"):
            pw, pv = _zoom_peaks(ev, lo, hi, rows, lambda Z, fn=fn: np.nan_to_num(fn(Z), nan=np.inf))
        for r in range(R):
            peaks[r][q] = (float(pw[r]), float(max(pv[r], V[r, j[r]])))
    return [_figures_for_row(names[r], L[r], w, gm_lists[r], pm_lists[r], peaks[r]) for r in range(R)]


# --------------------------------------------------------------- stability


def _argument_principle(ev: _Evaluator, ol_poles: np.ndarray, w_hi: float, eps: float, n_freq: int):
    """Number of closed-loop roots right of Re s = -eps (plant-input cut, row -1)."""
    im_axis = np.abs(ol_poles.imag[np.abs(ol_poles.real) < 10 * eps])
    extra = [w0 + eps * np.linspace(-30, 30, 61) for w0 in im_axis if w0 > 0]
    w = np.concatenate([[0.0], np.logspace(np.log10(eps / 100), np.log10(w_hi), n_freq), *extra])
    w = np.unique(w[w >= 0])
    phi = 1.0 + ev(w, shift=eps)[-1]
    for _ in range(10):
        ang = np.angle(phi)
        d = np.abs(np.angle(phi[1:] / phi[:-1]))
        bad = np.nonzero(d > 0.3)[0]
        if bad.size == 0:
            break
        bad = bad[:4000]
        new = (w[bad, None] + (w[bad + 1] - w[bad])[:, None] * np.linspace(0, 1, 10)[None, 1:-1]).ravel()
        wn = np.concatenate([w, new])
        phin = np.concatenate([phi, 1.0 + ev(new, shift=eps)[-1]])
        o = np.argsort(wn)
        w, phi = wn[o], phin[o]
    ang = np.unwrap(np.angle(phi))
    d_one_plus_L = ang[-1] - ang[0]
    # tail to infinity: |L| < 1 there keeps 1 + L in the right half-plane
    far = 1.0 + ev(np.array([w_hi * 1e4]), shift=eps)[-1, 0]
    tail_ok = abs(far - 1.0) < 1.0
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


def _stability(ev: _Evaluator, cas: Cascade, lin: LinearModel, delay: DelayModel, w_hi: float, n_freq: int):
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
    nyq, frac_err, tail_ok, l_inf = _argument_principle(ev, ol, w_hi, eps, n_freq)
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
        tol = 1e-9 * max(1.0, float(np.max(np.abs(np.linalg.eigvals(lin_full.A)))))
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


def analyse(cas: Cascade, lin: LinearModel, delay: DelayModel, n_freq: int = 2000) -> Analysis:
    """Margins at every break point and closed-loop stability for a one-member cascade."""
    ev = _Evaluator(cas, lin, delay)
    w, L = _grid(ev, cas, lin, delay, n_freq)
    figs = _margins(ev, w, L, cas.break_names)
    stab = _stability(ev, cas, lin, delay, float(w[-1]), max(400, n_freq // 2))
    return Analysis(figs, stab, (float(w[0]), float(w[-1])))
