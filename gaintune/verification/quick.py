"""Cheap, batched margin estimates and the requirement violation every search is constrained by.

Same loop algebra and definitions as :func:`gaintune.verification.verify` (break
points, dt/2 sampling delay, upper/lower GM, binding PM) but on a coarse log
grid (default 320 points), numpy-vectorised over the batch of gain sets:

* crossings by sign change with linear interpolation in log w;
* Ms and Mt peaks with a parabolic refinement in log w;
* closed-loop stability from the eigenvalues of the batched closed-loop state
  matrices (delay as a Padé approximant, order ``verify.pade_order`` or 6).

The estimates agree with the exact verification to a few percent on smooth
loops; use :func:`gaintune.verification.verify` for the verdict.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from gaintune.controllers.layout import GainLayout
from gaintune.lti.arrays import finite
from gaintune.lti.modes import plant_eigvals
from gaintune.lti.pade import pade_response
from gaintune.plants.noise_limit import noise_limits
from gaintune.plants.plant import LinearModel, Plant
from gaintune.spec import RequirementsSpec, TuningSpec
from gaintune.verification.analysis import analysis_dt, sampling_delay
from gaintune.verification.cascade import Cascade, build_cascade
from gaintune.verification.sampled import SampledPlant, sample_plant
from gaintune.verification.stability import observable_part, sampled_stability

__all__ = ["QuickMargins", "quick_margins", "requirement_violation", "requirement_scores", "unstable_violation",
           "noise_limit_array", "margin_terms", "sampled_grid", "UNSTABLE_VIOLATION", "FEASIBILITY_MARGIN", "MAX_TERM"]

#: Violation of an unstable closed loop, plus a grade that grows with the largest real pole.
UNSTABLE_VIOLATION = 10.0
#: The search counts a requirement as met only this far (relative) inside its limit. The
#: estimate agrees with the exact verification to ~1e-5 in Ms and a few 1e-5 in PM on the
#: standard suite, so answers the search calls feasible pass the exact check; the exact
#: settle step (gaintune.evaluation.boundary_exact) then pushes them onto the boundary itself.
FEASIBILITY_MARGIN = 5e-5
#: Cap of one requirement's relative violation.
MAX_TERM = 5.0
_BIG = 1e10
#: The sensitivity peaks :func:`quick_margins` can estimate.
PEAKS = ("ms", "mt", "mks")
_GM_CAP = 1e4  # GM beyond 80 dB counts as infinite, as in the exact verification


@dataclass
class QuickMargins:
    """Per-candidate estimates; arrays are (B, R) with R = n_loops + 1 break points
    (each loop at its controller output, then the plant input), except ``mks`` (B, n_loops)
    and ``stable``/``max_real`` (B,)."""

    gm_db: np.ndarray
    pm_deg: np.ndarray
    delay_margin: np.ndarray
    ms: np.ndarray
    mt: np.ndarray
    mks: np.ndarray  # (B, n_loops): noise sensitivity per loop (NaN for an LQ loop)
    wc: np.ndarray  # crossover of the binding PM (rad/s), 0 without a gain crossover
    stable: np.ndarray
    max_real: np.ndarray
    omega: np.ndarray
    breaks: list[tuple[str, str]]


def _grid(lin: LinearModel, T: float, n: int) -> np.ndarray:
    """Log grid from the plant alone (poles/zeros magnitudes and the delay), so that a
    candidate's estimate does not depend on the rest of its batch."""
    mags = [abs(x) for x in plant_eigvals(lin)]  # remembered per model: the search calls this per batch
    if T > 0:
        mags.append(1.0 / T)
    f = np.array([x for x in mags if np.isfinite(x) and x > 1e-12])
    if f.size == 0:
        f = np.array([1.0])
    lo, hi = f.min() / 300.0, f.max() * 300.0
    return np.logspace(np.log10(lo), np.log10(hi), n)


def sampled_grid(w: np.ndarray, sp: SampledPlant) -> np.ndarray:
    """A log grid like ``w`` (same size, same lower end or lower) ending exactly at the Nyquist frequency pi/dt."""
    wn = sp.nyquist
    lo = min(float(w[0]), wn * 1e-4)
    g = np.logspace(np.log10(lo), np.log10(wn), w.size)
    g[0], g[-1] = lo, wn
    return g


