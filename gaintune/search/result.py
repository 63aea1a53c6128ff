"""The result of a gain search: what the library returns and the CLI, API and report show."""

from __future__ import annotations

import json
from typing import Any, Literal

from pydantic import BaseModel, Field, field_serializer, field_validator, model_validator

from gaintune.spec import Gains, ScenarioDefault
from gaintune.verification.report import VerificationReport, load_report

__all__ = ["CurvePoint", "Progress", "Provenance", "SettleInfo", "Diagnosis", "TuneResult", "accepted",
           "report_json"]


def accepted(gains: Gains, verdict: str | None) -> Gains | None:
    """The one rule of acceptance: ``gains`` when their verification verdict is ``pass``, else None.

    Parameters
    ----------
    gains
        The gains that were verified.
    verdict
        Their verdict: "pass", "fail", or None when they were not verified.

    Returns
    -------
    Gains or None
        ``gains`` on a pass; None otherwise.

    Examples
    --------
    >>> g = {"main": {"Kp": 1.0}}
    >>> accepted(g, "pass")
    {'main': {'Kp': 1.0}}
    >>> accepted(g, "fail") is None, accepted(g, None) is None
    (True, True)
    """
    return gains if verdict == "pass" else None


def report_json(v: VerificationReport | None) -> dict[str, Any] | None:
    """A verification report in its own JSON form ("Infinity" strings), in python mode too, so that
    stored results and answers keep one form."""
    return None if v is None else json.loads(v.model_dump_json())


class CurvePoint(BaseModel):
    """Best candidate found after a number of simulations (ranked feasibility first)."""

    sims: int
    best_cost: float = Field(description="Plain cost of the best-ranked candidate so far.")
    feasible: bool = Field(True, description="Whether that candidate met every requirement (search estimate).")
    wall_time: float


class SettleInfo(BaseModel):
    """What the exact boundary step (:func:`~gaintune.evaluation.boundary_exact.onto_boundary_exact`) did."""

    action: Literal["unchanged", "pulled_inside", "pushed_to_boundary", "not_settled"]
    alpha: float = Field(description="Loop-gain scale applied to the binding loop (1 = unchanged).")
    loop: str | None = None
    margin: float = Field(description="Tightest requirement margin / |limit| after settling (>= 0 passes).")
    checks: int = Field(description="Exact verifications run.")


