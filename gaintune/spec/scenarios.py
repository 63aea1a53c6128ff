"""What a gain set is scored on: the ``scenarios``, the ``objective`` and the ``requirements``.

Scenarios are the simulated experiments (reference and disturbance profiles), the
objective turns their traces into one cost, and the requirements are the hard limits
that verification enforces per loop.
"""

from __future__ import annotations

import math
from typing import Any, Literal

from pydantic import Field, field_validator, model_validator

from gaintune.spec.backoff import BackoffSpec
from gaintune.spec.base import MAX_STEPS, _finite, _Model

__all__ = ["ProfileSpec", "ReferenceSpec", "DisturbanceSpec", "ScenarioSpec", "ScenarioDefault", "ObjectiveSpec",
           "RequirementsSpec"]


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
    def _check(self) -> ProfileSpec:
        for x in (self.amplitude, self.time, self.slope):
            _finite(x, "profile value")
        if self.kind == "sequence":
            if not self.points:
                raise ValueError("a sequence profile needs points: [[t0, v0], [t1, v1], ...]")
            times = [p[0] for p in self.points]
            if any(t < 0 for t in times) or times != sorted(times):
                raise ValueError("sequence points must have non-negative, increasing times")
        return self


class ReferenceSpec(ProfileSpec):
    """The reference profile; with several chains of loops, ``loop`` names the chain it steps."""

    loop: str | None = Field(
        None, exclude_if=lambda v: v is None,
        description="The outer loop whose setpoint follows this profile (several chains: the others hold "
        "their operating point); default: the first loop.")


class DisturbanceSpec(ProfileSpec):
    """A load disturbance; ``entry`` says where it enters the plant."""

    kind: Literal["step", "ramp", "impulse", "sequence", "none"] = "none"
    entry: Literal["input", "output"] = "input"
    input: str | None = Field(
        None, exclude_if=lambda v: v is None,
        description="Plants with several inputs: the input it is added to, after the actuator and its delay (a "
        "transfer-function matrix: it passes each entry's delay; state space: it enters after the input "
        "delay, as for a single input); default: the first input.")
    state: str | None = Field(
        None, exclude_if=lambda v: v is None,
        description="Plants with several inputs or a loop graph (state space or ODE): a named state whose "
        "derivative the disturbance is added to (a load torque on a speed state, in that state's units per "
        "second); replaces 'input'.")


