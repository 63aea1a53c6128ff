"""The verification report: pydantic models (JSON-serialisable) and a plain-text table.

Infinite figures (no phase crossover -> GM = inf, no gain crossover -> PM and
delay margin = inf) are kept as floats in Python and serialise to JSON as the
strings ``"Infinity"`` / ``"-Infinity"`` (pydantic ``ser_json_inf_nan='strings'``);
``VerificationReport.model_validate_json`` reads them back as floats. Figures that
do not exist (e.g. the frequency of a GM that is infinite) are ``null``.
"""

from __future__ import annotations

import math
from typing import Literal

from pydantic import BaseModel, ConfigDict, Field, model_validator

from gaintune.spec import Gains

__all__ = [
    "CrossingModel",
    "LoopFigures",
    "StabilityReport",
    "PadeCheck",
    "WorstCase",
    "WorstSide",
    "RobustReport",
    "NonlinearReport",
    "RequirementLine",
    "MimoDisk",
    "MimoFigures",
    "VerificationReport",
    "load_report",
    "format_table",
]


class _Out(BaseModel):
    model_config = ConfigDict(ser_json_inf_nan="strings", extra="forbid")


class CrossingModel(_Out):
    """One crossing of a loop's Nyquist curve."""

    kind: Literal["gain", "phase"] = Field(description="gain: |L| = 1; phase: L on the negative real axis.")
    omega: float = Field(description="Frequency in rad/s.")
    value: float = Field(
        description="gain crossing: phase margin (deg); phase crossing: gain margin (dB, >0 upper, <0 lower).")
    delay_margin: float | None = Field(
        None, description="Gain crossings: extra delay (s) that reaches -1 at this crossing.")
    binding: bool = Field(False, description="This crossing gives the reported PM or GM.")


class LoopFigures(_Out):
    """Loop-at-a-time figures of one break point."""

    loop: str
    break_point: Literal["controller_output", "plant_input", "plant_output"]
    gm_db: float = Field(
        description="The binding gain margin in dB: min(gm_upper_db, gm_lower_db), the one of smaller |dB| "
        "(gm_binding says which); inf when neither exists.")
    gm_upper_db: float = Field(description="dB by which the loop gain may be increased; inf if no limit.")
    gm_lower_db: float = Field(
        description="dB by which the loop gain may be decreased (conditionally stable loops); inf if none.")
    gm_binding: Literal["increase", "reduction", "none"] = Field(
        description="Which gain margin gm_db is: increase (gm_upper_db), reduction (gm_lower_db), none (both inf).")
    gm_freq: float | None = Field(description="Phase-crossover frequency of the binding GM (rad/s).")
    pm_deg: float = Field(
        description="Phase margin in degrees at the binding gain crossover (the one nearest -180 degrees in phase), "
        "signed as python-control and MATLAB give it: a crossover with phase lead reports a negative PM. The "
        "pm_min_deg requirement judges |pm_deg|, the phase distance from -180 degrees either way.")
    pm_freq: float | None = Field(description="Gain-crossover frequency of the binding PM (rad/s).")
    delay_margin: float = Field(
        description="Extra input delay (s) the loop tolerates: min over gain crossovers of (PM mod 360, in rad) / wc.")
    delay_margin_samples: float | None = Field(
        None,
        description="delay_margin / dt (dt: the analysis sample time): compare with a computation delay in samples.")
    ms: float = Field(description="Sensitivity peak max|1/(1+L)|.")
    ms_freq: float | None = None
    mt: float = Field(description="Complementary-sensitivity peak max|L/(1+L)|.")
    mt_freq: float | None = None
    mks: float | None = Field(
        None, description="Noise sensitivity: peak gain from this loop's measurement noise to the plant input "
        "(SISO: max|C S|), actuator units per measured unit. Null at the plant-input break point and for LQ loops.")
    mks_freq: float | None = None
    mks_max: float | None = Field(
        None, description="The noise-sensitivity limit applied to this loop (requirements.mks_max, 'auto' resolved).")
    disk_alpha: float = Field(description="Balanced (skew 0) disk margin alpha.")
    disk_gm_db: float = Field(description="Disk-based gain margin in dB.")
    disk_pm_deg: float = Field(description="Disk-based phase margin in degrees.")
    disk_freq: float | None = None
    gain_crossovers: list[float] = Field(default_factory=list, description="All gain-crossover frequencies (rad/s).")
    phase_crossovers: list[float] = Field(
        default_factory=list, description="Listed phase-crossover frequencies (rad/s), within the analysis band.")
    crossings: list[CrossingModel] = Field(default_factory=list)
    crossings_omitted: int = Field(
        0, description="Phase crossings in the analysis band not listed (only the 20 of smallest |GM| are kept).")

    @model_validator(mode="before")
    @classmethod
    def _old_reports(cls, data):
        # reports written before gm_binding existed: derive it from the two margins
        if isinstance(data, dict) and "gm_binding" not in data:
            up, lo = (_as_float(data.get(k, math.inf)) for k in ("gm_upper_db", "gm_lower_db"))
            binding = "none" if math.isinf(up) and math.isinf(lo) else ("increase" if up <= lo else "reduction")
            data = {**data, "gm_binding": binding}
        return data


