"""The verdict on a MIMO spec's gains: :func:`verify_mimo`, what :func:`gaintune.verification.verify`
runs for a spec with several plant inputs or a loop graph.

The loop analysed is, by default (``verify.sampled``), the exact sampled loop at the largest
scenario dt (:mod:`.mimo_sampled`): the plant ZOH-discretised as the MIMO simulator steps it
(delays split into whole samples and a fraction, ``verify.compute_delay`` samples added), every
loop's discrete PID law, stability from the discrete closed-loop eigenvalues (|z| < 1) and the
figures on z = e^{jw dt} up to pi/dt. ``verify.sampled: false`` analyses the continuous loop with
``dt/2`` of sample-and-hold delay and the computation delay on every driven input
(:mod:`.mimo_spec`): stability by Padé eigenvalues cross-checked by the generalised Nyquist
count on the exact delays. Either way: the loop-at-a-time margins at every driven input and
measured output, the multiloop disk margins at the plant inputs and outputs, and the MIMO Ms and
Mt. Each requirement gives one line at its binding place; the verdict fails naming the
requirement and where.

When the spec randomises plant parameters (``randomize.params``) the gains are also judged on the
robust set the single-loop verdict draws (:mod:`.mimo_robust`): each requirement gets a second line,
case ``worst``, the least margin over the stable drawn loops with the draw attaining it, and the
verdict passes only when the nominal and the worst case pass and every drawn closed loop is stable.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from gaintune.classical.timescale import scenario_defaults
from gaintune.controllers.layout import GainLayout
from gaintune.plants.plant import build_plant
from gaintune.spec import TuningSpec
from gaintune.verification.figures import loop_figures
from gaintune.verification.gains import coerce_gains, fixed_gain_overrides
from gaintune.verification.mimo import REQUIREMENTS, MimoLine, MimoMargins
from gaintune.verification.mimo_robust import MimoRobust, check_randomize, mimo_robust
from gaintune.verification.mimo_sampled_report import sampled_margins
from gaintune.verification.mimo_spec import MIMO_NOT_CHECKED, SpecLoop, spec_margins
from gaintune.verification.nonlinear import nonlinear_check
from gaintune.verification.report import (
    MimoDisk,
    MimoFigures,
    RequirementLine,
    RobustReport,
    StabilityReport,
    VerificationReport,
)

__all__ = ["verify_mimo", "mimo_lines"]


def mimo_lines(lines: list[MimoLine], stable: bool) -> list[RequirementLine]:
    """The report's requirement lines: ``loop`` is the binding loop (a MIMO-wide figure: the side,
    ``input`` or ``output``), ``break_point`` the break (None for a MIMO-wide figure); on an unstable
    loop none applies."""
    out = []
    for q in lines:
        loop, _, brk = q.where.partition("/")
        out.append(RequirementLine(
            requirement=q.requirement if q.target == "all" else f"{q.requirement}[{q.target}]",
            figure=REQUIREMENTS[q.requirement][0], limit=q.limit, value=q.value,
            margin=q.margin if not math.isnan(q.margin) else -math.inf, passed=q.passed and stable,
            loop=loop, break_point=brk or None, applicable=stable))
    return out


def _stability(rep: MimoMargins, sampled: bool) -> StabilityReport:
    st = rep.stability
    z = np.asarray(st.poles, dtype=complex)
    poles = sorted(z, key=lambda p: -abs(p) if sampled else -p.real)[:50]
    max_re = float(st.max_real_pole) if math.isfinite(st.max_real_pole) else (1e300 if st.max_real_pole > 0 else -1e300)
    return StabilityReport(
        stable=st.stable, method="nyquist" if st.method == "nyquist" else "poles", rhp_count=st.rhp_poles,
        nyquist_rhp=st.nyquist_rhp, poles=[(float(p.real), float(p.imag)) for p in poles],
        poles_method="exact" if sampled else f"pade{st.pade_order}", max_real_pole=max_re, notes=list(st.notes),
        domain="z" if sampled else "s", spectral_radius=float(np.max(np.abs(z), initial=0.0)) if sampled else None)


def _figures(rep: MimoMargins) -> MimoFigures:
    def disk(d) -> MimoDisk:
        return MimoDisk(alpha=d.alpha, gm_db=d.gm_db, pm_deg=d.pm_deg, freq=d.freq)

    return MimoFigures(loops=rep.loops, inputs=rep.inputs, outputs=rep.outputs, ms=rep.ms,
                       ms_input=rep.ms_input.value, ms_output=rep.ms_output.value, mt=rep.mt,
                       mt_input=rep.mt_input.value, mt_output=rep.mt_output.value,
                       disk_input=disk(rep.disk_input), disk_output=disk(rep.disk_output),
                       pade_rhp=rep.stability.rhp_poles, nyquist_rhp=rep.stability.nyquist_rhp,
                       grid_points=rep.grid_points)


def _case(q: RequirementLine) -> str:
    """`` (worst case, draw K=1.2)`` for a worst-case line, nothing for a nominal one."""
    if q.case != "worst":
        return ""
    draw = ", ".join(f"{k}={v:.4g}" for k, v in (q.draw or {}).items())
    return f" (worst case, draw {draw})" if draw else " (worst case)"


def _reasons(stable: bool, lines: list[RequirementLine], nl_failed: bool, rob: RobustReport | None = None) -> list[str]:
    out = [] if stable else ["closed loop unstable (all loops closed)"]
    if rob is not None and rob.n_unstable:
        out.append(f"robust: {rob.n_unstable} of {rob.n_samples} sampled plants give an unstable closed loop")
    failing = sorted((q for q in lines if q.applicable and not q.passed),
                     key=lambda q: q.margin / max(abs(q.limit), 1e-12))
    out += [f"{q.requirement}: {q.figure} = {q.value:.4g} vs limit {q.limit:.4g} (margin {q.margin:+.4g}) "
            f"at {'/'.join(x for x in (q.loop, q.break_point) if x)}{_case(q)}" for q in failing]
    if nl_failed:
        out.append("nonlinear simulation diverged or tripped the safety monitor")
    return out


def _loop_note(sl: SpecLoop, cd: int, sampled: bool) -> str:
    """Which loop the verdict judged."""
    comp = f", {cd} sample(s) of computation delay" if cd else ""
    if sampled:
        return (f"MIMO loop analysed sampled at dt {sl.dt:.4g} (exact: plant ZOH with its delays, the discrete "
                f"PID laws{comp}; stability from the discrete closed-loop poles)")
    return (f"MIMO loop analysed in continuous time with {sl.extra_delay:.4g} s of delay added at every driven "
            f"input (dt/2 sample-and-hold at dt {sl.dt:.4g}{comp})")


def _robust_lines(spec: TuningSpec, plant: Any, layout: GainLayout, full: np.ndarray, sampled: bool, dt: float,
                  notes: list[str]) -> tuple[RobustReport, list[RequirementLine]]:
    """The robust set's report section and its worst-case requirement lines (``case="worst"``, with their draw)."""
    rob: MimoRobust = mimo_robust(spec, plant, layout, full, sampled, dt)
    lines = [q.model_copy(update={"case": "worst", "draw": d})
             for q, d in zip(mimo_lines(rob.worst_lines, rob.n_unstable == 0), rob.worst_draws, strict=True)]
    r = rob.report
    notes.append(f"robust set: {r.n_samples} drawn plants ({r.n_corners} box corners + {r.n_monte_carlo} Monte-Carlo "
                 f"draws, seed {r.seed}), each judged as the nominal plant; the nonlinear check runs on the nominal "
                 "plant only")
    return r, lines


