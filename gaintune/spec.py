"""The tuning-problem schema: one pydantic model shared by the library, CLI and API.

A spec describes a plant, a cascade of control loops wrapped around it, the
actuator, the scenarios a gain set is scored on, the objective, the
requirements that verification enforces, domain randomisation, the safety
monitor and the search settings. Every field has a default, so a minimal spec
is a plant plus one loop::

    plant: {tf: {num: [1], den: "(s+1)^3"}}
    loops: [{type: pid}]

Numeric plant coefficients may be numbers or expressions over ``plant.params``
(parsed by :mod:`gaintune.plants.expr`, never ``eval``-ed), which is how
randomised LTI plants are expressed.
"""

from __future__ import annotations

import json
import math
from pathlib import Path
from typing import Annotated, Any, Literal, Union

import yaml
from pydantic import AfterValidator, BaseModel, ConfigDict, Field, field_validator, model_validator

from gaintune.errors import SpecError
from gaintune.spec_design import DesignSpec, expand_design

__all__ = [
    "MAX_STEPS",
    "MAX_ORDER",
    "MAX_LOOPS",
    "Coef",
    "TransferFunctionSpec",
    "StateSpaceSpec",
    "OdeSpec",
    "ModelRefSpec",
    "PlantSpec",
    "GainSpec",
    "DerivativeFilterSpec",
    "LoopSpec",
    "ActuatorSpec",
    "ProfileSpec",
    "ScenarioSpec",
    "ObjectiveSpec",
    "RequirementsSpec",
    "DistSpec",
    "RandomizeSpec",
    "SafetySpec",
    "RobustSpec",
    "SearchSpec",
    "VerifySpec",
    "TuningSpec",
    "load_spec",
    "GAIN_NAMES",
]

#: Largest number of simulation steps (horizon / dt) in one scenario.
MAX_STEPS = 200_000
#: Largest plant state dimension accepted.
MAX_ORDER = 20
#: Deepest cascade accepted.
MAX_LOOPS = 6

#: A plant coefficient: a number, or an expression over ``plant.params``.
Coef = Union[float, str]


class _Model(BaseModel):
    """Base: unknown keys are errors, so typos are caught, not ignored."""

    model_config = ConfigDict(extra="forbid", populate_by_name=True)


def _finite(v: Any, what: str) -> Any:
    if isinstance(v, float) and not math.isfinite(v):
        raise ValueError(f"{what} must be finite, got {v}; use a real number")
    return v


def _check_coefs(values: Any, what: str) -> Any:
    if isinstance(values, list):
        for item in values:
            if isinstance(item, list):
                _check_coefs(item, what)
            else:
                _finite(item, what)
    return values


def _finite_params(v: dict[str, float]) -> dict[str, float]:
    for k, x in v.items():
        _finite(x, f"parameter {k!r}")
    return v


#: Parameter values by name, all finite.
FiniteParams = Annotated[dict[str, float], AfterValidator(_finite_params)]

# --------------------------------------------------------------------- plant


class TransferFunctionSpec(_Model):
    """A SISO transfer function num(s)/den(s).

    ``num``/``den`` are coefficient lists in descending powers of s (numbers or
    parameter expressions), or one polynomial expression in ``s`` such as
    ``"K"`` and ``"(T*s + 1)^3"``.
    """

    num: list[Coef] | str = Field(description="Numerator, descending powers of s, or a polynomial in s.")
    den: list[Coef] | str = Field(description="Denominator, descending powers of s, or a polynomial in s.")
    output: str = Field("y", description="Name of the single output.")

    @field_validator("num", "den")
    @classmethod
    def _coefs(cls, v: Any) -> Any:
        if isinstance(v, list) and not v:
            raise ValueError("needs at least one coefficient")
        return _check_coefs(v, "coefficient")