class StabilityReport(_Out):
    """Closed-loop stability of the nominal loop: the verdict, how it was decided, and the poles."""

    stable: bool
    method: Literal["poles", "nyquist"] = Field(
        description="What decided: closed-loop eigenvalues (rational or sampled loop) or the argument principle "
        "(continuous loop with an exact delay; sampled loop with more closed-loop states than are eigen-solved).")
    rhp_count: int = Field(
        description="Unstable closed-loop poles (Re >= 0; sampled loop: |z| >= 1), counted by the deciding method.")
    nyquist_rhp: int | None = Field(None, description="Argument-principle (Nyquist) count (cross-check).")
    poles: list[tuple[float, float]] = Field(
        default_factory=list, description="Closed-loop poles (re, im): s-plane poles of the delay-free or Padé loop "
        "(domain s), or z-plane poles of the sampled loop (domain z), largest first.")
    poles_method: str = Field(
        "exact", description="exact; padeN when the delay is Padé-approximated for the pole list; none when not "
        "computed.")
    max_real_pole: float = Field(
        description="Largest real part of the closed-loop poles; sampled loop: ln(max|z|)/dt, the equivalent s-plane "
        "figure (negative when stable). NaN when the poles are not computed.")
    notes: list[str] = Field(default_factory=list)
    domain: Literal["s", "z"] = Field("s", description="s: continuous-time poles; z: poles of the sampled loop.")
    spectral_radius: float | None = Field(
        None, description="Sampled loop: max |z| over the closed-loop poles (< 1 when stable).")


class PadeCheck(_Out):
    """Adequacy of the Padé approximation, when ``verify.pade_order`` is set."""

    order: int
    adequate: bool
    max_pm_err_deg: float
    max_gm_err_db: float
    max_ms_rel_err: float
    same_stability: bool


class WorstCase(_Out):
    """Worst figure over the robust sample set, per break point, with the sample attaining it."""

    loop: str
    break_point: Literal["controller_output", "plant_input", "plant_output"]
    gm_db: float
    pm_deg: float
    delay_margin: float
    delay_margin_samples: float | None = None
    ms: float
    mt: float
    mks: float | None = None
    disk_alpha: float
    where: dict[str, dict[str, float]] = Field(
        default_factory=dict, description="figure -> sample (parameter values, delay) attaining it.")


class WorstSide(_Out):
    """Worst MIMO-wide figures of one side (plant inputs or outputs) over the robust set, with the draw of each."""

    side: Literal["input", "output"]
    ms: float = Field(description="Peak sigma_max of S at this side.")
    mt: float = Field(description="Peak sigma_max of T at this side.")
    disk_alpha: float = Field(description="Multiloop disk margin alpha at this side.")
    where: dict[str, dict[str, float]] = Field(default_factory=dict, description="figure -> draw attaining it.")


