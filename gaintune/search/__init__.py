"""RL gain search: SB3 agents on the batched gain-tuning env, returning frozen, verified gains.

Every name loads on first use (PEP 562): ``tune`` and ``policy_gains`` load torch and
stable-baselines3, so reading a :class:`TuneResult` (the API, the report, exports) stays light,
and ``import gaintune.search.algos`` (the CLI's ``--algo`` help) loads neither pydantic nor the spec.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

__all__ = ["tune", "policy_gains", "TuneResult", "Progress", "CurvePoint"]

if TYPE_CHECKING:  # pragma: no cover
    from gaintune.search.result import CurvePoint, Progress, TuneResult
    from gaintune.search.tuning import policy_gains, tune


def __getattr__(name: str) -> Any:
    import importlib

    if name in ("tune", "policy_gains"):
        # deferred on purpose: torch + SB3. The module is gaintune.search.tuning, not .tune: a submodule
        # named tune would become the package's attribute "tune" once imported, hiding the function
        module = importlib.import_module("gaintune.search.tuning")
        globals().update(tune=module.tune, policy_gains=module.policy_gains)
        return globals()[name]
    if name in ("TuneResult", "Progress", "CurvePoint"):
        value = getattr(importlib.import_module("gaintune.search.result"), name)
        globals()[name] = value
        return value
    raise AttributeError(f"module 'gaintune.search' has no attribute {name!r}")
