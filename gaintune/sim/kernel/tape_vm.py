"""The tape interpreter: a casadi instruction tape run on the lanes of a chunk (nonlinear plants).

The tape (:mod:`gaintune.sim.tape`) is a flat list of instructions; each one is
a short loop over the chunk's lanes, so the interpreter's dispatch is paid once
per instruction for the whole chunk and the loops vectorise.
"""

from __future__ import annotations

import math

import numba as nb
import numpy as np

from gaintune.sim import tape as T

from .ops import _max, _min


@nb.njit(cache=True)
def _run_tape(op, ta, tb, to, tc, inp, w, out, m):
    """Execute a tape on chunk columns 0..m-1: inputs ``inp`` (rows), work ``w``, outputs ``out``."""
    for q in range(op.shape[0]):
        code = op[q]
        a = ta[q]
        b = tb[q]
        o = to[q]
        if code == T.LOAD:
            for j in range(m):
                w[o, j] = inp[a, j]
        elif code == T.STORE:
            for j in range(m):
                out[o, j] = w[a, j]
        elif code == T.CONST:
            for j in range(m):
                w[o, j] = tc[q]
        elif code == T.ADD:
            for j in range(m):
                w[o, j] = w[a, j] + w[b, j]
        elif code == T.SUB:
            for j in range(m):
                w[o, j] = w[a, j] - w[b, j]
        elif code == T.MUL:
            for j in range(m):
                w[o, j] = w[a, j] * w[b, j]
        elif code == T.DIV:
            for j in range(m):
                w[o, j] = w[a, j] / w[b, j]
        elif code == T.NEG:
            for j in range(m):
                w[o, j] = -w[a, j]
        elif code == T.EXP:
            for j in range(m):
                w[o, j] = math.exp(_min(w[a, j], 700.0))
        elif code == T.LOG:
            for j in range(m):
                w[o, j] = math.log(w[a, j]) if w[a, j] > 0 else np.nan
        elif code == T.POW:
            for j in range(m):
                w[o, j] = w[a, j] ** w[b, j]
        elif code == T.SQRT:
            for j in range(m):
                w[o, j] = math.sqrt(w[a, j]) if w[a, j] >= 0 else np.nan
        elif code == T.SQ:
            for j in range(m):
                w[o, j] = w[a, j] * w[a, j]
        elif code == T.TWICE:
            for j in range(m):
                w[o, j] = 2.0 * w[a, j]
        elif code == T.SIN:
            for j in range(m):
                w[o, j] = math.sin(w[a, j])
        elif code == T.COS:
            for j in range(m):
                w[o, j] = math.cos(w[a, j])
        elif code == T.TAN:
            for j in range(m):
                w[o, j] = math.tan(w[a, j])
        elif code == T.ASIN:
            for j in range(m):
                w[o, j] = math.asin(w[a, j]) if abs(w[a, j]) <= 1 else np.nan
        elif code == T.ACOS:
            for j in range(m):
                w[o, j] = math.acos(w[a, j]) if abs(w[a, j]) <= 1 else np.nan
        elif code == T.ATAN:
            for j in range(m):
                w[o, j] = math.atan(w[a, j])
        elif code == T.ATAN2:
            for j in range(m):
                w[o, j] = math.atan2(w[a, j], w[b, j])
        elif code == T.SINH:
            for j in range(m):
                w[o, j] = math.sinh(_min(_max(w[a, j], -700.0), 700.0))
        elif code == T.COSH:
            for j in range(m):
                w[o, j] = math.cosh(_min(_max(w[a, j], -700.0), 700.0))
        elif code == T.TANH:
            for j in range(m):
                w[o, j] = math.tanh(w[a, j])
        elif code == T.FABS:
            for j in range(m):
                w[o, j] = abs(w[a, j])
        elif code == T.SIGN:
            for j in range(m):
                x = w[a, j]
                w[o, j] = 1.0 if x > 0 else (-1.0 if x < 0 else 0.0)
        elif code == T.FMIN:
            for j in range(m):
                w[o, j] = _min(w[a, j], w[b, j])
        elif code == T.FMAX:
            for j in range(m):
                w[o, j] = _max(w[a, j], w[b, j])
        elif code == T.INV:
            for j in range(m):
                w[o, j] = 1.0 / w[a, j]
        elif code == T.LT:
            for j in range(m):
                w[o, j] = 1.0 if w[a, j] < w[b, j] else 0.0
        elif code == T.LE:
            for j in range(m):
                w[o, j] = 1.0 if w[a, j] <= w[b, j] else 0.0
        elif code == T.EQ:
            for j in range(m):
                w[o, j] = 1.0 if w[a, j] == w[b, j] else 0.0
        elif code == T.NE:
            for j in range(m):
                w[o, j] = 1.0 if w[a, j] != w[b, j] else 0.0
        elif code == T.NOT:
            for j in range(m):
                w[o, j] = 1.0 if w[a, j] == 0 else 0.0
        elif code == T.AND:
            for j in range(m):
                w[o, j] = 1.0 if ((w[a, j] != 0) & (w[b, j] != 0)) else 0.0
        elif code == T.OR:
            for j in range(m):
                w[o, j] = 1.0 if ((w[a, j] != 0) | (w[b, j] != 0)) else 0.0
        elif code == T.IF_ELSE_ZERO:
            for j in range(m):
                v = w[b, j]  # loaded unconditionally: no masked load in the vector loop
                w[o, j] = v if w[a, j] != 0 else 0.0
        elif code == T.ASSIGN:
            for j in range(m):
                w[o, j] = w[a, j]
