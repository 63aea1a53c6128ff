"""RL gain search: SB3 agents on the batched gain-tuning env, returning frozen, verified gains.

``tune`` and ``policy_gains`` load torch and stable-baselines3; they are imported on first
use (PEP 562), so reading a :class:`TuneResult` (the API, the report, exports) stays light.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

from gaintune.search.result import CurvePoint, Progress, TuneResult

__all__ = ["tune", "policy_gains", "TuneResult", "Progress", "CurvePoint"]

if TYPE_CHECKING:  # pragma: no cover
    from gaintune.search.tune import policy_gains, tune


def __getattr__(name: str) -> Any:
    if name in ("tune", "policy_gains"):
        import importlib

        module = importlib.import_module("gaintune.search.tune")  # deferred on purpose: torch + SB3
        # importing the submodule bound the name "tune" to it; bind both names to the functions,
        # as an eager ``from gaintune.search.tune import policy_gains, tune`` would
        globals().update(tune=module.tune, policy_gains=module.policy_gains)
        return globals()[name]
    raise AttributeError(f"module 'gaintune.search' has no attribute {name!r}")
