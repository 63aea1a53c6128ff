"""The analysis of one gain set on one linear model: the band, its grid, the tail above it, :func:`analyse`.

:func:`analyse` runs the whole exact analysis: the band's ends (every frequency where some
|L| >= MAG_FLOOR, or up to the Nyquist frequency for the sampled loop), a log grid refined
where the phase turns fast (delays), the margins of every break point on it
(:mod:`gaintune.verification.margins`) and closed-loop stability (:mod:`gaintune.verification.stability`).

The continuous analysis may stop the grid at a band (a multiple of the controller's
Nyquist frequency) only when the frequencies above are proven unable to change any
figure or the stability count (the tail, with the bounds of :mod:`gaintune.verification.tail`);
:func:`sampling_delay` is the dt/2 of extra delay that analysis adds for sample and hold.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from gaintune.errors import SpecError
from gaintune.plants.plant import LinearModel
from gaintune.spec import TuningSpec
from gaintune.verification.cascade import Cascade
from gaintune.verification.freqresp import DelayModel, Evaluator, char_freqs
from gaintune.verification.margins import MAG_FLOOR, BreakFigures, all_margins
from gaintune.verification.sampled import SampledPlant
from gaintune.verification.stability import (
    Stability,
    closed_loop_stability,
    closed_loop_stability_sampled,
    observable_part,
)
from gaintune.verification.tail import INNER_LEVEL, chain_ss, level_clear, series, tail_levels

__all__ = ["Analysis", "analyse", "analysis_dt", "analysis_band", "sampling_delay", "BAND_NYQUIST"]

#: The continuous analysis band ends at this multiple of the controller's Nyquist frequency pi/dt
#: (largest scenario dt) when the frequencies above are proven harmless (:func:`analyse`, ``band``).
#: The sampled analysis ends at pi/dt itself.
BAND_NYQUIST = 10.0


@dataclass
class Analysis:
    """The result of :func:`analyse`: figures per break point, stability, and the band analysed (rad/s)."""

    figures: list[BreakFigures]
    stability: Stability
    omega_range: tuple[float, float]
    #: Why the figures cannot be trusted (the loop response overflowed on the grid); empty when fine.
    problems: list[str] = field(default_factory=list)


def _overflow_problems(L: np.ndarray) -> list[str]:
    """A non-finite L on the grid (absurd gains or plant coefficients) makes every margin figure
    unreliable: crossings and peaks may be missed, so the margins are not certified."""
    bad = int(np.count_nonzero(~np.isfinite(L)))
    if not bad:
        return []
    return [f"margins not computable: the loop response overflows (non-finite) at {bad} of {L.size} grid points; "
            "gains or plant coefficients too large to analyse"]


def analysis_dt(spec: TuningSpec) -> float:
    """The sample time verification uses: the largest scenario dt (the conservative choice).

    Raises
    ------
    SpecError
        When a scenario has no dt yet (derive it from the plant first:
        :func:`gaintune.classical.timescale.resolve_scenarios`, as :func:`gaintune.verification.verify` does).
    """
    for i, sc in enumerate(spec.scenarios):
        if sc.dt is None:
            raise SpecError(f"scenarios[{i}].dt", "not set yet: derive it from the plant first "
                            "(gaintune.classical.timescale.resolve_scenarios) or give it in the spec")
    return max(sc.dt for sc in spec.scenarios if sc.dt is not None)


def analysis_band(spec: TuningSpec) -> float:
    """Upper end (rad/s) of the continuous analysis band: BAND_NYQUIST x the Nyquist frequency pi/dt
    of the largest dt."""
    return BAND_NYQUIST * math.pi / analysis_dt(spec)


def sampling_delay(spec: TuningSpec) -> float:
    """Sample-and-hold approximation: dt/2 of extra input delay (largest scenario dt)."""
    return 0.5 * analysis_dt(spec)


#: A grid interval is refined when L turns by more than 0.5 rad over it.
_COS_DPH = math.cos(0.5)


def _band_ends(ev: Evaluator, cas, lin) -> tuple[float, float, np.ndarray]:
    """(lo, hi) of the full grid: every frequency where max|L| >= MAG_FLOOR (end probes in one
    call), and L(0) per row (the same call). A sampled loop's grid ends at the Nyquist frequency."""
    cf = char_freqs(cas, lin, DelayModel(0.0))
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


#: Grid intervals (left w, right w, left L, right L, left |L|, right |L|); L and |L| are (R, count).
_Intervals = tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]


