"""Reference and disturbance signals: sums of additive pieces, held while no piece starts or ends.

A signal ``s`` (0 reference, 1 input disturbance, 2 output disturbance) of
candidate b is a sum of pieces ``soff + sslope * (t - t0)`` active on steps
``sk0 <= k < sk1`` (see :class:`gaintune.sim.kernel_args.KernelArgs`).
"""

from __future__ import annotations

import numba as nb
import numpy as np

from .layout import F_DIN, F_DOUT, F_R

__all__ = ["signals_shared", "hold_shared_signals", "fill_signals"]


@nb.njit(cache=True)
def _signal(s, k, b, sk0, sk1, soff, sslope, dt):
    """Sum of the additive pieces of signal ``s`` active at step k for candidate b."""
    v = 0.0
    for p in range(sk0.shape[1]):
        k0 = sk0[s, p, b]
        if k >= k0 and k < sk1[s, p, b]:
            v += soff[s, p, b] + sslope[s, p, b] * ((k - k0) * dt)
    return v


@nb.njit(cache=True)
def _signal_until(s, k, b, sk0, sk1, sslope):
    """First step after k at which signal ``s`` of candidate b can change.

    Between piece starts and ends a signal whose active pieces are all flat
    (steps, sequences) keeps the value :func:`_signal` gave at k, exactly; a
    sloped active piece (ramp) changes it every step.
    """
    until = np.iinfo(np.int64).max
    for p in range(sk0.shape[1]):
        k0 = sk0[s, p, b]
        k1 = sk1[s, p, b]
        if k0 > k:
            until = min(until, k0)
        elif k1 > k:
            until = min(until, k1)
            if sslope[s, p, b] != 0.0:
                return k + 1
    return until


@nb.njit(cache=True, inline="always")
def signals_shared(sk0, sk1, soff, sslope, b0, m):
    """Whether all signals are identical across the chunk's lanes (no randomised references)."""
    shared = True
    for sg in range(3):
        for p in range(sk0.shape[1]):
            for j in range(m):
                b = b0 + j
                if (sk0[sg, p, b] != sk0[sg, p, b0] or sk1[sg, p, b] != sk1[sg, p, b0]
                        or soff[sg, p, b] != soff[sg, p, b0] or sslope[sg, p, b] != sslope[sg, p, b0]):
                    shared = False
    return shared


@nb.njit(cache=True, inline="always")
def hold_shared_signals(k, b0, has_sig, sk0, sk1, soff, sslope, dt, rs, dins, douts, r_until, din_until, dout_until):
    """Chunk-shared signal values at step k, and the steps until which they hold.

    Evaluated again only when a piece starts or ends, or while a ramp is active
    (the signal scan measured ~30 % of a single simulation when done every step).
    """
    if k >= r_until:
        rs = _signal(0, k, b0, sk0, sk1, soff, sslope, dt)
        r_until = _signal_until(0, k, b0, sk0, sk1, sslope)
    if has_sig[1] and k >= din_until:
        dins = _signal(1, k, b0, sk0, sk1, soff, sslope, dt)
        din_until = _signal_until(1, k, b0, sk0, sk1, sslope)
    if has_sig[2] and k >= dout_until:
        douts = _signal(2, k, b0, sk0, sk1, soff, sslope, dt)
        dout_until = _signal_until(2, k, b0, sk0, sk1, sslope)
    return rs, dins, douts, r_until, din_until, dout_until


@nb.njit(cache=True, inline="always")
def fill_signals(S, C, m, k, b0, shared, has_sig, rs, dins, douts, y_op, sk0, sk1, soff, sslope, dt):
    """Reference and disturbances of step k into the chunk rows ``F_R``, ``F_DIN`` and ``F_DOUT``."""
    if shared:
        for j in range(m):
            S[F_R * C + j] = rs + y_op[0, b0 + j]
        if has_sig[1]:
            for j in range(m):
                S[F_DIN * C + j] = dins
        if has_sig[2]:
            for j in range(m):
                S[F_DOUT * C + j] = douts
    else:
        for j in range(m):
            b = b0 + j
            S[F_R * C + j] = _signal(0, k, b, sk0, sk1, soff, sslope, dt) + y_op[0, b]
            S[F_DIN * C + j] = _signal(1, k, b, sk0, sk1, soff, sslope, dt) if has_sig[1] else 0.0
            S[F_DOUT * C + j] = _signal(2, k, b, sk0, sk1, soff, sslope, dt) if has_sig[2] else 0.0