class RobustReport(_Out):
    """The robust check: the sample set (box corners and Monte-Carlo draws), the unstable samples
    and the worst figures per break point."""

    n_samples: int
    n_corners: int
    n_monte_carlo: int
    seed: int
    n_unstable: int
    unstable_samples: list[dict[str, float]] = Field(default_factory=list)
    worst: list[WorstCase] = Field(default_factory=list)
    sides: list[WorstSide] = Field(
        default_factory=list, description="MIMO verdict: the worst MIMO-wide figures per side over the stable draws.")


class NonlinearReport(_Out):
    """The nonlinear simulation check: whether it ran and passed (no divergence, no safety trip)."""

    ran: bool
    passed: bool | None = None
    tripped: bool | None = None
    diverged: bool | None = None
    metrics: dict[str, float] = Field(default_factory=dict)
    note: str = ""


class RequirementLine(_Out):
    """One requirement, at its binding loop/break point/case."""

    requirement: str
    figure: str
    limit: float
    value: float
    margin: float = Field(
        description="Distance to the limit, positive when met (value - limit for minima, limit - value for maxima).")
    passed: bool
    loop: str | None = None
    break_point: str | None = None
    case: Literal["nominal", "worst"] = "nominal"
    draw: dict[str, float] | None = Field(
        None, description="MIMO verdict, worst case: the robust-set draw (parameter values) attaining the value.")
    applicable: bool = Field(
        True, description="False when the closed loop the figure is read on is unstable (nominal case: the nominal "
        "loop; worst case: any sampled plant): margins and sensitivity peaks of an unstable loop mean nothing. "
        "Such a line is neither pass nor fail: passed is false and the instability is the reason.")

    @property
    def status(self) -> Literal["pass", "fail", "n/a"]:
        """``"n/a"`` (not applicable: closed loop unstable), ``"pass"`` or ``"fail"``."""
        return "n/a" if not self.applicable else ("pass" if self.passed else "fail")


class MimoDisk(_Out):
    """Multiloop disk margin of one side: every channel perturbed at once (balanced, skew 0)."""

    alpha: float = Field(description="Guaranteed disk margin (1/mu upper bound).")
    gm_db: float = Field(description="Disk-based gain margin (dB), every channel at once.")
    pm_deg: float = Field(description="Disk-based phase margin (deg), every channel at once.")
    freq: float | None = Field(None, description="Frequency of the smallest margin (rad/s).")


class MimoFigures(_Out):
    """The MIMO figures of a spec with several loops on several inputs (:mod:`gaintune.verification.mimo`);
    the loop-at-a-time figures are in ``VerificationReport.loops`` (break point ``plant_input`` at each
    driven input, ``plant_output`` at each loop's measured output, every other loop closed)."""

    loops: list[str]
    inputs: list[str] = Field(description="The plant input each loop's chain ends at.")
    outputs: list[str] = Field(description="The plant output each loop measures.")
    ms: float = Field(description="MIMO Ms: peak largest singular value of S (the larger of the two sides).")
    ms_input: float
    ms_output: float
    mt: float = Field(description="MIMO Mt: peak largest singular value of T (the larger of the two sides).")
    mt_input: float
    mt_output: float
    disk_input: MimoDisk
    disk_output: MimoDisk
    pade_rhp: int = Field(description="Closed-loop eigenvalues with Re >= 0 of the Padé realisation.")
    nyquist_rhp: int | None = Field(None, description="Generalised Nyquist count on the exact delays.")
    grid_points: int = 0


