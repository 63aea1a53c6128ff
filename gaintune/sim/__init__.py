"""Batched closed-loop simulation: B gain sets (each with its own draw) in one compiled call.

* :mod:`~gaintune.sim.simulator` - :class:`Simulator`, :class:`SimResult`, :func:`simulate`;
* :mod:`~gaintune.sim.kernel_args` - :class:`KernelArgs`, the kernel's arguments by name;
* :mod:`~gaintune.sim.kernel` - the compiled (numba) kernel and its metrics, split by job
  (controller law, plant, signals, monitor, metrics, drivers);
* :mod:`~gaintune.sim.build` - discretisation and kernel arrays;
* :mod:`~gaintune.sim.draws` - per-candidate plant and scenario draws;
* :mod:`~gaintune.sim.chatter` - chattering-saturation detection.

``Simulator`` and friends load on first use (PEP 562): importing ``gaintune.sim.draws``
(as verification does) does not load numba, nor does ``KernelArgs``.
"""

from __future__ import annotations

import importlib
from typing import TYPE_CHECKING, Any

__all__ = ["Simulator", "SimResult", "KernelArgs", "METRICS", "simulate"]

if TYPE_CHECKING:  # pragma: no cover
    from gaintune.sim.kernel import METRICS
    from gaintune.sim.kernel_args import KernelArgs
    from gaintune.sim.simulator import SimResult, Simulator, simulate


def __getattr__(name: str) -> Any:
    if name in ("Simulator", "SimResult", "simulate"):
        return getattr(importlib.import_module("gaintune.sim.simulator"), name)
    if name == "KernelArgs":
        return importlib.import_module("gaintune.sim.kernel_args").KernelArgs
    if name == "METRICS":
        return importlib.import_module("gaintune.sim.kernel").METRICS
    raise AttributeError(f"module 'gaintune.sim' has no attribute {name!r}")