class StateSpaceSpec(_Model):
    """dx/dt = A x + B u, y = C x + D u with one actuator input and named outputs."""

    A: list[list[Coef]]
    B: list[list[Coef]]
    C: list[list[Coef]]
    D: list[list[Coef]] | None = Field(None, description="Defaults to zeros.")
    outputs: list[str] | None = Field(None, description="One name per row of C; default y0, y1, ...")
    states: list[str] | None = Field(None, description="One name per state; default x0, x1, ...")

    @field_validator("A", "B", "C", "D")
    @classmethod
    def _coefs(cls, v: Any) -> Any:
        return _check_coefs(v, "matrix entry")


class OdeSpec(_Model):
    """A nonlinear plant dx/dt = f(x, u, p), y = h(x, u, p) written as expressions."""

    states: list[str] = Field(min_length=1)
    input: str = Field("u", description="Name of the actuator input in the expressions.")
    rhs: dict[str, str] = Field(description="d(state)/dt expression for every state.")
    outputs: dict[str, str] = Field(description="Output name -> expression.")
    x0: dict[str, Coef] = Field(default_factory=dict, description="Operating-point state (default 0, or solved).")
    u0: Coef | None = Field(None, description="Operating-point input; solved from x0 for equilibrium if omitted.")

    @model_validator(mode="after")
    def _rhs_matches_states(self) -> "OdeSpec":
        missing = [s for s in self.states if s not in self.rhs]
        extra = [s for s in self.rhs if s not in self.states]
        if missing:
            raise ValueError(f"rhs has no expression for state(s) {missing}; add 'rhs: {{{missing[0]}: ...}}'")
        if extra:
            raise ValueError(f"rhs names unknown state(s) {extra}; declare them in 'states'")
        if not self.outputs:
            raise ValueError("outputs must name at least one output expression")
        return self


class ModelRefSpec(_Model):
    """A built-in model from ``models/`` with parameter overrides."""

    name: str = Field(description="File stem in models/, e.g. 'dc_motor'.")
    params: FiniteParams = Field(default_factory=dict, description="Overrides of the model's nominal parameters.")


class PlantSpec(_Model):
    """Exactly one of ``tf``, ``ss``, ``ode`` or ``model``, plus delay and parameters."""

    tf: TransferFunctionSpec | None = None
    ss: StateSpaceSpec | None = None
    ode: OdeSpec | None = None
    model: ModelRefSpec | str | None = None
    delay: Coef | None = Field(
        None, description="Input/output time delay in seconds (number or parameter expression); default 0, or the model's."
    )
    params: FiniteParams = Field(default_factory=dict, description="Nominal parameter values.")

    @field_validator("delay")
    @classmethod
    def _delay(cls, v: Coef | None) -> Coef | None:
        if isinstance(v, float):
            _finite(v, "delay")
            if v < 0:
                raise ValueError(f"delay must be >= 0 seconds, got {v}")
        return v

    @model_validator(mode="after")
    def _exactly_one(self) -> "PlantSpec":
        given = [k for k in ("tf", "ss", "ode", "model") if getattr(self, k) is not None]
        if len(given) != 1:
            raise ValueError(
                f"plant needs exactly one of tf, ss, ode or model; got {given or 'none'}"
            )
        if isinstance(self.model, str):
            self.model = ModelRefSpec(name=self.model)
        return self


# --------------------------------------------------------------------- loops

#: Gain names per controller type and form. Order defines the action layout.
GAIN_NAMES: dict[tuple[str, str], tuple[str, ...]] = {
    ("p", "parallel"): ("Kp",),
    ("pi", "parallel"): ("Kp", "Ki"),
    ("pd", "parallel"): ("Kp", "Kd"),
    ("pid", "parallel"): ("Kp", "Ki", "Kd"),
    ("p", "ideal"): ("Kp",),
    ("pi", "ideal"): ("Kp", "Ti"),
    ("pd", "ideal"): ("Kp", "Td"),
    ("pid", "ideal"): ("Kp", "Ti", "Td"),
}