def _parabolic_peak(V: np.ndarray) -> np.ndarray:
    """Max over the last axis with a 3-point parabola (in grid index) around the argmax.

    NaN and +inf count as ``_BIG`` (``V`` is a magnitude: never negative)."""
    V = np.where(np.isfinite(V), V, _BIG)
    shape, W = V.shape[:-1], V.shape[-1]
    V = V.reshape(-1, W)  # rows indexed directly: take_along_axis costs more than the arithmetic here
    rows = np.arange(V.shape[0])
    j = np.argmax(V, axis=-1)
    jc = np.minimum(np.maximum(j, 1), W - 2)  # np.clip's argument handling costs more than this
    a, b, c = V[rows, jc - 1], V[rows, jc], V[rows, jc + 1]
    den = a - 2 * b + c
    with np.errstate(divide="ignore", invalid="ignore"):
        peak = b - 0.125 * (a - c) ** 2 / den
    ok = (den < 0) & np.isfinite(peak) & (j == jc)
    vmax = V[rows, j]
    return np.where(ok, np.maximum(peak, vmax), vmax).reshape(shape)


def _delay_response(s: np.ndarray, T: float, order: int | None) -> np.ndarray:
    """The delay factor at ``s``: e^{-sT}, its Padé approximant of ``order``, or 1 without delay."""
    if T > 0 and order is None:
        return np.exp(-s * T)
    if T > 0 and order is not None:
        return pade_response(s, T, order)
    return np.ones_like(s)


def _responses(cas: Cascade, lin: LinearModel, s: np.ndarray, dly: np.ndarray, sp: SampledPlant | None,
               peaks: tuple[str, ...]) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(L (R, B, W), L(0) (R, B), Mks (R, B)) of the controller-output rows; ``s`` ends with 0."""
    R, B = len(cas.loops), cas.batch
    if "mks" in peaks:
        Lall, Nall = cas.noise_responses(s, lin, dly, sampled=sp)  # (R+1, B, W+1), (R, B, W+1)
        mks = _parabolic_peak(np.abs(Nall[..., :-1]))
        mks[[lp.kind != "pid" for lp in cas.loops]] = np.nan
    else:
        Lall = cas.loop_responses(s, lin, dly, sampled=sp)
        mks = np.full((R, B), np.nan)
    L, L0 = Lall[:R, :, :-1], Lall[:R, :, -1]
    if sp is not None:
        L[..., -1] = L[..., -1].real  # real at z = -1: an end point, like w = 0
    return L, L0, mks


def _gain_crossings(L: np.ndarray, aL: np.ndarray, w: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(binding PM, its crossover (0 without one), delay margin), each (R, B), by linear
    interpolation in log w at the sign changes of log|L|."""
    R, B = L.shape[:2]
    lw = np.log(w)
    above = aL > 1.0
    r, b, i = np.nonzero(above[..., :-1] != above[..., 1:])
    f0, f1 = np.log(aL[r, b, i]), np.log(aL[r, b, i + 1])
    a = np.clip(f0 / (f0 - f1), 0.0, 1.0)
    wc = np.exp(lw[i] + a * (lw[i + 1] - lw[i]))
    z0 = L[r, b, i]
    ph = np.degrees(np.angle(z0) + a * np.angle(L[r, b, i + 1] / z0))
    pm = 180.0 - np.mod(-ph, 360.0)
    dm = np.radians(np.mod(pm, 360.0)) / wc
    ok = np.isfinite(pm) & np.isfinite(wc)
    r, b, pm, dm, wc = r[ok], b[ok], pm[ok], dm[ok], wc[ok]
    pm_b = np.full((R, B), np.inf)
    wc_b = np.zeros((R, B))  # the binding PM's crossover; 0 without a gain crossover
    dm_b = np.full((R, B), np.inf)
    # binding PM: the one of smallest |PM| (sort descending by |PM| so the last write wins)
    o = np.argsort(-np.abs(pm))
    pm_b[r[o], b[o]] = pm[o]
    wc_b[r[o], b[o]] = wc[o]
    np.minimum.at(dm_b, (r, b), dm)
    return pm_b, wc_b, dm_b