class Diagnosis(BaseModel):
    """What a result means, in words an engineer can act on."""

    status: Literal["pass", "fail", "unverified"]
    summary: str
    binding: str | None = Field(
        None, description="The requirement that decides the verdict (most violated, or tightest).")
    value: float | None = Field(None, description="Its figure for the returned gains.")
    limit: float | None = None
    hints: list[str] = Field(default_factory=list)


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

    ``verification`` is a :class:`~gaintune.verification.VerificationReport`. It is dumped
    (``model_dump`` in either mode, ``model_dump_json``) in the report's own JSON form,
    infinite figures as the strings ``"Infinity"``/``"-Infinity"``, so stored results
    read as plain dicts keep their form. A dict is read back into a report, tolerant of
    older files (:func:`gaintune.verification.report.load_report`: infinities stored as
    ``null``, fields added since).

    Examples
    --------
    Unverified gains are not accepted; :func:`gaintune.search.tuning.tune` returns verified ones.

    >>> r = TuneResult(spec={}, algo="manual", gains={"loop0": {"Kp": 1.0}}, cost=1.0,
    ...                provenance=Provenance(spec_hash="-", seed=0, versions={}))
    >>> r.verdict is None, r.accepted_gains is None
    (True, True)
    >>> TuneResult.model_validate_json(r.model_dump_json()).gains
    {'loop0': {'Kp': 1.0}}
    """

    spec: dict[str, Any] = Field(
        description="The spec as validated (JSON form), every scenario's dt and horizon filled in.")
    scenario_defaults: list[ScenarioDefault] = Field(
        default_factory=list, description="The scenarios whose dt or horizon the spec left out: the values derived "
        "from the plant's time scale, and why (docs/simulation.md).")
    algo: str
    gains: Gains = Field(description="Frozen gains chosen as the answer (best of policy / best seen / refined).")
    gains_source: Literal["policy", "best_seen", "start", "refined"] = Field(
        "best_seen", description="policy output, best gains the agent sampled, the start point (search box centre), "
        "or the local polish."
    )
    policy_gains: Gains | None = Field(None, description="Deterministic policy output for the nominal context.")
    best_seen_gains: Gains | None = None
    cost: float = Field(description="Plain cost of `gains` (the objective, no penalty terms), on the robust draws.")
    violation: float = Field(
        0.0, description="Requirement violation of `gains` by the search's estimate (0 = feasible).")
    rl_cost: float | None = Field(None, description="Plain cost reached by the RL agent alone (before any refinement).")
    rl_feasible: bool | None = Field(
        None, description="Whether the RL agent's own answer met every requirement (search estimate).")
    settle: SettleInfo | None = None
    policy_cost: float | None = None
    metrics: dict[str, dict[str, float | None]] = Field(
        default_factory=dict, description="Per-scenario metrics of `gains` on the nominal plant."
    )
    curve: list[CurvePoint] = Field(default_factory=list)
    sims: int = 0
    setup_sims: int = Field(0, description="Simulations spent before the search: the search box and the reward scale.")
    rl_sims: int = 0
    wall_time: float = 0.0
    stopped: str = Field("budget", description="Why the search stopped: budget, wall_time, converged, cancelled.")
    diverged_episodes: int = Field(0, description="Search episodes whose simulation diverged.")
    tripped_episodes: int = Field(0, description="Search episodes in which the safety monitor tripped.")
    agent_path: str | None = None
    warm_start: str | None = Field(
        None, description="The saved agent this search continued from (learning on), if any.")
    verification: VerificationReport | None = Field(None, description="The verification report, when verified.")
    verification_set_aside: str | None = Field(
        None, description="Why a stored verification was set aside when this result was read: it was for other "
        "gains or another spec (the result was edited after it was verified). The gains are unverified until verified "
        "again.")
    baselines: list[dict[str, Any]] = Field(default_factory=list, description="Baseline results for comparison.")
    diagnosis: Diagnosis | None = None
    provenance: Provenance

    @field_validator("verification", mode="before")
    @classmethod
    def _stored_verification(cls, v: Any) -> Any:
        return load_report(v) if isinstance(v, dict) else v

    @model_validator(mode="after")
    def _verification_belongs_to_these_gains(self) -> TuneResult:
        # A verdict is only ever shown beside the gains and spec it was reached on: a result edited
        # by hand (gains or requirements) keeps its numbers but loses the verdict (report, exports, API).
        why = _verification_mismatch(self.spec, self.gains, self.verification)
        if why is not None:
            # the diagnosis was read from that verdict ("the gains pass verification ..."): it goes too
            self.verification, self.verification_set_aside, self.diagnosis = None, why, None
        return self

    @field_serializer("verification")
    def _verification_json(self, v: VerificationReport | None) -> dict[str, Any] | None:
        return report_json(v)

    @property
    def verdict(self) -> str | None:
        """The verification's verdict ("pass" or "fail"), or None when the gains are unverified."""
        return None if self.verification is None else self.verification.verdict

    @property
    def accepted_gains(self) -> Gains | None:
        """The gains, only when verification passed; otherwise None (:func:`accepted`)."""
        return accepted(self.gains, self.verdict)


def _verification_mismatch(spec: dict[str, Any], gains: Gains, report: VerificationReport | None) -> str | None:
    """Why ``report`` is not the verification of ``gains`` on ``spec`` (None when it is, or when there is none)."""
    if report is None:
        return None
    if report.gains != gains:
        return ("the stored verification was for other gains than this result's (edited after the tune?); "
                "its verdict does not hold for them")
    from gaintune.spec import TuningSpec  # validating the stored spec: the library's layer below, loaded anyway

    try:
        spec_hash = TuningSpec.model_validate(spec).content_hash()
    except ValueError:
        return "the stored spec does not validate, so its verification cannot be vouched for"
    if spec_hash != report.spec_hash:
        return ("the stored verification was for another spec than this result's (edited after the tune, or written "
                "by a gaintune with other defaults); its verdict does not hold for it")
    return None
