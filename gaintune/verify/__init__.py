"""Verification of frozen gains: stability, loop-at-a-time margins, robustness, nonlinear check, verdict.

See ``docs/verification.md`` for the conventions (break points, dt/2 sampling
delay, infinity handling, exact delay vs Padé, robust sampling).
"""

from gaintune.verify.core import coerce_gains, verify
from gaintune.verify.nonlinear import nonlinear_check
from gaintune.verify.quick import QuickMargins, quick_margins, requirement_violation
from gaintune.verify.report import VerificationReport, format_table

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
