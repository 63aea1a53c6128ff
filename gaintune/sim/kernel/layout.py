"""Constants of the kernel: chunk width, metric rows, anti-windup codes and the chunk state layout.

All mutable state of a chunk lives in ONE flat float array ``S`` of rows of
``CHUNK`` lanes: value ``(row, lane j)`` is ``S[row * C + j]`` with ``C`` the
chunk width. Because ``C`` is a compile-time constant in every kernel variant,
two rows touched by one loop body are a known constant distance apart, which
lets LLVM prove the per-lane loops free of overlap and vectorise them (AVX2:
4 candidates per instruction). With 2-D chunk arrays (runtime strides, separate
allocations) it could not, and this layout measured about 3x faster per core
on the reference case.

Row indices are unsigned (``np.uint64``): with signed ones numba emits a
negative-index wrap-around select, which hides the affine address from LLVM
and stops it from vectorising the per-lane loops.
"""

from __future__ import annotations

import numpy as np

__all__ = ["CHUNK", "METRICS", "AW_NONE", "AW_CLAMP", "AW_BACKCALC"]

#: Candidates per chunk (the lanes of one row of the chunk state).
CHUNK = 64

#: Metric rows of the kernel's output, in order.
METRICS = (
    "iae", "ise", "itae", "effort", "tv", "overshoot", "rise_time", "settling_time",
    "sse", "sat_frac", "peak_u", "load_iae", "diverged", "tripped", "trip_time", "y_final",
)
(M_IAE, M_ISE, M_ITAE, M_EFFORT, M_TV, M_OVERSHOOT, M_RISE, M_SETTLE, M_SSE, M_SAT,
 M_PEAKU, M_LOAD, M_DIV, M_TRIP, M_TRIPT, M_YFIN) = map(np.uint64, range(len(METRICS)))

AW_NONE, AW_CLAMP, AW_BACKCALC = 0, 1, 2

_U = np.uint64

# Per-candidate scalar fields: rows 0 .. N_F-1.
(F_UPREV, F_ALIVE, F_TRIP, F_Z, F_Y0, F_INVSPAN, F_PEAK, F_T10, F_T90, F_LAST, F_ULO, F_UHI,
 F_UOP, F_KST, F_KLD, F_R, F_DIN, F_DOUT, F_UA, F_UB, F_U) = map(_U, range(21))
N_F = _U(21)
#: Metric accumulators: rows A0 + metric index.
A0 = N_F
#: Per-loop fields: rows LP0 + loop * N_P + field.
LP0 = A0 + _U(len(METRICS))
(P_YM, P_YT, P_I, P_D, P_EDP, P_AWE, P_VOUT, P_SP, P_KP, P_KI, P_KB, P_AL, P_BE, P_BW, P_CW,
 P_LO, P_HI) = map(_U, range(17))
N_P = _U(17)
# After the loops come the plant state rows and the next-state rows (see drivers.py), swapped every step.
_1 = _U(1)
