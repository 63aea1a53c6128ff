"""Chattering saturation: an actuator banging between its limits is not a working loop.

A run can stay bounded (not diverged) while the actuator switches from one limit to the
other every few samples (e.g. ±24 V on a motor): the metrics look finite, the hardware
would not survive. :func:`saturation_switches` counts limit-to-limit reversals in an
actuator trace; :func:`is_chattering` flags a run with at least :data:`CHATTER_SWITCHES`.
"""

from __future__ import annotations

import numpy as np

__all__ = ["CHATTER_SWITCHES", "saturation_switches", "is_chattering"]

#: Limit-to-limit reversals in one run that mark chattering.
CHATTER_SWITCHES = 10


def saturation_switches(u: np.ndarray, limits: tuple[float, float] | None, rel_tol: float = 1e-9) -> int:
    """Number of times ``u`` goes from one actuator limit to the other (time in between allowed)."""
    if limits is None:
        return 0
    lo, hi = limits
    tol = rel_tol * max(abs(lo), abs(hi), 1.0)
    u = np.asarray(u, dtype=float)
    side = np.where(u >= hi - tol, 1, np.where(u <= lo + tol, -1, 0))
    sat = side[side != 0]
    return int(np.count_nonzero(sat[1:] != sat[:-1])) if sat.size > 1 else 0


def is_chattering(u: np.ndarray, limits: tuple[float, float] | None) -> bool:
    """True when the actuator trace switches between its limits at least CHATTER_SWITCHES times."""
    return saturation_switches(u, limits) >= CHATTER_SWITCHES
