"""Gain layout: which gains a spec has, which are tuned, and how actions map to them.

The layout is the single place that orders gains. Tuned gains form the search
vector (and the RL action, mapped from [-1, 1] to log-scaled bounds); fixed
gains are filled in from the spec. Gains travel between interfaces as a
nested dict ``{loop_name: {gain_name: value}}``.

The layout also owns the **sign** of every gain. Each loop is direct- or
reverse-acting (``loops[i].direction``, resolved by
:func:`~gaintune.controllers.direction.loop_directions`). The search vector
holds positive *magnitudes* (log scale, bounds are magnitudes); :meth:`GainLayout.full`,
:meth:`GainLayout.to_dict` and :meth:`GainLayout.from_dict` work with *signed* gains:
a reverse-acting PID loop has ``Kp``, ``Ki``, ``Kd`` < 0 (ideal form: ``Kp`` < 0,
``Ti``, ``Td`` > 0). Direct state-feedback entries (``k_<state>``, ``k_int``) keep
whatever sign they are given.

Tuned entries of the static blocks (:mod:`gaintune.spec.blocks`) follow the loops' gains, under the
pseudo-loops ``decoupler`` (``d_<input>_<input>``, row then column) and ``feedforward``
(``ff_<loop>_<input>``); each keeps the sign of its bounds. A spec without tuned entries has
exactly the loops' slots.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np

from gaintune.controllers.direction import LoopDirection, loop_directions, resolve_directions
from gaintune.controllers.forms import to_form
from gaintune.errors import GainError, SpecError
from gaintune.spec import GAIN_NAMES, Gains, LoopSpec, TuningSpec
from gaintune.spec.blocks import (
    DECOUPLER,
    FEEDFORWARD,
    BlockGainSpec,
    decoupler_gain_name,
    feedforward_gain_name,
    is_tuned,
)

__all__ = [
    "GainSlot", "GainLayout", "loop_gain_names", "DEFAULT_BOUNDS", "loop_directions",
    "gain_sign", "SIGNED_GAINS", "block_slots",
]

#: PID gains that carry the loop's direction (negative for a reverse-acting loop); Ti, Td stay positive.
SIGNED_GAINS = ("Kp", "Ki", "Kd")

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



def loop_gain_names(loop: LoopSpec, states: list[str]) -> tuple[str, ...]:
    """Gain names of one loop, in layout order."""
    if loop.type in ("lqr", "lqi"):
        if loop.lq_mode == "weights":
            names = [f"q_{s}" for s in states] + (["q_int"] if loop.type == "lqi" else []) + ["r"]
        else:
            names = [f"k_{s}" for s in states] + (["k_int"] if loop.type == "lqi" else [])
        return tuple(names)
    return GAIN_NAMES[(loop.type, loop.form)]


def _in_form(form: str, given: dict[str, Any], where: str) -> dict[str, Any]:
    """``given`` gains of one PID loop in the loop's ``form`` (K/Ti/Td read on a parallel loop, Ki/Kd on an ideal one).

    Non-numbers are left for the caller's check, which names them.
    """
    if not all(isinstance(v, (int, float)) and not isinstance(v, bool) for v in given.values()):
        return given
    ti = given.get("Ti")
    if form == "parallel" and ti is not None and not ti > 0:
        raise GainError(f"{where}.Ti", f"must be > 0, got {ti:g} (the integral time; to turn integral action off, "
                        "use a PD loop or give Ki: 0)")
    return to_form(form, given)


def gain_sign(loop: LoopSpec, name: str, direction: int) -> int:
    """Sign gain ``name`` of ``loop`` must have: ``direction`` for Kp/Ki/Kd, +1 for Ti, Td, q, r; 0 = any (k_*)."""
    if loop.is_lq:
        return 0 if name.startswith("k_") else 1
    return direction if name in SIGNED_GAINS else 1


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
    value: float | None  # signed (as in the spec)
    bounds: tuple[float, float]  # of the magnitude
    sign: int = 1  # +1 / -1: the value's required sign (the search holds |value|); 0: any sign, searched as is
    field: str = ""  # where the spec sets it, for a block entry (a loop gain: loops[loop].gains.name)

    @property
    def spec_field(self) -> str:
        """The spec field that sets this gain (``loops[0].gains.Kp``, ``decoupler.matrix[0][1]``)."""
        return self.field or f"loops[{self.loop}].gains.{self.name}"


def _block_slot(loop: int, block: str, name: str, e: BlockGainSpec, field: str) -> GainSlot:
    assert e.bounds is not None  # a tuned entry has bounds (gaintune.spec.blocks)
    lo, hi = e.bounds
    mags = (min(abs(lo), abs(hi)), max(abs(lo), abs(hi)))
    return GainSlot(loop, block, name, True, e.value, mags, 1 if lo > 0 else -1, field)


def block_slots(spec: TuningSpec) -> list[GainSlot]:
    """Slots of the tuned block entries: the decoupler's row by row, then the feedforward gains in spec order.

    Their ``loop`` index is past the loops' (``len(spec.loops)`` for the decoupler, one more for the
    feedforward), so nothing indexes ``spec.loops`` with it by mistake.
    """
    out: list[GainSlot] = []
    n = len(spec.loops)
    dec = spec.decoupler
    if dec is not None:
        for a, row in enumerate(dec.matrix):
            for b, e in enumerate(row):
                if is_tuned(e):
                    assert isinstance(e, BlockGainSpec)
                    out.append(_block_slot(n, DECOUPLER, decoupler_gain_name(dec.inputs[a], dec.inputs[b]), e,
                                           f"decoupler.matrix[{a}][{b}]"))
    for k, ff in enumerate(spec.feedforward or []):
        if is_tuned(ff.gain):
            assert isinstance(ff.gain, BlockGainSpec)
            out.append(_block_slot(n + 1, FEEDFORWARD, feedforward_gain_name(ff.loop, ff.input), ff.gain,
                                   f"feedforward[{k}].gain"))
    return out


class GainLayout:
    """Ordered gains of a spec.

    Parameters
    ----------
    spec
        The tuning problem.
    states
        Plant state names (needed for LQ loops).
    auto_bounds
        Bounds (of magnitudes) to use for gains whose spec gives none, keyed
        ``(loop_name, gain)``; typically derived from a classical tuning rule.
    plant
        The spec's built plant, used to resolve ``direction: auto`` (built from
        the spec when omitted; the resolution is memoised per spec either way).
    directions
        +1/-1 per loop, overriding the resolution (tests and tools).

    Raises
    ------
    SpecError
        For unknown gains, initial values outside their bounds or of the wrong
        sign, and loops whose direction cannot be resolved.
    """

    def __init__(
        self,
        spec: TuningSpec,
        states: list[str],
        auto_bounds: dict[tuple[str, str], tuple[float, float]] | None = None,
        *,
        plant: Any = None,
        directions: tuple[int, ...] | None = None,
    ) -> None:
        slots: list[GainSlot] = []
        auto_bounds = auto_bounds or {}
        if directions is None:
            self.direction_info: tuple[LoopDirection, ...] = resolve_directions(spec, plant)
        else:
            if len(directions) != len(spec.loops) or any(d not in (1, -1) for d in directions):
                raise ValueError(f"directions must be +1/-1 per loop ({len(spec.loops)}), got {directions}")
            self.direction_info = tuple(
                LoopDirection(int(d), "set", "set", None, "given to the layout") for d in directions
            )
        self.directions: tuple[int, ...] = tuple(d.sign for d in self.direction_info)
        self._pid_forms = {i: lp.form for i, lp in enumerate(spec.loops) if not lp.is_lq}
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
                sign = gain_sign(loop, name, self.directions[i])
                if value is not None and sign != 0 and value * sign < 0:
                    raise SpecError(f"loops[{i}].gains.{name}.value", self._sign_message(i, name, value))
                mag = abs(value) if value is not None and sign != 0 else value
                if mag is not None and tuned and not bounds[0] <= mag <= bounds[1]:
                    what = "initial value" if sign >= 0 or mag == value else f"initial value {value}: its magnitude"
                    raise SpecError(
                        f"loops[{i}].gains.{name}.value", f"{what} {mag} lies outside bounds {list(bounds)}"
                    )
                slots.append(GainSlot(i, loop.name or f"loop{i}", name, tuned, value, (bounds[0], bounds[1]), sign))
        slots.extend(block_slots(spec))  # tuned static-block entries after every loop's gains
        self.slots = slots
        #: (follower, leader) slot pairs of spec.ties: a follower takes its leader's value (one tuned gain)
        self.ties: list[tuple[int, int]] = self._tie(spec)
        self.tuned_idx = np.array([k for k, s in enumerate(slots) if s.tuned], dtype=int)
        self.log_lo = np.log(np.array([slots[k].bounds[0] for k in self.tuned_idx], dtype=float))
        self.log_hi = np.log(np.array([slots[k].bounds[1] for k in self.tuned_idx], dtype=float))
        self.fixed = np.array([s.value if s.value is not None and not s.tuned else np.nan for s in slots])
        #: Sign of every gain (+1/-1; 0 = any sign), and of the tuned ones.
        self.signs = np.array([s.sign for s in slots], dtype=float)
        self.tuned_signs = self.signs[self.tuned_idx]
        self._free = self.tuned_signs == 0  # tuned entries searched as they are (k_* of LQ loops)
        self._any_free = bool(self._free.any())
        self._all_positive = bool(np.all(self.tuned_signs == 1))

    def _tie(self, spec: TuningSpec) -> list[tuple[int, int]]:
        """Make every tied gain after the first of its tie follow the first (spec.ties), in place."""
        index = {f"{s.loop_name}.{s.name}": k for k, s in enumerate(self.slots)}
        pairs = []
        for tie in spec.ties or []:
            lead = index[tie[0]]  # names checked by the spec (gaintune.spec.mimo)
            for ref in tie[1:]:
                k = index[ref]
                s, ld = self.slots[k], self.slots[lead]
                self.slots[k] = GainSlot(s.loop, s.loop_name, s.name, False, None, ld.bounds, s.sign, s.field)
                pairs.append((k, lead))
        return pairs

    def _follow(self, out: np.ndarray) -> np.ndarray:
        """Tied gains set from their leaders (the follower's own sign: opposite directions share a magnitude)."""
        for k, lead in self.ties:
            f, ld = self.slots[k].sign, self.slots[lead].sign
            out[..., k] = out[..., lead] * (f * ld if f and ld else 1.0)
        return out

    # ------------------------------------------------------------ directions
    def _sign_message(self, loop: int, name: str, value: float) -> str:
        if loop >= len(self.direction_info):  # a block entry: the sign of its bounds
            slot = next(s for s in self.slots if s.loop == loop and s.name == name)
            want = "> 0" if slot.sign > 0 else "< 0"
            return (f"must be {want}, got {value:g}: the bounds of {slot.spec_field} are "
                    f"{'positive' if slot.sign > 0 else 'negative'}; give a value of that sign or change the bounds")
        d = self.direction_info[loop]
        want = "negative" if d.sign < 0 and name in SIGNED_GAINS else "positive"
        if name not in SIGNED_GAINS:
            return f"must be > 0, got {value:g} ({name} is a time or weight, positive for either direction)"
        return (
            f"must be {'< 0' if want == 'negative' else '> 0'}, got {value:g}: this loop is {d.word} ({d.reason}); "
            f"give a {want} value or set loops[{loop}].direction: {d.other}"
        )

    def require_tuned(self) -> None:
        """Raise a SpecError (field ``loops``) when no gain is left to tune: a search needs one."""
        if not self.n_tuned:
            raise SpecError(
                "loops",
                "every gain is fixed (tune: false), so there is nothing to tune; check these gains "
                "with 'gaintune verify SPEC --gains ...' (the POST /v1/verify route), or set tune: true on "
                "the gains to search",
            )

    # ---------------------------------------------------------------- sizes
    @property
    def n_gains(self) -> int:
        """Number of gains, tuned and fixed."""
        return len(self.slots)

    @property
    def n_tuned(self) -> int:
        """Number of tuned gains (the search dimension)."""
        return len(self.tuned_idx)

    @property
    def tuned_slots(self) -> list[GainSlot]:
        """The tuned gains' slots, in search-vector order."""
        return [self.slots[k] for k in self.tuned_idx]

    # ------------------------------------------------------- action mapping
    def action_to_tuned(self, action: np.ndarray) -> np.ndarray:
        """Map actions in [-1, 1]^d (clipped) to tuned gain magnitudes, log-uniformly inside the bounds."""
        a = np.clip(np.asarray(action, dtype=float), -1.0, 1.0)
        return np.exp(self.log_lo + (a + 1.0) * 0.5 * (self.log_hi - self.log_lo))

    def _magnitudes(self, tuned: np.ndarray) -> np.ndarray:
        t = np.asarray(tuned, dtype=float)
        if self._all_positive:
            return np.abs(t)
        return np.where(self._free, t, np.abs(t))

    def tuned_to_action(self, tuned: np.ndarray) -> np.ndarray:
        """Inverse of :meth:`action_to_tuned` (values outside the bounds map outside [-1, 1]).

        Signed tuned values (``full[..., tuned_idx]``) are accepted: their magnitudes are used.
        """
        t = np.log(self._magnitudes(tuned))
        return 2.0 * (t - self.log_lo) / (self.log_hi - self.log_lo) - 1.0

    def full(self, tuned: np.ndarray) -> np.ndarray:
        """Signed full gain vector: (..., n_tuned) magnitudes -> (..., n_gains), fixed gains inserted.

        Each tuned entry becomes ``sign * |entry|`` (its loop's direction for Kp/Ki/Kd), so both
        the search vector and the signed entries of a full vector (``full[..., tuned_idx]``) map
        to the same gains; ``k_*`` state-feedback entries are used as given.
        """
        tuned = np.asarray(tuned, dtype=float)
        out = np.broadcast_to(self.fixed, (*tuned.shape[:-1], self.n_gains)).copy()
        if self._all_positive:
            out[..., self.tuned_idx] = np.abs(tuned)
        else:
            out[..., self.tuned_idx] = np.where(self._free, tuned, self.tuned_signs * np.abs(tuned))
        return self._follow(out) if self.ties else out

    def tuned_of(self, full: np.ndarray) -> np.ndarray:
        """The search vector (magnitudes) of signed full gain vectors: (..., n_gains) -> (..., n_tuned)."""
        return self._magnitudes(np.asarray(full, dtype=float)[..., self.tuned_idx])

    def initial_tuned(self) -> np.ndarray:
        """Initial guesses (magnitudes): spec values where given, else the geometric centre of the bounds."""
        centre = np.exp(0.5 * (self.log_lo + self.log_hi))
        given = [self.slots[k].value for k in self.tuned_idx]
        out = np.array([v if v is not None else c for v, c in zip(given, centre, strict=True)], dtype=float)
        return self._magnitudes(out)

    # ----------------------------------------------------------- dict forms
    def to_dict(self, full: np.ndarray) -> Gains:
        """Signed full gain vector -> ``{loop: {gain: value}}``."""
        out: Gains = {}
        for slot, v in zip(self.slots, np.asarray(full, dtype=float), strict=True):
            out.setdefault(slot.loop_name, {})[slot.name] = float(v)
        return out

    def from_dict(self, gains: Any, *, field: str = "gains") -> np.ndarray:
        """``{loop: {gain: value}}`` -> full gain vector, validated.

        Fixed gains may be omitted (the spec's value is used). Tuned gains must be
        given. Every value must be finite and nonzero with its loop's sign: Kp, Ki,
        Kd positive for a direct-acting loop and negative for a reverse-acting one;
        Ti, Td and LQ weights positive; ``k_*`` entries any sign.

        Raises
        ------
        GainError
            Naming the loop and gain that is missing, unknown or invalid (for a wrong
            sign: the loop's direction, why, and the fix).
        """
        if not isinstance(gains, dict):
            raise GainError(field, "must be a mapping {loop_name: {gain_name: value}}")
        loops = {s.loop_name for s in self.slots}
        unknown_loops = set(gains) - loops
        if unknown_loops:
            raise GainError(field, f"unknown loop(s) {sorted(unknown_loops)}; loops are {sorted(loops)}")
        out = np.empty(self.n_gains)
        followers = {k for k, _ in self.ties}
        for k, slot in enumerate(self.slots):
            if k in followers:
                continue
            given = gains.get(slot.loop_name, {})
            if not isinstance(given, dict):
                raise GainError(f"{field}.{slot.loop_name}", "must be a mapping {gain_name: value}")
            if slot.loop in self._pid_forms:  # K/Ti/Td on a parallel loop (or Ki/Kd on an ideal one): converted
                given = _in_form(self._pid_forms[slot.loop], given, f"{field}.{slot.loop_name}")
            names = {s.name for s in self.slots if s.loop_name == slot.loop_name}
            extra = set(given) - names
            if extra:
                raise GainError(
                    f"{field}.{slot.loop_name}", f"unknown gain(s) {sorted(extra)}; this loop has {sorted(names)}"
                )
            v = given.get(slot.name, None)
            if v is None:
                if slot.tuned or slot.value is None:
                    want = "a negative" if slot.sign < 0 else ("a" if slot.sign == 0 else "a positive")
                    raise GainError(f"{field}.{slot.loop_name}.{slot.name}", f"missing; give {want} number")
                v = slot.value
            if isinstance(v, bool) or not isinstance(v, (int, float)):
                raise GainError(f"{field}.{slot.loop_name}.{slot.name}", f"must be a number, got {v!r}")
            v = float(v)
            if not math.isfinite(v):
                raise GainError(f"{field}.{slot.loop_name}.{slot.name}", f"must be finite, got {v}")
            # Direct state-feedback entries may take any sign; every other gain has its slot's sign. A PID gain
            # (Kp, Ki, Kd) or Td of 0 is legal: that action is off.
            off_ok = slot.name in SIGNED_GAINS + ("Td",) and slot.loop in self._pid_forms
            if slot.sign != 0 and not (v * slot.sign > 0 or (v == 0 and off_ok)):
                raise GainError(f"{field}.{slot.loop_name}.{slot.name}", self._sign_message(slot.loop, slot.name, v))
            out[k] = v
        return self._tied_from(gains, out, field) if self.ties else out

    def _tied_from(self, gains: dict, out: np.ndarray, field: str) -> np.ndarray:
        """Tied gains of ``gains``: left out, or equal to what their leader gives (else GainError)."""
        given = self._follow(out.copy())
        for k, lead in self.ties:
            s, ld = self.slots[k], self.slots[lead]
            v = gains.get(s.loop_name, {}).get(s.name) if isinstance(gains.get(s.loop_name), dict) else None
            if v is not None and not (isinstance(v, (int, float)) and math.isclose(float(v), given[k], rel_tol=1e-9)):
                raise GainError(f"{field}.{s.loop_name}.{s.name}", f"is tied to {ld.loop_name}.{ld.name} "
                                f"({given[k]:g}); give that value or leave it out")
        return given