class GainSpec(_Model):
    """One controller gain: tuned within log-scale bounds, or fixed at ``value``."""

    tune: bool = True
    value: float | None = Field(None, description="Fixed value (tune: false) or initial guess.")
    bounds: tuple[float, float] | None = Field(
        None, description="Positive [low, high] searched on a log scale; default: derived from a classical rule."
    )

    @model_validator(mode="after")
    def _check(self) -> "GainSpec":
        if self.value is not None:
            _finite(self.value, "gain value")
        if not self.tune and self.value is None:
            raise ValueError("a fixed gain (tune: false) needs a value")
        if self.bounds is not None:
            lo, hi = self.bounds
            if not (math.isfinite(lo) and math.isfinite(hi)) or lo <= 0 or hi <= lo:
                raise ValueError(f"bounds must satisfy 0 < low < high (log scale), got {list(self.bounds)}")
        return self


class DerivativeFilterSpec(_Model):
    """First-order derivative filter: Tf fixed in seconds, or Tf = Td / N."""

    N: float | None = Field(10.0, gt=0, description="Filter divisor: Tf = Td/N (Td = Kd/Kp).")
    Tf: float | None = Field(None, gt=0, description="Fixed filter time constant in seconds; overrides N.")


class LoopSpec(_Model):
    """One loop of a cascade. Loops are listed outer first; the innermost drives the actuator."""

    name: str | None = Field(None, description="Label; default loop0, loop1, ...")
    measure: str | None = Field(None, description="Plant output this loop measures; default: the first output.")
    type: Literal["p", "pi", "pd", "pid", "lqr", "lqi"] = "pid"
    form: Literal["parallel", "ideal"] = "parallel"
    gains: dict[str, GainSpec] = Field(
        default_factory=dict,
        description="Per-gain settings keyed by gain name (Kp, Ki, Kd / Ti, Td; LQ: q_<state>, r, q_int or k_<state>, k_int).",
    )
    filter: DerivativeFilterSpec = Field(default_factory=DerivativeFilterSpec)
    b: float = Field(1.0, ge=0, description="Setpoint weight on the proportional term.")
    c: float = Field(0.0, ge=0, description="Setpoint weight on the derivative term (0 = derivative on measurement).")
    anti_windup: Literal["clamping", "back_calculation", "none"] = "clamping"
    tracking_time: float | None = Field(
        None, gt=0, description="Back-calculation tracking time Tt in s; default sqrt(Ti*Td), or Ti for PI."
    )
    output_limits: tuple[float, float] | None = Field(
        None, description="Saturation of this loop's output (inner setpoint); the innermost loop uses the actuator."
    )
    lq_mode: Literal["weights", "gains"] = Field(
        "weights", description="LQ loops: tune diagonal Q/R weights (K from control.lqr) or K entries directly."
    )
    direction: Literal["auto", "direct", "reverse"] = Field(
        "auto",
        description=(
            "Controller action. direct: positive gains, for a path whose gain is positive (the output rises "
            "when this loop's output rises); reverse: Kp, Ki, Kd all negative (ideal form: Kp negative, Ti, Td "
            "positive), for a negative path gain; auto: from the sign of the static gain of the path this loop "
            "controls at the nominal operating point (integrating path: of its velocity gain; open-loop unstable "
            "with an odd number of real unstable poles: the opposite sign). The innermost loop's path runs from "
            "the actuator to its output, an outer loop's from its inner loop's setpoint, inner loops closed. "
            "When auto cannot tell (e.g. zero static gain) the spec is rejected: set direct or reverse. "
            "Bounds are magnitudes either way. Not for LQ loops."
        ),
    )

    @model_validator(mode="after")
    def _lq_direction(self) -> "LoopSpec":
        if self.type in ("lqr", "lqi") and self.direction == "reverse":
            raise ValueError(
                f"direction: reverse does not apply to an {self.type} loop (state feedback has no controller sign; "
                "its gains K take any sign); remove direction or set it to auto"
            )
        return self

    @field_validator("output_limits")
    @classmethod
    def _limits(cls, v: tuple[float, float] | None) -> tuple[float, float] | None:
        if v is not None and not (v[0] < v[1]):
            raise ValueError(f"output_limits must be [low, high] with low < high, got {list(v)}")
        return v

    @property
    def is_lq(self) -> bool:
        return self.type in ("lqr", "lqi")


