"""The steps of :func:`gaintune.verification.verify`, each on its own.

:func:`prepare` resolves the spec, plant, linearisation and gains; then :func:`nominal_analysis`
(margins and stability of the nominal loop, the Padé check), :func:`noise_figures` (Mks per loop),
:func:`stability_findings`, :func:`robust_step`, :func:`nonlinear_step`, :func:`requirement_step`
and :func:`closing_notes` add their figures, and the verdict's reasons and notes to a shared
:class:`Findings`; :func:`assemble_report` builds the :class:`VerificationReport`.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Literal

import numpy as np

from gaintune.classical.timescale import scenario_defaults
from gaintune.controllers.layout import GainLayout
from gaintune.plants.noise_limit import noise_limits
from gaintune.plants.plant import LinearModel, Plant, build_plant
from gaintune.spec import ScenarioDefault, TuningSpec
from gaintune.verification.analysis import Analysis, analyse, analysis_band, analysis_dt, sampling_delay
from gaintune.verification.cascade import Cascade, build_cascade
from gaintune.verification.context import SpecContext, spec_context
from gaintune.verification.figures import loop_figures, pade_check, stability_model
from gaintune.verification.freqresp import DelayModel
from gaintune.verification.gains import coerce_gains
from gaintune.verification.noise import noise_peaks
from gaintune.verification.nonlinear import nonlinear_check, settling_notes
from gaintune.verification.report import (
    LoopFigures,
    NonlinearReport,
    PadeCheck,
    RequirementLine,
    RobustReport,
    StabilityReport,
    VerificationReport,
    WorstCase,
)
from gaintune.verification.requirements import failing_reasons, not_applicable, requirement_lines
from gaintune.verification.robust import robust_check
from gaintune.verification.sampled import SampledPlant, sample_plant

__all__ = ["Findings", "Setup", "Nominal", "prepare", "nominal_analysis", "noise_figures",
           "stability_findings", "robust_step", "nonlinear_step", "requirement_step", "closing_notes",
           "assemble_report"]


@dataclass
class Findings:
    """What the steps found beyond figures: the verdict's reasons (fail when any) and the notes."""

    reasons: list[str] = field(default_factory=list)
    notes: list[str] = field(default_factory=list)


@dataclass
class Setup:
    """Everything the analysis steps share: the resolved spec, plant, linearisation and gains."""

    spec: TuningSpec
    #: The scenarios whose dt/horizon were derived from the plant (a note each).
    derived: list[ScenarioDefault]
    #: The hash the report names.
    report_hash: str
    ctx: SpecContext | None
    plant: Plant
    layout: GainLayout
    lin: LinearModel
    full: np.ndarray
    cas: Cascade
    dt: float


def prepare(spec: TuningSpec, gains: object, plant: Plant | None, layout: GainLayout | None, cache: bool,
            spec_hash: str | None, context: SpecContext | None = None) -> Setup:
    """Resolve the scenarios, build (or fetch from the cache) plant, layout and linearisation, check the gains.

    ``context``: the caller's own :class:`SpecContext` of this (resolved) spec, used instead of the cache.

    Raises
    ------
    GainError
        For gains :func:`gaintune.verification.gains.coerce_gains` refuses.
    """
    given = spec
    spec, derived = scenario_defaults(spec, plant)  # scenarios without dt/horizon: from the plant
    # the report names the spec as given (its scenarios filled in the same way every time)
    report_hash = (spec_hash or given.content_hash()) if derived else None
    if derived:
        spec_hash = None  # the caller's hash was of the spec before its scenarios were filled in
    ctx = context if context is not None and not derived else (
        spec_context(spec, plant, layout, spec_hash=spec_hash) if cache else None)
    if ctx is not None:
        plant, layout, lin = ctx.plant, ctx.layout, ctx.lin
    else:
        plant = plant or build_plant(spec.plant)
        layout = layout or GainLayout(spec, plant.states)
        lin = plant.linearize()
    full = coerce_gains(layout, gains)
    cas = build_cascade(spec, layout, full[None, :], lin)
    if report_hash is None:
        report_hash = ctx.spec_hash if ctx is not None else (spec_hash or spec.content_hash())
    return Setup(spec, derived, report_hash, ctx, plant, layout, lin, full, cas, analysis_dt(spec))


