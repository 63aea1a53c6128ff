"""The nonlinear plant's arguments to the MIMO kernel: its casadi tapes and its rows per parameter set.

See :mod:`gaintune.sim.mimo_ode_kernel` for what the kernel does with them.
"""

from __future__ import annotations

import numpy as np

from gaintune.plants.mimo import MimoPlant

__all__ = ["ode_tapes", "ode_rows"]


def ode_tapes(mimo: MimoPlant) -> tuple[tuple, tuple]:
    """The kernel's tape arguments (op, a, b, o, c, n_work) for f and h; empty ones for a linear plant."""
    if not mimo.nonlinear:
        empty_i, empty_f = np.zeros(0, dtype=np.int64), np.zeros(0)
        blank = (empty_i, empty_i, empty_i, empty_i, empty_f, 1)
        return blank, blank
    from gaintune.sim.tape import make_tape

    out = []
    for fn in (mimo.ode.f, mimo.ode.h):
        t = make_tape(fn)
        out.append((t.op, t.a, t.b, t.o, t.c, t.n_work))
    return out[0], out[1]


def ode_rows(mimo: MimoPlant, values: dict[str, float], row: np.ndarray) -> dict:
    """The kernel's plant arrays for a nonlinear plant at one parameter row: no channels, its operating point."""
    x0, u0, y0 = mimo.operating_point(values)
    n, p = len(x0), len(y0)
    zi, zf = np.zeros(0, dtype=np.int64), np.zeros((0, n))
    return dict(Ad=np.zeros((n, n)), Cm=np.zeros((p, n)), bstart=zi, bsize=zi, ch_blk=zi, ch_src=zi, ch_du=zi,
                ch_dd=zi, G0u=zf, G1u=zf, G0d=zf, G1d=zf, Pq=np.asarray(row, dtype=float).reshape(-1),
                x_op=x0, u_op=u0, y_op=y0)
