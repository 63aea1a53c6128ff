"""The compiled (numba) closed-loop kernel, split by job:

* :mod:`.drivers` - the time loop, its two compiled variants (``CHUNK`` lanes,
  single lane), the threads over chunks and the JIT dispatch: :func:`.drivers.run_jit`,
  :func:`simulate_kernel`;
* :mod:`.law` - the controller law and the actuator;
* :mod:`.plant` - measured outputs, the delayed input, the state update (ZOH, RK4);
* :mod:`.signals` - reference and disturbance signals;
* :mod:`.monitor` - divergence and the safety monitor;
* :mod:`.metrics` - streaming metrics and traces;
* :mod:`.tape_vm` - the casadi tape interpreter (nonlinear plants);
* :mod:`.layout`, :mod:`.ops` - chunk state layout, metric rows, scalar primitives;
* :mod:`.pipeline` - the numba compiler pipeline of the variants.

Importing this package does not import numba: :func:`run_kernel` runs one candidate on the
single-lane kernel compiled ahead of time (:mod:`gaintune.sim.kernel_aot`) where it is built, and
imports :mod:`.drivers` (numba) for anything else. The other names of :mod:`.drivers` load it on
first use.

The stage modules are inlined into the one compiled function (numba
``inline="always"``). Its arguments are a :class:`gaintune.sim.kernel_args.KernelArgs`.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

import numpy as np

from gaintune.sim.kernel_aot import load_single
from gaintune.sim.kernel_args import KernelArgs

from .layout import CHUNK, METRICS

if TYPE_CHECKING:
    from .drivers import (
        COMPILED,
        VARIANTS,
        simulate_kernel,
        simulate_kernel_parallel,
        simulate_kernel_serial,
        simulate_kernel_single,
    )

__all__ = [
    "KernelArgs", "run_kernel", "simulate_kernel", "simulate_kernel_parallel", "simulate_kernel_serial",
    "simulate_kernel_single", "VARIANTS", "COMPILED", "METRICS", "CHUNK",
]

_FROM_DRIVERS = {"COMPILED", "VARIANTS", "simulate_kernel", "simulate_kernel_parallel", "simulate_kernel_serial",
                 "simulate_kernel_single"}


def run_kernel(args: KernelArgs, variant: str = "auto") -> np.ndarray:
    """Run the compiled kernel on a record.

    Parameters
    ----------
    args
        The kernel's arguments, e.g. from :meth:`gaintune.sim.Simulator.kernel_args`.
        Trace arrays in it are written in place when ``args.want_traces``.
    variant
        ``"auto"`` (what :meth:`~gaintune.sim.Simulator.run` uses): one candidate on the single-lane
        kernel compiled ahead of time where it is built (:mod:`gaintune.sim.kernel_aot`: the same
        numbers, bit for bit, without importing numba), else the JIT variant ``"single"``; one chunk on
        ``"serial"``; more on ``"parallel"``. Or one of the JIT :data:`VARIANTS` by name. All variants
        give the same numbers on a plant shared by a chunk.

    Returns
    -------
    np.ndarray
        (16, B) metric rows, in the order of :data:`METRICS` (diverged/tripped as 0/1 floats).
    """
    if variant == "auto" and args.u_op.shape[0] == 1:
        single = load_single()
        if single is not None:
            return single(*args, 0, 1)
    from .drivers import run_jit

    return run_jit(args, variant)


def __getattr__(name: str) -> Any:
    if name in _FROM_DRIVERS:
        from . import drivers

        return getattr(drivers, name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
