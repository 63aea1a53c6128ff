"""``verify(spec, gains) -> VerificationReport``: stability, margins, robustness, nonlinear check, verdict."""

from __future__ import annotations

import math
import time
from pathlib import Path
from typing import Any

import numpy as np

from gaintune.classical.timescale import scenario_defaults
from gaintune.controllers.layout import GainLayout
from gaintune.errors import GainError
from gaintune.plants.noise_limit import noise_limits
from gaintune.plants.plant import Plant, build_plant
from gaintune.spec import TuningSpec, load_spec
from gaintune.verification.analysis import Analysis, analyse, sampling_delay
from gaintune.verification.cascade import build_cascade
from gaintune.verification.context import spec_context
from gaintune.verification.freqresp import DelayModel
from gaintune.verification.margins import BreakFigures
from gaintune.verification.nonlinear import nonlinear_check
from gaintune.verification.report import (
    CrossingModel,
    LoopFigures,
    PadeCheck,
    RequirementLine,
    RobustReport,
    StabilityReport,
    VerificationReport,
    WorstCase,
)
from gaintune.verification.noise import noise_peaks
from gaintune.verification.robust import DELAY_KEY, robust_samples
from gaintune.verification.sampled import SampledPlant, sample_plant

__all__ = ["verify", "coerce_gains", "REQUIREMENTS", "loop_frequency_responses"]

#: requirement field -> (figure attribute, kind) ; kind "min": value >= limit, "max": value <= limit.
REQUIREMENTS: dict[str, tuple[str, str]] = {
    "gm_min_db": ("gm_db", "min"),
    "pm_min_deg": ("pm_deg", "min"),
    "dm_min": ("delay_margin", "min"),
    "ms_max": ("ms", "max"),
    "mt_max": ("mt", "max"),
    "wc_min": ("pm_freq", "min"),
    "wc_max": ("pm_freq", "max"),
}

#: The continuous analysis band ends at this multiple of the controller's Nyquist frequency pi/dt
#: (largest scenario dt) when the frequencies above are proven harmless (:func:`analyse`, ``band``).
#: The sampled analysis ends at pi/dt itself.
BAND_NYQUIST = 10.0

#: Padé adequacy tolerances (vs the exact e^{-jwT} figures).
PADE_TOL = {"pm_deg": 1.0, "gm_db": 0.5, "ms_rel": 0.02}


def coerce_gains(layout: GainLayout, gains: Any) -> np.ndarray:
    """Nested dict or vector (full or tuned-only) -> validated, signed full gain vector. Raises GainError.

    Dicts and full vectors carry signed gains (negative Kp, Ki, Kd for a reverse-acting loop);
    a tuned-only vector may hold the search magnitudes (the layout gives them their loop's sign).
    """
    if isinstance(gains, dict):
        return layout.from_dict(gains)
    if _has_boolean(gains):  # numpy would read true as 1.0
        raise GainError("gains", "must be numbers, not booleans (true/false)")
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


def _has_boolean(gains: Any) -> bool:
    """True when a gain vector holds a bool (a bool array, or one in a list or tuple)."""
    if isinstance(gains, np.ndarray):
        return gains.dtype == bool
    if isinstance(gains, (list, tuple)):
        return any(isinstance(g, (bool, np.bool_)) for g in gains)
    return isinstance(gains, (bool, np.bool_))


def _fixed_gain_overrides(spec: TuningSpec, layout: GainLayout, full: np.ndarray) -> list[str]:
    """A note per gain the spec fixes (``tune: false``) but the given gains set to another value.

    The given value is the one verified (an engineer adjusts a fixed gain by hand and checks it), so
    the report says so instead of letting a reader assume the spec's value."""
    out = []
    for k, slot in enumerate(layout.slots):
        given = spec.loops[slot.loop].gains.get(slot.name)
        if slot.tuned or given is None or given.value is None or full[k] == given.value:
            continue
        out.append(f"{slot.loop_name}.{slot.name} = {full[k]:g} was verified, not the spec's fixed value "
                   f"{given.value:g} (loops[{slot.loop}].gains.{slot.name}, tune: false)")
    return out


#: Most phase crossings listed per break point (those of smallest |GM|; delays give infinitely many).
MAX_PHASE_CROSSINGS = 20


def gm_binding(f: BreakFigures) -> str:
    """Which gain margin binds: "increase" (upper), "reduction" (lower) or "none" (both infinite)."""
    if math.isinf(f.gm_upper_db) and math.isinf(f.gm_lower_db):
        return "none"
    return "increase" if f.gm_upper_db <= f.gm_lower_db else "reduction"


