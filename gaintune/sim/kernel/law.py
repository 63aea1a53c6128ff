"""The controller law on a chunk: PID rows per loop, LQ state feedback, the actuator.

The discrete-time law is documented in :mod:`gaintune.controllers.pid`
(backward-Euler integral, filtered derivative, 2-DOF weights, output limits,
anti-windup); loops run outer first and each output is the next loop's setpoint.
Every function here is inlined into the kernel (numba ``inline="always"``), so
it compiles as if written in the time loop, with the kernel's compile-time
chunk width ``C`` and its flags.
"""

from __future__ import annotations

import numba as nb

from .layout import (
    AW_BACKCALC,
    AW_CLAMP,
    F_ALIVE,
    F_R,
    F_TRIP,
    F_U,
    F_UHI,
    F_ULO,
    F_UOP,
    F_UPREV,
    F_Z,
    LP0,
    N_P,
    P_AL,
    P_AWE,
    P_BE,
    P_BW,
    P_CW,
    P_D,
    P_EDP,
    P_HI,
    P_I,
    P_KB,
    P_KI,
    P_KP,
    P_LO,
    P_SP,
    P_VOUT,
    _1,
)
from .ops import _max, _min

__all__ = ["load_gains", "init_loops", "controllers", "actuator"]


@nb.njit(cache=True, inline="always")
def load_gains(S, C, p, b, l, kp, ki, kd, tf, kb, dt):
    """Loop l's PID gains of candidate b into the rows at base ``p`` (lane included), in per-step form."""
    S[p + P_KP * C] = kp[l, b]
    S[p + P_KI * C] = ki[l, b] * dt  # stored times dt: one multiply less per step
    S[p + P_KB * C] = kb[l, b] * dt
    S[p + P_AL * C] = tf[l, b] / (tf[l, b] + dt)
    S[p + P_BE * C] = kd[l, b] / (tf[l, b] + dt)


@nb.njit(cache=True, inline="always")
def init_loops(S, C, j, b, uL, kp, ki, kd, tf, kb, bw, cw, lo, hi, u_lo, u_hi, y_op, u_op, dt):
    """Controller rows of lane j (candidate b): gains, weights, limits, and a bumpless start."""
    for l in range(uL):
        p = (LP0 + l * N_P) * C + j
        load_gains(S, C, p, b, l, kp, ki, kd, tf, kb, dt)
        S[p + P_BW * C] = bw[l, b]
        S[p + P_CW * C] = cw[l, b]
        S[p + P_LO * C] = u_lo[b] if l == uL - _1 else lo[l, b]
        S[p + P_HI * C] = u_hi[b] if l == uL - _1 else hi[l, b]
        # bumpless start at the operating point: integrators hold the next setpoint / u0
        S[p + P_I * C] = y_op[l + _1, b] if l + _1 < uL else u_op[b]


