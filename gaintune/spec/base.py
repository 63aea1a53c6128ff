"""The shared base of the spec schema: the strict pydantic model, finiteness checks and size limits.

Every spec model derives from :class:`_Model`: unknown keys are errors, every number must be
finite (NaN and infinity are refused in every numeric field, from YAML's ``.nan`` as from JSON),
and a boolean is not a number (``true`` is refused where a number is expected, not read as 1).
The limits (:data:`MAX_STEPS`, :data:`MAX_ORDER`, :data:`MAX_LOOPS`) live here so the section
modules can enforce them without importing the package that re-exports them.
"""

from __future__ import annotations

import math
from functools import cache
from typing import Annotated, Any, Literal, get_args

from pydantic import BaseModel, BeforeValidator, ConfigDict, Field, ValidationError, ValidationInfo, field_validator
from pydantic_core import InitErrorDetails, PydanticCustomError

from gaintune.errors import SpecError

__all__ = ["MAX_STEPS", "MAX_DELAY_STEPS", "MAX_ORDER", "MAX_LOOPS", "MAX_BUDGET", "check_delay_samples",
           "FiniteNumber"]

#: Largest number of simulation steps (horizon / dt) in one scenario.
MAX_STEPS = 200_000
#: Largest plant delay in samples (delay / dt): the simulator holds that many past inputs per lane,
#: 40 MB each at this limit (a 1e7 s delay at dt = 0.05 s took ~5 GB and 1e300 s overflowed). Larger
#: than MAX_STEPS on purpose: a long delay sampled finely (5 s at dt = 1 us) is a valid verification.
MAX_DELAY_STEPS = 5_000_000
#: Largest plant state dimension accepted.
MAX_ORDER = 20
#: Deepest cascade accepted.
MAX_LOOPS = 6
#: Largest search budget (closed-loop simulations). Far beyond any useful search (a 3,000-sim tune
#: takes seconds; this is hours), it keeps a mistyped budget (1e23) from training for ever and
#: from sizing an off-policy agent's replay buffer in terabytes.
MAX_BUDGET = 10_000_000


def _not_boolean(v: Any) -> Any:
    if isinstance(v, bool):
        raise _boolean_error("must be a number", v)
    return v


def _boolean_error(what: str, value: bool) -> PydanticCustomError:
    return PydanticCustomError("number_not_boolean", "{msg}", {"msg": f"{what}, not a boolean ({str(value).lower()})"})


#: A float field for models outside the spec (the API's gains): finite, and true/false refused
#: rather than read as 1.0/0.0; ints are taken. The spec's own models get the same rules from
#: :class:`_Model`.
FiniteNumber = Annotated[float, Field(allow_inf_nan=False), BeforeValidator(_not_boolean)]


class _Model(BaseModel):
    """Base: unknown keys are errors, so typos are caught, not ignored; numbers are finite and not booleans."""

    # allow_inf_nan=False: one rule for every float field, whatever the input format (the CLI's
    # YAML has .nan and .inf; the API's JSON parser refuses them before the schema sees them)
    model_config = ConfigDict(extra="forbid", populate_by_name=True, allow_inf_nan=False)

    @field_validator("*", mode="before")
    @classmethod
    def _no_boolean_numbers(cls, v: Any, info: ValidationInfo) -> Any:
        # pydantic's lax mode reads true as 1.0 (or 1): a boolean where a number belongs is a mistake
        field = info.field_name or ""  # always set for a field validator
        policy = _bool_policy(cls, field)
        if policy == "allow" or (policy == "top" and not isinstance(v, bool)):
            return v
        found = _boolean_in(v, field)
        if found is not None:
            where, value = found
            raise _boolean_error(f"{where} must be a number", value)
        return v


def _finite(v: Any, what: str) -> Any:
    if isinstance(v, float) and not math.isfinite(v):
        raise ValueError(f"{what} must be finite, got {v}; use a real number")
    return v


def _error_at(loc: tuple, msg: str, value: Any) -> ValidationError:
    """A ValidationError located at the field ``loc`` (a ValueError raised in a model validator has no
    location); raised in a nested model's validator, ``loc`` is relative to that model."""
    return ValidationError.from_exception_data("TuningSpec", [InitErrorDetails(
        type=PydanticCustomError("spec_field", "{msg}", {"msg": msg}), loc=loc, input=value)])


def check_delay_samples(delay: float, dt: float, field: str = "plant.delay") -> None:
    """SpecError when ``delay`` is more than MAX_DELAY_STEPS samples of ``dt``: each simulated lane
    holds that many past inputs. The spec bounds numeric delays when it loads; this catches one
    written as a parameter expression (``delay: "T"`` with ``T: 1e300``) once it has a value."""
    if not delay / dt <= MAX_DELAY_STEPS:
        raise SpecError(field, f"the delay, {delay:g} s, is {delay / dt:.3g} samples at dt = {dt:g} s, over the limit "
                               f"of {MAX_DELAY_STEPS}; give a delay <= {MAX_DELAY_STEPS * dt:g} s or a larger dt")


@cache
def _bool_policy(model: type[BaseModel], field: str) -> Literal["allow", "top", "deep"]:
    """How :class:`_Model` checks ``field`` for booleans: "allow" unless its type holds numbers and no
    bool; then "deep" (every value inside lists, tuples and dicts, e.g. ``bounds`` or ``params``), or
    "top" (the value itself) when the type may also be a model, which checks its own fields."""
    kinds = set(_types_in(model.model_fields[field].annotation))
    if bool in kinds or not kinds & {float, int}:
        return "allow"
    if any(isinstance(k, type) and issubclass(k, BaseModel) for k in kinds):
        return "top"
    return "deep"


def _types_in(tp: Any) -> list[Any]:
    out = [tp]
    for arg in get_args(tp):
        out.extend(_types_in(arg))
    return out


def _boolean_in(v: Any, path: str) -> tuple[str, bool] | None:
    """The path (``field[1]``, ``field.key``) and value of the first bool in ``v``, else None."""
    if not _holds_boolean(v):  # the common case, without building a path per value
        return None
    stack: list[tuple[Any, str]] = [(v, path)]
    while stack:
        node, where = stack.pop()
        if isinstance(node, bool):
            return where, node
        if isinstance(node, dict):
            stack.extend(reversed([(x, f"{where}.{k}") for k, x in node.items()]))
        elif isinstance(node, (list, tuple)):
            stack.extend(reversed([(x, f"{where}[{i}]") for i, x in enumerate(node)]))
    return None


def _holds_boolean(v: Any) -> bool:
    """True when ``v`` is a bool or holds one in its lists, tuples and dicts (iterative: YAML may nest
    thousands of levels)."""
    if isinstance(v, bool):
        return True
    stack = [v]
    while stack:
        node = stack.pop()
        if isinstance(node, dict):
            node = node.values()
        elif not isinstance(node, (list, tuple)):
            continue
        for x in node:
            if isinstance(x, bool):
                return True
            if isinstance(x, (dict, list, tuple)):
                stack.append(x)
    return False