def _samples(seconds: float, dt: float | None) -> float | None:
    return None if not dt else seconds / dt


def _to_model(f: BreakFigures, dt: float | None = None) -> LoopFigures:
    phase = sorted((c for c in f.crossings if c.kind == "phase"), key=lambda c: (not c.binding, abs(c.value)))
    kept = [c for c in f.crossings if c.kind == "gain"] + phase[:MAX_PHASE_CROSSINGS]
    kept.sort(key=lambda c: c.omega)
    cr = [CrossingModel(kind=c.kind, omega=c.omega, value=c.value, delay_margin=c.delay_margin, binding=c.binding) for c in kept]
    omitted = len(f.crossings) - len(kept) + f.phase_omitted
    return LoopFigures(
        loop=f.loop, break_point=f.break_point, gm_db=f.gm_db, gm_upper_db=f.gm_upper_db, gm_lower_db=f.gm_lower_db,
        gm_binding=gm_binding(f), gm_freq=f.gm_freq, pm_deg=f.pm_deg, pm_freq=f.pm_freq, delay_margin=f.delay_margin,
        delay_margin_samples=_samples(f.delay_margin, dt), ms=f.ms, ms_freq=f.ms_freq,
        mt=f.mt, mt_freq=f.mt_freq, disk_alpha=f.disk_alpha, disk_gm_db=f.disk_gm_db, disk_pm_deg=f.disk_pm_deg,
        disk_freq=f.disk_freq, gain_crossovers=[c.omega for c in f.crossings if c.kind == "gain"],
        phase_crossovers=[c.omega for c in kept if c.kind == "phase"], crossings=cr,
        crossings_omitted=omitted,
    )


def _finite_or_big(x: float) -> float:
    """+-inf as +-1e300 (no poles at all: -inf); NaN (not computed) stays NaN."""
    return x if not math.isinf(x) else math.copysign(1e300, x)


