"""Request and response models (schema families per resource). The spec itself is ``gaintune.spec.TuningSpec``.

:func:`request_defaults_optional` shapes the OpenAPI document for typed clients (see its docstring).
"""

from __future__ import annotations

import copy
import json
from datetime import datetime
from typing import TYPE_CHECKING, Any, Literal

from pydantic import BaseModel, ConfigDict, Field

from gaintune.spec import FiniteNumber, Gains, TuningSpec

if TYPE_CHECKING:
    from fastapi import FastAPI

__all__ = [
    "GainsBody", "JobStatus", "ProgressPublic", "JobResultPublic", "JobPublic", "JobSummary", "JobList",
    "VerifyRequest", "SimulateRequest", "ScenarioTrace", "SimulateResponse",
    "ParamPublic", "SignalPublic", "PlantPublic", "PlantList", "Health", "Ready", "ExportFormat",
    "TunerRange", "TunerValidation", "TunerTraining", "TunerPublic", "TunerList", "TunerQuery", "TunerAnswerPublic",
    "TunerTrainRequest", "JobKind",
    "request_schema_names", "request_defaults_optional", "install_client_openapi",
]

#: A finite number; true/false are refused, not read as 1/0.
FiniteFloat = FiniteNumber
#: Request gains, :data:`gaintune.spec.Gains` with every value finite and not a boolean
GainsBody = dict[str, dict[str, FiniteFloat]]
JobStatus = Literal["queued", "running", "succeeded", "failed", "cancelled"]
#: What a job does: a tuning search (``POST /v1/tune``) or a tuner's training (``POST /v1/tuners``).
JobKind = Literal["tune", "tuner"]
ExportFormat = Literal["json", "yaml", "c", "matlab", "python"]
#: A number, or "Infinity"/"-Infinity"/"NaN" for non-finite figures (JSON has no such numbers).
Num = float | str | None


class _In(BaseModel):
    model_config = ConfigDict(extra="forbid")


# ------------------------------------------------------------------ jobs


class ProgressPublic(BaseModel):
    """Progress of a running search (the last heartbeat's)."""

    sims: int = Field(description="Simulations done.")
    budget: int = Field(description="Simulation budget of the search.")
    fraction: float = Field(description="sims / budget, in [0, 1].")
    best_cost: Num = Field(None, description="Best cost found so far.")
    elapsed: float = Field(0.0, description="Seconds since the search started.")
    eta: float | None = Field(None, description="Estimated seconds left.")
    phase: str = "search"
    episodes: int | None = Field(None, description="A tuner-training job: episodes done (null for a tuning job).")
    episodes_total: int | None = Field(None, description="A tuner-training job: episodes in all.")
    median_ratio: float | None = Field(
        None, description="A tuner-training job: median cost / per-plant optimum on the training curve's plants, "
                          "at the last checkpoint.")


class JobResultPublic(BaseModel):
    """The outcome of a finished search. ``accepted_gains`` is set only when verification passed."""

    verdict: Literal["pass", "fail"] | None = Field(description="Verification verdict (null: not verified).")
    accepted_gains: Gains | None = Field(
        description="The tuned gains, present ONLY when the verification verdict is pass."
    )
    algo: str
    cost: Num
    rl_cost: Num = None
    policy_cost: Num = None
    gains_source: str
    sims: int
    rl_sims: int = 0
    wall_time: float
    stopped: str
    metrics: dict[str, dict[str, Any]] = Field(default_factory=dict, description="Per-scenario metrics of the gains.")
    curve: list[dict[str, Any]] = Field(default_factory=list, description="Training curve: best cost vs simulations.")
    verification: dict[str, Any] | None = Field(None, description="The full VerificationReport.")
    baselines: list[dict[str, Any]] = Field(default_factory=list)
    provenance: dict[str, Any] = Field(description="spec_hash, seed, versions.")
    agent_available: bool = Field(description="GET /v1/jobs/{id}/agent serves the trained SB3 agent.")


class JobSummary(BaseModel):
    """A job's status and progress, without its result."""

    id: str
    kind: JobKind = Field("tune", description="tune: a tuning search; tuner: a tuner's training.")
    status: JobStatus
    spec_name: str
    spec_hash: str
    created_at: datetime
    updated_at: datetime
    started_at: datetime | None = None
    finished_at: datetime | None = None
    progress: ProgressPublic | None = None
    cancel_requested: bool = False
    attempts: int = Field(0, description="Times a worker started this job (>1 after recovery).")
    error: str | None = Field(None, description="Why the job failed, was cancelled or re-queued.")


class JobPublic(JobSummary):
    """A job with its result (once finished) and links to its files."""

    result: JobResultPublic | None = None
    tuner: TunerPublic | None = Field(
        None, description="A finished tuner-training job: the tuner it trained (query it at links.query).")
    links: dict[str, str] = Field(default_factory=dict)


