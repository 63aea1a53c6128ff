"""Verification of frozen gains: stability, loop-at-a-time margins, robustness, nonlinear check, verdict.

:func:`verify` (``verify(spec, gains) -> VerificationReport``) is also the public ``gaintune.verify``.

See ``docs/verification.md`` for the conventions (break points, the sampled loop
(default) or the continuous one plus dt/2, computation delay, infinity handling,
exact delay vs Padé, robust sampling).
"""

from gaintune.verification.core import coerce_gains, verify
from gaintune.verification.nonlinear import nonlinear_check
from gaintune.verification.quick import QuickMargins, quick_margins, requirement_violation
from gaintune.verification.report import VerificationReport, format_table

__all__ = [
    "verify",
    "coerce_gains",
    "VerificationReport",
    "format_table",
    "nonlinear_check",
    "quick_margins",
    "requirement_violation",
    "QuickMargins",
]

