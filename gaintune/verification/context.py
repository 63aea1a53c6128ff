"""Per-spec objects reused between verifications: plant, gain layout, linearisation, simulator.

Verifying a new gain set on a spec seen before rebuilds nothing: the entry (keyed by
``spec.content_hash()``) holds the plant (whose linearisation cache is then warm), the
layout, the nominal linear model and the :class:`gaintune.sim.Simulator` (whose
discretisation / draw-array memo is then warm). A small thread-safe LRU
(:class:`gaintune.cache.LRU`).
"""

from __future__ import annotations

import threading
from dataclasses import dataclass, field
from typing import Any

from gaintune.cache import LRU
from gaintune.controllers.layout import GainLayout
from gaintune.plants.noise_limit import NoiseLimit, noise_limits
from gaintune.plants.plant import LinearModel, Plant, build_plant
from gaintune.spec import TuningSpec

__all__ = ["SpecContext", "spec_context", "clear_cache", "CACHE_SIZE"]

#: Specs kept (least recently used evicted).
CACHE_SIZE = 32


@dataclass
class SpecContext:
    """The per-spec objects verification reuses: plant, layout, linearisation, and (built on first
    use) noise limits and simulator."""

    spec_hash: str
    plant: Plant
    layout: GainLayout
    lin: LinearModel
    _sim: Any = None
    _noise: list[NoiseLimit] | None = None
    _lock: threading.Lock = field(default_factory=threading.Lock, repr=False)

    def noise_limits(self, spec: TuningSpec) -> list[NoiseLimit]:
        """The spec's per-loop noise-sensitivity limits (``auto`` resolved on the nominal model), computed once."""
        if self._noise is None:
            self._noise = noise_limits(spec, self.lin)
        return self._noise

    def simulator(self, spec: TuningSpec):
        """The spec's simulator (built on first use); None when :mod:`gaintune.sim` is unavailable."""
        if self._sim is None:
            with self._lock:
                if self._sim is None:
                    import importlib

                    try:
                        sim = importlib.import_module("gaintune.sim")
                        runner = sim.Simulator
                    except (ImportError, AttributeError):
                        return None
                    self._sim = runner(spec, self.plant, self.layout)
        return self._sim


_CACHE: LRU[str, SpecContext] = LRU(CACHE_SIZE)


def spec_context(spec: TuningSpec, plant: Plant | None = None, layout: GainLayout | None = None, *,
                 spec_hash: str | None = None) -> SpecContext:
    """The cached context of ``spec`` (built on a miss, from ``plant``/``layout`` when given).

    A cached entry wins over ``plant``/``layout`` passed in: both are built from the spec
    (the key is the hash of its full content), so they are equivalent. ``spec_hash``:
    ``spec.content_hash()`` when the caller has it already. Two threads missing the same
    spec may both build it; the first stored is kept and returned to both.
    """
    key = spec_hash or spec.content_hash()

    def build() -> SpecContext:
        p = plant or build_plant(spec.plant)
        lay = layout or GainLayout(spec, p.states)
        return SpecContext(key, p, lay, p.linearize())

    return _CACHE.get_or_build(key, build)


def clear_cache() -> None:
    """Forget every cached spec context."""
    _CACHE.clear()
