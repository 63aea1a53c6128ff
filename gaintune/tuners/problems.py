"""What a tuner is trained on and answers: its context space and the tuning problem of one context.

A tuner maps a **context** (the values that pick one plant out of a family) to gains. Every
context is its own tuning problem, with its own plant, its own requirements as hard constraints
and its own optimum: :meth:`TunerProblem.spec_at` gives that problem's spec. Two kinds:

* :class:`FamilyProblem`: a ready-made family (:mod:`gaintune.tuners.families`). The context is the
  dimensionless shape (``tau = L/(L+T)`` for FOTD); training runs on the unit plants and a query's
  physical parameters are reduced to the shape, the answer scaled back.
* :class:`SpecProblem`: any spec with a ``randomize`` block (``gaintune tuner train SPEC``). The
  context is the randomised plant parameters, the delay and the actuator scale, each inside its
  range; everything else of the spec is fixed.

The policy's action lives in a fixed log-scale **gain box** per tuned gain (:class:`GainBox`), the
same for every context, stored with the tuner.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np

from gaintune.errors import SpecError
from gaintune.spec import Gains, RandomizeSpec, TuningSpec, load_spec
from gaintune.tuners.families import Family, family, problem_data

__all__ = ["ContextVar", "GainBox", "TunerProblem", "FamilyProblem", "SpecProblem", "problem_from_dict"]


@dataclass(frozen=True)
class ContextVar:
    """One context variable, its training range and whether it is read on a log scale."""

    name: str
    lo: float
    hi: float
    log: bool

    def feature(self, v: float) -> float:
        """The value mapped to [-1, 1] over the training range (beyond it for values outside)."""
        f = (lambda x: math.log(x)) if self.log else (lambda x: x)
        return 2.0 * (f(v) - f(self.lo)) / max(f(self.hi) - f(self.lo), 1e-12) - 1.0

    def draw(self, u: np.ndarray) -> np.ndarray:
        """Values for uniform numbers ``u`` in [0, 1) (log-uniform where :attr:`log`)."""
        if self.log:
            return np.exp(math.log(self.lo) + u * (math.log(self.hi) - math.log(self.lo)))
        return self.lo + u * (self.hi - self.lo)

    def contains(self, v: float, rtol: float = 1e-9) -> bool:
        """Inside the training range (with a relative tolerance for rounding, on either sign of the ends)."""
        return self.lo - rtol * (abs(self.lo) + 1) <= v <= self.hi + rtol * (abs(self.hi) + 1)


@dataclass(frozen=True)
class GainBox:
    """The tuned gains, as ``(loop, gain)`` slots, and their log-scale bounds: where the action maps.

    ``scale_axis`` marks the gains the boundary move scales together (1 on Kp, Ki, Kd of a parallel
    PID loop). The move sets their common scale for every answer, so the action's component along
    that axis means nothing: :meth:`to_tuned` removes it (the mean log-gain over the axis is put at
    the box's centre). Left in, a flat direction lets the actor drift into the saturated corner of
    the box, where the controller's shape is frozen at the corner's.
    """

    slots: tuple[tuple[str, str], ...]
    log_lo: np.ndarray
    log_hi: np.ndarray
    scale_axis: np.ndarray | None = None

    def to_tuned(self, action: np.ndarray) -> np.ndarray:
        """(B, d) tuned gains for actions in [-1, 1]^d (log-linear in the box, scale removed along the axis)."""
        a = np.clip(np.atleast_2d(np.asarray(action, dtype=float)), -1.0, 1.0)
        x = self.log_lo + 0.5 * (a + 1.0) * (self.log_hi - self.log_lo)
        ax = self.scale_axis
        if ax is not None and ax.any():
            on = ax > 0
            centre = 0.5 * (self.log_lo + self.log_hi)
            shift = np.mean(x[:, on] - centre[on], axis=1)
            x = np.clip(x - shift[:, None] * ax, self.log_lo, self.log_hi)
        return np.exp(x)

    def to_gains(self, tuned: np.ndarray) -> Gains:
        """One tuned vector as ``{loop: {gain: value}}``."""
        out: dict[str, dict[str, float]] = {}
        for (loop, g), x in zip(self.slots, np.asarray(tuned, dtype=float).ravel(), strict=True):
            out.setdefault(loop, {})[g] = float(x)
        return out

    def as_dict(self) -> dict[str, Any]:
        out: dict[str, Any] = {"slots": [list(s) for s in self.slots], "lo": np.exp(self.log_lo).tolist(),
                               "hi": np.exp(self.log_hi).tolist()}
        if self.scale_axis is not None:
            out["scale_axis"] = self.scale_axis.tolist()
        return out

    @classmethod
    def from_dict(cls, d: Mapping[str, Any]) -> GainBox:
        """The box of a tuner.json (ValueError saying what is wrong: a damaged file must not crash its reader)."""
        slots = tuple((str(a), str(b)) for a, b in d["slots"])
        lo, hi = np.asarray(d["lo"], float), np.asarray(d["hi"], float)
        axis = d.get("scale_axis")
        ax = None if axis is None else np.asarray(axis, float)
        if not slots or any(x.shape != (len(slots),) for x in (lo, hi, *([] if ax is None else [ax]))):
            raise ValueError(f"its gain box needs one lo, hi (and scale_axis) value per slot ({len(slots)} slots)")
        if not (np.all(np.isfinite(lo)) and np.all(np.isfinite(hi)) and np.all(lo > 0) and np.all(hi > lo)):
            raise ValueError("its gain box bounds must be finite with 0 < lo < hi")
        return cls(slots, np.log(lo), np.log(hi), ax)


def _with_bounds(data: dict[str, Any], bounds: Mapping[tuple[str, str], tuple[float, float]]) -> dict[str, Any]:
    """The spec dict with ``loops[*].gains[g].bounds`` set (the gain box, so evaluators move inside it)."""
    for lp in data["loops"]:
        for (loop, g), (lo, hi) in bounds.items():
            if lp.get("name", "main") == loop:
                lp.setdefault("gains", {})
                entry = lp["gains"].get(g) or {}
                entry = dict(entry) if isinstance(entry, dict) else {}
                entry.pop("value", None)
                lp["gains"][g] = {**entry, "bounds": [float(lo), float(hi)]}
    return data


class TunerProblem:
    """Base: the context variables, the tuned-gain box and the spec of one context."""

    kind: str
    variables: tuple[ContextVar, ...]
    box: GainBox | None = None

    def spec_at(self, context: Mapping[str, float]) -> TuningSpec:  # pragma: no cover - abstract
        """The tuning problem of one context, gains bounded by the box."""
        raise NotImplementedError

    def context_of(self, params: Mapping[str, float]) -> dict[str, float]:  # pragma: no cover - abstract
        """The context of a query's physical parameters (checked)."""
        raise NotImplementedError

    def physical_spec(self, params: Mapping[str, float]) -> TuningSpec:  # pragma: no cover - abstract
        """The tuning problem of the plant a query names."""
        raise NotImplementedError

    def scale_answer(self, gains: Gains, params: Mapping[str, float]) -> Gains:  # pragma: no cover - abstract
        """The policy's gains for the plant a query names."""
        raise NotImplementedError

    def tuned_slots(self) -> tuple[tuple[str, str], ...]:
        """The (loop, gain) slots the central context's spec tunes, read from its gain layout (bounded by the
        current box, if any). SpecError for a gain the loop's form does not have."""
        from gaintune.controllers.layout import GainLayout
        from gaintune.plants import build_plant

        spec = self.spec_at(self.centre())
        plant = build_plant(spec.plant)
        return tuple((s.loop_name, s.name) for s in GainLayout(spec, plant.states, plant=plant).tuned_slots)

    def features(self, context: Mapping[str, float]) -> np.ndarray:
        """The policy's input for one context: each variable mapped to [-1, 1]."""
        return np.array([v.feature(float(context[v.name])) for v in self.variables], dtype=float)

    def draw(self, rng: np.random.Generator, n: int) -> list[dict[str, float]]:
        """``n`` contexts drawn from the training ranges."""
        cols = {v.name: v.draw(rng.random(n)) for v in self.variables}
        return [{k: float(c[i]) for k, c in cols.items()} for i in range(n)]

    def outside(self, context: Mapping[str, float]) -> list[str]:
        """Names of the context variables outside their training range."""
        return [v.name for v in self.variables if not v.contains(float(context[v.name]))]

    def centre(self) -> dict[str, float]:
        """The middle of every range (geometric for log variables)."""
        return {v.name: float(v.draw(np.array([0.5]))[0]) for v in self.variables}

    def as_dict(self) -> dict[str, Any]:  # pragma: no cover - abstract
        raise NotImplementedError


class FamilyProblem(TunerProblem):
    """A ready-made family's unit plants over their shape (see :mod:`gaintune.tuners.families`)."""

    kind = "family"

    def __init__(self, fam: Family | str, ctype: str = "pi", ms_max: float = 1.4) -> None:
        self.family = family(fam) if isinstance(fam, str) else fam
        self.ctype, self.ms_max = ctype, float(ms_max)
        self.variables = tuple(ContextVar(k, lo, hi, True) for k, (lo, hi) in self.family.shape.items())

    def spec_at(self, context: Mapping[str, float]) -> TuningSpec:
        """The unit plant of this shape, its problem spec, gains bounded by the box."""
        return self._bounded(problem_data(self.family, self.family.unit_params(context), self.ctype, self.ms_max), {})

    def physical_spec(self, params: Mapping[str, float]) -> TuningSpec:
        """The problem of the real plant with physical ``params``, gains bounded by the box scaled to it."""
        return self._bounded(problem_data(self.family, params, self.ctype, self.ms_max), params)

    def _bounded(self, data: dict[str, Any], params: Mapping[str, float]) -> TuningSpec:
        """The spec of ``data`` with its gains bounded by the box, scaled to the plant ``params`` (the unit box
        when empty); validated once."""
        if self.box is None:
            return load_spec(data)
        lo = self.box.to_gains(np.exp(self.box.log_lo))
        hi = self.box.to_gains(np.exp(self.box.log_hi))
        if params:
            lo = {k: self.family.scale_gains(v, params) for k, v in lo.items()}
            hi = {k: self.family.scale_gains(v, params) for k, v in hi.items()}
        bounds = {(lp, g): (lo[lp][g], hi[lp][g]) for lp, g in self.box.slots}
        return load_spec(_with_bounds(data, bounds))

    def context_of(self, params: Mapping[str, float]) -> dict[str, float]:
        """The shape of a physical plant (parameters checked by the family)."""
        return self.family.shape_of(params)

    def scale_answer(self, gains: Gains, params: Mapping[str, float]) -> Gains:
        """Unit-plant gains scaled to the physical plant."""
        return {lp: self.family.scale_gains(g, params) for lp, g in gains.items()}

    def as_dict(self) -> dict[str, Any]:
        return {"kind": self.kind, "family": self.family.name, "ctype": self.ctype, "ms_max": self.ms_max}


class SpecProblem(TunerProblem):
    """A spec's plant family: the context is its ``randomize`` parameters, delay and actuator scale."""

    kind = "spec"

    def __init__(self, spec: TuningSpec) -> None:
        rz = spec.randomize
        unsupported = [k for k in ("reference_kinds", "reference_amplitude", "disturbance_size", "disturbance_time")
                       if getattr(rz, k)]
        if unsupported:
            raise SpecError(f"randomize.{unsupported[0]}", "a tuner's context is the plant: its parameters, delay "
                            "and actuator scale; give the scenario's signals fixed values, or tune a robust design "
                            "over them with 'gaintune tune'")
        vs = [ContextVar(k, *d.box, d.dist == "loguniform") for k, d in rz.params.items()]
        if rz.delay:
            vs.append(ContextVar("delay", *rz.delay.box, rz.delay.dist == "loguniform"))
        if rz.actuator_scale:
            vs.append(ContextVar("actuator_scale", *rz.actuator_scale.box, rz.actuator_scale.dist == "loguniform"))
        if not vs:
            raise SpecError("randomize.params", "a tuner needs a family: give the plant parameters that vary, e.g. "
                            "randomize: {params: {K: [0.5, 5]}}")
        from gaintune.plants import build_plant
        from gaintune.plants.checks import validate_against_plant

        plant = build_plant(spec.plant)
        # as 'tune' checks it: a parameter the plant does not have trained a tuner over nothing
        validate_against_plant(spec, plant)
        # a query's unnamed variables take these: the built plant's, so a default that lives in a model file
        # (the water tank's H0) and a delay given as an expression have one
        self._nominal_params, self._nominal_delay = dict(plant.params), plant.delay()
        self.spec = spec
        self.variables = tuple(vs)

    def spec_at(self, context: Mapping[str, float]) -> TuningSpec:
        """The spec at one context: its parameters, delay and actuator limits set, nothing randomised."""
        data = self.spec.model_dump(mode="json", exclude_defaults=True)
        data["randomize"] = RandomizeSpec().model_dump(mode="json")
        params = {k: float(v) for k, v in context.items() if k not in ("delay", "actuator_scale")}
        data["plant"]["params"] = {**data["plant"].get("params", {}), **params}
        if "delay" in context:
            data["plant"]["delay"] = float(context["delay"])
        if "actuator_scale" in context and self.spec.actuator.limits is not None:
            lo, hi = self.spec.actuator.limits
            data.setdefault("actuator", {})["limits"] = [lo * context["actuator_scale"], hi * context["actuator_scale"]]
        if self.box is not None:
            bounds = {s: (float(np.exp(a)), float(np.exp(b)))
                      for s, a, b in zip(self.box.slots, self.box.log_lo, self.box.log_hi, strict=True)}
            data = _with_bounds(data, bounds)
        return load_spec(data)

    def context_of(self, params: Mapping[str, float]) -> dict[str, float]:
        """The context of a query: every variable given, finite; unnamed ones take the spec's nominal value."""
        names = [v.name for v in self.variables]
        for k, x in params.items():
            if k not in names:
                raise SpecError(f"params.{k}", f"not a variable the tuner was trained over; its context is "
                                f"{', '.join(names)}")
            if isinstance(x, bool) or not isinstance(x, (int, float)) or not math.isfinite(x):
                raise SpecError(f"params.{k}", f"must be a finite number, got {x!r}")
        return {n: float(params[n]) if n in params else self._nominal(n) for n in names}

    def _nominal(self, name: str) -> float:
        """The spec's nominal value of a context variable (see ``__init__``)."""
        if name == "actuator_scale":
            return 1.0
        return float(self._nominal_delay) if name == "delay" else float(self._nominal_params[name])

    def physical_spec(self, params: Mapping[str, float]) -> TuningSpec:
        return self.spec_at(self.context_of(params))

    def scale_answer(self, gains: Gains, params: Mapping[str, float]) -> Gains:
        return gains

    def as_dict(self) -> dict[str, Any]:
        return {"kind": self.kind, "spec": self.spec.model_dump(mode="json", exclude_defaults=True)}


def problem_from_dict(d: Mapping[str, Any], box: GainBox | None = None) -> TunerProblem:
    """The problem an artefact's ``problem`` entry describes (SpecError naming ``problem`` otherwise)."""
    try:
        if d["kind"] == "family":
            p: TunerProblem = FamilyProblem(d["family"], d["ctype"], d["ms_max"])
        elif d["kind"] == "spec":
            p = SpecProblem(load_spec(d["spec"]))
        else:
            raise KeyError(d["kind"])
    except (KeyError, TypeError) as exc:
        raise SpecError("problem", f"not a tuner problem ({exc}); the artefact is damaged or from another "
                        "version: retrain it") from None
    p.box = box
    return p

