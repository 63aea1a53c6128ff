"""The compiled (numba) closed-loop kernel, split by job:

* :mod:`.drivers` - the time loop, its two compiled variants (``CHUNK`` lanes,
  single lane), the threads over chunks and the dispatch: :func:`run_kernel`,
  :func:`simulate_kernel`;
* :mod:`.law` - the controller law and the actuator;
* :mod:`.plant` - measured outputs, the delayed input, the state update (ZOH, RK4);
* :mod:`.signals` - reference and disturbance signals;
* :mod:`.monitor` - divergence and the safety monitor;
* :mod:`.metrics` - streaming metrics and traces;
* :mod:`.tape_vm` - the casadi tape interpreter (nonlinear plants);
* :mod:`.layout`, :mod:`.ops` - chunk state layout, metric rows, scalar primitives;
* :mod:`.pipeline` - the numba compiler pipeline of the variants.

The stage modules are inlined into the one compiled function (numba
``inline="always"``). Its arguments are a :class:`gaintune.sim.kernel_args.KernelArgs`.
"""

from __future__ import annotations

from gaintune.sim.kernel_args import KernelArgs

from .drivers import (
    COMPILED,
    VARIANTS,
    run_kernel,
    simulate_kernel,
    simulate_kernel_parallel,
    simulate_kernel_serial,
    simulate_kernel_single,
)
from .layout import CHUNK, METRICS

__all__ = [
    "KernelArgs", "run_kernel", "simulate_kernel", "simulate_kernel_parallel", "simulate_kernel_serial",
    "simulate_kernel_single", "VARIANTS", "COMPILED", "METRICS", "CHUNK",
]