class VerificationReport(_Out):
    """Result of :func:`gaintune.verification.verify`."""

    spec_name: str
    spec_hash: str
    gains: Gains
    verdict: Literal["pass", "fail"]
    reasons: list[str] = Field(default_factory=list, description="Why the verdict is fail (binding requirement first).")
    delay: float = Field(description="Nominal plant input delay (s).")
    sampling_delay: float = Field(
        description="Continuous analysis (sampled false): dt/2 added to the loop delay for sample-and-hold (largest "
        "scenario dt). Sampled analysis: 0, the hold is modelled exactly.")
    sampled: bool = Field(
        False, description="The sampled loop was analysed (verify.sampled); false: continuous plus dt/2.")
    dt: float | None = Field(None, description="Sample time of the analysis (s): the largest scenario dt.")
    compute_delay: int = Field(0, description="Samples of computation delay included (verify.compute_delay).")
    delay_method: Literal["exact", "pade", "none"]
    pade: PadeCheck | None = None
    operating_point: dict[str, float] = Field(default_factory=dict, description="x0 and u0 of the linearisation.")
    stability: StabilityReport
    analysis_band: tuple[float, float] | None = Field(
        None, description="Frequency band (rad/s) of the nominal analysis. Sampled loop: it ends at the Nyquist "
        "frequency pi/dt (the rest of the unit circle mirrors it). Continuous loop: it ends at 10 x pi/dt when the "
        "frequencies above are proven unable to change any figure or the stability count, else higher; crossings "
        "above it are neither listed nor counted.")
    loops: list[LoopFigures]
    robust: RobustReport | None = None
    nonlinear: NonlinearReport | None = None
    requirements: list[RequirementLine] = Field(default_factory=list)
    notes: list[str] = Field(default_factory=list)
    elapsed_s: float = 0.0
    mimo: MimoFigures | None = Field(
        None, exclude_if=lambda v: v is None, description="Several loops on several inputs: the MIMO figures.")

    @property
    def passed(self) -> bool:
        """Whether the verdict is ``pass``."""
        return self.verdict == "pass"

    @property
    def accepted_gains(self) -> Gains | None:
        """The gains, only when the verdict is ``pass``; else None."""
        return self.gains if self.verdict == "pass" else None


def load_report(data: VerificationReport | dict) -> VerificationReport:
    """A stored report (its JSON form, a dict) as a :class:`VerificationReport`; a report is returned as it is.

    Tolerant of older files: a report dumped with ``model_dump()`` keeps ``inf`` floats,
    which a JSON writer without ``ser_json_inf_nan='strings'`` (e.g. an older
    ``TuneResult.model_dump_json()``) wrote as ``null``. A required float that reads
    back as ``null`` was such an infinity: a figure without crossover is +inf; a
    requirement margin is +inf if the requirement passed, else -inf. Fields added
    since take their defaults. Any other invalid input raises pydantic's ``ValidationError``.
    """
    import json

    from pydantic import ValidationError

    if isinstance(data, VerificationReport):
        return data
    try:
        return VerificationReport.model_validate(data)
    except ValidationError as exc:
        if not isinstance(data, dict):
            raise
        fixed = json.loads(json.dumps(data))
        for e in exc.errors():
            if e["type"] not in ("float_type", "float_parsing"):
                raise
            *path, key = e["loc"]
            node = fixed
            for k in path:
                node = node[k]
            if node[key] is not None:
                raise
            node[key] = "Infinity" if key != "margin" or node.get("passed") else "-Infinity"
        return VerificationReport.model_validate(fixed)


# ------------------------------------------------------------------ table


def _as_float(x) -> float:
    """A JSON figure (a float, or "Infinity"/"-Infinity"/"NaN") as a float."""
    try:
        return float(x)
    except (TypeError, ValueError):
        return math.nan


#: How every view (CLI, API, report) shows a margin or peak of an unstable closed loop.
NOT_APPLICABLE = "not applicable (closed loop unstable)"


def _f(x: float | None, fmt: str = "{:.3g}") -> str:
    if x is None:
        return "-"
    if isinstance(x, float) and math.isinf(x):
        return "inf" if x > 0 else "-inf"
    return fmt.format(x)


