"""The shared base of the spec schema: the strict pydantic model, finiteness checks and size limits.

Every spec model derives from :class:`_Model` (unknown keys are errors). The limits
(:data:`MAX_STEPS`, :data:`MAX_ORDER`, :data:`MAX_LOOPS`) live here so the section
modules can enforce them without importing the package that re-exports them.
"""

from __future__ import annotations

import math
from typing import Any

from pydantic import BaseModel, ConfigDict

from gaintune.errors import SpecError

__all__ = ["MAX_STEPS", "MAX_DELAY_STEPS", "MAX_ORDER", "MAX_LOOPS", "MAX_BUDGET", "check_delay_samples"]

#: Largest number of simulation steps (horizon / dt) in one scenario.
MAX_STEPS = 200_000
#: Largest plant delay in samples (delay / dt): the simulator holds that many past inputs per lane,
#: 40 MB each at this limit (a 1e7 s delay at dt = 0.05 s took ~5 GB and 1e300 s overflowed). Larger
#: than MAX_STEPS on purpose: a long delay sampled finely (5 s at dt = 1 us) is a valid verification.
MAX_DELAY_STEPS = 5_000_000
#: Largest plant state dimension accepted.
MAX_ORDER = 20
#: Deepest cascade accepted.
MAX_LOOPS = 6
#: Largest search budget (closed-loop simulations). Far beyond any useful search (a 3,000-sim tune
#: takes seconds; this is hours), it keeps a mistyped budget (1e23) from training for ever and
#: from sizing an off-policy agent's replay buffer in terabytes.
MAX_BUDGET = 10_000_000


class _Model(BaseModel):
    """Base: unknown keys are errors, so typos are caught, not ignored."""

    model_config = ConfigDict(extra="forbid", populate_by_name=True)


def _finite(v: Any, what: str) -> Any:
    if isinstance(v, float) and not math.isfinite(v):
        raise ValueError(f"{what} must be finite, got {v}; use a real number")
    return v


def check_delay_samples(delay: float, dt: float, field: str = "plant.delay") -> None:
    """SpecError when ``delay`` is more than MAX_DELAY_STEPS samples of ``dt``: each simulated lane
    holds that many past inputs. The spec bounds numeric delays when it loads; this catches one
    written as a parameter expression (``delay: "T"`` with ``T: 1e300``) once it has a value."""
    if not delay / dt <= MAX_DELAY_STEPS:
        raise SpecError(field, f"the delay, {delay:g} s, is {delay / dt:.3g} samples at dt = {dt:g} s, over the limit "
                               f"of {MAX_DELAY_STEPS}; give a delay <= {MAX_DELAY_STEPS * dt:g} s or a larger dt")