class ScenarioSpec(_Model):
    """One simulated experiment. Several scenarios are summed (by weight) into one cost.
    ``dt`` and ``horizon`` left out (or null) are derived from the plant's time scale when
    the spec is used, and the result says which values were chosen and why
    (``scenario_defaults``; the rule is in docs/simulation.md).

    Until then they are None and :attr:`resolved` is False
    (:func:`gaintune.classical.timescale.resolve_scenarios` fills them in).
    """

    name: str = "nominal"
    dt: float | None = Field(
        None, description="Sample time in seconds. Omitted: derived from the plant (delay/20, at least 2,000 "
        "samples per horizon; docs/simulation.md).")
    horizon: float | None = Field(
        None, description="Simulated time in seconds. Omitted: derived from the plant (10 x its settling scale, "
        "after the last reference or disturbance event; docs/simulation.md).")
    reference: ReferenceSpec = Field(default_factory=ReferenceSpec)
    disturbance: DisturbanceSpec = Field(default_factory=DisturbanceSpec)
    noise_std: float = Field(0.0, ge=0, description="Std of white measurement noise on every measured output.")
    weight: float = Field(1.0, ge=0, description="Weight of this scenario in the combined cost.")

    @model_validator(mode="after")
    def _check(self) -> ScenarioSpec:
        for name in ("dt", "horizon"):
            v = getattr(self, name)
            if v is None:
                continue
            _finite(v, name)
            if v <= 0:
                raise ValueError(f"{name} must be > 0 seconds, got {v}")
        if self.dt is None or self.horizon is None:  # not resolved yet: checked once derived from the plant
            return self
        steps = self.horizon / self.dt
        if steps > MAX_STEPS:
            raise ValueError(
                f"horizon/dt = {steps:.0f} steps exceeds the limit of {MAX_STEPS}; raise dt or shorten the horizon"
            )
        if steps < 2:
            raise ValueError("horizon must cover at least 2 samples of dt")
        return self

    @property
    def resolved(self) -> bool:
        """Whether both ``dt`` and ``horizon`` are numbers (given, or derived from the plant)."""
        return self.dt is not None and self.horizon is not None

    @property
    def resolved_dt(self) -> float:
        """``dt`` once resolved (given, or derived from the plant); ValueError before."""
        if self.dt is None:
            raise ValueError(f"scenario {self.name!r} has no dt yet: derive it from the plant first "
                             "(gaintune.classical.timescale.resolve_scenarios)")
        return self.dt

    @property
    def resolved_horizon(self) -> float:
        """``horizon`` once resolved (given, or derived from the plant); ValueError before."""
        if self.horizon is None:
            raise ValueError(f"scenario {self.name!r} has no horizon yet: derive it from the plant first "
                             "(gaintune.classical.timescale.resolve_scenarios)")
        return self.horizon

    @property
    def n_steps(self) -> int:
        """Simulated samples, ``horizon / dt`` (ValueError before both are resolved)."""
        if self.dt is None or self.horizon is None:
            raise ValueError(f"scenario {self.name!r} has no dt/horizon yet: derive them from the plant first "
                             "(gaintune.classical.timescale.resolve_scenarios)")
        return int(round(self.horizon / self.dt))

    def last_event(self) -> float:
        """Time (s) of the last reference or disturbance change: a derived horizon starts counting there."""
        times = [0.0]
        for p in (self.reference, self.disturbance):
            if p.kind == "none":
                continue
            times.append(p.time)
            if p.kind == "sequence":
                times.append(p.points[-1][0])
            elif p.kind == "impulse" and p.width is not None:
                times.append(p.time + p.width)
        return max(times)


class ScenarioDefault(_Model):
    """How a scenario's ``dt`` and ``horizon`` were chosen: given in the spec, or derived from the plant."""

    scenario: str
    dt: float
    horizon: float
    dt_from: Literal["spec", "plant"] = "plant"
    horizon_from: Literal["spec", "plant"] = "plant"
    reason: str = ""


# ------------------------------------------------------- objective and reqs


