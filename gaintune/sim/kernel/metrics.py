"""Streaming metrics on a chunk: integrals and step-response marks per step, the metric rows at the end.

No trace is kept: every metric is an accumulator row of the chunk state
(rows ``A0 + metric``) or a step-response mark (``F_PEAK``, ``F_T10``, ...).
Conditions combine with ``&`` and ``|`` (not ``and``/``or``): short-circuit
branches cost 2x in the vectorised loop. All functions are inlined into the
kernel (numba ``inline="always"``).
"""

from __future__ import annotations

import numba as nb
import numpy as np

from .layout import (
    _U,
    A0,
    F_ALIVE,
    F_INVSPAN,
    F_KLD,
    F_KST,
    F_LAST,
    F_PEAK,
    F_R,
    F_T10,
    F_T90,
    F_TRIP,
    F_U,
    F_UHI,
    F_ULO,
    F_UOP,
    F_UPREV,
    F_Y0,
    LP0,
    M_DIV,
    M_EFFORT,
    M_IAE,
    M_ISE,
    M_ITAE,
    M_LOAD,
    M_OVERSHOOT,
    M_PEAKU,
    M_RISE,
    M_SAT,
    M_SETTLE,
    M_SSE,
    M_TRIPT,
    M_TV,
    M_YFIN,
    METRICS,
    N_P,
    P_SP,
    P_YT,
)
from .ops import _max

__all__ = ["start_metrics", "accumulate_metrics", "record_traces", "finish_metrics"]


@nb.njit(cache=True, inline="always")
def start_metrics(S, C, m, b0, target):
    """At step 0: the initial output and the step span to the final reference value."""
    y0row = (LP0 + P_YT) * C
    for j in range(m):
        S[F_Y0 * C + j] = S[y0row + j]
        span = target[b0 + j] - S[F_Y0 * C + j]
        S[F_INVSPAN * C + j] = 1.0 / span if span != 0.0 else 0.0
        if span == 0.0:  # no step to measure: step metrics never start
            S[F_KST * C + j] = np.inf


@nb.njit(cache=True, inline="always")
def accumulate_metrics(S, C, m, k, t, dt):
    """Step k's contribution to the integrals and step-response marks, masked by alive."""
    y0row = (LP0 + P_YT) * C
    for j in range(m):
        a = S[F_ALIVE * C + j]
        u = S[F_U * C + j]
        y0 = S[y0row + j]
        e0 = S[F_R * C + j] - y0
        ae = abs(e0)
        du = u - S[F_UOP * C + j]
        # integrals of a candidate that dies are replaced by inf at the end: no alive mask needed
        S[(A0 + M_IAE) * C + j] += ae * dt
        S[(A0 + M_ISE) * C + j] += e0 * e0 * dt
        S[(A0 + M_ITAE) * C + j] += t * ae * dt
        S[(A0 + M_EFFORT) * C + j] += du * du * dt
        S[(A0 + M_TV) * C + j] += abs(u - S[F_UPREV * C + j])
        S[(A0 + M_PEAKU) * C + j] = _max(S[(A0 + M_PEAKU) * C + j] + 0.0, abs(du))
        S[(A0 + M_SAT) * C + j] += a * ((u <= S[F_ULO * C + j]) | (u >= S[F_UHI * C + j]))
        S[(A0 + M_LOAD) * C + j] += (k >= S[F_KLD * C + j]) * ae * dt
        S[F_UPREV * C + j] = u
        # step metrics relative to the final reference value
        dev = (y0 - S[F_Y0 * C + j]) * S[F_INVSPAN * C + j]
        act = (k >= S[F_KST * C + j]) & (a > 0.0)
        # "+ 0.0" (exact here) keeps LLVM from turning "store the new value or the old one"
        # into a masked store, which is microcoded and several times slower on AMD cores
        pk = S[F_PEAK * C + j] + 0.0
        S[F_PEAK * C + j] = _max(pk, dev) if act else pk
        t10 = S[F_T10 * C + j] + 0.0
        S[F_T10 * C + j] = t if (act & (t10 < 0) & (dev >= 0.1)) else t10
        t90 = S[F_T90 * C + j] + 0.0
        S[F_T90 * C + j] = t if (act & (t90 < 0) & (dev >= 0.9)) else t90
        last = S[F_LAST * C + j] + 0.0
        S[F_LAST * C + j] = k if (act & (abs(dev - 1.0) >= 0.02)) else last


@nb.njit(cache=True, inline="always")
def record_traces(S, C, m, b0, k, uL, tr_y, tr_sp, tr_u):
    """Step k's applied input, outputs and setpoints into the trace arrays."""
    for j in range(m):
        b = b0 + j
        tr_u[k, b] = S[F_U * C + j]
        for l in range(uL):
            p = (LP0 + l * N_P) * C + j
            tr_y[l, k, b] = S[p + P_YT * C]
            tr_sp[l, k, b] = S[p + P_SP * C]


@nb.njit(cache=True, inline="always")
def finish_metrics(out, S, C, m, b0, n_steps, dt, target, k_step):
    """The chunk's metric rows into ``out`` (16, B): step metrics, then dead and untripped lanes marked."""
    for j in range(m):
        b = b0 + j
        for q in range(_U(len(METRICS))):
            out[q, b] = S[(A0 + q) * C + j]
        span = target[b] - S[F_Y0 * C + j]
        out[M_SAT, b] = S[(A0 + M_SAT) * C + j] / n_steps
        out[M_YFIN, b] = S[(LP0 + P_YT) * C + j]  # the output at the last step
        out[M_SSE, b] = abs(target[b] - out[M_YFIN, b])
        if span != 0.0:
            out[M_OVERSHOOT, b] = _max(0.0, S[F_PEAK * C + j] - 1.0) * 100.0
            t10 = S[F_T10 * C + j]
            t90 = S[F_T90 * C + j]
            out[M_RISE, b] = (t90 - t10) if (t10 >= 0 and t90 >= 0) else np.nan
            last = S[F_LAST * C + j]
            if last < n_steps - 1:
                out[M_SETTLE, b] = (last + 1) * dt - k_step[b] * dt if last >= 0 else 0.0
            else:
                out[M_SETTLE, b] = np.nan
        else:
            out[M_OVERSHOOT, b] = 0.0
            out[M_RISE, b] = np.nan
            out[M_SETTLE, b] = np.nan
        if S[F_ALIVE * C + j] == 0.0:
            out[M_DIV, b] = 1.0
            for q in (M_IAE, M_ISE, M_ITAE, M_EFFORT, M_TV, M_LOAD, M_PEAKU, M_SSE):
                out[q, b] = np.inf
            out[M_OVERSHOOT, b] = np.nan
            out[M_YFIN, b] = np.nan
        if S[F_TRIP * C + j] == 0.0:
            out[M_TRIPT, b] = np.nan