class ActuatorSpec(_Model):
    """Actuator saturation and rate limit (None = unlimited)."""

    limits: tuple[float, float] | None = Field(None, description="[low, high] actuator saturation.")
    rate_limit: float | None = Field(None, gt=0, description="Maximum |du/dt| in units per second.")
    safe_value: float = Field(0.0, description="Actuator value the safety monitor applies when it trips.")

    @field_validator("limits")
    @classmethod
    def _limits(cls, v: tuple[float, float] | None) -> tuple[float, float] | None:
        if v is not None:
            _finite(v[0], "limits")
            _finite(v[1], "limits")
            if not v[0] < v[1]:
                raise ValueError(f"limits must be [low, high] with low < high, got {list(v)}")
        return v

    @field_validator("safe_value", "rate_limit")
    @classmethod
    def _finite_value(cls, v: float | None) -> float | None:
        return v if v is None else _finite(v, "value")


# ----------------------------------------------------------------- scenarios


class ProfileSpec(_Model):
    """A reference or disturbance signal added to the operating point.

    step: ``amplitude`` from ``time``; ramp: ``slope`` from ``time``;
    impulse: a pulse of area ``amplitude`` and width ``width`` (default one
    sample); sequence: piecewise-constant ``points`` [[t, value], ...].
    """

    kind: Literal["step", "ramp", "impulse", "sequence", "none"] = "step"
    amplitude: float = 1.0
    time: float = Field(0.0, ge=0)
    slope: float = 1.0
    width: float | None = Field(None, gt=0)
    points: list[tuple[float, float]] = Field(default_factory=list)

    @field_validator("points")
    @classmethod
    def _finite_points(cls, v: list[tuple[float, float]]) -> list[tuple[float, float]]:
        for t, x in v:
            _finite(t, "sequence time")
            _finite(x, "sequence value")
        return v

    @model_validator(mode="after")
    def _check(self) -> "ProfileSpec":
        for x in (self.amplitude, self.time, self.slope):
            _finite(x, "profile value")
        if self.kind == "sequence":
            if not self.points:
                raise ValueError("a sequence profile needs points: [[t0, v0], [t1, v1], ...]")
            times = [p[0] for p in self.points]
            if any(t < 0 for t in times) or times != sorted(times):
                raise ValueError("sequence points must have non-negative, increasing times")
        return self


class DisturbanceSpec(ProfileSpec):
    """A load disturbance; ``entry`` says where it enters the plant."""

    kind: Literal["step", "ramp", "impulse", "sequence", "none"] = "none"
    entry: Literal["input", "output"] = "input"


class ScenarioSpec(_Model):
    """One simulated experiment. Several scenarios are summed (by weight) into one cost."""

    name: str = "nominal"
    dt: float = Field(0.01, description="Sample time in seconds.")
    horizon: float = Field(20.0, description="Simulated time in seconds.")
    reference: ProfileSpec = Field(default_factory=ProfileSpec)
    disturbance: DisturbanceSpec = Field(default_factory=DisturbanceSpec)
    noise_std: float = Field(0.0, ge=0, description="Std of white measurement noise on every measured output.")
    weight: float = Field(1.0, ge=0, description="Weight of this scenario in the combined cost.")

    @model_validator(mode="after")
    def _check(self) -> "ScenarioSpec":
        _finite(self.dt, "dt")
        _finite(self.horizon, "horizon")
        if self.dt <= 0:
            raise ValueError(f"dt must be > 0 seconds, got {self.dt}")
        if self.horizon <= 0:
            raise ValueError(f"horizon must be > 0 seconds, got {self.horizon}")
        steps = self.horizon / self.dt
        if steps > MAX_STEPS:
            raise ValueError(
                f"horizon/dt = {steps:.0f} steps exceeds the limit of {MAX_STEPS}; raise dt or shorten the horizon"
            )
        if steps < 2:
            raise ValueError("horizon must cover at least 2 samples of dt")
        return self

    @property
    def n_steps(self) -> int:
        return int(round(self.horizon / self.dt))


