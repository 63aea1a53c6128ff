"""The verdict of gains at a sample time, and the verification stamp every export format carries.

Verdicts are per sample time
----------------------------
Verification depends on ``dt``: it analyses the sampled loop at the largest scenario
``dt`` (:mod:`gaintune.verification.sampled`; a MIMO payload's loops together,
:mod:`gaintune.verification.mimo_sampled`: the plant ZOH-sampled with its delays, every loop's
discrete law as the C/MATLAB files implement it, the cascades and the decoupler; frequencies up
to ``pi/dt``) and the nonlinear check simulates at the scenarios' ``dt``. A file therefore only
claims the verdict obtained *at the dt it is exported for*:
:func:`verdict_at_dt` returns the stored verdict when ``dt`` is the one the result
was verified at (:func:`verified_dt`, every scenario at that ``dt``), and otherwise
re-verifies on a copy of the spec whose scenarios all run at ``dt``
(:func:`spec_at_dt`). Every format records ``dt``, ``verified_dt`` and, for
failed gains, why they failed.
"""

from __future__ import annotations

import json
from typing import Any

from gaintune.export.common import ExportError, Gains, _check_dt, _fmt_dt, _same_dt, is_mimo
from gaintune.spec import MAX_STEPS, TuningSpec
from gaintune.verification.report import VerificationReport

__all__ = ["verified_dt", "spec_at_dt", "stored_verdict_holds", "verdict_at_dt", "result_verdict_at_dt", "first_reason",
           "verify_if_possible", "stamp_fields"]


def verified_dt(spec: TuningSpec) -> float:
    """The sample time a verification of ``spec`` holds for: the largest scenario ``dt``.

    The sampled-loop analysis (:mod:`gaintune.verification.sampled`) and the analysis band use it.
    """
    return max(sc.resolved_dt for sc in spec.scenarios)


_spec_verified_dt = verified_dt  # for functions whose ``verified_dt`` parameter shadows the name


def spec_at_dt(spec: TuningSpec, dt: float, *, max_steps: int | None = None) -> TuningSpec:
    """A copy of ``spec`` whose scenarios all run at sample time ``dt`` (each keeps its horizon).

    Raises :class:`ExportError` (field ``dt``) when a horizon would need more than
    ``max_steps`` (default and ceiling: :data:`gaintune.spec.MAX_STEPS`) or fewer than 2 steps.
    """
    dt = _check_dt(dt)
    limit = MAX_STEPS if max_steps is None else min(int(max_steps), MAX_STEPS)
    for i, sc in enumerate(spec.scenarios):
        horizon = sc.resolved_horizon
        steps = horizon / dt
        if steps > limit:
            raise ExportError(
                "dt", f"dt = {_fmt_dt(dt)} s needs horizon/dt = {steps:.0f} steps for scenario {sc.name!r} "
                f"(horizon {_fmt_dt(horizon)} s), over the limit of {limit}; export at dt >= "
                f"{_fmt_dt(horizon / limit)} s, or shorten scenarios.{i}.horizon and re-tune")
        if steps < 2:
            raise ExportError(
                "dt", f"dt = {_fmt_dt(dt)} s leaves fewer than 2 samples in the {_fmt_dt(horizon)} s horizon of "
                f"scenario {sc.name!r}; export at dt <= {_fmt_dt(horizon / 2)} s, or lengthen "
                f"scenarios.{i}.horizon and re-tune")
    if all(_same_dt(sc.resolved_dt, dt) for sc in spec.scenarios):
        return spec
    from pydantic import ValidationError

    data = spec.model_dump(mode="json")
    for sc in data["scenarios"]:
        sc["dt"] = dt
    try:
        return TuningSpec.model_validate(data)
    except ValidationError as exc:
        e = exc.errors(include_url=False, include_input=False)[0]
        loc = ".".join(str(p) for p in e["loc"])
        raise ExportError("dt", f"the spec is not valid at dt = {_fmt_dt(dt)} s ({loc}: {e['msg']}); "
                                "choose another dt") from None


def first_reason(report: Any) -> str | None:
    """The first reason of a verification report (dict or :class:`~gaintune.verification.VerificationReport`)."""
    if report is None:
        return None
    reasons = report.get("reasons") if isinstance(report, dict) else getattr(report, "reasons", None)
    return str(reasons[0]) if reasons else None


def stored_verdict_holds(spec: TuningSpec, dt: float, stored: VerificationReport | dict[str, Any] | None) -> bool:
    """Whether the verification ``stored`` for ``spec`` (a report, its JSON form, or None) gives the verdict at ``dt``.

    It does when it has a verdict, was obtained on this very spec (its ``spec_hash`` is
    ``spec.content_hash()``: a result written before a requirement or a default changed, e.g.
    the noise-sensitivity limit, is not vouched for by its old verdict), and ``dt`` is the
    sample time it was obtained at (:func:`verified_dt`), with every scenario at that ``dt``.
    A MIMO report must also have judged the loop ``verify.sampled`` names: a MIMO verdict stored
    from the continuous loop plus dt/2 (what every MIMO verdict was before the exact sampled
    loop, :mod:`gaintune.verification.mimo_sampled`) does not vouch for the sampled loop.
    Otherwise the gains must be re-verified at ``dt`` (:func:`verdict_at_dt` does).
    """
    if stored is None:
        return False
    held = json.loads(stored.model_dump_json()) if isinstance(stored, VerificationReport) else stored
    verdict, spec_hash = held.get("verdict"), held.get("spec_hash")
    if held.get("mimo") is not None and bool(held.get("sampled", False)) != bool(spec.verify.sampled):
        return False
    vdt = verified_dt(spec)
    return (verdict is not None and spec_hash == spec.content_hash() and _same_dt(dt, vdt)
            and all(_same_dt(sc.resolved_dt, vdt) for sc in spec.scenarios))


