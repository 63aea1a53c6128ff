"""The ``loops`` and ``actuator`` sections of a spec: the controller cascade and what it drives.

Loops are listed outer first; the innermost drives the actuator. :data:`GAIN_NAMES`
fixes the gain names of every PID type and form, and their order in the action layout.
"""

from __future__ import annotations

import math
from typing import Any, Literal

from pydantic import Field, field_validator, model_validator
from pydantic_core import PydanticCustomError

from gaintune.spec.base import _finite, _Model
from gaintune.spec.names import name_problem

__all__ = ["GAIN_NAMES", "Gains", "GainSpec", "DerivativeFilterSpec", "LoopSpec", "ActuatorSpec"]

#: Gains of a spec's loops, ``{loop name: {gain name: value}}``: what every search answers, verification
#: checks and the exports write (the one definition; ``gaintune.spec`` re-exports it).
Gains = dict[str, dict[str, float]]

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
    def _check(self) -> GainSpec:
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

    name: str | None = Field(
        None,
        description=(
            "Label; default loop0, loop1, ... Printable text on one line (no control characters, no '/*' or '*/'): "
            "it is written into gains.h and gains.m. Names must also differ after every character other than "
            "A-Z, a-z, 0-9 and _ becomes _ and letters are upper-cased, as they form the C macro and MATLAB "
            "variable names (loop 'a b' gives GT_A_B_KP and gt_a_b)."
        ),
    )
    measure: str | None = Field(None, description="Plant output this loop measures; default: the first output.")
    drives: str | None = Field(
        None, exclude_if=lambda v: v is None,
        description="What this loop's output drives: a plant input (drives: R) or the setpoint of another loop "
        "(drives: loop:<name>). Left out on every loop: the loops are one cascade, outer first, the innermost "
        "driving the (only) input.")
    type: Literal["p", "pi", "pd", "pid", "lqr", "lqi"] = "pid"
    form: Literal["parallel", "ideal"] = "parallel"
    gains: dict[str, GainSpec] = Field(
        default_factory=dict,
        description="Per-gain settings keyed by gain name (Kp, Ki, Kd / Ti, Td; LQ: q_<state>, r, q_int or "
        "k_<state>, k_int).",
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
            "the actuator to its output, an outer loop's from its inner loop's setpoint, inner loops closed; "
            "behind a decoupler the actuator is the decoupler's column at the input the chain drives "
            "(tuned entries at their start value). When auto cannot tell (e.g. zero static gain) the spec is "
            "rejected: set direct or reverse. "
            "Bounds are magnitudes either way. Not for LQ loops."
        ),
    )

    @field_validator("name")
    @classmethod
    def _printable_name(cls, v: str | None) -> str | None:
        # the name lands in comments of gains.h / gains.m: a newline or '*/' there would turn it into code
        problem = None if v is None else name_problem(v)
        if problem is not None:
            raise PydanticCustomError("loop_name", "{problem}", {"problem": f"loop name {v!r} {problem}"})
        return v

    @field_validator("b", "c")
    @classmethod
    def _finite_weight(cls, v: float, info: Any) -> float:
        # YAML's .inf passes ge=0; an infinite weight makes inf * 0 = NaN in the loop algebra
        return _finite(v, info.field_name)

    @model_validator(mode="after")
    def _lq_direction(self) -> LoopSpec:
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
        """Whether this is a state-feedback (LQR/LQI) loop."""
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