def _pick(idx: np.ndarray, E: np.ndarray, LE: np.ndarray, AE: np.ndarray, rest: _Intervals) -> _Intervals:
    """The intervals ``idx`` of a block (end points E (m, k+1), responses LE and |L| AE (R, m, k+1))
    followed by the leftover intervals ``rest`` (indices from m k on)."""
    m, k = E.shape[0], E.shape[1] - 1
    blk = idx[idx < m * k]
    bi, bj = np.divmod(blk, k)
    ri = idx[idx >= m * k] - m * k
    cat = np.concatenate
    return (cat([E[bi, bj], rest[0][ri]]), cat([E[bi, bj + 1], rest[1][ri]]),
            cat([LE[:, bi, bj], rest[2][:, ri]], axis=1), cat([LE[:, bi, bj + 1], rest[3][:, ri]], axis=1),
            cat([AE[:, bi, bj], rest[4][:, ri]], axis=1), cat([AE[:, bi, bj + 1], rest[5][:, ri]], axis=1))


def _grid(ev: Evaluator, lo: float, hi: float, n_freq: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
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
    rest: _Intervals = (np.zeros(0), np.zeros(0), np.zeros((R, 0), complex), np.zeros((R, 0), complex),
                        np.zeros((R, 0)), np.zeros((R, 0)))
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
        wl, wr, Ll, Lr, al, ar = _pick(bad_all[:20000], E, LE, AE, rest)
        rest = _pick(bad_all[20000:], E, LE, AE, rest)
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


def _analyse_sampled(cas: Cascade, lin: LinearModel, sp: SampledPlant, n_freq: int) -> Analysis:
    """:func:`analyse` of the sampled loop: the band is [lo, pi/dt] and both ends are end points
    of the Nyquist curve (L is real at z = 1 and z = -1)."""
    ev = Evaluator(cas, lin, None, sp)
    lo, hi, L0 = _band_ends(ev, cas, lin)
    w, L, aL = _grid(ev, lo, hi, n_freq)
    Lend = L[:, -1].real + 0j
    L[:, -1] = Lend
    figs = all_margins(ev, w, L, aL, cas, L0, Lend)
    stab = closed_loop_stability_sampled(ev, cas, lin, sp, max(400, n_freq // 2))
    return Analysis(figs, stab, (float(w[0]), float(w[-1])), _overflow_problems(L))


#: Band widenings tried (x10 each) when the tail above the band cannot be proven harmless.
_BAND_TRIES = 3


def _tail_clear(cas: Cascade, lin: LinearModel, figs: list[BreakFigures], w_cap: float):
    """Proven: above ``w_cap`` no break point's |L| can change its figures (see :mod:`gaintune.verification.tail`).

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
    discrete laws; :mod:`gaintune.verification.sampled`) on [lo, pi/dt]; ``delay`` and ``band`` are then unused.

    ``band``: upper end (rad/s) of the analysis band, normally a multiple of the controller's
    Nyquist frequency. The grid stops there only when the frequencies above are proven unable
    to change any figure or the stability count (:mod:`gaintune.verification.tail`); otherwise the
    band is widened x10 (a few times), and finally the grid runs to where |L| < MAG_FLOOR, as
    without ``band``. Crossings above the band are neither listed nor counted.
    """
    if sampled is not None:
        return _analyse_sampled(cas, lin, sampled, n_freq)
    if delay is None:
        raise ValueError("analyse: the continuous loop needs its delay model")
    ev = Evaluator(cas, lin, delay)
    lo, hi, L0 = _band_ends(ev, cas, lin)
    caps: list[float] = []
    if band is not None and cas.batch == 1 and math.isfinite(band) and band > 0:
        c = max(float(band), lo * 10.0)
        while c < hi and len(caps) < _BAND_TRIES:
            caps.append(c)
            c *= 10.0
    n_ap = max(400, n_freq // 2)
    for cap in caps:
        w, L, aL = _grid(ev, lo, cap, n_freq)
        figs = all_margins(ev, w, L, aL, cas, L0)
        g_u = _tail_clear(cas, lin, figs, cap)
        if g_u is None:
            continue
        stab = closed_loop_stability(ev, cas, lin, delay, cap, n_ap, capped=True, g_u=g_u)
        if stab is not None:
            return Analysis(figs, stab, (float(w[0]), float(w[-1])), _overflow_problems(L))
    w, L, aL = _grid(ev, lo, hi, n_freq)
    figs = all_margins(ev, w, L, aL, cas, L0)
    stab = closed_loop_stability(ev, cas, lin, delay, float(w[-1]), n_ap)
    return Analysis(figs, stab, (float(w[0]), float(w[-1])), _overflow_problems(L))
