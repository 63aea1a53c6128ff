"""pidtune's interface as a spec shortcut: ``design: {phase_margin, focus, ...}``.

MATLAB's ``pidtune(G, type, opts)`` asks for a target phase margin (60 deg by default)
and a design focus; gaintune maps that onto its own spec, so the tuned gains are the
constrained optimum of a stated objective rather than a loop-shaping heuristic:

==========================  ==================================================================
design field                becomes
==========================  ==================================================================
``phase_margin`` (60)       ``requirements.pm_min_deg`` (a hard constraint); the other
                            requirements keep their defaults unless the spec sets them
``crossover`` (optional)    pidtune's target crossover ``wc`` (rad/s): the band
                            ``requirements.wc_min = wc/(1+tol)``, ``wc_max = wc (1+tol)``
                            with ``tol = crossover_tolerance`` (default 0.1): an equality is
                            not a constraint a search can sit strictly inside, a band is.
                            One loop only (a cascade's loops need crossovers of their own:
                            set ``requirements.wc_min``/``wc_max`` there)
``focus: reference_tracking``  one scenario: unit setpoint step; cost IAE + effort
``focus: disturbance_rejection``  one scenario: unit load step at the plant input; cost IAE
``focus: balanced`` (default)  both scenarios, weight 0.5 each
``dt``, ``horizon``          the scenarios' sample time and length; left out, both are derived
                            from the plant like any scenario's (docs/simulation.md)
==========================  ==================================================================

A spec that sets ``scenarios`` (or ``scenario``) itself keeps them and uses ``design`` for
the requirements only; one that sets ``requirements.pm_min_deg`` and a different
``design.phase_margin`` is rejected (two sources for one limit), and so is one that sets
``requirements.wc_min``/``wc_max`` beside ``design.crossover``.
"""

from __future__ import annotations

from typing import Any, Literal

from pydantic import BaseModel, ConfigDict, Field, ValidationError, ValidationInfo, field_validator

__all__ = ["DesignSpec", "expand_design"]


class DesignSpec(BaseModel):
    """pidtune-style design goals, expanded into requirements and scenarios (see :mod:`gaintune.spec.design`)."""

    # as the spec's own models (gaintune.spec.base._Model): numbers are finite and not booleans
    model_config = ConfigDict(extra="forbid", allow_inf_nan=False)

    phase_margin: float = Field(
        60.0, gt=0, lt=90, description="Target (minimum) phase margin in degrees, as pidtune's default.")
    focus: Literal["balanced", "reference_tracking", "disturbance_rejection"] = Field(
        "balanced", description="What the cost measures: setpoint steps, load steps at the plant input, or both."
    )
    crossover: float | None = Field(
        None, gt=0, description="Target gain-crossover frequency wc (rad/s), as pidtune's second argument: "
        "the loop's crossover must lie within wc/(1+crossover_tolerance) .. wc (1+crossover_tolerance).")
    crossover_tolerance: float = Field(0.1, gt=0, le=1, description="Relative width of the crossover band.")
    dt: float | None = Field(
        None, gt=0, description="Sample time of the generated scenarios (s); omitted: derived from the plant.")
    horizon: float | None = Field(
        None, gt=0, description="Length of the generated scenarios (s); omitted: derived from the plant.")

    @field_validator("phase_margin", "crossover", "crossover_tolerance", "dt", "horizon", mode="before")
    @classmethod
    def _not_boolean(cls, v: Any, info: ValidationInfo) -> Any:
        if isinstance(v, bool):  # pydantic's lax mode would read true as 1.0
            raise ValueError(f"{info.field_name} must be a number, not a boolean ({str(v).lower()})")
        return v


def _scenarios(d: DesignSpec) -> list[dict[str, Any]]:
    # dt/horizon left out stay None: the plant's time scale sets them (gaintune.classical.timescale);
    # both steps start at t = 0, so a derived horizon needs no event offset
    timing = {k: v for k, v in (("dt", d.dt), ("horizon", d.horizon)) if v is not None}
    track = {"name": "tracking", **timing, "reference": {"kind": "step", "amplitude": 1.0}}
    load = {"name": "load", **timing, "reference": {"kind": "none"},
            "disturbance": {"kind": "step", "amplitude": 1.0, "entry": "input"}}
    if d.focus == "reference_tracking":
        return [track]
    if d.focus == "disturbance_rejection":
        return [load]
    return [{**track, "weight": 0.5}, {**load, "weight": 0.5}]


def _number(req: dict[str, Any], key: str) -> float | None:
    """``req[key]`` as a float, None when absent; a ValueError naming the field when it is not a number."""
    v = req.get(key)
    if v is None:
        return None
    try:
        if isinstance(v, bool) or not isinstance(v, (int, float, str)):
            raise TypeError
        return float(v)  # a numeric string passes, as the schema's lax mode would take it
    except (TypeError, ValueError):
        raise ValueError(f"requirements.{key} must be a number, got {v!r}") from None


def expand_design(data: dict[str, Any]) -> dict[str, Any]:
    """Fill ``requirements.pm_min_deg`` (and ``wc_min``/``wc_max`` for a crossover) and, when absent,
    ``scenarios`` from ``data["design"]``.

    Raises ValueError when the spec gives the phase margin or the crossover twice, or a
    crossover for more than one loop.
    """
    raw = data.get("design")
    if raw is None:
        return data
    try:
        d = raw if isinstance(raw, DesignSpec) else DesignSpec.model_validate(raw)
    except ValidationError:
        return data  # the schema's own check of the `design` field names design.<field>
    out = dict(data)
    raw_req = out.get("requirements")
    if raw_req is not None and not isinstance(raw_req, (dict, BaseModel)):
        return data  # not a mapping: the schema's own check names `requirements`
    req = dict(raw_req or {})
    given = _number(req, "pm_min_deg")
    if given is not None and abs(given - d.phase_margin) > 1e-12:
        raise ValueError(f"requirements.pm_min_deg ({given}) and design.phase_margin ({d.phase_margin}) disagree; "
                         "give the phase margin once")
    req["pm_min_deg"] = d.phase_margin
    if d.crossover is not None:
        loops = out.get("loops")
        if isinstance(loops, (list, tuple)) and len(loops) != 1:
            raise ValueError("design.crossover applies to a single loop; for a cascade set requirements.wc_min "
                             "and requirements.wc_max instead")
        band = {"wc_min": d.crossover / (1.0 + d.crossover_tolerance),
                "wc_max": d.crossover * (1.0 + d.crossover_tolerance)}
        for k, v in band.items():  # a dumped spec carries both; they must agree
            given = _number(req, k)
            if given is not None and abs(given - v) > 1e-12 * v:
                raise ValueError(f"requirements.{k} ({req[k]}) and design.crossover ({d.crossover}) both set the "
                                 "crossover; give it once")
        req.update(band)
    out["requirements"] = req
    if "scenarios" not in out and "scenario" not in out:
        out["scenarios"] = _scenarios(d)
    return out
