"""How a tuning run is carried out: the ``randomize``, ``safety``, ``search`` and ``verify`` sections.

Domain randomisation (:class:`DistSpec`, :class:`RandomizeSpec`), the safety monitor run
inside every simulation, the RL search settings with robust scoring, and the
verification settings.
"""

from __future__ import annotations

from typing import Any, Literal

from pydantic import Field, GetJsonSchemaHandler, ValidationInfo, field_validator, model_validator
from pydantic.json_schema import JsonSchemaValue
from pydantic_core import core_schema as cs

from gaintune.spec.base import MAX_BUDGET, _finite, _Model
from gaintune.spec.loops import Gains

__all__ = ["DistSpec", "RandomizeSpec", "SafetySpec", "RobustSpec", "SearchSpec", "VerifySpec"]

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

    @classmethod
    def __get_pydantic_json_schema__(cls, schema: cs.CoreSchema, handler: GetJsonSchemaHandler) -> JsonSchemaValue:
        # Publish the [low, high] shorthand too, so the JSON schema accepts what the model accepts.
        obj = handler.resolve_ref_schema(handler(schema))
        pair = {"type": "array", "prefixItems": [{"type": "number"}, {"type": "number"}], "minItems": 2,
                "maxItems": 2, "description": "[low, high]: shorthand for {dist: uniform, low, high}."}
        return {"title": obj.pop("title", cls.__name__), "description": obj.pop("description", ""),
                "anyOf": [obj, pair]}

    @model_validator(mode="after")
    def _check(self) -> DistSpec:
        for name in ("low", "high", "mean", "std"):
            v = getattr(self, name)
            if v is not None:
                _finite(v, name)
        if self.dist == "normal":
            if self.mean is None or self.std is None:
                raise ValueError("a normal distribution needs mean and std")
        else:
            low, high = self.low, self.high
            if low is None or high is None:
                missing = [k for k, v in (("low", low), ("high", high)) if v is None]
                normal = self.mean is not None or self.std is not None
                other = " (mean and std describe a normal one: set dist: normal)" if normal else ""
                raise ValueError(f"a {self.dist} distribution needs low and high; {' and '.join(missing)} "
                                 f"missing{other}")
            if not low <= high:
                raise ValueError(f"a {self.dist} distribution needs low <= high, got low {low} > high {high}")
            if self.dist == "loguniform" and low <= 0:
                raise ValueError("a loguniform distribution needs low > 0")
        return self

    @property
    def box(self) -> tuple[float, float]:
        """Range used for corners and normalisation (mean +/- 2 std for normal)."""
        # the validator above made sure the numbers of this kind of distribution are there
        if self.dist == "normal" and self.mean is not None and self.std is not None:
            return (self.mean - 2 * self.std, self.mean + 2 * self.std)
        if self.low is None or self.high is None:
            raise ValueError(f"a {self.dist} distribution without low and high has no range")
        return (self.low, self.high)


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

    @field_validator("delay", "actuator_scale")
    @classmethod
    def _physical_range(cls, d: DistSpec | None, info: ValidationInfo) -> DistSpec | None:
        # Draws are clipped where a value has no meaning (a delay below 0, a scale at or below 0). A
        # whole range there would be replaced silently, so it is refused; a normal's far tail is clipped.
        if d is None:
            return d
        strict = info.field_name == "actuator_scale"
        what, lowest = ("mean", d.mean) if d.dist == "normal" else ("low", d.low)
        if lowest is None:  # not reached: DistSpec requires mean (normal) or low (the others)
            return d
        if lowest < 0 or (strict and lowest == 0):
            raise ValueError(f"{what} must be {'> 0' if strict else '>= 0 s'}, got {lowest}")
        return d

    @property
    def active(self) -> bool:
        """Whether anything is randomised."""
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
    fallback_gains: Gains | None = Field(
        None, description="Loop name -> gain dict used after a trip when action is fallback."
    )
    divergence_bound: float = Field(1e6, gt=0, description="|state| beyond this, or NaN/inf, marks divergence.")

    @model_validator(mode="after")
    def _finite_numbers(self) -> SafetySpec:
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
    env: Literal["oneshot", "iterative"] = Field(
        "oneshot", description="Gains chosen in one action, or refined in steps.")
    budget: int = Field(
        3000, ge=10, le=MAX_BUDGET,
        description=f"Hard limit on closed-loop simulations (10 .. {MAX_BUDGET:,}; use wall_time for a time limit).",
    )
    wall_time: float | None = Field(None, gt=0, description="Wall-time limit in seconds.")
    seed: int = Field(
        0, ge=0, le=2**32 - 1, description="Random seed of the search and the draws (0 .. 2^32 - 1, numpy's range).")
    n_envs: int = Field(32, ge=1, le=4096, description="Parallel environments, simulated in one batched call.")
    robust: RobustSpec = Field(default_factory=RobustSpec)
    early_stop_patience: int | None = Field(
        None, ge=1, description="Stop after this many simulations without a 0.1 % improvement."
    )
    repair: bool = Field(
        True,
        description="RL search: move a sampled gain set that violates a requirement (but is stable) onto the "
        "requirement boundary along its loop-gain scale before scoring it (a safety layer; docs/search.md).",
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