@nb.njit(cache=True, inline="always")
def controllers(S, C, m, b0, k, uL, un, xa, ymf, sf, aw, dt, nr, y_op, K, x_op, kint):
    """Every loop's output at step k, outer loop first; each output is the next loop's setpoint.

    ``ymf`` is the measured-output field (``P_YM``, or ``P_YT`` without noise);
    the innermost loop is LQ state feedback when ``sf``.
    """
    for l in range(uL):
        p = (LP0 + l * N_P) * C
        # the setpoint row: the reference, or the outer loop's output
        sprow = F_R * C if l == 0 else (LP0 + (l - _1) * N_P + P_VOUT) * C
        if l == uL - _1 and sf:
            for j in range(m):
                b = b0 + j
                sp = S[sprow + j]
                e = sp - S[p + ymf * C + j]
                v = S[F_UOP * C + j] + nr[b] * (sp - y_op[l, b])
                for i in range(un):
                    v -= K[i, b] * (S[(xa + i) * C + j] - x_op[i, b])
                zt = S[F_Z * C + j] + dt * e
                vu = v + kint[b] * zt
                vs = _min(_max(vu, S[F_ULO * C + j]), S[F_UHI * C + j])
                if vs != vu and e * kint[b] * (vu - vs) > 0:
                    vs = _min(_max(v + kint[b] * S[F_Z * C + j], S[F_ULO * C + j]), S[F_UHI * C + j])
                else:
                    S[F_Z * C + j] = zt
                S[p + P_SP * C + j] = sp
                S[p + P_VOUT * C + j] = vs
            continue
        mode = aw[l]
        if k == 0:
            for j in range(m):  # no derivative kick at start (inner setpoints are known only now)
                S[p + P_EDP * C + j] = S[p + P_CW * C + j] * S[sprow + j] - S[p + ymf * C + j]
        backcalc = mode == AW_BACKCALC
        clamp = mode == AW_CLAMP
        # the setpoint is copied into this loop's own rows first: the stage loop then touches
        # only rows at compile-time distances from p, and it measured ~1.4x faster per core
        for j in range(m):
            S[p + P_SP * C + j] = S[sprow + j]
        for j in range(m):
            sp = S[p + P_SP * C + j]
            y = S[p + ymf * C + j]
            e = sp - y
            ed = S[p + P_CW * C + j] * sp - y
            dterm = S[p + P_AL * C + j] * S[p + P_D * C + j] + S[p + P_BE * C + j] * (ed - S[p + P_EDP * C + j])
            S[p + P_EDP * C + j] = ed
            S[p + P_D * C + j] = dterm
            pterm = S[p + P_KP * C + j] * (S[p + P_BW * C + j] * sp - y)
            iold = S[p + P_I * C + j]
            it = iold + S[p + P_KI * C + j] * e
            if backcalc:
                it += S[p + P_KB * C + j] * S[p + P_AWE * C + j]
            vu = pterm + it + dterm
            vlo = S[p + P_LO * C + j]
            vhi = S[p + P_HI * C + j]
            vs = _min(_max(vu, vlo), vhi)
            if clamp:
                # conditional integration: do not integrate further into saturation
                hold = (vs != vu) & (e * (vu - vs) * S[p + P_KI * C + j] > 0)
                it = (iold + 0.0) if hold else it  # + 0.0: see the step metrics in metrics.py
                vu = pterm + it + dterm
                vs = _min(_max(vu, vlo), vhi)
            S[p + P_I * C + j] = it
            S[p + P_AWE * C + j] = vs - vu
            S[p + P_VOUT * C + j] = vs


@nb.njit(cache=True, inline="always")
def actuator(S, C, m, uL, L, aw, has_rate, rate, dt, monitor, safe_mode, u_safe, buf, upos):
    """The applied input ``F_U``: rate limit, safety hold, dead candidates at rest; into the delay line."""
    vout = (LP0 + (uL - _1) * N_P + P_VOUT) * C
    hold_safe = monitor and safe_mode == 0
    for j in range(m):
        uprev = S[F_UPREV * C + j]
        u = S[vout + j]
        if has_rate:
            u = _min(_max(u, uprev - rate * dt), uprev + rate * dt)
        if hold_safe:
            u = u_safe if S[F_TRIP * C + j] > 0.0 else u
        uop = S[F_UOP * C + j]  # loaded unconditionally: no masked load
        u = u if S[F_ALIVE * C + j] > 0.0 else uop
        S[F_U * C + j] = u
    # the applied input also goes to the delay line, in a loop of its own, so that the
    # actuator and metrics loops touch only the chunk state ``S``
    for j in range(m):
        buf[upos * C + j] = S[F_U * C + j]
    if aw[L - 1] == AW_BACKCALC:
        awe = (LP0 + (uL - _1) * N_P + P_AWE) * C
        for j in range(m):
            S[awe + j] += S[F_U * C + j] - S[vout + j]  # track what was applied