def _gain_margin(L: np.ndarray, aL: np.ndarray, L0: np.ndarray, sampled: bool) -> np.ndarray:
    """Binding |GM| in dB (R, B) from the phase crossings (sign changes of Im L with Re L < 0),
    w = 0 and, for the sampled loop, the Nyquist end point."""
    R, B = L.shape[:2]
    im, re = L.imag, L.real
    pos = im > 0
    brk = (pos[..., :-1] != pos[..., 1:]) & ((re[..., :-1] < 0) | (re[..., 1:] < 0))
    if sampled:
        brk[..., -1] = False  # the Nyquist end point is added below
    r, b, i = np.nonzero(brk)
    i0, i1 = im[r, b, i], im[r, b, i + 1]
    t = np.clip(i0 / (i0 - i1), 0.0, 1.0)
    mag = np.exp(np.log(aL[r, b, i]) + t * (np.log(aL[r, b, i + 1]) - np.log(aL[r, b, i])))
    keep = (mag > 1.0 / _GM_CAP) & (mag < _GM_CAP) & (re[r, b, i] + t * (re[r, b, i + 1] - re[r, b, i]) < 0)
    gm_b = np.full((R, B), np.inf)
    np.minimum.at(gm_b, (r[keep], b[keep]), np.abs(20.0 * np.log10(mag[keep])))
    dc_cross = np.isfinite(L0) & (L0.real < 0) & (np.abs(L0.imag) < 1e-9 * np.abs(L0))
    dc_cross &= (np.abs(L0) > 1.0 / _GM_CAP) & (np.abs(L0) < _GM_CAP)
    gm_b = np.minimum(gm_b, np.where(dc_cross, np.abs(20.0 * np.log10(np.abs(L0))), np.inf))
    if sampled:
        Ln = L[..., -1].real
        ny_cross = np.isfinite(Ln) & (Ln < 0) & (-Ln > 1.0 / _GM_CAP) & (-Ln < _GM_CAP)
        gm_b = np.minimum(gm_b, np.where(ny_cross, np.abs(20.0 * np.log10(np.abs(Ln))), np.inf))
    return gm_b


def _continuous_stability(cas: Cascade, lin: LinearModel, w: np.ndarray, T: float,
                          order: int | None) -> tuple[np.ndarray, np.ndarray]:
    """Batched closed-loop stability of the continuous loop: (stable (B,), max real pole (B,)),
    from the eigenvalues of the closed-loop state matrices (delay as Padé)."""
    w_char = w[-1] / 300.0  # fastest characteristic frequency of the loop (see _grid)
    pade = (T, order or (6 if T * w_char > 0.05 else 2)) if T > 0 else None
    lin_cl = lin
    extra_unstable = False
    if cas.measured is not None:  # modes no loop measures are not moved by feedback
        lin_cl, unobs = observable_part(lin, cas.measured)
        if unobs.size:
            extra_unstable = bool(np.any(unobs.real > 1e-9 * max(1.0, float(np.max(np.abs(unobs))))))
    Acl = cas.closed_loop_A(lin_cl, pade)
    with np.errstate(all="ignore"):
        finite = np.all(np.isfinite(Acl), axis=(1, 2))
        Acl = np.where(finite[:, None, None], Acl, 0.0)
        ev = np.linalg.eigvals(Acl) if Acl.shape[1] else np.zeros((cas.batch, 0))
    max_re = np.where(finite, ev.real.max(axis=-1) if ev.shape[-1] else -np.inf, np.inf)
    scale = np.maximum(1.0, np.abs(ev).max(axis=-1) if ev.shape[-1] else 1.0)
    stable = (max_re < -1e-12 * scale) & (not extra_unstable)
    return stable, max_re


#: The plant side of recent estimates (grid, s and delay factor), by model object: see :func:`_frequencies`.
_FREQ_CACHE: dict[tuple, tuple[LinearModel, SampledPlant | None, tuple[np.ndarray, np.ndarray, np.ndarray]]] = {}


