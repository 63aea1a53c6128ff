"""The analysis results as report models: loop figures, the stability summary, the Padé check."""

from __future__ import annotations

import math
from collections.abc import Callable

from gaintune.verification.analysis import Analysis
from gaintune.verification.margins import BreakFigures
from gaintune.verification.report import CrossingModel, LoopFigures, PadeCheck, StabilityReport

__all__ = ["gm_binding", "delay_samples", "loop_figures", "stability_model", "pade_check", "MAX_PHASE_CROSSINGS",
           "PADE_TOL"]

#: Most phase crossings listed per break point (those of smallest |GM|; delays give infinitely many).
MAX_PHASE_CROSSINGS = 20

#: Padé adequacy tolerances (vs the exact e^{-jwT} figures).
PADE_TOL = {"pm_deg": 1.0, "gm_db": 0.5, "ms_rel": 0.02}


def gm_binding(f: BreakFigures) -> str:
    """Which gain margin binds: "increase" (upper), "reduction" (lower) or "none" (both infinite)."""
    if math.isinf(f.gm_upper_db) and math.isinf(f.gm_lower_db):
        return "none"
    return "increase" if f.gm_upper_db <= f.gm_lower_db else "reduction"


def delay_samples(seconds: float, dt: float | None) -> float | None:
    """A delay margin in samples of ``dt`` (None without a sample time)."""
    return None if not dt else seconds / dt


def loop_figures(f: BreakFigures, dt: float | None = None) -> LoopFigures:
    """One break point's figures as the report's :class:`LoopFigures`.

    Every gain crossing is listed, but at most :data:`MAX_PHASE_CROSSINGS` phase crossings
    (the binding one first, then by smallest |GM|); the rest are counted in ``crossings_omitted``.
    """
    phase = sorted((c for c in f.crossings if c.kind == "phase"), key=lambda c: (not c.binding, abs(c.value)))
    kept = [c for c in f.crossings if c.kind == "gain"] + phase[:MAX_PHASE_CROSSINGS]
    kept.sort(key=lambda c: c.omega)
    cr = [CrossingModel(kind=c.kind, omega=c.omega, value=c.value, delay_margin=c.delay_margin, binding=c.binding)
          for c in kept]
    omitted = len(f.crossings) - len(kept) + f.phase_omitted
    return LoopFigures(
        loop=f.loop, break_point=f.break_point, gm_db=f.gm_db, gm_upper_db=f.gm_upper_db, gm_lower_db=f.gm_lower_db,
        gm_binding=gm_binding(f), gm_freq=f.gm_freq, pm_deg=f.pm_deg, pm_freq=f.pm_freq, delay_margin=f.delay_margin,
        delay_margin_samples=delay_samples(f.delay_margin, dt), ms=f.ms, ms_freq=f.ms_freq,
        mt=f.mt, mt_freq=f.mt_freq, disk_alpha=f.disk_alpha, disk_gm_db=f.disk_gm_db, disk_pm_deg=f.disk_pm_deg,
        disk_freq=f.disk_freq, gain_crossovers=[c.omega for c in f.crossings if c.kind == "gain"],
        phase_crossovers=[c.omega for c in kept if c.kind == "phase"], crossings=cr,
        crossings_omitted=omitted,
    )


def _finite_or_big(x: float) -> float:
    """+-inf as +-1e300 (no poles at all: -inf); NaN (not computed) stays NaN."""
    return x if not math.isinf(x) else math.copysign(1e300, x)


def stability_model(a: Analysis) -> StabilityReport:
    """The closed-loop stability of an analysis as the report's :class:`StabilityReport` (poles sorted)."""
    st = a.stability
    # largest real part first (s-plane), largest modulus first (z-plane: the sampled loop)
    key: Callable[[tuple[float, float]], float] = (
        (lambda z: -math.hypot(*z)) if st.domain == "z" else (lambda z: -z[0]))
    poles = sorted(((float(p.real), float(p.imag)) for p in st.poles), key=key)
    return StabilityReport(
        stable=st.stable, method=st.method, rhp_count=st.rhp_count, nyquist_rhp=st.nyquist_rhp, poles=poles,
        poles_method=st.poles_method,
        max_real_pole=_finite_or_big(st.max_real_pole),
        notes=st.notes, domain=st.domain, spectral_radius=st.spectral_radius,
    )


def _abs_diff(a: float, b: float) -> float:
    """|a - b|, 0 when both are infinite (the same "no crossing")."""
    if math.isinf(a) and math.isinf(b):
        return 0.0
    return abs(a - b)


def pade_check(order: int, pade: Analysis, exact: Analysis) -> PadeCheck:
    """Whether the Padé analysis is close enough to the exact-delay one (:data:`PADE_TOL`)."""
    pairs = list(zip(pade.figures, exact.figures, strict=True))
    pm = max(_abs_diff(p.pm_deg, e.pm_deg) for p, e in pairs)
    gm = max(_abs_diff(p.gm_db, e.gm_db) for p, e in pairs)
    ms = max(abs(p.ms - e.ms) / max(e.ms, 1e-12) for p, e in pairs)
    same = pade.stability.stable == exact.stability.stable
    ok = same and pm <= PADE_TOL["pm_deg"] and gm <= PADE_TOL["gm_db"] and ms <= PADE_TOL["ms_rel"]
    return PadeCheck(order=order, adequate=ok, max_pm_err_deg=pm, max_gm_err_db=gm, max_ms_rel_err=ms,
                     same_stability=same)