def verdict_at_dt(
    spec: TuningSpec,
    gains: Gains,
    dt: float | None = None,
    *,
    stored: VerificationReport | dict[str, Any] | None = None,
    robust: bool | None = None,
    max_steps: int | None = None,
) -> tuple[str | None, dict[str, Any] | None]:
    """The verdict of ``gains`` at sample time ``dt`` and the report it comes from (JSON form).

    The verdict is None (unverified, with the reason in the report's ``reasons``) for a MIMO spec
    the verification does not cover (:func:`verify_if_possible`).

    ``stored`` is the verification already done on ``spec`` (a report or its JSON form,
    e.g. ``TuneResult.verification``). It is returned (in JSON form; a dict as it is) when
    it holds at ``dt`` (:func:`stored_verdict_holds`: ``dt`` is the sample time it was
    obtained at, :func:`verified_dt`, with every scenario at that ``dt``). Otherwise
    (another ``dt``, scenarios of mixed ``dt``, or nothing stored) the gains are verified
    with :func:`gaintune.verification.verify` on :func:`spec_at_dt` ``(spec, dt)``; ``robust``
    defaults to what the stored report did (else the spec's default).

    The JSON form is the report's own (``json.loads(report.model_dump_json())``: infinite
    figures as the strings ``"Infinity"``/``"-Infinity"``).

    Raises :class:`ExportError` (field ``dt``) for a ``dt`` the spec cannot run at.
    """
    dt = verified_dt(spec) if dt is None else _check_dt(dt)
    held: dict[str, Any] | None = (json.loads(stored.model_dump_json())
                                   if isinstance(stored, VerificationReport) else stored)
    if held is not None and stored_verdict_holds(spec, dt, held):
        return str(held["verdict"]), held
    target = spec_at_dt(spec, dt, max_steps=max_steps)
    if robust is None and held is not None and "robust" in held:
        robust = held["robust"] is not None  # as the stored verification did
    report, why = verify_if_possible(target, gains, robust=robust)
    if report is None:
        return None, {"verdict": None, "reasons": [why]}
    return report.verdict, json.loads(report.model_dump_json())


def verify_if_possible(spec: TuningSpec, gains: Gains, **kwargs: Any) -> tuple[VerificationReport | None, str | None]:
    """``(report, None)`` from :func:`gaintune.verification.verify`; ``(None, why)`` for a MIMO spec it cannot verify.

    A spec with several plant inputs or a loop graph (:func:`gaintune.export.common.is_mimo`) has no
    verdict until the verification covers it: its gains are then unverified (never accepted, never
    exported as firmware), and ``why`` says so. Any other spec's errors are raised as they are.
    """
    from gaintune.errors import SpecError
    from gaintune.verification import verify

    try:
        return verify(spec, gains, **kwargs), None
    except SpecError as exc:
        if not is_mimo(spec):
            raise
        return None, f"not verified: the verification does not cover this MIMO architecture ({exc.message})"


def result_verdict_at_dt(result: Any, dt: float | None = None, *,
                         max_steps: int | None = None) -> tuple[str | None, dict[str, Any] | None]:
    """:func:`verdict_at_dt` for a :class:`~gaintune.search.result.TuneResult` (its stored verification included)."""
    spec = TuningSpec.model_validate(result.spec)
    return verdict_at_dt(spec, result.gains, dt, stored=result.verification, max_steps=max_steps)


class _Stamp:
    """What a file says about verification: the verdict at the exported ``dt``."""

    def __init__(self, verdict: str | None, dt: float, verified_dt: float | None, reasons: list[str] | None) -> None:
        self.dt = dt
        self.verified_dt = verified_dt
        self.reasons = [str(r) for r in (reasons or [])]
        self.stale = verdict is not None and verified_dt is not None and not _same_dt(dt, verified_dt)
        #: the verdict that holds at ``dt`` (None: not verified at this dt)
        self.verdict = None if self.stale else verdict
        self.held = verdict  # the verdict as given (for the not-at-this-dt message)

    @property
    def accepted(self) -> bool:
        return self.verdict == "pass"

    @property
    def label(self) -> str:
        return self.verdict or "unverified"

    @property
    def reason(self) -> str:
        if self.reasons:
            return self.reasons[0]
        return "no reason recorded in the verification report"

    def banner(self) -> str:
        dt = _fmt_dt(self.dt)
        if self.verdict == "pass":
            return f"verification: PASS at dt = {dt} s"
        if self.verdict == "fail":
            return (f"verification: FAILED at dt = {dt} s - {self.reason} - these gains did not pass verification "
                    "at this sample time; do not deploy")
        if self.stale and self.verified_dt is not None:
            return (f"verification: NOT verified at dt = {dt} s (the verdict '{self.held}' holds at dt = "
                    f"{_fmt_dt(self.verified_dt)} s only) - do not deploy; re-verify or re-tune at this sample time")
        return "verification: not run - these gains are unverified"


def stamp_fields(spec: TuningSpec, gains: Gains, st: _Stamp) -> dict[str, Any]:
    """The head every JSON/YAML/Python export document starts with: the spec, the verdict stamp, the gains."""
    return {
        "spec": spec.name,
        "spec_hash": spec.content_hash(),
        "verdict": st.label,
        "accepted": st.accepted,
        "dt": st.dt,
        "verified_dt": st.verified_dt,
        "reasons": st.reasons if st.verdict == "fail" else [],
        "gains": gains,
    }
