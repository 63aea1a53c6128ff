"""The result of a gain search: what the library returns and the CLI, API and report show."""

from __future__ import annotations

from typing import Any, Literal

from pydantic import BaseModel, Field

__all__ = ["CurvePoint", "Progress", "Provenance", "TuneResult"]

Gains = dict[str, dict[str, float]]


class CurvePoint(BaseModel):
    """Best cost found after a number of simulations."""

    sims: int
    best_cost: float
    wall_time: float


class Progress(BaseModel):
    """Progress report sent to callbacks (CLI progress bar, API job progress)."""

    sims: int
    budget: int
    best_cost: float | None = None
    elapsed: float = 0.0
    eta: float | None = Field(None, description="Estimated seconds left.")
    phase: str = "search"


class Provenance(BaseModel):
    """Everything needed to reproduce a result."""

    spec_hash: str
    seed: int
    versions: dict[str, str]
    command: str = ""


class TuneResult(BaseModel):
    """Frozen gains from a search, their cost and metrics, and how they were found.

    ``gains`` are the answer *before* verification; the accepted gains exist only
    when ``verification.verdict == "pass"`` (see :attr:`accepted_gains`).
    """

    spec: dict[str, Any] = Field(description="The spec as validated (JSON form).")
    algo: str
    gains: Gains = Field(description="Frozen gains chosen as the answer (best of policy / best seen / refined).")
    gains_source: Literal["policy", "best_seen", "refined"] = "best_seen"
    policy_gains: Gains | None = Field(None, description="Deterministic policy output for the nominal context.")
    best_seen_gains: Gains | None = None
    cost: float = Field(
        description="Search objective of `gains`: the cost x (1 + margin_weight x requirement penalty); "
        "equal to the plain cost when the requirements are met."
    )
    rl_cost: float | None = Field(None, description="Cost reached by the RL agent alone (before any refinement).")
    policy_cost: float | None = None
    metrics: dict[str, dict[str, float | None]] = Field(
        default_factory=dict, description="Per-scenario metrics of `gains` on the nominal plant."
    )
    curve: list[CurvePoint] = Field(default_factory=list)
    sims: int = 0
    rl_sims: int = 0
    wall_time: float = 0.0
    stopped: str = Field("budget", description="Why the search stopped: budget, wall_time, converged, cancelled.")
    diverged_episodes: int = Field(0, description="Search episodes whose simulation diverged.")
    tripped_episodes: int = Field(0, description="Search episodes in which the safety monitor tripped.")
    agent_path: str | None = None
    verification: dict[str, Any] | None = Field(None, description="VerificationReport as JSON, when verified.")
    baselines: list[dict[str, Any]] = Field(default_factory=list, description="Baseline results for comparison.")
    provenance: Provenance

    @property
    def verdict(self) -> str | None:
        return None if self.verification is None else self.verification.get("verdict")

    @property
    def accepted_gains(self) -> Gains | None:
        """The gains, only when verification passed; otherwise None."""
        return self.gains if self.verdict == "pass" else None
