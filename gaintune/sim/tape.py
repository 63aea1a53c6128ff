"""Turn a casadi SX function into a flat instruction tape the numba kernel executes.

casadi builds nonlinear plants symbolically; its SX functions expose their
algorithm as a list of instructions. Executing that list inside the compiled
simulator, vectorised over the batch, keeps nonlinear plants as fast as LTI
ones without generating or compiling any code from user input.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache
from typing import TYPE_CHECKING, Any

import numpy as np

from gaintune.errors import SpecError

if TYPE_CHECKING:  # pragma: no cover
    import casadi as ca

__all__ = ["Tape", "make_tape", "OPS"]  # noqa: F822  # OPS comes from the module __getattr__ (loads casadi lazily)

# Kernel op codes (independent of casadi's numbering).
LOAD, STORE, CONST, ADD, SUB, MUL, DIV, NEG, EXP, LOG, POW, SQRT, SQ, TWICE = range(14)
SIN, COS, TAN, ASIN, ACOS, ATAN, ATAN2, SINH, COSH, TANH, FABS, SIGN, FMIN, FMAX = range(14, 28)
INV, LT, LE, EQ, NE, NOT, AND, OR, IF_ELSE_ZERO, ASSIGN = range(28, 38)


@lru_cache(maxsize=1)
def _from_casadi() -> dict[int, int]:
    """casadi op code -> kernel op code. casadi is imported here, on purpose: only nonlinear
    (ODE) plants make tapes, and importing casadi costs every LTI run ~15 ms at start-up."""
    import casadi as ca

    return {
        ca.OP_CONST: CONST, ca.OP_ADD: ADD, ca.OP_SUB: SUB, ca.OP_MUL: MUL, ca.OP_DIV: DIV,
        ca.OP_NEG: NEG, ca.OP_EXP: EXP, ca.OP_LOG: LOG, ca.OP_POW: POW, ca.OP_CONSTPOW: POW,
        ca.OP_SQRT: SQRT, ca.OP_SQ: SQ, ca.OP_TWICE: TWICE, ca.OP_SIN: SIN, ca.OP_COS: COS,
        ca.OP_TAN: TAN, ca.OP_ASIN: ASIN, ca.OP_ACOS: ACOS, ca.OP_ATAN: ATAN, ca.OP_ATAN2: ATAN2,
        ca.OP_SINH: SINH, ca.OP_COSH: COSH, ca.OP_TANH: TANH, ca.OP_FABS: FABS, ca.OP_SIGN: SIGN,
        ca.OP_FMIN: FMIN, ca.OP_FMAX: FMAX, ca.OP_INV: INV, ca.OP_LT: LT, ca.OP_LE: LE,
        ca.OP_EQ: EQ, ca.OP_NE: NE, ca.OP_NOT: NOT, ca.OP_AND: AND, ca.OP_OR: OR,
        ca.OP_IF_ELSE_ZERO: IF_ELSE_ZERO, ca.OP_ASSIGN: ASSIGN,
    }


def __getattr__(name: str) -> Any:
    if name == "OPS":  # the casadi op codes a tape supports (loads casadi on first use)
        return frozenset(_from_casadi())
    raise AttributeError(f"module 'gaintune.sim.tape' has no attribute {name!r}")


@dataclass(frozen=True)
class Tape:
    """Instructions: op, two operand registers, a target register and a constant."""

    op: np.ndarray  # int64 (I,)
    a: np.ndarray  # int64 (I,)
    b: np.ndarray  # int64 (I,)
    o: np.ndarray  # int64 (I,)
    c: np.ndarray  # float64 (I,)
    n_work: int
    n_out: int


def make_tape(fn: ca.Function) -> Tape:
    """Flatten a casadi SX Function of (x, u, p) with one vector output.

    Inputs are read from one stacked vector [x; u; p]: input ``i``, non-zero
    ``nz`` lives at offset ``sum(len(inputs before i)) + nz``.
    """
    import casadi as ca  # deferred: only nonlinear plants get here (see _from_casadi)

    from_casadi = _from_casadi()
    if not fn.is_a("SXFunction"):
        fn = fn.expand()
    offsets = np.cumsum([0] + [fn.nnz_in(i) for i in range(fn.n_in())])
    rows = []
    for k in range(fn.n_instructions()):
        cop = fn.instruction_id(k)
        ins = list(fn.instruction_input(k))
        outs = list(fn.instruction_output(k))
        if cop == ca.OP_INPUT:
            rows.append((LOAD, int(offsets[ins[0]] + ins[1]), 0, outs[0], 0.0))
        elif cop == ca.OP_OUTPUT:
            if outs[0] != 0:
                raise SpecError("plant", "internal: tape expects a single vector output")
            rows.append((STORE, ins[0], 0, outs[1], 0.0))
        elif cop in from_casadi:
            a = ins[0] if ins else 0
            b = ins[1] if len(ins) > 1 else 0
            const = float(fn.instruction_constant(k)) if cop == ca.OP_CONST else 0.0
            rows.append((from_casadi[cop], a, b, outs[0], const))
        else:
            raise SpecError("plant.ode", f"operation code {cop} is not supported by the simulator")
    arr = np.array(rows, dtype=object) if rows else np.zeros((0, 5), dtype=object)
    return Tape(
        op=arr[:, 0].astype(np.int64),
        a=arr[:, 1].astype(np.int64),
        b=arr[:, 2].astype(np.int64),
        o=arr[:, 3].astype(np.int64),
        c=arr[:, 4].astype(np.float64),
        n_work=max(int(fn.sz_w()), 1),
        n_out=int(fn.nnz_out(0)),
    )