#: MIMO limits, judged by the MIMO verification as given (no back-off is defined for them yet).
_MIMO_LIMITS = ("mimo_ms_max", "mimo_mt_max", "disk_margin_min", "disk_margin_at", "targets")
#: Requirements ``targets`` may set per loop, plant input, plant output or side (the MIMO verdict).
_TARGETED = ("gm_min_db", "pm_min_deg", "dm_min", "ms_max", "mt_max", "mimo_ms_max", "mimo_mt_max", "disk_margin_min")

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
    wc_min: float | None = Field(
        None, gt=0, description="Minimum gain-crossover frequency (rad/s) at every break point: the crossover of the "
        "binding phase margin (pm_freq); a loop without a crossover counts as 0.")
    wc_max: float | None = Field(
        None, gt=0, description="Maximum gain-crossover frequency (rad/s) at every break point (as wc_min).")
    mks_max: float | dict[str, float | None] | Literal["auto"] | None = Field(
        "auto",
        description="Maximum noise sensitivity Mks: the peak gain from a loop's measurement noise to the plant "
        "input (SISO: max |C S|), in actuator units per measured unit. A number applies to every PID loop; "
        "{loop: limit} sets it per loop (a loop left out, or null, has none). 'auto': a limit derived from "
        "the plant where nothing in it bounds the loop's speed (a delay-free, stable path of relative degree "
        "<= 1): Mks <= 10/|static gain|, so the design no longer follows the sample time; no limit elsewhere. "
        "null: no limit.")
    mimo_ms_max: float | None = Field(
        None, gt=1, exclude_if=lambda v: v is None,
        description="Several loops: maximum peak of the largest singular value of the sensitivity S (MIMO Ms).")
    mimo_mt_max: float | None = Field(
        None, gt=0, exclude_if=lambda v: v is None,
        description="Several loops: maximum peak of the largest singular value of T (MIMO Mt).")
    disk_margin_min: float | None = Field(
        None, gt=0, exclude_if=lambda v: v is None,
        description="Several loops: minimum multiloop disk margin (all channels perturbed at once), at the "
        "plant inputs, outputs or both (disk_margin_at).")
    disk_margin_at: Literal["inputs", "outputs", "all"] = Field(
        "all", exclude_if=lambda v: v == "all", description="Where disk_margin_min applies.")
    targets: dict[str, dict[str, float]] | None = Field(
        None, exclude_if=lambda v: v is None,
        description="Several loops: limits at named places, added to the ones above, e.g. {gm_min_db: {xD: 8}, "
        "disk_margin_min: {input: 0.5}}. A loop-at-a-time figure (gm_min_db, pm_min_deg, dm_min, ms_max, mt_max) "
        "takes a loop, a plant input or output, or all; a MIMO figure (mimo_ms_max, mimo_mt_max, disk_margin_min) "
        "takes input, output or all.")
    # the default is left out of dumps, so specs and hashes written before the field existed stay as they were
    backoff: BackoffSpec = Field(
        default_factory=BackoffSpec, exclude_if=lambda b: b == BackoffSpec(),
        description="How far inside each limit the search aims (the verdict judges the exact limits): "
        "{peaks, pm_deg, gm_db, dm}; 0 for none (the answer lands on the limit itself). See docs/search.md.")

    def aimed(self) -> RequirementsSpec:
        """These requirements with every limit moved to the search's aim (:meth:`BackoffSpec.aim`) and no
        back-off left; themselves when the back-off is 0. ``mks_max: auto`` stays ``auto``: a caller that
        resolves it aims the resolved limit with ``backoff.aim("mks_max", limit)``."""
        b = self.backoff
        if not b.active:
            return self
        plain = self.model_dump(exclude={"mks_max", "backoff", *_MIMO_LIMITS})
        new: dict[str, Any] = {k: b.aim(k, v) for k, v in plain.items() if v is not None}
        mks = self.mks_max
        if isinstance(mks, dict):
            new["mks_max"] = {k: None if v is None else b.aim("mks_max", v) for k, v in mks.items()}
        elif isinstance(mks, (int, float)):
            new["mks_max"] = b.aim("mks_max", float(mks))
        return self.model_copy(update={**new, "backoff": BackoffSpec.model_validate(0)})

    @field_validator("targets")
    @classmethod
    def _targets(cls, v: dict[str, dict[str, float]] | None) -> dict[str, dict[str, float]] | None:
        for name, per in (v or {}).items():
            if name not in _TARGETED:
                raise ValueError(f"targets.{name}: not a requirement with targets; choose one of {list(_TARGETED)}")
            for where, x in per.items():
                if not math.isfinite(x):
                    raise ValueError(f"targets.{name}.{where}: limit must be finite, got {x}")
        return v

    @field_validator("mks_max", mode="before")
    @classmethod
    def _mks_form(cls, v: Any) -> Any:
        # one message for a value of none of the four forms (pydantic would list its union's internals)
        for x in v.values() if isinstance(v, dict) else [v]:
            if isinstance(x, float) and not math.isfinite(x):
                raise ValueError(f"noise-sensitivity limits must be finite and > 0, got {x}")
        if v is None or v == "auto" or isinstance(v, dict) or (isinstance(v, (int, float)) and not isinstance(v, bool)):
            return v
        if isinstance(v, str):
            try:
                return float(v)
            except ValueError:
                pass
        raise ValueError(f"give a number, 'auto', null or {{loop: limit}}, got {v!r}")

    @field_validator("mks_max")
    @classmethod
    def _positive_mks(cls, v: Any) -> Any:
        vals = v.values() if isinstance(v, dict) else [v]
        for x in vals:
            if isinstance(x, float) and not (math.isfinite(x) and x > 0):
                raise ValueError(f"noise-sensitivity limits must be finite and > 0, got {x}")
        return v