# ------------------------------------------------------- objective and reqs


_REMOVED_OBJECTIVE_FIELDS = ("margin_weight", "divergence_penalty", "trip_penalty")


class ObjectiveSpec(_Model):
    """cost = performance + effort_weight*int(u^2) + tv_weight*TV(u) + penalties.

    The requirements are not part of the cost: every search treats them as hard constraints.
    """

    @model_validator(mode="before")
    @classmethod
    def _removed_margin_weight(cls, data: Any) -> Any:
        # margin_weight, divergence_penalty and trip_penalty (soft reward terms) were removed when
        # requirements, stability and trips became hard constraints; specs and stored results that
        # still carry them load unchanged.
        if isinstance(data, dict):
            data = {k: v for k, v in data.items() if k not in _REMOVED_OBJECTIVE_FIELDS}
        return data

    measure: Literal["iae", "ise", "itae"] = "iae"
    effort_weight: float = Field(0.01, ge=0, description="Weight on the integral of (u - u0)^2.")
    tv_weight: float = Field(0.0, ge=0, description="Weight on the total variation of u.")
    overshoot_limit: float = Field(100.0, ge=0, description="Overshoot (%) allowed before the penalty starts.")
    overshoot_weight: float = Field(0.0, ge=0, description="Penalty per % of overshoot above the limit.")
    settling_weight: float = Field(0.0, ge=0, description="Penalty per second of 2 % settling time.")


class RequirementsSpec(_Model):
    """Limits that verification enforces per loop (None = not required)."""

    gm_min_db: float | None = Field(6.0, description="Minimum gain margin in dB.")
    pm_min_deg: float | None = Field(45.0, description="Minimum phase margin in degrees.")
    dm_min: float | None = Field(None, ge=0, description="Minimum delay margin in seconds.")
    ms_max: float | None = Field(2.0, gt=1, description="Maximum sensitivity peak.")
    mt_max: float | None = Field(None, gt=0, description="Maximum complementary-sensitivity peak.")


# ------------------------------------------------------------- randomising


class DistSpec(_Model):
    """A scalar distribution drawn once per episode."""

    dist: Literal["uniform", "loguniform", "normal"] = "uniform"
    low: float | None = None
    high: float | None = None
    mean: float | None = None
    std: float | None = Field(None, ge=0)

    @model_validator(mode="before")
    @classmethod
    def _shorthand(cls, v: Any) -> Any:
        # [low, high] is shorthand for a uniform range.
        if isinstance(v, (list, tuple)) and len(v) == 2:
            return {"dist": "uniform", "low": v[0], "high": v[1]}
        return v

    @model_validator(mode="after")
    def _check(self) -> "DistSpec":
        for name in ("low", "high", "mean", "std"):
            v = getattr(self, name)
            if v is not None:
                _finite(v, name)
        if self.dist == "normal":
            if self.mean is None or self.std is None:
                raise ValueError("a normal distribution needs mean and std")
        else:
            if self.low is None or self.high is None or not self.low <= self.high:
                raise ValueError(f"a {self.dist} distribution needs low <= high")
            if self.dist == "loguniform" and self.low <= 0:
                raise ValueError("a loguniform distribution needs low > 0")
        return self

    @property
    def box(self) -> tuple[float, float]:
        """Range used for corners and normalisation (mean +/- 2 std for normal)."""
        if self.dist == "normal":
            return (self.mean - 2 * self.std, self.mean + 2 * self.std)  # type: ignore[operator]
        return (self.low, self.high)  # type: ignore[return-value]


