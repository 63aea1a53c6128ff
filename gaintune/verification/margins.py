"""Loop-at-a-time margins of one gain set from its frequency responses.

Definitions (L = open-loop response at a break point: L(jw) of the continuous loop, or
L(e^{jw dt}) of the sampled loop, :mod:`gaintune.verification.sampled`, for 0 < w <= pi/dt):

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

:func:`all_margins` takes L on a grid (:mod:`gaintune.verification.analysis` builds it): every
sign change is located on the grid and then zoomed in on
(:func:`gaintune.verification.freqresp.zoom_roots`, vectorised over all brackets at once), and
the peaks are refined the same way.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, field, replace

import numpy as np

from gaintune.verification.cascade import Cascade
from gaintune.verification.freqresp import Evaluator, zoom_roots

__all__ = ["Crossing", "BreakFigures", "judged_pm", "all_margins", "row_margins", "disk_from_alpha", "MAG_FLOOR",
           "GM_INF_LIMIT", "MAX_PHASE_LISTED", "PEAK_FIGURES"]

#: |L| below this at a phase crossing counts as no crossing (GM > 80 dB is reported as inf).
MAG_FLOOR = 1e-4
#: GM beyond this factor (80 dB) is reported as inf.
GM_INF_LIMIT = 1.0 / MAG_FLOOR
#: The peak figures of a break point: Ms, Mt and the disk margin's 1/alpha.
PEAK_FIGURES = ("ms", "mt", "disk")
#: Points per round of the peak zoom.
_ZOOM = 24


@dataclass
class Crossing:
    """One gain or phase crossing of a break point's L, refined."""

    kind: str  # "gain" | "phase"
    omega: float
    value: float  # gain: PM deg; phase: GM dB (positive upper, negative lower)
    delay_margin: float | None = None  # gain crossings only
    binding: bool = False


def judged_pm(pm_deg: float) -> float:
    """The phase margin a requirement judges: the binding crossover's phase distance from -180 degrees,
    either way, ``|pm_deg|``.

    The reported PM keeps its sign (python-control's and MATLAB's convention: a crossover with
    phase lead, e.g. +91 degrees, reports -89). Such a crossover is 89 degrees of phase away from
    -1 in either direction, and the binding crossover is already chosen by this distance; closed-loop
    stability is judged separately. Judging the signed value failed the velocity loops of a stable
    cascade whose sensitivity peak was 1.01 (``test_crossover_with_phase_lead_is_judged_by_its_phase_distance``).

    >>> judged_pm(-88.9), judged_pm(50.0)
    (88.9, 50.0)
    """
    return abs(pm_deg)


@dataclass
class BreakFigures:
    """Every margin figure of one break point (loop, break point); frequencies in rad/s."""

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


# ------------------------------------------------------------------ helpers


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


def _zoom_peaks(ev: Evaluator, lo: np.ndarray, hi: np.ndarray, rows: np.ndarray, q: np.ndarray, rounds: int = 3):
    """Refine the maximum of :func:`_peak_values` (figure q_i) inside [lo_i, hi_i] (row rows_i),
    all peaks in one evaluation per round. Returns (w, value)."""
    best_w = np.sqrt(lo * hi)
    best_v = np.full(lo.size, -np.inf)
    k = np.arange(lo.size)
    t = np.linspace(0.0, 1.0, _ZOOM)
    for _ in range(rounds):
        W = np.exp(np.log(lo)[:, None] + (np.log(hi) - np.log(lo))[:, None] * t[None, :])
        f = _peak_values(ev.rows_at(W.ravel(), np.repeat(rows, W.shape[1])).reshape(W.shape), q)
        j = np.argmax(f, axis=1)
        better = f[k, j] > best_v
        best_v = np.where(better, f[k, j], best_v)
        best_w = np.where(better, W[k, j], best_w)
        lo, hi = W[k, np.maximum(j - 1, 0)], W[k, np.minimum(j + 1, _ZOOM - 1)]
    return best_w, best_v


def disk_from_alpha(alpha: float) -> tuple[float, float]:
    """Disk GM (dB) and PM (deg) for a balanced (skew 0) disk margin alpha, as control.disk_margins."""
    if not np.isfinite(alpha):
        return math.inf, 90.0
    gmin = (1 - 0.5 * alpha) / (1 + 0.5 * alpha)
    gmax = (1 + 0.5 * alpha) / (1 - 0.5 * alpha) if alpha != 2 else math.inf
    with np.errstate(all="ignore"):
        # alpha == 2 (S ~ 0 everywhere, e.g. huge gains) rounds gmin to 0: infinite, not a ZeroDivisionError
        dgm = 20 * np.log10(np.minimum(1 / gmin if gmin != 0 else math.inf, gmax))
    dgm = math.inf if (np.isnan(dgm) or alpha >= 2) else float(dgm)
    if np.isinf(gmax):
        dpm = 90.0
    else:
        c = (1 + gmin * gmax) / (gmin + gmax)
        dpm = math.inf if abs(c) >= 1 else float(np.degrees(np.arccos(c)))
    return dgm, dpm