@dataclass
class Nominal:
    """The nominal analysis and the loop model it was made on."""

    analysis: Analysis
    #: Total loop delay (the sampled loop: the sampled plant's, exact in z).
    delay: DelayModel
    #: The sampled plant (``verify.sampled``), else None.
    sampled: SampledPlant | None
    #: dt/2 of sampling delay added by the continuous analysis (0 for the sampled one).
    t_s: float
    pade: PadeCheck | None = None


def nominal_analysis(setup: Setup, found: Findings) -> Nominal:
    """Margins and stability of the nominal loop: the sampled loop, or the continuous one with dt/2
    (and the computation delay) of delay, whose Padé approximation (when asked for) is checked."""
    spec, lin, cas, dt = setup.spec, setup.lin, setup.cas, setup.dt
    vs = spec.verify
    if vs.sampled:
        sp = sample_plant(lin, dt, vs.compute_delay, setup.plant.kind == "nonlinear")
        nom = analyse(cas, lin, None, vs.n_freq, sampled=sp)
        if vs.pade_order is not None:
            found.notes.append("verify.pade_order is not used by the sampled analysis (delays are exact in z)")
        return Nominal(nom, DelayModel(sp.total_delay), sp, 0.0)
    t_s = sampling_delay(spec)
    delay = DelayModel(lin.delay + t_s + vs.compute_delay * dt, vs.pade_order)
    band = analysis_band(spec)
    nom = analyse(cas, lin, delay, vs.n_freq, band)
    pade = None
    if delay.pade_order is not None and delay.T > 0:
        exact = analyse(cas, lin, DelayModel(delay.T, None), vs.n_freq, band)
        pade = pade_check(delay.pade_order, nom, exact)
        if not pade.adequate:
            found.reasons.append(
                f"Padé order {pade.order} is not adequate (PM error {pade.max_pm_err_deg:.2f} deg, GM error "
                f"{pade.max_gm_err_db:.2f} dB, Ms error {100 * pade.max_ms_rel_err:.1f} %); raise verify.pade_order "
                "or set it to null (exact delay)"
            )
    return Nominal(nom, delay, None, t_s, pade)


#: (Mks or None, its frequency or None) per loop.
Peaks = list[tuple[float | None, float | None]]


def noise_figures(setup: Setup, nom: Nominal, found: Findings) -> tuple[list[LoopFigures], Peaks]:
    """The report's figures per break point, with each loop's noise sensitivity Mks and its limit."""
    spec, lin = setup.spec, setup.lin
    loops = [loop_figures(f, setup.dt) for f in nom.analysis.figures]
    mks = noise_peaks(setup.cas, lin, nom.analysis.omega_range, None if nom.sampled is not None else nom.delay,
                      nom.sampled)
    limits = setup.ctx.noise_limits(spec) if setup.ctx is not None else noise_limits(spec, lin)
    for i, (value, w_pk) in enumerate(mks):
        loops[i].mks, loops[i].mks_freq, loops[i].mks_max = value, w_pk, limits[i].limit
        if limits[i].note:
            found.notes.append(f"{loops[i].loop}: {limits[i].note}")
    return loops, mks


def stability_findings(nom: Nominal, found: Findings) -> StabilityReport:
    """The nominal closed loop's stability section; an unstable or undecided loop (or an overflowing
    analysis) is a reason to fail."""
    stab = stability_model(nom.analysis)
    if nom.analysis.stability.uncertain:
        found.reasons.append(f"closed-loop stability not certified: {nom.analysis.stability.uncertain}")
    elif not stab.stable:
        where = "|z| >= 1" if stab.domain == "z" else "Re >= 0"
        found.reasons.append(f"closed loop unstable: {stab.rhp_count} pole(s) with {where} ({stab.method})")
    found.reasons.extend(nom.analysis.problems)
    return stab


