"""``verify(spec, gains) -> VerificationReport``: stability, margins, robustness, nonlinear check, verdict."""

from __future__ import annotations

import math
import time
from typing import Any

import numpy as np

from gaintune.controllers.layout import GainLayout
from gaintune.errors import GainError
from gaintune.plants.plant import Plant, build_plant
from gaintune.spec import TuningSpec
from gaintune.verify.context import spec_context
from gaintune.verify.loops import build_cascade, sampling_delay
from gaintune.verify.margins import Analysis, BreakFigures, DelayModel, analyse
from gaintune.verify.nonlinear import nonlinear_check
from gaintune.verify.report import (
    CrossingModel,
    LoopFigures,
    PadeCheck,
    RequirementLine,
    RobustReport,
    StabilityReport,
    VerificationReport,
    WorstCase,
)
from gaintune.verify.robust import DELAY_KEY, robust_samples

__all__ = ["verify", "coerce_gains", "REQUIREMENTS"]

#: requirement field -> (figure attribute, kind) ; kind "min": value >= limit, "max": value <= limit.
REQUIREMENTS: dict[str, tuple[str, str]] = {
    "gm_min_db": ("gm_db", "min"),
    "pm_min_deg": ("pm_deg", "min"),
    "dm_min": ("delay_margin", "min"),
    "ms_max": ("ms", "max"),
    "mt_max": ("mt", "max"),
}

#: The analysis band ends at this multiple of the controller's Nyquist frequency pi/dt (largest
#: scenario dt) when the frequencies above are proven harmless (:func:`analyse`, ``band``).
BAND_NYQUIST = 10.0

#: Padé adequacy tolerances (vs the exact e^{-jwT} figures).
PADE_TOL = {"pm_deg": 1.0, "gm_db": 0.5, "ms_rel": 0.02}


def coerce_gains(layout: GainLayout, gains: Any) -> np.ndarray:
    """Nested dict or vector (full or tuned-only) -> validated full gain vector. Raises GainError."""
    if isinstance(gains, dict):
        return layout.from_dict(gains)
    try:
        arr = np.asarray(gains, dtype=float)
    except (TypeError, ValueError):
        raise GainError("gains", "must be a mapping {loop: {gain: value}} or a vector of numbers") from None
    if arr.ndim != 1:
        raise GainError("gains", f"a gain vector must be 1-D, got shape {arr.shape}")
    if arr.size == layout.n_gains:
        full = arr
    elif arr.size == layout.n_tuned:
        full = layout.full(arr)
    else:
        names = [f"{s.loop_name}.{s.name}" for s in layout.slots]
        raise GainError("gains", f"expected {layout.n_gains} gains ({', '.join(names)}), got {arr.size}")
    return layout.from_dict(layout.to_dict(full))


#: Most phase crossings listed per break point (those of smallest |GM|; delays give infinitely many).
MAX_PHASE_CROSSINGS = 20


def _to_model(f: BreakFigures) -> LoopFigures:
    phase = sorted((c for c in f.crossings if c.kind == "phase"), key=lambda c: (not c.binding, abs(c.value)))
    kept = [c for c in f.crossings if c.kind == "gain"] + phase[:MAX_PHASE_CROSSINGS]
    kept.sort(key=lambda c: c.omega)
    cr = [CrossingModel(kind=c.kind, omega=c.omega, value=c.value, delay_margin=c.delay_margin, binding=c.binding) for c in kept]
    omitted = len(f.crossings) - len(kept) + f.phase_omitted
    return LoopFigures(
        loop=f.loop, break_point=f.break_point, gm_db=f.gm_db, gm_upper_db=f.gm_upper_db, gm_lower_db=f.gm_lower_db,
        gm_freq=f.gm_freq, pm_deg=f.pm_deg, pm_freq=f.pm_freq, delay_margin=f.delay_margin, ms=f.ms, ms_freq=f.ms_freq,
        mt=f.mt, mt_freq=f.mt_freq, disk_alpha=f.disk_alpha, disk_gm_db=f.disk_gm_db, disk_pm_deg=f.disk_pm_deg,
        disk_freq=f.disk_freq, gain_crossovers=[c.omega for c in f.crossings if c.kind == "gain"],
        phase_crossovers=[c.omega for c in kept if c.kind == "phase"], crossings=cr,
        crossings_omitted=omitted,
    )


def _stability_model(a: Analysis) -> StabilityReport:
    st = a.stability
    poles = sorted(((float(p.real), float(p.imag)) for p in st.poles), key=lambda z: -z[0])
    return StabilityReport(
        stable=st.stable, method=st.method, rhp_count=st.rhp_count, nyquist_rhp=st.nyquist_rhp, poles=poles,
        poles_method=st.poles_method, max_real_pole=st.max_real_pole if math.isfinite(st.max_real_pole) else -1e300,
        notes=st.notes,
    )