def _stability_model(a: Analysis) -> StabilityReport:
    st = a.stability
    # largest real part first (s-plane), largest modulus first (z-plane: the sampled loop)
    key = (lambda z: -math.hypot(*z)) if st.domain == "z" else (lambda z: -z[0])
    poles = sorted(((float(p.real), float(p.imag)) for p in st.poles), key=key)
    return StabilityReport(
        stable=st.stable, method=st.method, rhp_count=st.rhp_count, nyquist_rhp=st.nyquist_rhp, poles=poles,
        poles_method=st.poles_method,
        max_real_pole=_finite_or_big(st.max_real_pole),
        notes=st.notes, domain=st.domain, spectral_radius=st.spectral_radius,
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


def loop_frequency_responses(spec: TuningSpec, plant: Plant, layout: GainLayout, full: np.ndarray, w: np.ndarray,
                             lin=None, *, noise: bool = False) -> np.ndarray:
    """L (n_loops + 1, W) at the frequencies ``w`` (rad/s) of every break point of the loop
    :func:`verify` analyses (rows as ``report.loops``): the sampled loop at z = e^{jw dt} (then
    w <= pi/dt is meaningful, higher w are aliases), or the continuous loop with dt/2 and the
    computation delay. For plots of the verified loop (Bode, Nyquist, sensitivity).

    ``noise``: return instead each loop's noise response N_i (n_loops, W), whose peak is Mks
    (:mod:`gaintune.verification.noise`; -C S for one loop)."""
    lin = lin if lin is not None else plant.linearize()
    full = np.asarray(full, dtype=float).reshape(1, -1)
    cas = build_cascade(spec, layout, full, lin)
    s = 1j * np.asarray(w, dtype=float)
    vs, dt = spec.verify, analysis_dt(spec)
    with np.errstate(all="ignore"):
        if vs.sampled:
            sp = sample_plant(lin, dt, vs.compute_delay, plant.kind == "nonlinear")
            out = cas.loop_responses(s, lin, sampled=sp, noise=noise)
        else:
            T = lin.delay + sampling_delay(spec) + vs.compute_delay * dt
            out = cas.loop_responses(s, lin, DelayModel(T, vs.pade_order).factor(s), noise=noise)
    return out[1][:, 0, :] if noise else out[:, 0, :]


def analysis_dt(spec: TuningSpec) -> float:
    """The sample time verification uses: the largest scenario dt (the conservative choice)."""
    return max(sc.dt for sc in spec.scenarios)


def analysis_band(spec: TuningSpec) -> float:
    """Upper end (rad/s) of the continuous analysis band: BAND_NYQUIST x the Nyquist frequency pi/dt of the largest dt."""
    return BAND_NYQUIST * math.pi / max(sc.dt for sc in spec.scenarios)


def _robust(spec, plant, cas, lin_nom, t_s, nominal: Analysis, nominal_mks, sampled: SampledPlant | None = None
            ) -> tuple[RobustReport, list[WorstCase], int]:
    """Worst figures over the robust samples, and how many samples could not be analysed (their
    loop response overflowed: figures not trustworthy). ``sampled``: the nominal sampled plant (its
    dt, computation delay and method are applied to every sample); else the continuous analysis
    with ``t_s`` of extra delay."""
    samples, n_corners, n_mc = robust_samples(spec)
    dt = analysis_dt(spec)
    keys = ("gm_db", "pm_deg", "delay_margin", "ms", "mt", "disk_alpha")
    worst_kind = {"gm_db": min, "pm_deg": min, "delay_margin": min, "ms": max, "mt": max, "disk_alpha": min}
    R = len(nominal.figures)
    worst = [{k: (getattr(nominal.figures[r], k), {"nominal": 1.0}) for k in keys} for r in range(R)]
    n_loops = len(cas.loops)
    mks_worst: list[tuple[float | None, dict]] = [(nominal_mks[r][0] if r < n_loops else None, {"nominal": 1.0})
                                                  for r in range(R)]
    unstable: list[dict[str, float]] = []
    n_bad = 0
    for smp in samples:
        params = {k: v for k, v in smp.items() if k != DELAY_KEY}
        lin = plant.linearize(params)
        tau = smp[DELAY_KEY] if DELAY_KEY in smp else lin.delay
        if sampled is not None:
            sp = sample_plant(lin, sampled.dt, sampled.compute_delay, sampled.method == "rk4", tau)
            a = analyse(cas, lin, None, spec.verify.n_freq, sampled=sp)
        else:
            a = analyse(cas, lin, DelayModel(tau + t_s, spec.verify.pade_order), spec.verify.n_freq, analysis_band(spec))
        if not a.stability.stable:
            unstable.append(dict(smp))
        n_bad += bool(a.problems or a.stability.uncertain)
        mks = noise_peaks(cas, lin, a.omega_range, DelayModel(tau + t_s) if sampled is None else None,
                          sp if sampled is not None else None)
        for r, (v, _) in enumerate(mks):
            if v is not None and (mks_worst[r][0] is None or v > mks_worst[r][0]):
                mks_worst[r] = (v, dict(smp))
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
                            delay_margin=w["delay_margin"][0], delay_margin_samples=_samples(w["delay_margin"][0], dt),
                            ms=w["ms"][0], mt=w["mt"][0], mks=mks_worst[r][0],
                            disk_alpha=w["disk_alpha"][0], where=where))
    rep = RobustReport(
        n_samples=len(samples), n_corners=n_corners, n_monte_carlo=n_mc, seed=spec.search.seed,
        n_unstable=len(unstable), unstable_samples=[{("delay" if k == DELAY_KEY else k): v for k, v in u.items()} for u in unstable[:20]],
        worst=wc,
    )
    return rep, wc, n_bad


def _requirement_lines(spec: TuningSpec, loops: list[LoopFigures], worst: list[WorstCase] | None) -> list[RequirementLine]:
    req = spec.requirements
    lines = []
    for name, (attr, kind) in REQUIREMENTS.items():
        limit = getattr(req, name)
        if limit is None:
            continue
        cands = [(getattr(f, attr), f.loop, f.break_point, "nominal") for f in loops]
        if worst and attr != "pm_freq":  # the robust set records no crossover frequencies
            cands += [(getattr(w, attr), w.loop, w.break_point, "worst") for w in worst]
        cands = [(0.0 if v is None else v, *rest) for v, *rest in cands]  # no gain crossover: wc = 0
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
    mks = _noise_line(loops, worst)
    if mks is not None:
        lines.append(mks)
    return lines


def _not_applicable(lines: list[RequirementLine], *, nominal_stable: bool, robust_stable: bool) -> list[RequirementLine]:
    """Mark the lines read on an unstable closed loop as not applicable (never pass): the instability is the reason."""
    stable = {"nominal": nominal_stable, "worst": robust_stable and nominal_stable}
    return [q if stable[q.case] else q.model_copy(update={"applicable": False, "passed": False}) for q in lines]