def _frequencies(lin: LinearModel, T: float, n: int, sp: SampledPlant | None,
                 order: int | None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(grid w, s = j w then 0, the delay factor at s): the plant side of an estimate, gain-independent.

    Remembered per model object (and sampled plant, delay, size and Pade order) as :func:`sample_plant` is:
    a boundary move estimates the same plant ~5 times per answer. The arrays are read-only (shared).
    """
    key = (id(lin), id(sp), float(T), int(n), order)
    hit = _FREQ_CACHE.get(key)
    if hit is not None and hit[0] is lin and hit[1] is sp:
        return hit[2]
    w = _grid(lin, T, n)
    if sp is not None:
        w = sampled_grid(w, sp)
    s = np.concatenate([1j * w, [0.0]])
    out = (w, s, _delay_response(s, T, order))
    for a in out:
        a.setflags(write=False)
    if len(_FREQ_CACHE) > 512:
        _FREQ_CACHE.clear()
    _FREQ_CACHE[key] = (lin, sp, out)
    return out


def _with_plant_input(x: np.ndarray) -> np.ndarray:
    """(R, B) -> (B, R + 1): the innermost loop's row repeated for the plant input, last.

    The innermost loop's output is the plant input u, so the loop broken there and at the plant
    input is one loop: its row is analysed once and reported for both break points."""
    out = np.empty((x.shape[0] + 1, *x.shape[1:]), dtype=x.dtype)  # concatenate + moveaxis, without their
    out[:-1] = x  # argument handling (called 6 times per estimate): the same values in the same layout
    out[-1] = x[-1]
    return out.transpose(*range(1, out.ndim), 0)


def _setup(spec: TuningSpec, plant: Plant, layout: GainLayout, full: np.ndarray, lin: LinearModel, n_freq: int
           ) -> tuple[Cascade, SampledPlant | None, float, np.ndarray, np.ndarray, np.ndarray]:
    """(cascade, sampled plant or None, total delay T, grid w, s, delay factor) of an estimate."""
    vs = spec.verify
    dt = analysis_dt(spec)
    sp = sample_plant(lin, dt, vs.compute_delay, plant.kind == "nonlinear") if vs.sampled else None
    T = sp.total_delay if sp is not None else lin.delay + sampling_delay(spec) + vs.compute_delay * dt
    cas = build_cascade(spec, layout, full, lin)
    w, s, dly = _frequencies(lin, T, n_freq, sp, vs.pade_order)
    return cas, sp, T, w, s, dly


def _stability(cas: Cascade, lin: LinearModel, w: np.ndarray, T: float, sp: SampledPlant | None,
               order: int | None) -> tuple[np.ndarray, np.ndarray]:
    """(stable (B,), max real pole (B,)) of the closed loop the estimate judges: the sampled loop's |z| < 1,
    or the continuous loop's eigenvalues."""
    if sp is not None:
        return sampled_stability(cas, lin, sp, float(w[0]))
    return _continuous_stability(cas, lin, w, T, order)


def _unstable_grade(max_real: np.ndarray, w: np.ndarray) -> np.ndarray:
    """The violation of an unstable loop: ``UNSTABLE_VIOLATION + log1p(max Re pole / w_ref)``, the log capped at 100.

    A negative max Re pole counts as 0 (a loop unstable through a mode no loop measures, whose measured part
    is stable: the grade is UNSTABLE_VIOLATION itself); NaN and +inf as 1e300."""
    w_ref = float(np.sqrt(w[0] * w[-1]))
    with np.errstate(all="ignore"):
        grade = np.log1p(np.minimum(np.maximum(finite(max_real, 1e300, 1e300, 0.0), 0.0), 1e300) / w_ref)
    return UNSTABLE_VIOLATION + np.minimum(grade, 100.0)


def unstable_violation(spec: TuningSpec, plant: Plant, layout: GainLayout, full_gains: np.ndarray,
                       lin: LinearModel | None = None, n_freq: int = 320) -> np.ndarray:
    """(B,): 0 where the estimate's closed loop is stable, else the violation :func:`requirement_scores` gives
    an unstable loop (>= UNSTABLE_VIOLATION).

    For a caller that knows the margins hold (their violation is 0): the full violation is then this, at
    the cost of the stability check alone.
    """
    full = np.atleast_2d(np.asarray(full_gains, dtype=float))
    lin = lin if lin is not None else plant.linearize()
    cas, sp, T, w, _, _ = _setup(spec, plant, layout, full, lin, n_freq)
    stable, max_re = _stability(cas, lin, w, T, sp, spec.verify.pade_order)
    return np.where(stable, 0.0, _unstable_grade(max_re, w))


def quick_margins(
    spec: TuningSpec,
    plant: Plant,
    layout: GainLayout,
    full_gains: np.ndarray,
    lin: LinearModel | None = None,
    n_freq: int = 320,
    stability: bool = True,
    peaks: tuple[str, ...] = PEAKS,
    crossings: bool = True,
) -> QuickMargins:
    """Batched margin estimates for full gain vectors ``full_gains`` (B, n_gains).

    The loop is the one :func:`gaintune.verification.verify` analyses: with ``verify.sampled`` the
    sampled loop on a grid ending at the Nyquist frequency (an end point of the Nyquist curve,
    like w = 0), else the continuous loop with dt/2 (and the computation delay) of extra delay.

    ``peaks``: which of the peaks ``"ms"``, ``"mt"``, ``"mks"`` to estimate (the others are NaN);
    a caller that needs only some of them saves their cost (``mks`` needs the noise responses).
    ``stability=False``: skip the closed-loop stability check (every loop counts as stable).
    ``crossings=False``: skip the gain and phase crossings (GM, PM, delay margin and crossover are NaN),
    for a caller whose requirements name none of them.
    """
    full = np.atleast_2d(np.asarray(full_gains, dtype=float))
    lin = lin if lin is not None else plant.linearize()
    cas, sp, T, w, s, dly = _setup(spec, plant, layout, full, lin, n_freq)
    order = spec.verify.pade_order
    R, B = len(cas.loops), full.shape[0]
    with np.errstate(all="ignore"):
        L, L0, mks = _responses(cas, lin, s, dly, sp, peaks)
        aL = np.abs(L)
        a1 = np.abs(1.0 + L)
        ms = _parabolic_peak(1.0 / a1) if "ms" in peaks else np.full((R, B), np.nan)
        mt = _parabolic_peak(aL / a1) if "mt" in peaks else np.full((R, B), np.nan)
        if crossings:
            pm_b, wc_b, dm_b = _gain_crossings(L, aL, w)
            gm_b = _gain_margin(L, aL, L0, sp is not None)

    if not stability:  # the caller checks stability elsewhere (gaintune.evaluation.boundary_estimate's final check)
        stable, max_re = np.ones(B, dtype=bool), np.full(B, -np.inf)
    else:
        stable, max_re = _stability(cas, lin, w, T, sp, order)
    tr = _with_plant_input
    if crossings:
        gm, pm, dm, wc = tr(gm_b), tr(pm_b), tr(dm_b), tr(wc_b)
    else:  # not asked for: NaN, without transposing four NaN arrays
        gm, pm, dm, wc = (np.full((B, R + 1), np.nan) for _ in range(4))
    return QuickMargins(gm, pm, dm, tr(ms), tr(mt), np.moveaxis(mks, 0, -1), wc, stable, max_re, w, cas.break_names)


def noise_limit_array(spec: TuningSpec, plant: Plant) -> np.ndarray:
    """The spec's per-loop Mks limits on the plant's nominal model, NaN where a loop has none."""
    limits = noise_limits(spec, plant.linearize())
    return np.array([np.nan if n.limit is None else n.limit for n in limits], dtype=float)


def requirement_violation(
    spec: TuningSpec,
    plant: Plant,
    layout: GainLayout,
    full_gains: np.ndarray,
    lin: LinearModel | None = None,
    noise_limit: np.ndarray | None = None,
) -> np.ndarray:
    """Non-negative violation (B,): 0 when every requirement holds at every break point.

    A stable loop scores the sum over requirements of the worst relative shortfall
    (each capped at :data:`MAX_TERM`, so < 10 in all). An unstable one scores
    ``UNSTABLE_VIOLATION + log1p(max Re pole / w_ref)`` (>= 10): graded, so a search
    far from any stabilising gains still sees which way stability lies.

    Relative shortfalls: GM ``(gm_min - gm)/gm_min`` (dB), PM ``(pm_min - pm)/pm_min``,
    delay margin ``(dm_min - dm)/dm_min``, Ms ``(ms - ms_max)/ms_max``, Mt ``(mt - mt_max)/mt_max``,
    Mks per loop ``(mks_i - limit_i)/limit_i``, crossover ``(wc_min - wc)/wc_min`` and ``(wc - wc_max)/wc_max``.

    ``noise_limit``: the per-loop Mks limits (n_loops,), NaN where none; default: resolved from
    the spec on the plant's nominal model (:func:`gaintune.plants.noise_limit.noise_limits`;
    a randomised ``lin`` does not move the limit).
    """
    return requirement_scores(spec, plant, layout, full_gains, lin, noise_limit)[0]


def margin_terms(req: RequirementsSpec, q: QuickMargins) -> list[np.ndarray]:
    """Signed relative shortfalls of the margin requirements, one (B, R) array per requirement set.

    ``req`` is a RequirementsSpec, ``q`` the quick margins (one column per break point): positive where a
    break point misses the limit, by that fraction of it. The search's violation and the per-loop repair
    (:mod:`gaintune.evaluation.boundary_loops`) both grade from these.
    """
    terms = []
    if req.gm_min_db is not None:
        terms.append((req.gm_min_db - q.gm_db) / max(abs(req.gm_min_db), 1e-9))
    if req.pm_min_deg is not None:
        terms.append((req.pm_min_deg - np.abs(q.pm_deg)) / max(abs(req.pm_min_deg), 1e-9))  # judged_pm
    if req.dm_min is not None:
        terms.append((req.dm_min - q.delay_margin) / max(req.dm_min, 1e-12))
    if req.ms_max is not None:
        terms.append((q.ms - req.ms_max) / req.ms_max)
    if req.mt_max is not None:
        terms.append((q.mt - req.mt_max) / req.mt_max)
    if req.wc_min is not None:
        terms.append((req.wc_min - q.wc) / req.wc_min)
    if req.wc_max is not None:
        terms.append((q.wc - req.wc_max) / req.wc_max)
    return terms


def requirement_scores(
    spec: TuningSpec,
    plant: Plant,
    layout: GainLayout,
    full_gains: np.ndarray,
    lin: LinearModel | None = None,
    noise_limit: np.ndarray | None = None,
    stability: bool = True,
) -> tuple[np.ndarray, np.ndarray]:
    """(violation, shortfall), each (B,): the violation of :func:`requirement_violation`, and the signed
    tightest relative shortfall (the largest term, FEASIBILITY_MARGIN included; <= 0 exactly when the
    violation is 0; the unstable grade for an unstable loop). The shortfall is what a root finder
    along a gain direction needs (:mod:`gaintune.evaluation.boundary_estimate`). ``stability=False`` skips the
    closed-loop stability check (every loop counts as stable): only for a caller that checks it afterwards."""
    if noise_limit is None:
        noise_limit = noise_limit_array(spec, plant)
    req = spec.requirements
    has_mks = np.isfinite(noise_limit)
    peaks = tuple(name for name, needed in (("ms", req.ms_max is not None), ("mt", req.mt_max is not None),
                                             ("mks", bool(has_mks.any()))) if needed)
    crossings = any(x is not None for x in (req.gm_min_db, req.pm_min_deg, req.dm_min, req.wc_min, req.wc_max))
    q = quick_margins(spec, plant, layout, full_gains, lin, stability=stability, peaks=peaks, crossings=crossings)
    B = q.stable.shape[0]
    out = np.zeros(B)
    short = np.full(B, -np.inf)
    with np.errstate(all="ignore"):
        terms = margin_terms(req, q)
        if has_mks.any():
            terms.append((q.mks[:, has_mks] - noise_limit[has_mks]) / noise_limit[has_mks])
        for t in terms:
            t = finite(t, MAX_TERM, MAX_TERM, 0.0).max(axis=-1)
            t = t + FEASIBILITY_MARGIN  # met means at least FEASIBILITY_MARGIN inside the limit
            out += np.where(t <= 0.0, 0.0, np.minimum(t, MAX_TERM))
            short = np.maximum(short, np.minimum(t, MAX_TERM))
    if q.stable.all():  # the grade of no row (the root find's margins-only estimates)
        return out, short
    unstable = _unstable_grade(q.max_real, q.omega)
    return np.where(q.stable, out, unstable), np.where(q.stable, short, unstable)