def _pade_check(order: int, pade: Analysis, exact: Analysis) -> PadeCheck:
    def d(a, b):
        if math.isinf(a) and math.isinf(b):
            return 0.0
        return abs(a - b)

    pm = max(d(p.pm_deg, e.pm_deg) for p, e in zip(pade.figures, exact.figures))
    gm = max(d(p.gm_db, e.gm_db) for p, e in zip(pade.figures, exact.figures))
    ms = max(abs(p.ms - e.ms) / max(e.ms, 1e-12) for p, e in zip(pade.figures, exact.figures))
    same = pade.stability.stable == exact.stability.stable
    ok = same and pm <= PADE_TOL["pm_deg"] and gm <= PADE_TOL["gm_db"] and ms <= PADE_TOL["ms_rel"]
    return PadeCheck(order=order, adequate=ok, max_pm_err_deg=pm, max_gm_err_db=gm, max_ms_rel_err=ms, same_stability=same)


def analysis_band(spec: TuningSpec) -> float:
    """Upper end (rad/s) of the analysis band: BAND_NYQUIST x the Nyquist frequency pi/dt of the largest dt."""
    return BAND_NYQUIST * math.pi / max(sc.dt for sc in spec.scenarios)


def _robust(spec, plant, cas, lin_nom, t_s, nominal: Analysis) -> tuple[RobustReport, list[WorstCase]]:
    samples, n_corners, n_mc = robust_samples(spec)
    keys = ("gm_db", "pm_deg", "delay_margin", "ms", "mt", "disk_alpha")
    worst_kind = {"gm_db": min, "pm_deg": min, "delay_margin": min, "ms": max, "mt": max, "disk_alpha": min}
    R = len(nominal.figures)
    worst = [{k: (getattr(nominal.figures[r], k), {"nominal": 1.0}) for k in keys} for r in range(R)]
    unstable: list[dict[str, float]] = []
    for smp in samples:
        params = {k: v for k, v in smp.items() if k != DELAY_KEY}
        lin = plant.linearize(params)
        T = (smp[DELAY_KEY] if DELAY_KEY in smp else lin.delay) + t_s
        a = analyse(cas, lin, DelayModel(T, spec.verify.pade_order), spec.verify.n_freq, analysis_band(spec))
        if not a.stability.stable:
            unstable.append(dict(smp))
        for r, f in enumerate(a.figures):
            for k in keys:
                v = getattr(f, k)
                cur = worst[r][k][0]
                if worst_kind[k](v, cur) != cur and v != cur:
                    worst[r][k] = (v, dict(smp))
    wc = []
    for r, f in enumerate(nominal.figures):
        w = worst[r]
        where = {k: {("delay" if kk == DELAY_KEY else kk): vv for kk, vv in w[k][1].items()} for k in keys}
        wc.append(WorstCase(loop=f.loop, break_point=f.break_point, gm_db=w["gm_db"][0], pm_deg=w["pm_deg"][0],
                            delay_margin=w["delay_margin"][0], ms=w["ms"][0], mt=w["mt"][0],
                            disk_alpha=w["disk_alpha"][0], where=where))
    rep = RobustReport(
        n_samples=len(samples), n_corners=n_corners, n_monte_carlo=n_mc, seed=spec.search.seed,
        n_unstable=len(unstable), unstable_samples=[{("delay" if k == DELAY_KEY else k): v for k, v in u.items()} for u in unstable[:20]],
        worst=wc,
    )
    return rep, wc


def _requirement_lines(spec: TuningSpec, loops: list[LoopFigures], worst: list[WorstCase] | None) -> list[RequirementLine]:
    req = spec.requirements
    lines = []
    for name, (attr, kind) in REQUIREMENTS.items():
        limit = getattr(req, name)
        if limit is None:
            continue
        cands = [(getattr(f, attr), f.loop, f.break_point, "nominal") for f in loops]
        if worst:
            cands += [(getattr(w, attr), w.loop, w.break_point, "worst") for w in worst]
        best = None
        for value, loop, brk, case in cands:
            margin = (value - limit) if kind == "min" else (limit - value)
            if math.isnan(margin):
                margin = -math.inf
            # ties (within rounding: e.g. a single loop's two identical break points) keep the first
            tol = 1e-12 * max(1.0, abs(best[0])) if best is not None and math.isfinite(best[0]) else 0.0
            if best is None or margin < best[0] - tol:
                best = (margin, value, loop, brk, case)
        margin, value, loop, brk, case = best  # type: ignore[misc]
        lines.append(RequirementLine(requirement=name, figure=attr, limit=float(limit), value=float(value),
                                     margin=float(margin), passed=margin >= 0, loop=loop, break_point=brk, case=case))
    return lines