def _noise_line(loops: list[LoopFigures], worst: list[WorstCase] | None) -> RequirementLine | None:
    """The Mks requirement at its binding loop: limits differ per loop, so the one with the least
    relative margin binds (the line states that loop's limit)."""
    limit = {f.loop: f.mks_max for f in loops if f.break_point == "controller_output" and f.mks_max is not None}
    cands = [(f.mks, f.loop, f.break_point, "nominal") for f in loops if f.loop in limit]
    cands += [(w.mks, w.loop, w.break_point, "worst") for w in (worst or []) if w.loop in limit and w.mks is not None]
    best = None
    for value, loop, brk, case in cands:
        v = math.inf if value is None or math.isnan(value) else value
        rel = (limit[loop] - v) / limit[loop]
        if best is None or rel < best[0] - 1e-12:
            best = (rel, v, loop, brk, case)
    if best is None:
        return None
    _, value, loop, brk, case = best
    margin = limit[loop] - value
    return RequirementLine(requirement="mks_max", figure="mks", limit=float(limit[loop]), value=float(value),
                           margin=float(margin), passed=margin >= 0, loop=loop, break_point=brk, case=case)


def settling_notes(spec: TuningSpec, sim, plant: Plant, layout: GainLayout, full: np.ndarray) -> list[str]:
    """A note per scenario whose response has not settled by its end (:mod:`gaintune.sim.settling`)."""
    from gaintune.sim import Simulator
    from gaintune.sim.settling import settling_messages

    return settling_messages(sim or Simulator(spec, plant, layout), full)


