"""Health of the candidates on a chunk: divergence, and the safety monitor's trip.

A diverged candidate (NaN, inf or beyond the bound) is dead from then on: its
plant is frozen at 0 and its metrics are replaced at the end. A tripped one is
held at the safe input or switched to the fallback gains. Both functions are
inlined into the kernel (numba ``inline="always"``).
"""

from __future__ import annotations

import numba as nb

from .law import load_gains
from .layout import A0, F_ALIVE, F_R, F_TRIP, LP0, M_TRIP, M_TRIPT, N_P, P_YT

__all__ = ["check_divergence", "safety_monitor"]


@nb.njit(cache=True, inline="always")
def check_divergence(S, C, m, un, uL, xa, div_bound, all_alive):
    """Mark lanes whose state or outputs left ``div_bound`` as dead; returns whether all are still alive.

    Called every 8 steps: NaN and inf propagate, so a late check misses nothing.
    """
    for i in range(un):
        xi = (xa + i) * C
        for j in range(m):
            S[F_ALIVE * C + j] *= 1.0 if abs(S[xi + j]) <= div_bound else 0.0
    for l in range(uL):
        yt = (LP0 + l * N_P + P_YT) * C
        for j in range(m):
            S[F_ALIVE * C + j] *= 1.0 if abs(S[yt + j]) <= div_bound else 0.0
    if all_alive:
        for j in range(m):
            all_alive = all_alive and S[F_ALIVE * C + j] != 0.0
    return all_alive


@nb.njit(cache=True, inline="always")
def safety_monitor(S, C, m, b0, un, uL, xa, t, dt, max_err, max_out, xbound, safe_mode,
                   fb_kp, fb_ki, fb_kd, fb_tf, fb_kb):
    """Trip lanes beyond the error, output or state bounds; with ``safe_mode == 1`` load the fallback gains."""
    for j in range(m):
        if S[F_TRIP * C + j] != 0.0 or S[F_ALIVE * C + j] == 0.0:
            continue
        b = b0 + j
        trip = abs(S[F_R * C + j] - S[(LP0 + P_YT) * C + j]) > max_err
        for l in range(uL):
            trip = trip or abs(S[(LP0 + l * N_P + P_YT) * C + j]) > max_out
        for i in range(un):
            trip = trip or abs(S[(xa + i) * C + j]) > xbound[i]
        if trip:
            S[F_TRIP * C + j] = 1.0
            S[(A0 + M_TRIP) * C + j] = 1.0
            S[(A0 + M_TRIPT) * C + j] = t
            if safe_mode == 1:
                for l in range(uL):
                    p = (LP0 + l * N_P) * C + j
                    load_gains(S, C, p, b, l, fb_kp, fb_ki, fb_kd, fb_tf, fb_kb, dt)