def verify(
    spec: TuningSpec,
    gains: Any,
    *,
    robust: bool | None = None,
    nonlinear: bool = True,
    plant: Plant | None = None,
    layout: GainLayout | None = None,
    cache: bool = True,
    spec_hash: str | None = None,
) -> VerificationReport:
    """Verify frozen gains against the spec's requirements.

    Parameters
    ----------
    spec
        The tuning problem.
    gains
        ``{loop: {gain: value}}``, or a vector of all gains (layout order) or of the tuned gains only.
    robust
        Evaluate the randomisation set (box corners + ``verify.robust_samples`` draws).
        Default: when the spec randomises plant parameters or the delay.
    nonlinear
        Run the nonlinear simulation check (skipped with a note if :mod:`gaintune.sim` is missing).
    plant, layout
        Pre-built objects to reuse (built from ``spec`` when omitted).
    cache
        Reuse the per-spec objects (plant, layout, linearisation, simulator) of earlier calls
        on the same spec (keyed by ``spec.content_hash()``; see :mod:`gaintune.verify.context`).
        A cached entry takes precedence over ``plant``/``layout``.
    spec_hash
        ``spec.content_hash()`` when the caller has computed it already (saves hashing the spec again).

    Raises
    ------
    GainError
        For NaN, non-positive, missing/unknown gains or a wrong count.
    """
    t0 = time.perf_counter()
    ctx = spec_context(spec, plant, layout, spec_hash=spec_hash) if cache else None
    if ctx is not None:
        plant, layout, lin = ctx.plant, ctx.layout, ctx.lin
    else:
        plant = plant or build_plant(spec.plant)
        layout = layout or GainLayout(spec, plant.states)
        lin = plant.linearize()
    full = coerce_gains(layout, gains)
    t_s = sampling_delay(spec)
    delay = DelayModel(lin.delay + t_s, spec.verify.pade_order)
    cas = build_cascade(spec, layout, full[None, :], lin)
    band = analysis_band(spec)
    nom = analyse(cas, lin, delay, spec.verify.n_freq, band)
    notes: list[str] = []
    reasons: list[str] = []
    pade = None
    if delay.pade_order is not None and delay.T > 0:
        exact = analyse(cas, lin, DelayModel(delay.T, None), spec.verify.n_freq, band)
        pade = _pade_check(delay.pade_order, nom, exact)
        if not pade.adequate:
            reasons.append(
                f"Padé order {pade.order} is not adequate (PM error {pade.max_pm_err_deg:.2f} deg, GM error "
                f"{pade.max_gm_err_db:.2f} dB, Ms error {100 * pade.max_ms_rel_err:.1f} %); raise verify.pade_order or set it to null (exact delay)"
            )
    loops = [_to_model(f) for f in nom.figures]
    stab = _stability_model(nom)
    if not stab.stable:
        reasons.append(f"closed loop unstable: {stab.rhp_count} pole(s) with Re >= 0 ({stab.method})")
    rob = None
    worst = None
    if robust is None:
        robust = bool(spec.randomize.params or spec.randomize.delay)
    if robust:
        rob, worst = _robust(spec, plant, cas, lin, t_s, nom)
        if rob.n_samples == 0:
            notes.append("robust check requested but the spec randomises neither plant parameters nor the delay")
        if rob.n_unstable:
            reasons.append(f"robust: {rob.n_unstable} of {rob.n_samples} sampled plants give an unstable closed loop")
    nl = None
    if nonlinear:
        nl = nonlinear_check(spec, plant, layout, full, sim=ctx.simulator(spec) if ctx is not None else None)
        if nl.ran and not nl.passed:
            reasons.append(f"nonlinear check failed: {nl.note}")
        elif not nl.ran:
            notes.append(f"nonlinear check not run: {nl.note}")
    req = _requirement_lines(spec, loops, worst)
    failing = sorted((q for q in req if not q.passed), key=lambda q: q.margin / max(abs(q.limit), 1e-12))
    for q in failing:
        reasons.append(
            f"{q.requirement}: {q.figure} = {q.value:.4g} vs limit {q.limit:.4g} (margin {q.margin:+.4g}) "
            f"at {q.loop}/{q.break_point} ({q.case})"
        )
    if not stab.stable and req:
        # requirement figures of an unstable loop are not meaningful: list the instability first
        pass
    for n in stab.notes:
        notes.append(n)
    if plant.kind == "nonlinear":
        notes.append("nonlinear plant: margins are for the casadi linearisation at the operating point")
    op = {f"x0.{s}": float(v) for s, v in zip(lin.states, lin.x0)}
    op["u0"] = float(lin.u0)
    verdict = "pass" if not reasons else "fail"
    return VerificationReport(
        spec_name=spec.name, spec_hash=ctx.spec_hash if ctx is not None else (spec_hash or spec.content_hash()),
        gains=layout.to_dict(full), verdict=verdict,
        reasons=reasons, delay=float(lin.delay), sampling_delay=t_s,
        delay_method="none" if delay.T <= 0 else ("pade" if delay.pade_order else "exact"), pade=pade,
        operating_point=op, stability=stab, analysis_band=nom.omega_range, loops=loops, robust=rob, nonlinear=nl, requirements=req, notes=notes,
        elapsed_s=time.perf_counter() - t0,
    )
