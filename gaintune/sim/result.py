"""What a simulator returns per scenario: :class:`SimResult` (metrics, and traces when asked)."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

__all__ = ["SimResult"]


@dataclass
class SimResult:
    """Metrics (each (B,)) for one scenario, and traces when requested."""

    scenario: str
    metrics: dict[str, np.ndarray]
    t: np.ndarray | None = None
    traces: dict[str, np.ndarray] = field(default_factory=dict)
