"""The gains verified: any accepted form as the validated, signed full gain vector."""

from __future__ import annotations

from typing import Any

import numpy as np

from gaintune.controllers.layout import GainLayout
from gaintune.errors import GainError
from gaintune.spec import TuningSpec

__all__ = ["coerce_gains", "fixed_gain_overrides"]


def coerce_gains(layout: GainLayout, gains: Any) -> np.ndarray:
    """Nested dict or vector (full or tuned-only) -> validated, signed full gain vector. Raises GainError.

    Dicts and full vectors carry signed gains (negative Kp, Ki, Kd for a reverse-acting loop);
    a tuned-only vector may hold the search magnitudes (the layout gives them their loop's sign).
    """
    if isinstance(gains, dict):
        return layout.from_dict(gains)
    if _has_boolean(gains):  # numpy would read true as 1.0
        raise GainError("gains", "must be numbers, not booleans (true/false)")
    try:
        arr = np.asarray(gains, dtype=float)
    except (TypeError, ValueError):
        raise GainError("gains", "must be a mapping {loop: {gain: value}} or a vector of numbers") from None
    if arr.ndim != 1:
        raise GainError("gains", f"a gain vector must be 1-D, got shape {arr.shape}")
    if arr.size == layout.n_gains:
        full = arr
    elif arr.size == layout.n_tuned:
        full = layout.full(arr)
    else:
        names = [f"{s.loop_name}.{s.name}" for s in layout.slots]
        raise GainError("gains", f"expected {layout.n_gains} gains ({', '.join(names)}), got {arr.size}")
    return layout.from_dict(layout.to_dict(full))


def _has_boolean(gains: Any) -> bool:
    """True when a gain vector holds a bool (a bool array, or one in a list or tuple)."""
    if isinstance(gains, np.ndarray):
        return gains.dtype == bool
    if isinstance(gains, (list, tuple)):
        return any(isinstance(g, (bool, np.bool_)) for g in gains)
    return isinstance(gains, (bool, np.bool_))


def fixed_gain_overrides(spec: TuningSpec, layout: GainLayout, full: np.ndarray) -> list[str]:
    """A note per gain the spec fixes (``tune: false``) but the given gains set to another value.

    The given value is the one verified (an engineer adjusts a fixed gain by hand and checks it), so
    the report says so instead of letting a reader assume the spec's value."""
    out = []
    for k, slot in enumerate(layout.slots):
        if slot.tuned:  # a tuned block entry's slot has no loop to look in
            continue
        given = spec.loops[slot.loop].gains.get(slot.name)
        if given is None or given.value is None or full[k] == given.value:
            continue
        out.append(f"{slot.loop_name}.{slot.name} = {full[k]:g} was verified, not the spec's fixed value "
                   f"{given.value:g} (loops[{slot.loop}].gains.{slot.name}, tune: false)")
    return out