class RandomizeSpec(_Model):
    """Domain randomisation: what is drawn anew each episode."""

    params: dict[str, DistSpec] = Field(default_factory=dict, description="Plant parameter -> distribution.")
    delay: DistSpec | None = Field(None, description="Plant delay in seconds.")
    actuator_scale: DistSpec | None = Field(None, description="Factor on both actuator limits.")
    reference_kinds: list[Literal["step", "ramp", "impulse"]] = Field(
        default_factory=list, description="Reference kinds drawn uniformly (empty: keep the scenario's)."
    )
    reference_amplitude: DistSpec | None = None
    disturbance_size: DistSpec | None = None
    disturbance_time: DistSpec | None = None

    @property
    def active(self) -> bool:
        return bool(
            self.params
            or self.delay
            or self.actuator_scale
            or self.reference_kinds
            or self.reference_amplitude
            or self.disturbance_size
            or self.disturbance_time
        )


class SafetySpec(_Model):
    """Software safety monitor, run inside every simulation."""

    max_abs_error: float | None = Field(None, gt=0, description="Trip when |r - y| of the outer loop exceeds this.")
    max_abs_output: float | None = Field(None, gt=0, description="Trip when any measured |y| exceeds this.")
    state_bounds: dict[str, float] = Field(default_factory=dict, description="State name -> max |x| allowed.")
    action: Literal["hold", "fallback"] = Field(
        "hold", description="hold: actuator to actuator.safe_value; fallback: switch to fallback_gains."
    )
    fallback_gains: dict[str, dict[str, float]] | None = Field(
        None, description="Loop name -> gain dict used after a trip when action is fallback."
    )
    divergence_bound: float = Field(1e6, gt=0, description="|state| beyond this, or NaN/inf, marks divergence.")

    @model_validator(mode="after")
    def _finite_numbers(self) -> "SafetySpec":
        for k, v in self.state_bounds.items():
            _finite(v, f"state bound {k!r}")
            if v <= 0:
                raise ValueError(f"state bound {k!r} must be > 0, got {v}")
        for loop, gains in (self.fallback_gains or {}).items():
            for g, v in gains.items():
                _finite(v, f"fallback gain {loop}.{g}")
        for name in ("max_abs_error", "max_abs_output", "divergence_bound"):
            _finite(getattr(self, name) or 1.0, name)
        return self


class RobustSpec(_Model):
    """Score one gain set over K sampled plants/scenarios."""

    samples: int = Field(1, ge=1, le=256, description="K draws per gain evaluation.")
    aggregate: Literal["mean", "worst", "cvar"] = "mean"
    alpha: float = Field(0.2, gt=0, le=1, description="CVaR tail fraction.")


class SearchSpec(_Model):
    """RL gain search settings."""

    algo: Literal["ppo", "sac", "td3", "a2c", "ddpg"] = "ppo"
    env: Literal["oneshot", "iterative"] = Field("oneshot", description="Gains chosen in one action, or refined in steps.")
    budget: int = Field(3000, ge=10, description="Hard limit on closed-loop simulations.")
    wall_time: float | None = Field(None, gt=0, description="Wall-time limit in seconds.")
    seed: int = 0
    n_envs: int = Field(32, ge=1, le=4096, description="Parallel environments, simulated in one batched call.")
    robust: RobustSpec = Field(default_factory=RobustSpec)
    early_stop_patience: int | None = Field(
        None, ge=1, description="Stop after this many simulations without a 0.1 % improvement."
    )
    refine: bool = Field(True, description="Polish the RL answer with a local search (reported separately).")


class VerifySpec(_Model):
    """Verification settings."""

    pade_order: int | None = Field(None, ge=1, le=20, description="None: exact e^{-jwT}; else this Pade order.")
    robust_samples: int = Field(16, ge=0, le=1000, description="Monte-Carlo draws besides the box corners.")
    n_freq: int = Field(2000, ge=100, le=100000, description="Frequency grid points.")
    sampled: bool = Field(
        True,
        description="Analyse the sampled loop: the plant discretised as the simulator steps it (ZOH with the delay "
        "exact) at the largest scenario dt, the controllers' discrete laws, z = e^{jw dt} up to pi/dt. "
        "false: continuous loop plus dt/2 of delay (the older approximation).",
    )
    compute_delay: int = Field(
        0, ge=0, le=1000,
        description="Samples of computation delay between controller output and plant input: z^-n in the sampled "
        "loop, n*dt of extra delay in the continuous one (also simulated by the nonlinear check).",
    )


