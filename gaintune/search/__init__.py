"""RL gain search: SB3 agents on the batched gain-tuning env, returning frozen, verified gains."""

from gaintune.search.result import CurvePoint, Progress, TuneResult
from gaintune.search.tune import policy_gains, tune

__all__ = ["tune", "policy_gains", "TuneResult", "Progress", "CurvePoint"]