class JobList(BaseModel):
    """One page of jobs, newest first."""

    items: list[JobSummary]
    total: int
    limit: int
    offset: int
    next_offset: int | None = Field(description="Offset of the next page, null on the last page.")


# ---------------------------------------------------------- verify/sim


class VerifyRequest(_In):
    """Gains to verify against a spec."""

    spec: TuningSpec
    gains: GainsBody = Field(description="{loop_name: {gain_name: value}}; fixed gains may be omitted.")
    robust: bool | None = Field(None, description="Check the randomisation set; default: when the spec randomises.")
    nonlinear: bool = Field(True, description="Run the nonlinear simulation check.")


class SimulateRequest(_In):
    """Gains to simulate on a spec's scenarios."""

    spec: TuningSpec
    gains: GainsBody
    max_points: int = Field(2000, ge=2, le=1_000_000, description="Most points per trace (capped by the server).")
    scenarios: list[str] | None = Field(None, max_length=64, description="Scenario names to run; default all.")


class ScenarioTrace(BaseModel):
    """One scenario's decimated traces and metrics."""

    name: str
    dt: float
    n_steps: int
    stride: int = Field(description="Every stride-th sample is returned (plus the last one).")
    t: list[float]
    traces: dict[str, list[Num]] = Field(description="y.<loop>, sp.<loop> per loop, and u.")
    metrics: dict[str, Num | bool]


class SimulateResponse(BaseModel):
    """Traces and metrics of the gains on each scenario run."""

    gains: Gains
    max_points: int
    scenarios: list[ScenarioTrace]


# -------------------------------------------------------------- plants


class ParamPublic(BaseModel):
    """A plant model parameter: nominal value, unit, meaning."""

    value: float
    unit: str
    description: str


class SignalPublic(BaseModel):
    """A plant input or output signal."""

    unit: str
    description: str


class PlantPublic(BaseModel):
    """A built-in plant model."""

    name: str
    title: str
    description: str
    parameters: dict[str, ParamPublic]
    input: SignalPublic
    outputs: dict[str, SignalPublic]
    order: int | None = Field(None, description="State dimension of the nominal plant.")
    plant: dict[str, Any] = Field(description="The plant section, in the spec schema.")
    example_spec: dict[str, Any] = Field(description="A complete spec using this model, tunable as is.")


class PlantList(BaseModel):
    """The built-in plant models."""

    items: list[PlantPublic]


# -------------------------------------------------------------- tuners


class TunerRange(BaseModel):
    """The training range of one context variable (a family's shape as the ratio users know, e.g. L/T)."""

    name: str
    lo: float
    hi: float
    variable: str = Field(description="The context variable's own name (tau for the shape L/(L+T)).")


class TunerValidation(BaseModel):
    """The held-out validation: cost / per-plant optimum, and verdicts."""

    n: int = Field(description="Held-out plants.")
    median_ratio: float | None
    worst_ratio: float | None
    passed: int = Field(description="Answers that passed verification.")


class TunerTraining(BaseModel):
    """The training record."""

    episodes: int
    sims: int
    wall_s: float | None
    resumed: int = Field(description="Times the training resumed from a checkpoint.")


class TunerPublic(BaseModel):
    """A trained tuner: what it answers, how well, how it was trained, its size."""

    name: str
    kind: Literal["family", "spec"] = Field(description="family: a ready-made model family; spec: a spec's family.")
    family: str
    model: str = Field(description="The family's model, or the spec's name.")
    controller: str
    ms_max: float | None
    params: list[str] = Field(description="The plant parameters a query gives.")
    context: list[TunerRange]
    validation: TunerValidation
    training: TunerTraining
    size_kb: float
    version: int = Field(description="Format version of the tuner folder.")


class TunerList(BaseModel):
    """The ready-made tuners, then those the caller's jobs trained (``job:{id}``)."""

    items: list[TunerPublic]


class TunerQuery(_In):
    """A plant to ask a tuner about."""

    params: dict[str, FiniteFloat] = Field(
        default_factory=dict, description="Plant parameter -> value, e.g. {\"K\": 2, \"T\": 60, \"L\": 10} for an "
        "FOTD tuner; a spec tuner's context variables not given keep the spec's nominal values.")
    refine: int = Field(0, ge=0, description="Continue from the answer with at most this many simulations "
                                             "(at most the server's max_tuner_refine).")


class TunerAnswerPublic(BaseModel):
    """A tuner's answer for one plant. ``accepted_gains`` is set only when the verdict is pass."""

    params: dict[str, float]
    context: dict[str, float]
    gains: Gains = Field(description="The answer's gains (diagnostic when the verdict fails).")
    verdict: Literal["pass", "fail"]
    accepted_gains: Gains | None = Field(description="The gains, present ONLY when the verdict is pass.")
    cost: Num
    policy_ms: float = Field(description="The policy's forward pass, milliseconds.")
    elapsed_ms: float = Field(description="The whole answer (policy, boundary move, refining, verification).")
    n_sims: int
    refined_sims: int
    failures: list[str] = Field(default_factory=list,
                                description="Why the verdict is fail (the verification's reasons); empty on pass.")


