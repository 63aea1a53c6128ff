"""The verdict gate of ``gaintune export``: the verdict at the exported sample time, and refusing failed gains.

The gains are always verified again at the exported sample time
(:func:`gaintune.export.verdict_at_dt` with nothing stored): a verdict stored in a result
file is never the authority, since a file can claim one consistently for gains that fail.
Gains whose verdict there is not PASS are not exported (exit 3) unless ``--allow-unverified``.
"""

from __future__ import annotations

import typer

from gaintune.cli.common import EXIT_VERIFY, _close, err

__all__ = ["_checked_at_dt"]


def _checked_at_dt(result, dt: float | None, *, allow_unverified: bool) -> tuple[float, tuple]:
    """The sample time to export ``result`` at and its ``(verdict, report)`` there; exit 3 if not PASS and not allowed.

    Parameters
    ----------
    result : TuneResult
        The result whose gains are exported.
    dt : float or None
        ``--dt``; None for the dt the result was verified at.
    allow_unverified : bool
        ``--allow-unverified``: export gains whose verdict at this dt is not PASS.

    Returns
    -------
    tuple
        ``(at, checked)``: the sample time and the ``(verdict, report)`` pair for
        :func:`gaintune.export.export_result`.
    """
    from gaintune.export import first_reason, verdict_at_dt, verified_dt
    from gaintune.export.verdict import stored_verdict_holds
    from gaintune.spec import TuningSpec

    spec = TuningSpec.model_validate(result.spec)
    vdt = verified_dt(spec)
    at = vdt if dt is None else dt
    # stored=None: verified here whatever the file claims (ExportError("dt", ...) -> exit 2)
    checked = verdict_at_dt(spec, result.gains, at, stored=None)
    verdict, report = checked
    if result.verdict is None:
        was = " (the result was not verified)"
    elif not stored_verdict_holds(spec, at, result.verification):
        was = f" (the result was verified at dt = {vdt:g} s)"
    elif result.verdict != verdict:
        was = f" (the result file claims {result.verdict.upper()}; a stored verdict is not used)"
    else:
        was = ""
    outcome = {"pass": "PASS", "fail": "FAILED", None: "NOT VERIFIED"}.get(verdict, str(verdict))
    err.print(f"re-verified at dt = {at:g} s{was}: {outcome}",
              markup=False, highlight=False)
    if verdict != "pass" and not allow_unverified:
        reason = first_reason(report) or "no reason recorded in the verification report"
        label = "FAILED verification" if verdict == "fail" else "are not verified"
        hint = ("" if _close(at, vdt) or result.verdict is None
                else f" They were verified at dt = {vdt:g} s ({result.verdict}), not at this sample time.")
        err.print(
            f"error: not exporting: at dt = {at:g} s these gains {label}: {reason}.{hint} "
            f"Re-tune at dt = {at:g} s (set scenarios[].dt: {at:g} in the spec and run 'gaintune tune'), "
            "or pass --allow-unverified to export them anyway (the file is then marked FAILED).",
            markup=False, highlight=False,
        )
        raise typer.Exit(EXIT_VERIFY)
    return at, checked
