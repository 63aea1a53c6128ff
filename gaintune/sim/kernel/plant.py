"""The plant on a chunk: its outputs as the loops measure them, its delayed input, its state update.

LTI plants update by exact ZOH with a fractional input delay,
``x[k+1] = Ad x[k] + G0 u[k-d] + G1 u[k-d-1]``; nonlinear ones by RK4 over a
casadi instruction tape with the input held over the sample (whole-sample
delays). The applied inputs wait in a ring buffer ``buf`` of ``M`` rows.
Every function here is inlined into the kernel (numba ``inline="always"``).
"""

from __future__ import annotations

import numba as nb

from .layout import _U, F_ALIVE, F_DIN, F_DOUT, F_UA, F_UB, LP0, N_P, P_YM, P_YT, _1
from .ops import _normal
from .tape_vm import _run_tape

__all__ = [
    "plant_shared", "delay_shared", "input_seen_by_outputs", "outputs_tape", "outputs_lti", "add_noise",
    "plant_input", "update_rk4", "update_zoh_shared", "update_zoh", "freeze_dead",
]


@nb.njit(cache=True, inline="always")
def plant_shared(Ad, G0, G1, Cm, b0, m, un, uL):
    """Whether the LTI plant is identical across the chunk (e.g. B gain sets on the nominal plant)."""
    shared_plant = True
    for j in range(_1, m):
        b = b0 + j
        for i in range(un):
            shared_plant = shared_plant and G0[i, b] == G0[i, b0] and G1[i, b] == G1[i, b0]
            for q in range(un):
                shared_plant = shared_plant and Ad[i, q, b] == Ad[i, q, b0]
            for l in range(uL):
                shared_plant = shared_plant and Cm[l, i, b] == Cm[l, i, b0]
    return shared_plant


@nb.njit(cache=True, inline="always")
def delay_shared(dsteps, b0, m):
    """Whether the input delay is common to the chunk (the ring buffer is then read at one row)."""
    shared_delay = True
    for j in range(m):
        shared_delay = shared_delay and dsteps[b0 + j] == dsteps[b0]
    return shared_delay


@nb.njit(cache=True, inline="always")
def input_seen_by_outputs(S, C, m, b0, pos, M, dsteps, buf):
    """Plant input a nonlinear output map sees: only the delayed u[k-1-d] is known before u[k]."""
    for j in range(m):
        idd = pos - 1 - dsteps[b0 + j]
        S[F_UB * C + j] = buf[_U(idd + M if idd < 0 else idd) * C + j]


@nb.njit(cache=True, inline="always")
def outputs_tape(S, C, m, mt, n, un, uL, xa, inp, h_op, h_a, h_b, h_o, h_c, wh, hout, meas_idx, dist_out_loops):
    """True measured outputs of a nonlinear plant (output tape), plus the output disturbance."""
    for j in range(m):
        for i in range(un):
            inp[i, j] = S[(xa + i) * C + j]
        inp[n, j] = S[F_UB * C + j] + S[F_DIN * C + j]
    _run_tape(h_op, h_a, h_b, h_o, h_c, inp, wh, hout, mt)
    for l in range(uL):
        mi = meas_idx[l]
        dl = dist_out_loops[l]
        yt = (LP0 + l * N_P + P_YT) * C
        for j in range(m):
            S[yt + j] = hout[mi, j] + dl * S[F_DOUT * C + j]


@nb.njit(cache=True, inline="always")
def outputs_lti(S, C, m, b0, un, uL, xa, shared_plant, has_sig, has_D, Cm, Dm, dist_out_loops, buf, pos, M, dsteps):
    """True measured outputs of an LTI plant, ``Cm x + Dm u[k-1-d]``, plus the output disturbance.

    The output is sampled before the control update (the input held just before t_k), so
    the feedthrough sees ``u[k-1-d]``: no algebraic loop, even without a delay.
    """
    for l in range(uL):
        dl = dist_out_loops[l]
        yt = (LP0 + l * N_P + P_YT) * C
        if has_sig[2]:
            for j in range(m):
                S[yt + j] = dl * S[F_DOUT * C + j]
        else:
            for j in range(m):
                S[yt + j] = 0.0
        for i in range(un):
            xi = (xa + i) * C
            if shared_plant:
                cli = Cm[l, i, b0]
                if cli != 0.0:
                    for j in range(m):
                        S[yt + j] += cli * S[xi + j]
            else:
                for j in range(m):
                    S[yt + j] += Cm[l, i, b0 + j] * S[xi + j]
        if has_D:  # the input held before this sample's update: u[k-1-d] (M >= d + 2 rows)
            for j in range(m):
                b = b0 + j
                idd = pos - 1 - dsteps[b]
                S[yt + j] += Dm[l, b] * (buf[_U(idd + M if idd < 0 else idd) * C + j] + S[F_DIN * C + j])


