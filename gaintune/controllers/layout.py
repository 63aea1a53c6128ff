"""Gain layout: which gains a spec has, which are tuned, and how actions map to them.

The layout is the single place that orders gains. Tuned gains form the search
vector (and the RL action, mapped from [-1, 1] to log-scaled bounds); fixed
gains are filled in from the spec. Gains travel between interfaces as a
nested dict ``{loop_name: {gain_name: value}}``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np

from gaintune.errors import GainError, SpecError
from gaintune.spec import GAIN_NAMES, LoopSpec, TuningSpec

__all__ = ["GainSlot", "GainLayout", "loop_gain_names", "search_layout", "DEFAULT_BOUNDS"]

#: Fallback log-scale bounds when neither the spec nor a classical rule gives any.
DEFAULT_BOUNDS: dict[str, tuple[float, float]] = {
    "Kp": (1e-3, 1e3),
    "Ki": (1e-4, 1e3),
    "Kd": (1e-4, 1e3),
    "Ti": (1e-3, 1e4),
    "Td": (1e-4, 1e3),
    "q": (1e-4, 1e4),
    "r": (1e-4, 1e4),
    "k": (1e-3, 1e3),
}

Gains = dict[str, dict[str, float]]


def loop_gain_names(loop: LoopSpec, states: list[str]) -> tuple[str, ...]:
    """Gain names of one loop, in layout order."""
    if loop.type in ("lqr", "lqi"):
        if loop.lq_mode == "weights":
            names = [f"q_{s}" for s in states] + (["q_int"] if loop.type == "lqi" else []) + ["r"]
        else:
            names = [f"k_{s}" for s in states] + (["k_int"] if loop.type == "lqi" else [])
        return tuple(names)
    return GAIN_NAMES[(loop.type, loop.form)]


def _default_bounds(name: str) -> tuple[float, float]:
    key = name if name in DEFAULT_BOUNDS else name.split("_")[0]
    return DEFAULT_BOUNDS.get(key, (1e-3, 1e3))


@dataclass(frozen=True)
class GainSlot:
    """One gain of one loop."""

    loop: int
    loop_name: str
    name: str
    tuned: bool
    value: float | None
    bounds: tuple[float, float]


class GainLayout:
    """Ordered gains of a spec.

    Parameters
    ----------
    spec
        The tuning problem.
    states
        Plant state names (needed for LQ loops).
    auto_bounds
        Bounds to use for gains whose spec gives none, keyed ``(loop_name, gain)``;
        typically derived from a classical tuning rule.
    """

    def __init__(
        self,
        spec: TuningSpec,
        states: list[str],
        auto_bounds: dict[tuple[str, str], tuple[float, float]] | None = None,
    ) -> None:
        slots: list[GainSlot] = []
        auto_bounds = auto_bounds or {}
        for i, loop in enumerate(spec.loops):
            names = loop_gain_names(loop, states)
            unknown = set(loop.gains) - set(names)
            if unknown:
                raise SpecError(
                    f"loops[{i}].gains",
                    f"unknown gain(s) {sorted(unknown)} for a {loop.form} {loop.type} loop; expected {list(names)}",
                )
            for name in names:
                g = loop.gains.get(name)
                lq_r_fixed = name == "r" and g is None  # only the Q/R ratio matters: fix r = 1 by default
                tuned = (g.tune if g is not None else True) and not lq_r_fixed
                value = g.value if g is not None else (1.0 if lq_r_fixed else None)
                bounds = (
                    (g.bounds if g is not None and g.bounds is not None else None)
                    or auto_bounds.get((loop.name or "", name))
                    or _default_bounds(name)
                )
                if value is not None and tuned and not bounds[0] <= value <= bounds[1]:
                    raise SpecError(f"loops[{i}].gains.{name}.value", f"initial value {value} lies outside bounds {list(bounds)}")
                slots.append(GainSlot(i, loop.name or f"loop{i}", name, tuned, value, tuple(bounds)))
        self.slots = slots
        self.tuned_idx = np.array([k for k, s in enumerate(slots) if s.tuned], dtype=int)
        self.log_lo = np.log(np.array([slots[k].bounds[0] for k in self.tuned_idx], dtype=float))
        self.log_hi = np.log(np.array([slots[k].bounds[1] for k in self.tuned_idx], dtype=float))
        self.fixed = np.array([s.value if s.value is not None and not s.tuned else np.nan for s in slots])

    # ---------------------------------------------------------------- sizes
    @property
    def n_gains(self) -> int:
        return len(self.slots)

    @property
    def n_tuned(self) -> int:
        return len(self.tuned_idx)

    @property
    def tuned_slots(self) -> list[GainSlot]:
        return [self.slots[k] for k in self.tuned_idx]

    # ------------------------------------------------------- action mapping
    def action_to_tuned(self, action: np.ndarray) -> np.ndarray:
        """Map actions in [-1, 1]^d (clipped) to tuned gains, log-uniformly inside the bounds."""
        a = np.clip(np.asarray(action, dtype=float), -1.0, 1.0)
        return np.exp(self.log_lo + (a + 1.0) * 0.5 * (self.log_hi - self.log_lo))

    def tuned_to_action(self, tuned: np.ndarray) -> np.ndarray:
        """Inverse of :meth:`action_to_tuned` (values outside the bounds map outside [-1, 1])."""
        t = np.log(np.asarray(tuned, dtype=float))
        return 2.0 * (t - self.log_lo) / (self.log_hi - self.log_lo) - 1.0

    def full(self, tuned: np.ndarray) -> np.ndarray:
        """Insert fixed gains: (..., n_tuned) -> (..., n_gains)."""
        tuned = np.asarray(tuned, dtype=float)
        out = np.broadcast_to(self.fixed, (*tuned.shape[:-1], self.n_gains)).copy()
        out[..., self.tuned_idx] = tuned
        return out

    def initial_tuned(self) -> np.ndarray:
        """Initial guesses: spec values where given, else the geometric centre of the bounds."""
        centre = np.exp(0.5 * (self.log_lo + self.log_hi))
        given = [self.slots[k].value for k in self.tuned_idx]
        return np.array([v if v is not None else c for v, c in zip(given, centre)], dtype=float)

    # ----------------------------------------------------------- dict forms
    def to_dict(self, full: np.ndarray) -> Gains:
        """Full gain vector -> ``{loop: {gain: value}}``."""
        out: Gains = {}
        for slot, v in zip(self.slots, np.asarray(full, dtype=float)):
            out.setdefault(slot.loop_name, {})[slot.name] = float(v)
        return out

    def from_dict(self, gains: Any, *, field: str = "gains") -> np.ndarray:
        """``{loop: {gain: value}}`` -> full gain vector, validated.

        Fixed gains may be omitted (the spec's value is used). Tuned gains must be
        given. Every value must be finite and positive.

        Raises
        ------
        GainError
            Naming the loop and gain that is missing, unknown or invalid.
        """
        if not isinstance(gains, dict):
            raise GainError(field, "must be a mapping {loop_name: {gain_name: value}}")
        loops = {s.loop_name for s in self.slots}
        unknown_loops = set(gains) - loops
        if unknown_loops:
            raise GainError(field, f"unknown loop(s) {sorted(unknown_loops)}; loops are {sorted(loops)}")
        out = np.empty(self.n_gains)
        for k, slot in enumerate(self.slots):
            given = gains.get(slot.loop_name, {})
            if not isinstance(given, dict):
                raise GainError(f"{field}.{slot.loop_name}", "must be a mapping {gain_name: value}")
            names = {s.name for s in self.slots if s.loop_name == slot.loop_name}
            extra = set(given) - names
            if extra:
                raise GainError(
                    f"{field}.{slot.loop_name}", f"unknown gain(s) {sorted(extra)}; this loop has {sorted(names)}"
                )
            v = given.get(slot.name, None)
            if v is None:
                if slot.tuned or slot.value is None:
                    raise GainError(f"{field}.{slot.loop_name}.{slot.name}", "missing; give a positive number")
                v = slot.value
            if isinstance(v, bool) or not isinstance(v, (int, float)):
                raise GainError(f"{field}.{slot.loop_name}.{slot.name}", f"must be a number, got {v!r}")
            v = float(v)
            if not math.isfinite(v):
                raise GainError(f"{field}.{slot.loop_name}.{slot.name}", f"must be finite, got {v}")
            # Direct state-feedback entries may take any sign; every other gain is positive.
            if not slot.name.startswith("k_") and v <= 0:
                raise GainError(f"{field}.{slot.loop_name}.{slot.name}", f"must be > 0, got {v}")
            out[k] = v
        return out


def search_layout(spec: TuningSpec, plant: Any) -> GainLayout:
    """The search space every optimiser shares: spec bounds, else bounds centred on a classical rule.

    RL, the black-box baselines and the reference optimum all search this same
    box, so their costs compare like with like.
    """
    from gaintune.baselines import auto_bounds  # lazy: baselines import the evaluator

    return GainLayout(spec, plant.states, auto_bounds=auto_bounds(spec, plant))
