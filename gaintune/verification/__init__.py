"""Verification of frozen gains: stability, loop-at-a-time margins, robustness, nonlinear check, verdict.

See ``docs/verification.md`` for the conventions (break points, the sampled loop
(default) or the continuous one plus dt/2, computation delay, infinity handling,
exact delay vs Padé, robust sampling).
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


class _CallablePackage(__import__("types").ModuleType):
    """Make ``from gaintune import verify; verify(spec, gains)`` work.

    ``gaintune.verify`` is this package, so the top-level name cannot also be bound to the
    function without breaking ``import gaintune.verify.x``. Calling the package calls
    :func:`gaintune.verify.core.verify` instead (module ``__class__`` assignment, PEP 549's
    documented fallback).
    """

    def __call__(self, *args, **kwargs):
        return verify(*args, **kwargs)


__import__("sys").modules[__name__].__class__ = _CallablePackage