# ------------------------------------------------------------------ margins


def _figures_for_row(row_name, gm_w, gm_k, pm_w, pm_deg, peaks, phase_omitted: int) -> BreakFigures:
    fig = BreakFigures(loop=row_name[0], break_point=row_name[1])
    crossings: list[Crossing] = []
    ups: list[tuple[float, float, int]] = []
    lows: list[tuple[float, float, int]] = []
    with np.errstate(divide="ignore", invalid="ignore"):
        keep = np.isfinite(gm_k) & (gm_k <= GM_INF_LIMIT) & (gm_k >= 1.0 / GM_INF_LIMIT)
    for wc, k in zip(gm_w[keep].tolist(), gm_k[keep].tolist(), strict=True):  # k: critical gain factor
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
    for wc, phase_deg in zip(np.asarray(pm_w).tolist(), np.asarray(pm_deg).tolist(), strict=True):
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


@dataclass
class _PhaseBrackets:
    """Grid intervals where L may cross the negative real axis, and how to rank them.

    Delays give hundreds of phase crossings; only those that can be listed (smallest |GM|) or
    whose classification is not clear from the bracket are refined, the rest counted."""

    rows: np.ndarray  # row of each bracket
    idx: np.ndarray  # grid index of its left end
    La: np.ndarray  # L at the ends
    Lb: np.ndarray
    lo_m: np.ndarray  # smaller and larger |L| of the ends
    hi_m: np.ndarray
    score: np.ndarray  # ~ |ln GM| of the crossing
    slack: np.ndarray  # how far the crossing's |ln GM| may be from score
    refine: np.ndarray  # bool: to be refined


def _phase_brackets(ev: Evaluator, w: np.ndarray, L: np.ndarray, aL: np.ndarray, end_point: bool) -> _PhaseBrackets:
    """The phase-crossing brackets on the grid; ``end_point``: the grid's last point is a sampled
    loop's Nyquist frequency (an end point of the Nyquist curve, added separately)."""
    R = L.shape[0]
    im, re = L.imag, L.real
    sp = (np.sign(im[:, :-1]) != np.sign(im[:, 1:])) & ((re[:, :-1] < 0) | (re[:, 1:] < 0))
    sp &= (aL[:, :-1] > 0.5 * MAG_FLOOR) | (aL[:, 1:] > 0.5 * MAG_FLOOR)
    sp &= (aL[:, :-1] < 2 * GM_INF_LIMIT) | (aL[:, 1:] < 2 * GM_INF_LIMIT)
    if end_point:
        sp[:, -1] = False  # the end point itself is on the real axis: added separately
    r_p, i_p = np.nonzero(sp)
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
    return _PhaseBrackets(r_p, i_p, Pa, Pb, lo_m, hi_m, score, slack, refine)


def _crossing_fn(ng: int) -> Callable[[np.ndarray, np.ndarray], np.ndarray]:
    """The function whose sign changes are zoomed: log|L| for the first ``ng`` brackets (gain
    crossings), sin(arg L) for the rest (phase crossings)."""

    def fn(Z: np.ndarray, kk: np.ndarray) -> np.ndarray:
        with np.errstate(divide="ignore", invalid="ignore"):
            return np.where(kk < ng, np.log(np.abs(Z)), Z.imag / np.abs(Z))

    return fn


def _needs_more(pb: _PhaseBrackets, done: np.ndarray, kp_: np.ndarray, R: int) -> bool:
    """Mark for refinement every unrefined bracket that could rank among the MAX_PHASE_LISTED
    smallest |GM| of its row; True when any was marked."""
    more = False
    for r in range(R):
        un = np.nonzero((pb.rows == r) & ~done)[0]
        if un.size == 0:
            continue
        kr = kp_[(pb.rows == r) & done]
        with np.errstate(divide="ignore", invalid="ignore"):
            v = np.abs(np.log(kr[np.isfinite(kr) & (kr <= GM_INF_LIMIT) & (kr >= 1 / GM_INF_LIMIT)]))
        tau = np.sort(v)[MAX_PHASE_LISTED - 1] if v.size >= MAX_PHASE_LISTED else np.inf
        need = un[pb.score[un] - pb.slack[un] <= tau]
        if need.size:
            pb.refine[need] = True
            more = True
    return more


