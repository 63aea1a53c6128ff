"""The verdict gate of ``gaintune export``: the verdict at the exported sample time, and refusing failed gains.

A file exported at the dt the result was verified at carries the stored verdict; at
any other ``--dt`` the gains are re-verified at that dt first
(:func:`gaintune.export.result_verdict_at_dt`). Gains whose verdict there is not PASS
are not exported (exit 3) unless ``--allow-unverified``.
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
    from gaintune.export import first_reason, result_verdict_at_dt, verified_dt
    from gaintune.export.verdict import stored_verdict_holds
    from gaintune.spec import TuningSpec

    spec = TuningSpec.model_validate(result.spec)
    vdt = verified_dt(spec)
    at = vdt if dt is None else dt
    checked = result_verdict_at_dt(result, at)  # ExportError("dt", ...) -> exit 2
    verdict, report = checked
    if not stored_verdict_holds(spec, at, result.verification):  # re-verified at this dt
        was = f"the result was verified at dt = {vdt:g} s" if result.verdict is not None else "the result was not verified"
        err.print(f"re-verified at dt = {at:g} s ({was}): {'PASS' if verdict == 'pass' else 'FAILED'}",
                  markup=False, highlight=False)
    if verdict != "pass" and not allow_unverified:
        reason = first_reason(report) or "no reason recorded in the verification report"
        label = "FAILED verification" if verdict == "fail" else f"are not verified (verdict: {verdict})"
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