@nb.njit(cache=True, inline="always")
def add_noise(S, C, m, b0, uL, k, noise_std, noise_seed):
    """Measured outputs ``P_YM``: the true outputs plus each candidate's seeded white noise."""
    for l in range(uL):
        p = (LP0 + l * N_P) * C
        for j in range(m):
            S[p + P_YM * C + j] = S[p + P_YT * C + j]
        for j in range(m):
            b = b0 + j
            if noise_std[b] > 0:
                S[p + P_YM * C + j] += noise_std[b] * _normal(noise_seed[b], k, l)


@nb.njit(cache=True, inline="always")
def plant_input(S, C, m, b0, pos, M, dsteps, buf, shared_delay, has_G1):
    """Input held over this sample: ``F_UA`` = u[k-d], ``F_UB`` = u[k-d-1] (plus the input disturbance)."""
    if shared_delay:
        ia = pos - dsteps[b0]
        ia = ia + M if ia < 0 else ia
        ib = ia - 1 if ia > 0 else M - 1
        for j in range(m):
            S[F_UA * C + j] = buf[_U(ia) * C + j] + S[F_DIN * C + j]
        if has_G1:  # the previous input only matters with a fractional delay
            for j in range(m):
                S[F_UB * C + j] = buf[_U(ib) * C + j] + S[F_DIN * C + j]
    else:
        for j in range(m):
            ia = pos - dsteps[b0 + j]
            ia = ia + M if ia < 0 else ia
            ib = ia - 1 if ia > 0 else M - 1
            S[F_UA * C + j] = buf[_U(ia) * C + j] + S[F_DIN * C + j]
            S[F_UB * C + j] = buf[_U(ib) * C + j] + S[F_DIN * C + j]


@nb.njit(cache=True, inline="always")
def update_rk4(S, C, m, mt, n, un, xa, xb, dt, f_op, f_a, f_b, f_o, f_c, inp, wf, k1, k2, k3, k4):
    """Next state of a nonlinear plant into rows ``xb``: RK4 with the input held over the sample."""
    for j in range(m):
        inp[n, j] = S[F_UA * C + j]
        for i in range(un):
            inp[i, j] = S[(xa + i) * C + j]
    _run_tape(f_op, f_a, f_b, f_o, f_c, inp, wf, k1, mt)
    for i in range(un):
        for j in range(m):
            inp[i, j] = S[(xa + i) * C + j] + 0.5 * dt * k1[i, j]
    _run_tape(f_op, f_a, f_b, f_o, f_c, inp, wf, k2, mt)
    for i in range(un):
        for j in range(m):
            inp[i, j] = S[(xa + i) * C + j] + 0.5 * dt * k2[i, j]
    _run_tape(f_op, f_a, f_b, f_o, f_c, inp, wf, k3, mt)
    for i in range(un):
        for j in range(m):
            inp[i, j] = S[(xa + i) * C + j] + dt * k3[i, j]
    _run_tape(f_op, f_a, f_b, f_o, f_c, inp, wf, k4, mt)
    for i in range(un):
        xi = (xa + i) * C
        for j in range(m):
            S[(xb + i) * C + j] = S[xi + j] + dt / 6.0 * (k1[i, j] + 2.0 * k2[i, j] + 2.0 * k3[i, j] + k4[i, j])


@nb.njit(cache=True, inline="always")
def update_zoh_shared(S, C, m, b0, un, xa, xb, Ad, G0, G1, has_G1):
    """Next LTI state into rows ``xb``, the plant shared by the chunk: scalars, zero entries skipped."""
    for i in range(un):
        xn = (xb + i) * C
        g0 = G0[i, b0]
        g1 = G1[i, b0]
        if has_G1:
            for j in range(m):
                S[xn + j] = g0 * S[F_UA * C + j] + g1 * S[F_UB * C + j]
        else:
            for j in range(m):
                S[xn + j] = g0 * S[F_UA * C + j]
        for q in range(un):
            a = Ad[i, q, b0]
            if a != 0.0:
                xq = (xa + q) * C
                for j in range(m):
                    S[xn + j] += a * S[xq + j]


@nb.njit(cache=True, inline="always")
def update_zoh(S, C, m, b0, un, xa, xb, Ad, G0, G1, has_G1):
    """Next LTI state into rows ``xb``, each lane with its own plant."""
    for i in range(un):
        xn = (xb + i) * C
        if has_G1:
            for j in range(m):
                S[xn + j] = G0[i, b0 + j] * S[F_UA * C + j] + G1[i, b0 + j] * S[F_UB * C + j]
        else:
            for j in range(m):
                S[xn + j] = G0[i, b0 + j] * S[F_UA * C + j]
        for q in range(un):
            xq = (xa + q) * C
            for j in range(m):
                S[xn + j] += Ad[i, q, b0 + j] * S[xq + j]


@nb.njit(cache=True, inline="always")
def freeze_dead(S, C, m, un, xb):
    """Dead candidates' next state frozen at 0."""
    for i in range(un):
        xn = (xb + i) * C
        for j in range(m):
            S[xn + j] *= S[F_ALIVE * C + j]