# ------------------------------------------------------------------ the spec


class TuningSpec(_Model):
    """A complete gain-tuning problem."""

    name: str = "untitled"
    description: str = ""
    plant: PlantSpec
    loops: list[LoopSpec] = Field(min_length=1, max_length=MAX_LOOPS)
    actuator: ActuatorSpec = Field(default_factory=ActuatorSpec)
    scenarios: list[ScenarioSpec] = Field(default_factory=lambda: [ScenarioSpec()], min_length=1)
    objective: ObjectiveSpec = Field(default_factory=ObjectiveSpec)
    requirements: RequirementsSpec = Field(default_factory=RequirementsSpec)
    randomize: RandomizeSpec = Field(default_factory=RandomizeSpec)
    safety: SafetySpec = Field(default_factory=SafetySpec)
    search: SearchSpec = Field(default_factory=SearchSpec)
    verify: VerifySpec = Field(default_factory=VerifySpec)
    design: DesignSpec | None = Field(
        None, description="pidtune-style shortcut: phase margin, focus; expanded into requirements and scenarios."
    )

    @model_validator(mode="before")
    @classmethod
    def _design_shortcut(cls, data: Any) -> Any:
        return expand_design(data) if isinstance(data, dict) else data

    @model_validator(mode="before")
    @classmethod
    def _single_scenario(cls, data: Any) -> Any:
        # Accept `scenario: {...}` as shorthand for a one-element `scenarios` list.
        if isinstance(data, dict) and "scenario" in data:
            data = dict(data)
            if "scenarios" in data:
                raise ValueError("give either 'scenario' or 'scenarios', not both")
            data["scenarios"] = [data.pop("scenario")]
        return data

    @model_validator(mode="after")
    def _loop_names(self) -> "TuningSpec":
        for i, loop in enumerate(self.loops):
            if loop.name is None:
                loop.name = f"loop{i}"
        names = [lp.name for lp in self.loops]
        if len(set(names)) != len(names):
            raise ValueError(f"loop names must be unique, got {names}")
        for i, loop in enumerate(self.loops):
            if loop.is_lq and i != len(self.loops) - 1:
                raise ValueError(f"loops[{i}]: an {loop.type} loop must be the innermost (last) loop")
        return self

    def content_hash(self) -> str:
        """Stable SHA-256 of the canonical JSON of this spec (provenance)."""
        import hashlib

        return hashlib.sha256(self.model_dump_json().encode()).hexdigest()


def load_spec(source: str | Path | dict[str, Any]) -> TuningSpec:
    """Load and validate a spec from a YAML/JSON file path, a YAML/JSON string or a dict.

    Raises
    ------
    SpecError
        When the file cannot be read or parsed, or the content is not a mapping.
    pydantic.ValidationError
        When a field is invalid (the message names the field).
    """
    if isinstance(source, dict):
        data = source
    else:
        text: str
        path = Path(source) if not (isinstance(source, str) and "\n" in source) else None
        if path is not None and path.suffix.lower() in (".yaml", ".yml", ".json") :
            try:
                text = path.read_text()
            except OSError as exc:
                raise SpecError("spec", f"cannot read {path}: {exc.strerror}") from None
        else:
            text = str(source)
        try:
            data = json.loads(text) if text.lstrip().startswith("{") else yaml.safe_load(text)
        except (yaml.YAMLError, json.JSONDecodeError) as exc:
            raise SpecError("spec", f"not valid YAML/JSON: {exc}") from None
    if not isinstance(data, dict):
        raise SpecError("spec", "must be a mapping with at least 'plant' and 'loops'")
    return TuningSpec.model_validate(data)