def _other_form(gains: dict[str, float]) -> str:
    """`` (ideal: Ti 2.5 s, Td 0.5 s)`` for a parallel PID's gains, `` (parallel: Ki ..)`` for an ideal one."""
    from gaintune.controllers.forms import form_of, other_form_text

    form = form_of(gains)
    if form is None:
        return ""
    other = "ideal" if form == "parallel" else "parallel"
    return f" ({other}: {other_form_text(form, gains, lambda v: _f(v, '{:.4g}'))})"


def _header(report: VerificationReport) -> list[str]:
    """Verdict, gains and the closed loop analysed."""
    lines = [f"verification of {report.spec_name!r}: {report.verdict.upper()}"]
    # the verdict belongs to these gains: print them, so that a table is never read without them
    lines.append("gains: " + "; ".join(
        f"{loop} " + ", ".join(f"{g} {_f(v, '{:.6g}')}" for g, v in gains.items()) + _other_form(gains)
        for loop, gains in report.gains.items()))
    st = report.stability
    cd = f", computation delay {report.compute_delay} sample(s)" if report.compute_delay else ""
    if report.sampled:
        pole = f"max |z| {_f(st.spectral_radius)}" if st.spectral_radius is not None else "poles not listed"
        lines.append(
            f"closed loop: {'stable' if st.stable else 'UNSTABLE'} ({st.method}; {pole}); sampled loop at dt "
            f"{_f(report.dt)} s (ZOH, delay {_f(report.delay)} s exact{cd})"
        )
    else:
        lines.append(
            f"closed loop: {'stable' if st.stable else 'UNSTABLE'} ({st.method}; max Re pole {_f(st.max_real_pole)})"
            f"; delay {_f(report.delay)} s + sampling {_f(report.sampling_delay)} s ({report.delay_method}{cd})"
        )
    return lines


def _loop_table(report: VerificationReport) -> list[str]:
    """The figures per break point (not applicable on an unstable loop)."""
    hdr = (f"{'loop':<12} {'break':<8} {'GM dB':>7} {'GMlo dB':>7} {'PM deg':>7} {'wc':>8} {'DM s':>8} {'DM smp':>7} "
           f"{'Ms':>6} {'Mt':>6} {'Mks':>8} {'disk a':>6}")
    lines = ["", hdr, "-" * len(hdr)]
    stable = report.stability.stable
    if not stable and report.loops:
        lines.append(f"{'(all loops)':<12} {NOT_APPLICABLE}")
    for f in report.loops if stable else []:
        brk = {"controller_output": "ctrl", "plant_output": "y"}.get(f.break_point, "u")
        gm_up, gm_lo = _f(f.gm_upper_db, '{:.2f}'), _f(f.gm_lower_db, '{:.2f}')
        if f.gm_binding == "increase":
            gm_up += "*"
        elif f.gm_binding == "reduction":
            gm_lo += "*"
        lines.append(
            f"{f.loop:<12} {brk:<8} {gm_up:>7} {gm_lo:>7} {_f(f.pm_deg, '{:.1f}'):>7} "
            f"{_f(f.pm_freq):>8} {_f(f.delay_margin):>8} {_f(f.delay_margin_samples, '{:.2f}'):>7} "
            f"{_f(f.ms, '{:.2f}'):>6} {_f(f.mt, '{:.2f}'):>6} {_f(f.mks, '{:.4g}'):>8} {_f(f.disk_alpha, '{:.2f}'):>6}"
        )
    if report.loops:
        lines.append("(* the binding gain margin, gm_db)")
    return lines