class TunerTrainRequest(_In):
    """A tuner to train: a spec whose ``randomize`` block is the family, or a ready-made ``family``."""

    spec: TuningSpec | None = Field(None, description="A spec with a randomize block (or give family).")
    family: Literal["fotd", "sotd", "ipd"] | None = Field(None, description="A ready-made family (or give spec).")
    ctype: Literal["pi", "pid"] | None = Field(None, description="With family: the controller. Default pi.")
    ms_max: float | None = Field(None, gt=1.0, le=10.0, allow_inf_nan=False,
                                 description="With family: the Ms limit. Default 1.4.")
    episodes: int | None = Field(None, ge=1, description="Training episodes (default 60,000; at most the server's "
                                                         "max_tuner_episodes).")
    seed: int = Field(0, ge=0, le=2**31 - 1, description="Training seed.")

    def label(self) -> str:
        """The job's name: the spec's, or ``<family>_<ctype>_ms<ms_max>``."""
        if self.spec is not None:
            return self.spec.name
        return f"{self.family}_{self.ctype or 'pi'}_ms{self.ms_max or 1.4:g}"


# ------------------------------------------------------------- health


class Health(BaseModel):
    """Liveness answer."""

    status: Literal["ok"] = "ok"


class Ready(BaseModel):
    """Readiness answer: database, workers and queue."""

    status: Literal["ready", "not_ready"]
    database: bool
    workers_alive: int
    workers_configured: int
    queue_depth: int


JobPublic.model_rebuild()  # its tuner field names a model defined after it


# ------------------------------------------------------ OpenAPI for typed clients

_REF = "#/components/schemas/"


def request_schema_names(doc: dict[str, Any]) -> set[str]:
    """Names of the component schemas reachable from a request body of ``doc``."""
    comps = doc.get("components", {}).get("schemas", {})
    todo: list[Any] = [op.get("requestBody", {}) for item in doc.get("paths", {}).values()
                       for op in item.values() if isinstance(op, dict)]
    seen: set[str] = set()
    while todo:
        node = todo.pop()
        if isinstance(node, dict):
            ref = node.get("$ref")
            if isinstance(ref, str) and ref.startswith(_REF):
                name = ref[len(_REF):]
                if name not in seen and name in comps:
                    seen.add(name)
                    todo.append(comps[name])
            todo.extend(node.values())
        elif isinstance(node, list):
            todo.extend(node)
    return seen


def request_defaults_optional(doc: dict[str, Any]) -> dict[str, Any]:
    """A copy of an OpenAPI document whose request schemas type every defaulted field as optional.

    Code generators read a property's ``default`` as "always present": openapi-typescript
    (``--default-non-nullable``, on by default since v7) types every property of a component
    schema that has a ``default`` as required, whatever ``required`` says, so the README's
    two-line spec would not type-check. In every component schema a request body reaches
    (nested objects and ``anyOf`` branches included), an optional property's ``default``
    therefore moves into its description ("Default: ..."). The server still applies it;
    ``required`` is unchanged. Request and response schemas are disjoint today; a shared one
    would only make the response type more cautious.
    """
    doc = copy.deepcopy(doc)
    comps = doc.get("components", {}).get("schemas", {})
    for name in request_schema_names(doc):
        _move_defaults(comps[name])
    return doc


#: Keywords whose values are data, not schemas.
_DATA_KEYS = frozenset({"default", "const", "enum", "example", "examples"})


def _move_defaults(schema: Any) -> None:
    if isinstance(schema, list):
        for item in schema:
            _move_defaults(item)
        return
    if not isinstance(schema, dict):
        return
    props = schema.get("properties")
    required = set(schema.get("required", ()))
    for field, prop in (props.items() if isinstance(props, dict) else ()):
        if isinstance(prop, dict) and field not in required and "default" in prop:
            value = json.dumps(prop.pop("default"), ensure_ascii=False)
            text = str(prop.get("description", "")).rstrip()
            sep = "" if not text else " " if text[-1] in ".:;!?" else ". "
            prop["description"] = f"{text}{sep}Default: `{value}`."
        _move_defaults(prop)
    for key, value in schema.items():
        if key != "properties" and key not in _DATA_KEYS:
            _move_defaults(value)


def install_client_openapi(app: FastAPI) -> None:
    """Serve :func:`request_defaults_optional` of the app's generated document as ``/openapi.json``."""
    build = app.openapi

    def openapi() -> dict[str, Any]:
        if not app.openapi_schema:
            app.openapi_schema = request_defaults_optional(build())  # build() caches the raw one first
        return app.openapi_schema

    app.openapi = openapi  # type: ignore[method-assign]  # FastAPI's documented way to customise the schema