def robust_step(setup: Setup, nom: Nominal, mks: Peaks, robust: bool | None,
                found: Findings) -> tuple[RobustReport | None, list[WorstCase] | None]:
    """The robust check (default: when the spec randomises plant parameters or the delay)."""
    spec, vs = setup.spec, setup.spec.verify
    if robust is None:
        robust = bool(spec.randomize.params or spec.randomize.delay)
    if not robust:
        return None, None
    res = robust_check(spec, setup.plant, setup.cas, nom.t_s + vs.compute_delay * setup.dt, nom.analysis, mks,
                       nom.sampled, analysis_band(spec), setup.dt)
    rob = res.report
    if rob.n_samples == 0:
        found.notes.append("robust check requested but the spec randomises neither plant parameters nor the delay")
    if rob.n_unstable:
        found.reasons.append(f"robust: {rob.n_unstable} of {rob.n_samples} sampled plants give an unstable closed loop")
    if res.n_bad:
        found.reasons.append(f"robust: {res.n_bad} of {rob.n_samples} sampled plants could not be analysed (the "
                             "loop overflows: gains or plant coefficients too large to analyse)")
    return rob, res.worst


def nonlinear_step(setup: Setup, stab: StabilityReport, run: bool, found: Findings) -> NonlinearReport | None:
    """The nonlinear simulation check (``run``); not applicable on an unstable linearised loop."""
    if not run:
        return None
    spec, ctx = setup.spec, setup.ctx
    nl = nonlinear_check(spec, setup.plant, setup.layout, setup.full,
                         sim=ctx.simulator(spec) if ctx is not None else None, compute_delay=spec.verify.compute_delay)
    if nl.ran and not stab.stable:  # a bounded run of an unstable loop is no "ok": saturation only hides it
        return nl.model_copy(update={"passed": None, "note": "not applicable: the linearised closed loop is unstable"})
    if nl.ran and not nl.passed:
        found.reasons.append(f"nonlinear check failed: {nl.note}")
    elif not nl.ran:
        found.notes.append(f"nonlinear check not run: {nl.note}")
    else:
        sim = ctx.simulator(spec) if ctx is not None else None
        found.notes.extend(settling_notes(spec, sim, setup.plant, setup.layout, setup.full))
    return nl


def requirement_step(setup: Setup, loops: list[LoopFigures], worst: list[WorstCase] | None, stab: StabilityReport,
                     rob: RobustReport | None, found: Findings) -> list[RequirementLine]:
    """The requirement lines (not applicable on an unstable loop); each failing one is a reason."""
    req = not_applicable(requirement_lines(setup.spec, loops, worst), nominal_stable=stab.stable,
                         robust_stable=rob is None or rob.n_unstable == 0)
    found.reasons.extend(failing_reasons(req))
    return req


def closing_notes(setup: Setup, stab: StabilityReport, found: Findings) -> None:
    """Notes on derived scenario timing, the stability analysis, and a nonlinear plant's linearisation."""
    found.notes.extend(f"scenario {d.scenario!r}: dt {d.dt:.4g} s, horizon {d.horizon:.4g} s derived from the plant "
                       f"({d.reason})" for d in setup.derived)
    found.notes.extend(stab.notes)
    if setup.plant.kind == "nonlinear":
        found.notes.append("nonlinear plant: margins are for the casadi linearisation at the operating point")


def _delay_method(delay: DelayModel) -> Literal["exact", "pade", "none"]:
    """How the loop delay entered the analysis."""
    if delay.T <= 0:
        return "none"
    return "pade" if delay.pade_order else "exact"


def assemble_report(setup: Setup, nom: Nominal, found: Findings, *, loops: list[LoopFigures], stab: StabilityReport,
                    rob: RobustReport | None, nl: NonlinearReport | None, req: list[RequirementLine],
                    elapsed_s: float) -> VerificationReport:
    """The :class:`VerificationReport` of the steps' results; the verdict is fail when any reason was found."""
    lin, vs = setup.lin, setup.spec.verify
    op = {f"x0.{s}": float(v) for s, v in zip(lin.states, lin.x0, strict=True)}
    op["u0"] = float(lin.u0)
    return VerificationReport(
        spec_name=setup.spec.name, spec_hash=setup.report_hash, gains=setup.layout.to_dict(setup.full),
        verdict="pass" if not found.reasons else "fail", reasons=found.reasons, delay=float(lin.delay),
        sampling_delay=nom.t_s, sampled=vs.sampled, dt=setup.dt, compute_delay=vs.compute_delay,
        delay_method=_delay_method(nom.delay), pade=nom.pade, operating_point=op, stability=stab,
        analysis_band=nom.analysis.omega_range, loops=loops, robust=rob, nonlinear=nl, requirements=req,
        notes=found.notes, elapsed_s=elapsed_s,
    )