def verify(
    spec: TuningSpec | dict[str, Any] | str | Path,
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

    The loop analysed is, by default (``verify.sampled``), the sampled loop the simulator runs:
    the plant discretised by ZOH with its delay at the largest scenario dt, the controllers'
    discrete laws, margins on z = e^{jw dt} up to pi/dt and stability from the discrete
    closed-loop poles (:mod:`gaintune.verification.sampled`); ``verify.sampled: false`` analyses the
    continuous loop with dt/2 of delay instead. ``verify.compute_delay`` samples of computation
    delay are included either way.

    Parameters
    ----------
    spec
        The tuning problem: a :class:`TuningSpec`, or anything :func:`gaintune.spec.load_spec` takes
        (a dict, a YAML/JSON file path or text).
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
        on the same spec (keyed by ``spec.content_hash()``; see :mod:`gaintune.verification.context`).
        A cached entry takes precedence over ``plant``/``layout``.
    spec_hash
        ``spec.content_hash()`` when the caller has computed it already (saves hashing the spec again).

    Raises
    ------
    GainError
        For NaN, non-positive, missing/unknown gains or a wrong count.
    SpecError, pydantic.ValidationError
        For a spec that is not a valid :class:`TuningSpec` (the message names the field).
    """
    t0 = time.perf_counter()
    if not isinstance(spec, TuningSpec):
        spec = load_spec(spec)
    given = spec
    spec, derived = scenario_defaults(spec, plant)  # scenarios without dt/horizon: from the plant
    # the report names the spec as given (its scenarios filled in the same way every time)
    report_hash = (spec_hash or given.content_hash()) if derived else None
    if derived:
        spec_hash = None  # the caller's hash was of the spec before its scenarios were filled in
    ctx = spec_context(spec, plant, layout, spec_hash=spec_hash) if cache else None
    if ctx is not None:
        plant, layout, lin = ctx.plant, ctx.layout, ctx.lin
    else:
        plant = plant or build_plant(spec.plant)
        layout = layout or GainLayout(spec, plant.states)
        lin = plant.linearize()
    full = coerce_gains(layout, gains)
    vs = spec.verify
    dt = analysis_dt(spec)
    cas = build_cascade(spec, layout, full[None, :], lin)
    notes: list[str] = _fixed_gain_overrides(spec, layout, full)
    reasons: list[str] = []
    pade = None
    sp = None
    if vs.sampled:
        t_s = 0.0
        sp = sample_plant(lin, dt, vs.compute_delay, plant.kind == "nonlinear")
        delay = DelayModel(sp.total_delay)
        nom = analyse(cas, lin, None, vs.n_freq, sampled=sp)
        if vs.pade_order is not None:
            notes.append("verify.pade_order is not used by the sampled analysis (delays are exact in z)")
    else:
        t_s = sampling_delay(spec)
        delay = DelayModel(lin.delay + t_s + vs.compute_delay * dt, vs.pade_order)
        nom = analyse(cas, lin, delay, vs.n_freq, analysis_band(spec))
    if sp is None and delay.pade_order is not None and delay.T > 0:
        band = analysis_band(spec)
        exact = analyse(cas, lin, DelayModel(delay.T, None), spec.verify.n_freq, band)
        pade = _pade_check(delay.pade_order, nom, exact)
        if not pade.adequate:
            reasons.append(
                f"Padé order {pade.order} is not adequate (PM error {pade.max_pm_err_deg:.2f} deg, GM error "
                f"{pade.max_gm_err_db:.2f} dB, Ms error {100 * pade.max_ms_rel_err:.1f} %); raise verify.pade_order or set it to null (exact delay)"
            )
    loops = [_to_model(f, dt) for f in nom.figures]
    mks = noise_peaks(cas, lin, nom.omega_range, None if sp is not None else delay, sp)
    limits = ctx.noise_limits(spec) if ctx is not None else noise_limits(spec, lin)
    for i, (value, w_pk) in enumerate(mks):
        loops[i].mks, loops[i].mks_freq, loops[i].mks_max = value, w_pk, limits[i].limit
        if limits[i].note:
            notes.append(f"{loops[i].loop}: {limits[i].note}")
    stab = _stability_model(nom)
    if nom.stability.uncertain:
        reasons.append(f"closed-loop stability not certified: {nom.stability.uncertain}")
    elif not stab.stable:
        where = "|z| >= 1" if stab.domain == "z" else "Re >= 0"
        reasons.append(f"closed loop unstable: {stab.rhp_count} pole(s) with {where} ({stab.method})")
    reasons.extend(nom.problems)
    rob = None
    worst = None
    if robust is None:
        robust = bool(spec.randomize.params or spec.randomize.delay)
    if robust:
        rob, worst, n_bad = _robust(spec, plant, cas, lin, t_s + vs.compute_delay * dt, nom, mks, sp)
        if rob.n_samples == 0:
            notes.append("robust check requested but the spec randomises neither plant parameters nor the delay")
        if rob.n_unstable:
            reasons.append(f"robust: {rob.n_unstable} of {rob.n_samples} sampled plants give an unstable closed loop")
        if n_bad:
            reasons.append(f"robust: {n_bad} of {rob.n_samples} sampled plants could not be analysed (the loop "
                           "overflows: gains or plant coefficients too large to analyse)")
    nl = None
    if nonlinear:
        nl = nonlinear_check(spec, plant, layout, full, sim=ctx.simulator(spec) if ctx is not None else None,
                             compute_delay=vs.compute_delay)
        if nl.ran and not stab.stable:  # a bounded run of an unstable loop is no "ok": saturation only hides it
            nl = nl.model_copy(update={"passed": None, "note": "not applicable: the linearised closed loop is unstable"})
        elif nl.ran and not nl.passed:
            reasons.append(f"nonlinear check failed: {nl.note}")
        elif not nl.ran:
            notes.append(f"nonlinear check not run: {nl.note}")
        else:
            notes.extend(settling_notes(spec, ctx.simulator(spec) if ctx is not None else None, plant, layout, full))
    notes.extend(f"scenario {d.scenario!r}: dt {d.dt:.4g} s, horizon {d.horizon:.4g} s derived from the plant ({d.reason})"
                 for d in derived)
    req = _not_applicable(_requirement_lines(spec, loops, worst), nominal_stable=stab.stable,
                          robust_stable=rob is None or rob.n_unstable == 0)
    failing = sorted((q for q in req if q.applicable and not q.passed), key=lambda q: q.margin / max(abs(q.limit), 1e-12))
    for q in failing:
        reasons.append(
            f"{q.requirement}: {q.figure} = {q.value:.4g} vs limit {q.limit:.4g} (margin {q.margin:+.4g}) "
            f"at {q.loop}/{q.break_point} ({q.case})"
        )
    for n in stab.notes:
        notes.append(n)
    if plant.kind == "nonlinear":
        notes.append("nonlinear plant: margins are for the casadi linearisation at the operating point")
    op = {f"x0.{s}": float(v) for s, v in zip(lin.states, lin.x0)}
    op["u0"] = float(lin.u0)
    verdict = "pass" if not reasons else "fail"
    return VerificationReport(
        spec_name=spec.name,
        spec_hash=report_hash or (ctx.spec_hash if ctx is not None else (spec_hash or spec.content_hash())),
        gains=layout.to_dict(full), verdict=verdict,
        reasons=reasons, delay=float(lin.delay), sampling_delay=t_s, sampled=vs.sampled, dt=dt,
        compute_delay=vs.compute_delay,
        delay_method="none" if delay.T <= 0 else ("pade" if delay.pade_order else "exact"), pade=pade,
        operating_point=op, stability=stab, analysis_band=nom.omega_range, loops=loops, robust=rob, nonlinear=nl, requirements=req, notes=notes,
        elapsed_s=time.perf_counter() - t0,
    )