def _zoom_crossings(ev: Evaluator, w: np.ndarray, L: np.ndarray, r_g: np.ndarray, i_g: np.ndarray,
                    pb: _PhaseBrackets) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Refine the gain crossings and the phase brackets to refine (gain and phase together in the
    first round, then more phase brackets until the listed ones are certain).

    Returns (w, L) at the gain crossings, and per phase bracket its crossing's w, critical gain
    factor (NaN where not refined) and whether it was refined."""
    R = L.shape[0]
    done = np.zeros(pb.rows.size, dtype=bool)
    wp = np.full(pb.rows.size, np.nan)
    kp_ = np.full(pb.rows.size, np.nan)
    wg, Lg = np.zeros(0), np.zeros(0, dtype=complex)
    first = True
    while True:
        todo = np.nonzero(pb.refine & ~done)[0]
        ng = r_g.size if first else 0
        lo = np.concatenate([w[i_g] if first else np.zeros(0), w[pb.idx[todo]]])
        hi = np.concatenate([w[i_g + 1] if first else np.zeros(0), w[pb.idx[todo] + 1]])
        rows = np.concatenate([r_g if first else np.zeros(0, dtype=np.int64), pb.rows[todo]]).astype(np.int64)
        La = np.concatenate([L[r_g, i_g] if first else np.zeros(0, dtype=complex), pb.La[todo]])
        Lb = np.concatenate([L[r_g, i_g + 1] if first else np.zeros(0, dtype=complex), pb.Lb[todo]])
        wz, Lz = zoom_roots(ev, lo, hi, rows, _crossing_fn(ng), La=La, Lb=Lb)
        if first:
            wg, Lg = wz[:ng], Lz[:ng]
            first = False
        wp[todo] = wz[ng:]
        kp_[todo] = _crit_gain(Lz[ng:])
        done[todo] = True
        # every unrefined bracket must rank after the MAX_PHASE_LISTED-th refined crossing of its row
        if not _needs_more(pb, done, kp_, R):
            return wg, Lg, wp, kp_, done


def _phase_crossing_lists(pb: _PhaseBrackets, wp: np.ndarray, kp_: np.ndarray, done: np.ndarray, R: int,
                          ends: list[tuple[float, np.ndarray]]
                          ) -> tuple[list[np.ndarray], list[np.ndarray], np.ndarray]:
    """Per row: the refined phase crossings' w and critical gain factors (with the real end points
    of the Nyquist curve that are crossings), and how many valid crossings were only counted."""
    gm_w: list[np.ndarray] = []
    gm_k: list[np.ndarray] = []
    omitted = np.zeros(R, dtype=np.int64)
    for r in range(R):
        sel = (pb.rows == r) & done
        gm_w.append(wp[sel])
        gm_k.append(kp_[sel])
        un = (pb.rows == r) & ~done
        # unrefined: clearly on the negative real axis, |L| clearly inside (MAG_FLOOR, GM_INF_LIMIT)
        omitted[r] = int(np.count_nonzero(un & (pb.lo_m > MAG_FLOOR) & (pb.hi_m < GM_INF_LIMIT)))
    # w = 0 (and a sampled loop's Nyquist frequency): a finite negative real L is a phase crossing too
    for r in range(R):
        for we, Le in ends:
            z = Le[r]
            if np.isfinite(z) and 0 < abs(z) < 1e8 and z.real < 0 and abs(z.imag) < 1e-9 * abs(z):
                o = np.argsort(np.concatenate([[we], gm_w[r]]), kind="stable")
                gm_w[r] = np.concatenate([[we], gm_w[r]])[o]
                with np.errstate(over="ignore"):  # |L| denormal (a 1e308 plant gain): GM inf, as meant
                    gm_k[r] = np.concatenate([[1.0 / abs(z)], gm_k[r]])[o]
    return gm_w, gm_k, omitted


def _peaks(ev: Evaluator, w: np.ndarray, L: np.ndarray,
           figures: tuple[str, ...] = PEAK_FIGURES) -> list[list[tuple[float, float]]]:
    """Per row, (w, value) of the Ms, Mt and 1/alpha peaks (all rows and figures zoomed together);
    a figure not in ``figures`` keeps its grid maximum (a lower bound), for a caller that reads it not."""
    R = L.shape[0]
    rows = np.tile(np.arange(R), 3)
    q = np.repeat(np.arange(3), R)
    with np.errstate(divide="ignore", invalid="ignore"):
        S = 1.0 / (1.0 + L)
    V = _figure_values(np.tile(S, (3, 1)), q)  # (3R, W), figure-major
    jj = np.argmax(V, axis=1)
    Vmax = V[np.arange(3 * R), jj]
    pw, pv = w[jj], Vmax.copy()
    zoom = np.isin(q, [PEAK_FIGURES.index(f) for f in figures])
    lo = w[np.maximum(jj - 1, 0)][zoom]
    hi = w[np.minimum(jj + 1, w.size - 1)][zoom]
    with np.errstate(divide="ignore", invalid="ignore"):
        pw[zoom], pv[zoom] = _zoom_peaks(ev, lo, hi, rows[zoom], q[zoom])
    pv = np.maximum(pv, Vmax)
    return [[(float(pw[qi * R + r]), float(pv[qi * R + r])) for qi in range(3)] for r in range(R)]


def _margins(ev: Evaluator, w: np.ndarray, L: np.ndarray, aL: np.ndarray, names: list[tuple[str, str]],
             L0: np.ndarray, Lend: np.ndarray | None = None,
             peaks: tuple[str, ...] = PEAK_FIGURES) -> list[BreakFigures]:
    """Figures per row from the grid (w, L, |L|); ``L0``: L at w = 0 per row. ``Lend``: a
    sampled loop's L at the grid's last point, the Nyquist frequency, where it is real: an end
    point of the Nyquist curve like w = 0 (its crossing is added from ``Lend``, not bracketed).
    ``peaks``: the peak figures to zoom in on (:func:`_peaks`)."""
    R = L.shape[0]
    with np.errstate(invalid="ignore"):
        fin = np.isfinite(aL) & (aL > 0)
        sgn = np.sign(aL - 1.0)  # sign of log|L|
    # gain crossings: sign changes of log|L|
    r_g, i_g = np.nonzero((sgn[:, :-1] != sgn[:, 1:]) & fin[:, :-1] & fin[:, 1:])
    pb = _phase_brackets(ev, w, L, aL, Lend is not None)
    wg, Lg, wp, kp_, done = _zoom_crossings(ev, w, L, r_g, i_g, pb)
    ends = [(0.0, L0)] + ([(float(w[-1]), Lend)] if Lend is not None else [])
    gm_w, gm_k, omitted = _phase_crossing_lists(pb, wp, kp_, done, R, ends)
    pm_w = [wg[r_g == r] for r in range(R)]
    pm_deg = [np.degrees(np.angle(Lg[r_g == r])) for r in range(R)]
    peak_values = _peaks(ev, w, L, peaks)
    return [_figures_for_row(names[r], gm_w[r], gm_k[r], pm_w[r], pm_deg[r], peak_values[r], omitted[r])
            for r in range(R)]


def row_margins(ev: Evaluator, w: np.ndarray, L: np.ndarray, names: list[tuple[str, str]],
                L0: np.ndarray, peaks: tuple[str, ...] = PEAK_FIGURES) -> list[BreakFigures]:
    """Figures of any continuous loop responses: rows of ``L`` on the grid ``w`` (break points named
    ``(loop, break point)``), ``L0`` at w = 0 per row; ``ev`` evaluates the rows at any frequency
    (the zooms call it). The MIMO loop-at-a-time margins use it (:mod:`.mimo_margins`). ``peaks``:
    the peak figures zoomed in on; the others (a check that reads them not) keep their grid maximum."""
    with np.errstate(invalid="ignore"):
        aL = np.abs(L)
    return _margins(ev, w, L, aL, names, L0, peaks=peaks)


def all_margins(ev: Evaluator, w, L, aL, cas: Cascade, L0, Lend=None) -> list[BreakFigures]:
    """Figures of every break point. The plant-input row is the innermost loop's controller-output
    row (L_{n-1} = -g_{n-1} H_n with H_n = 1, bit for bit): analysed once, copied.

    Parameters
    ----------
    ev
        The loop's :class:`~gaintune.verification.freqresp.Evaluator` (zooms evaluate it).
    w, L, aL
        The grid (W,), L on it (rows: break points, as ``cas.break_names``) and |L|.
    cas
        The one-member cascade.
    L0
        L at w = 0 per row.
    Lend
        A sampled loop's L at the grid's last point, the Nyquist frequency (real there); None
        for the continuous loop.
    """
    n = len(cas.loops)
    names = cas.break_names
    figs = _margins(ev, w, L[:n], aL[:n], names[:n], L0[:n], None if Lend is None else Lend[:n])
    inner = figs[n - 1]
    figs.append(replace(inner, loop=names[n][0], break_point=names[n][1],
                        crossings=[replace(c) for c in inner.crossings]))
    return figs


