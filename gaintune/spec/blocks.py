"""Static blocks of a loop architecture whose entries may be tuned: decoupler entries and feedforward gains.

An entry is a number (fixed) or a mapping written like a loop gain (``loops[i].gains.<name>``):
``{value: 1.4, bounds: [0.5, 3], tune: true}``. Unlike a loop gain, an entry has no direction to take its
sign from: its ``bounds`` carry the sign. Both bounds are of one sign (``[0.5, 3]`` or ``[-3, -0.5]``)
and the search covers their magnitudes on a log scale, as it does every gain; an entry that must be
able to cross zero is not tunable this way (fix it, or give the sign the plant's gains say it has).

* :class:`BlockGainSpec`: one tunable entry;
* :class:`FeedforwardSpec`: ``u[input] += gain * r[loop]``, the reference of a chain's outer loop;
* :func:`check_blocks`: the names the blocks use, checked once the whole spec is known.
"""

from __future__ import annotations

import math
from typing import TYPE_CHECKING, Annotated, Any

from pydantic import Discriminator, Field, Tag, model_validator

from gaintune.spec.base import _error_at, _finite, _Model

if TYPE_CHECKING:  # pragma: no cover
    from gaintune.spec import TuningSpec

__all__ = ["BlockGainSpec", "BlockEntry", "FeedforwardSpec", "DECOUPLER", "FEEDFORWARD", "entry_value",
           "decoupler_gain_name", "feedforward_gain_name", "check_blocks", "has_tuned_blocks", "is_tuned"]

#: Pseudo-loop name of the tuned decoupler entries in a gain set ``{loop: {gain: value}}``.
DECOUPLER = "decoupler"
#: Pseudo-loop name of the tuned feedforward gains.
FEEDFORWARD = "feedforward"


class BlockGainSpec(_Model):
    """One entry of a static block: fixed at ``value`` (``tune: false``), or tuned within signed ``bounds``."""

    tune: bool = True
    value: float | None = Field(None, description="Fixed value (tune: false) or initial guess, inside the bounds.")
    bounds: tuple[float, float] | None = Field(
        None, description="[low, high] of one sign (e.g. [0.1, 3] or [-3, -0.1]): the magnitude is searched on a "
        "log scale; required when tuned.")

    @model_validator(mode="after")
    def _check(self) -> BlockGainSpec:
        if self.value is not None:
            _finite(self.value, "value")
        if not self.tune:
            if self.value is None:
                raise _error_at(("value",), "a fixed entry (tune: false) needs a value", None)
            return self
        if self.bounds is None:
            raise _error_at(("bounds",), "a tuned entry needs bounds [low, high] of one sign, e.g. [0.1, 3] or "
                            "[-3, -0.1] (its magnitude is searched on a log scale); or fix it with tune: false", None)
        lo, hi = self.bounds
        if not (math.isfinite(lo) and math.isfinite(hi)) or not lo < hi or lo * hi <= 0:
            raise _error_at(("bounds",), f"must be [low, high] with low < high, both of one sign and nonzero, got "
                            f"{list(self.bounds)}: the magnitude is searched on a log scale, so the range cannot "
                            "contain 0; give e.g. [0.1, 3] or [-3, -0.1]", list(self.bounds))
        if self.value is not None and not lo <= self.value <= hi:
            raise _error_at(("value",), f"initial value {self.value:g} lies outside bounds {list(self.bounds)}; "
                            "give a value inside them or widen the bounds", self.value)
        return self

    @property
    def initial(self) -> float:
        """The value, else the bounds' geometric centre (with their sign)."""
        if self.value is not None:
            return float(self.value)
        assert self.bounds is not None  # a tuned entry has bounds (checked above)
        lo, hi = self.bounds
        return math.copysign(math.sqrt(lo * hi), lo)


def _entry_kind(v: Any) -> str:
    return "entry" if isinstance(v, dict | BlockGainSpec) else "number"


#: A block entry: a number (fixed) or ``{value, bounds, tune}``.
BlockEntry = Annotated[Annotated[float, Tag("number")] | Annotated[BlockGainSpec, Tag("entry")],
                       Discriminator(_entry_kind)]


def entry_value(e: float | BlockGainSpec) -> float:
    """The number an entry stands for in a fixed matrix: the number, the value or the bounds' centre."""
    return float(e) if not isinstance(e, BlockGainSpec) else e.initial