def _robust_lines(r: RobustReport) -> list[str]:
    """The robust check's worst figures per break point."""
    lines = ["", f"robust: {r.n_samples} samples ({r.n_corners} corners + {r.n_monte_carlo} draws), "
             f"{r.n_unstable} unstable"]
    for w in r.worst:
        brk = {"controller_output": "ctrl", "plant_output": "y"}.get(w.break_point, "u")
        lines.append(
            f"{w.loop:<12} {brk:<8} worst GM {_f(w.gm_db, '{:.2f}')} dB, PM {_f(w.pm_deg, '{:.1f}')} deg, "
            f"DM {_f(w.delay_margin)} s, Ms {_f(w.ms, '{:.2f}')}, Mt {_f(w.mt, '{:.2f}')}"
            + (f", Mks {_f(w.mks, '{:.4g}')}" if w.mks is not None else "")
        )
    for sd in r.sides:  # the MIMO verdict's worst MIMO-wide figures
        lines.append(f"{'MIMO':<12} {sd.side + 's':<8} worst Ms {_f(sd.ms, '{:.3f}')}, Mt {_f(sd.mt, '{:.3f}')}, "
                     f"disk a {_f(sd.disk_alpha, '{:.3f}')}")
    return lines


def _requirement_table(requirements: list[RequirementLine]) -> list[str]:
    """One line per requirement: PASS, FAIL or N/A, with its figure, limit and margin."""
    lines = ["", "requirements:"]
    for q in requirements:
        where = "/".join(x for x in (q.loop, q.break_point, q.case) if x) if q.loop else q.case
        if q.draw:
            where += " (draw " + ", ".join(f"{k}={v:.4g}" for k, v in q.draw.items()) + ")"
        if not q.applicable:
            lines.append(f"  N/A  {q.requirement:<11} {NOT_APPLICABLE} at {where}")
            continue
        lines.append(
            f"  {'PASS' if q.passed else 'FAIL'} {q.requirement:<11} {q.figure}={_f(q.value, '{:.4g}')} "
            f"limit {_f(q.limit, '{:.4g}')} margin {_f(q.margin, '{:+.4g}')} at {where}"
        )
    return lines


def _mimo_table(report: VerificationReport) -> list[str]:
    """The MIMO-wide figures: Ms, Mt and the multiloop disk margins per side."""
    m = report.mimo
    if m is None:
        return []
    if not report.stability.stable:
        return ["", f"MIMO figures: {NOT_APPLICABLE}"]
    out = ["", f"{'MIMO side':<12} {'Ms':>6} {'Mt':>6} {'disk a':>7} {'disk GM dB':>10} {'disk PM deg':>11}"]
    for side, ms, mt, d in (("inputs", m.ms_input, m.mt_input, m.disk_input),
                            ("outputs", m.ms_output, m.mt_output, m.disk_output)):
        out.append(f"{side:<12} {_f(ms, '{:.3f}'):>6} {_f(mt, '{:.3f}'):>6} {_f(d.alpha, '{:.3f}'):>7} "
                   f"{_f(d.gm_db, '{:.2f}'):>10} {_f(d.pm_deg, '{:.1f}'):>11}")
    return out


def format_table(report: VerificationReport) -> str:
    """Plain-text summary used by ``gaintune verify``.

    Parameters
    ----------
    report
        A verification report.

    Returns
    -------
    str
        Verdict, gains and closed loop; the figures per break point; the robust and nonlinear
        checks; the requirement lines; the reasons and notes.
    """
    lines = _header(report) + _loop_table(report) + _mimo_table(report)
    if report.robust is not None:
        lines += _robust_lines(report.robust)
    if report.nonlinear is not None:
        nl = report.nonlinear
        passed = "not applicable" if nl.passed is None else ("ok" if nl.passed else "FAILED")
        state = "not run" if not nl.ran else passed
        lines += ["", f"nonlinear check: {state}" + (f" ({nl.note})" if nl.note else "")]
    if report.requirements:
        lines += _requirement_table(report.requirements)
    if report.reasons:
        lines += ["", "reasons:"] + [f"  - {r}" for r in report.reasons]
    lines += [f"note: {note}" for note in report.notes]
    return "\n".join(lines)