def verify_mimo(spec: TuningSpec, gains: Any, plant: Any = None, layout: GainLayout | None = None,
                spec_hash: str | None = None, nonlinear: bool = True, elapsed_from: float = 0.0,
                robust: bool | None = None) -> VerificationReport:
    """Verify one gain set of a MIMO spec (see the module docstring); ``gains`` as
    :func:`gaintune.verification.verify` takes them; ``robust``: judge the robust set too (default:
    when the spec randomises plant parameters)."""
    import time

    t0 = elapsed_from or time.perf_counter()
    given = spec
    spec, derived = scenario_defaults(spec, plant)
    plant = plant or build_plant(spec.plant)
    layout = layout or GainLayout(spec, plant.states, plant=plant)
    full = coerce_gains(layout, gains)
    notes = fixed_gain_overrides(spec, layout, full)
    sampled = bool(spec.verify.sampled)
    robust = bool(spec.randomize.params or spec.randomize.delay) if robust is None else robust
    if robust:
        check_randomize(spec, plant)  # a bad randomize entry is refused before any analysis
    sl, rep, lines = (sampled_margins if sampled else spec_margins)(spec, plant, layout, full)
    stable = rep.stability.stable
    req_lines = mimo_lines(lines, stable)
    notes += list(rep.notes)
    rob = None
    if robust and spec.randomize.params:
        rob, worst = _robust_lines(spec, plant, layout, full, sampled, sl.dt, notes)
        req_lines += worst
    elif robust:
        notes.append("robust check requested but the spec randomises no plant parameter")
    notes.append(_loop_note(sl, spec.verify.compute_delay, sampled))
    skipped = [f for f in MIMO_NOT_CHECKED if f != "mks_max" and getattr(spec.requirements, f) is not None]
    if skipped:
        notes.append(f"not judged on several loops: {', '.join(skipped)}")
    nl = nonlinear_check(spec, plant, layout, full) if nonlinear else None
    nl_failed = nl is not None and nl.ran and nl.passed is False
    reasons = _reasons(stable, req_lines, nl_failed, rob)
    verdict = "pass" if not reasons else "fail"
    figs = [loop_figures(f, sl.dt) for f in rep.input_breaks + rep.output_breaks] if stable else []
    return VerificationReport(
        spec_name=spec.name, spec_hash=spec_hash or given.content_hash(), gains=layout.to_dict(full),
        verdict=verdict, reasons=reasons, delay=0.0, sampling_delay=0.0 if sampled else sl.extra_delay,
        sampled=sampled, dt=sl.dt, compute_delay=spec.verify.compute_delay, delay_method="exact",
        stability=_stability(rep, sampled),
        analysis_band=rep.band, loops=figs, robust=rob, nonlinear=nl, requirements=req_lines, notes=notes,
        elapsed_s=time.perf_counter() - t0, mimo=_figures(rep))
