"""Plant-only work of the MIMO verification, done once per plant object and reused for every controller.

A search checks thousands of controllers on one plant. The plant's Padé realisation of the loop
channels, its eigenvalues, its hidden modes and its modal form do not depend on the controller:
:func:`plant_parts` keeps them per (plant object, measured outputs, driven inputs), so every
:class:`~gaintune.verification.mimo_loop.MimoLoop` built on the same plant object reuses them. The
values are those a fresh computation gives (the same functions on the same arrays), so a report
is the same with or without the cache.

Entries are kept for the most recent :data:`MAX_PLANTS` plants (least recently used evicted); a key
holds the plant object itself, so an id reused by a new object never matches an old entry.
"""

from __future__ import annotations

import threading
from collections import OrderedDict
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np

from gaintune.lti.mimo import MimoLti

__all__ = ["PlantParts", "plant_parts", "registered", "plant_eigvals", "plant_memo", "register_transient", "MAX_PLANTS"]

#: Plants whose parts are kept.
MAX_PLANTS = 8

_LOCK = threading.Lock()
_PARTS: OrderedDict[tuple[int, tuple[int, ...], tuple[int, ...]], PlantParts] = OrderedDict()
#: Controller realisations known to plant_memo: the few most recent (one per loop being checked)
_TRANSIENT: OrderedDict[int, PlantParts] = OrderedDict()
_MAX_TRANSIENT = 4
#: id(A) of a kept realisation -> (its parts, Padé order): how hidden_modes and eigvals recognise it
_BY_A: dict[int, tuple[PlantParts, int]] = {}


@dataclass
class PlantParts:
    """The plant-only figures of one plant's loop channels (``outs`` measured, ``ins`` driven)."""

    plant: MimoLti
    outs: tuple[int, ...]
    ins: tuple[int, ...]
    real: dict[int, tuple] = field(default_factory=dict)  # Padé order -> (A, B, C, D) of the loop channels
    eig: dict[int, np.ndarray] = field(default_factory=dict)  # Padé order -> eigenvalues of A
    hidden: dict[tuple, np.ndarray] = field(default_factory=dict)  # (order, floor) or (name, order) -> modes
    modal: tuple | None = None  # the modal form of a state-space plant (MimoLoop._plant_channels)
    max_delay: float | None = None  # the largest delay of the channels

    def realisation(self, order: int) -> tuple:
        """(A, B, C, D) of the loop channels, delays as Padé approximants of ``order`` (0 drops them)."""
        hit = self.real.get(order)
        if hit is None:
            P = self.plant.pade_ss(order)
            ins, outs = list(self.ins), list(self.outs)
            hit = (P.A, P.B[:, ins], P.C[outs], P.D[np.ix_(outs, ins)])
            with _LOCK:
                self.real[order] = hit
                _BY_A[id(hit[0])] = (self, order)
        return hit

    def memo(self, store: dict, key: object, compute: Callable[[], np.ndarray]) -> np.ndarray:
        """``store[key]``, computed once; a copy, so a caller may change it."""
        hit = store.get(key)
        if hit is None:
            hit = compute()
            store[key] = hit
        return hit.copy()


def plant_parts(plant: MimoLti, outs: tuple[int, ...], ins: tuple[int, ...]) -> PlantParts:
    """The kept parts of ``plant``'s channels ``outs`` x ``ins`` (new, empty ones the first time)."""
    key = (id(plant), tuple(outs), tuple(ins))
    with _LOCK:
        hit = _PARTS.get(key)
        if hit is not None and hit.plant is plant:
            _PARTS.move_to_end(key)
            return hit
        parts = PlantParts(plant, tuple(outs), tuple(ins))
        _PARTS[key] = parts
        while len(_PARTS) > MAX_PLANTS:
            _, old = _PARTS.popitem(last=False)
            for A, _B, _C, _D in old.real.values():
                _BY_A.pop(id(A), None)
        return parts


def registered(A: np.ndarray, B: np.ndarray | None = None, C: np.ndarray | None = None
               ) -> tuple[PlantParts, int] | None:
    """(parts, Padé order) when ``A`` (and ``B``, ``C`` if given) are a kept plant realisation's arrays."""
    hit = _BY_A.get(id(A))
    if hit is None:
        return None
    parts, order = hit
    real = parts.real.get(order)
    if real is None or real[0] is not A or (B is not None and real[1] is not B) or (C is not None and real[2] is not C):
        return None
    return hit


def plant_eigvals(A: np.ndarray) -> np.ndarray:
    """``np.linalg.eigvals(A)``, remembered when ``A`` is a kept plant realisation's state matrix."""
    hit = registered(A)
    if hit is None:
        return np.linalg.eigvals(A)
    parts, order = hit
    return parts.memo(parts.eig, order, lambda: np.linalg.eigvals(A))


def plant_memo(A: np.ndarray, B: np.ndarray, C: np.ndarray, name: str, compute: Callable[[], np.ndarray]
               ) -> np.ndarray:
    """``compute()``, remembered under ``name`` when (A, B, C) are a kept plant realisation's arrays (a
    plant-only figure, e.g. its hidden modes); computed afresh for any other (a controller's) realisation."""
    hit = registered(A, B, C)
    if hit is None:
        return compute()
    parts, order = hit
    return parts.memo(parts.hidden, (name, order), compute)


def register_transient(owner: MimoLti, real: tuple) -> None:
    """Make the realisation ``real`` (A, B, C, D) of ``owner`` (a controller) known to :func:`plant_memo`
    for a short while: a figure asked for twice within one check (its hidden modes, once per Padé order)
    is then computed once. Only the most recent few are kept."""
    parts = PlantParts(owner, (), (), real={0: real})
    with _LOCK:
        _TRANSIENT[id(real[0])] = parts
        _BY_A[id(real[0])] = (parts, 0)
        while len(_TRANSIENT) > _MAX_TRANSIENT:
            key, _ = _TRANSIENT.popitem(last=False)
            _BY_A.pop(key, None)