def is_tuned(e: float | BlockGainSpec) -> bool:
    """Whether an entry is searched."""
    return isinstance(e, BlockGainSpec) and e.tune


class FeedforwardSpec(_Model):
    """A static reference feedforward: ``u[input] += gain * r``, ``r`` the reference of the chain whose outer loop is
    ``loop``, added before the input's saturation."""

    loop: str = Field(description="The outer loop of a chain (a loop that takes a reference, not another loop's "
                                  "output).")
    input: str = Field(description="The plant input the feedforward adds to.")
    gain: BlockEntry = Field(description="A number (fixed), or {value, bounds, tune} (bounds of one sign).")


def decoupler_gain_name(row: str, col: str) -> str:
    """Name of the tuned decoupler entry from the loop output at ``col`` to plant input ``row``."""
    return f"d_{row}_{col}"


def feedforward_gain_name(loop: str, inp: str) -> str:
    """Name of the tuned feedforward gain from loop ``loop``'s reference to plant input ``inp``."""
    return f"ff_{loop}_{inp}"


def has_tuned_blocks(spec: TuningSpec) -> tuple[bool, bool]:
    """(any decoupler entry tuned, any feedforward gain tuned)."""
    dec = spec.decoupler is not None and any(is_tuned(e) for row in spec.decoupler.matrix for e in row)
    ff = any(is_tuned(f.gain) for f in spec.feedforward or [])
    return dec, ff


def check_blocks(spec: TuningSpec, names: list[str], in_names: list[str] | None, outer: set[str]) -> None:
    """The feedforward's loops and inputs, and the pseudo-loop names of the tuned entries (ValidationError);
    ``outer`` names the loops that take a reference (the chains' outer loops)."""
    seen: dict[tuple[str, str], int] = {}
    for k, ff in enumerate(spec.feedforward or []):
        if ff.loop not in names:
            raise _error_at(("feedforward", k, "loop"), f"no loop named {ff.loop!r}; loops: {', '.join(names)}",
                            ff.loop)
        if ff.loop not in outer:
            raise _error_at(("feedforward", k, "loop"), f"loop {ff.loop!r} takes its setpoint from another loop; a "
                            "feedforward starts from a reference: name the outer loop of the chain", ff.loop)
        if in_names is not None and ff.input not in in_names:
            raise _error_at(("feedforward", k, "input"), f"the plant has no input {ff.input!r}; inputs: "
                            f"{', '.join(in_names)}", ff.input)
        if (ff.loop, ff.input) in seen:
            raise _error_at(("feedforward", k), f"feedforward[{seen[ff.loop, ff.input]}] already goes from "
                            f"{ff.loop!r} to {ff.input!r}; give one gain per pair", ff.loop)
        seen[ff.loop, ff.input] = k
    dec_tuned, ff_tuned = has_tuned_blocks(spec)
    for block, on in ((DECOUPLER, dec_tuned), (FEEDFORWARD, ff_tuned)):
        if on and block in names:
            raise _error_at(("loops", names.index(block), "name"), f"{block!r} names the tuned {block} entries in a "
                            f"gain set ({{{block}: {{...}}}}); rename this loop", block)
    _unique_gain_names(spec)


def _unique_gain_names(spec: TuningSpec) -> None:
    """Two tuned entries whose names coincide (``d_a_b_c`` from inputs ``a_b, c`` and ``a, b_c``) are refused."""
    if spec.decoupler is not None:
        ins, seen = spec.decoupler.inputs, set()
        for a, row in enumerate(spec.decoupler.matrix):
            for b, e in enumerate(row):
                name = decoupler_gain_name(ins[a], ins[b])
                if is_tuned(e) and name in seen:
                    raise _error_at(("decoupler", "matrix", a, b), f"its gain name {name} is another tuned entry's "
                                    "too (the input names run together); rename an input", name)
                seen.add(name)
    names = [feedforward_gain_name(f.loop, f.input) for f in spec.feedforward or [] if is_tuned(f.gain)]
    for k, n in enumerate(names):
        if n in names[:k]:
            raise _error_at(("feedforward",), f"two tuned gains are both named {n} (the names run together); "
                            "rename a loop or an input", n)
