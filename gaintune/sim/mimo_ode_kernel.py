"""The nonlinear plant of the MIMO kernel: a several-input ODE on a chunk's lanes (numba, inlined).

The ODE's ``f(x, u, p)`` and ``h(x, u, p)`` run as casadi instruction tapes
(:mod:`gaintune.sim.tape`, :func:`gaintune.sim.kernel.tape_vm._run_tape`) over the stacked rows
``inp = [x; u; p]``, as in the single-input simulator. The state advances by RK4 with every
input held over the sample (whole-sample actuator delays), plus a state disturbance added to
one state's derivative. The kernel's signals are deviations from the operating point
(``u = u0 + u_dev``, ``y_dev = h - y0``); the states are absolute.
"""

from __future__ import annotations

import numba as nb

from gaintune.sim.kernel.tape_vm import _run_tape

__all__ = ["ode_outputs", "ode_rk4"]


@nb.njit(cache=True, inline="always")
def ode_outputs(x, ua, inp, n, m, nl, h_op, h_a, h_b, h_o, h_c, wh, hout, y_op_q, y):
    """``y = h(x, ua, p) - y0`` on lanes ``0 .. nl - 1`` (``inp`` already holds the parameters)."""
    for i in range(n):
        for j in range(nl):
            inp[i, j] = x[i, j]
    for a in range(m):
        for j in range(nl):
            inp[n + a, j] = ua[a, j]
    _run_tape(h_op, h_a, h_b, h_o, h_c, inp, wh, hout, nl)
    for o in range(y.shape[0]):
        for j in range(nl):
            y[o, j] = hout[o, j] - y_op_q[o]


@nb.njit(cache=True, inline="always")
def _stage(x, kprev, h, inp, n, nl, f_op, f_a, f_b, f_o, f_c, wf, kout, ds, dv):
    """One RK4 stage: ``kout = f(x + h kprev, u, p)`` plus the state disturbance ``dv`` on state ``ds``."""
    for i in range(n):
        if h == 0.0:
            for j in range(nl):
                inp[i, j] = x[i, j]
        else:
            for j in range(nl):
                inp[i, j] = x[i, j] + h * kprev[i, j]
    _run_tape(f_op, f_a, f_b, f_o, f_c, inp, wf, kout, nl)
    if ds >= 0:
        for j in range(nl):
            kout[ds, j] += dv


@nb.njit(cache=True, inline="always")
def ode_rk4(x, xn, ua, inp, n, m, nl, dt, f_op, f_a, f_b, f_o, f_c, wf, k1, k2, k3, k4, ds, dv):
    """Next state ``xn`` by RK4 with the inputs ``ua`` held over the sample."""
    for a in range(m):
        for j in range(nl):
            inp[n + a, j] = ua[a, j]
    _stage(x, k4, 0.0, inp, n, nl, f_op, f_a, f_b, f_o, f_c, wf, k1, ds, dv)
    _stage(x, k1, 0.5 * dt, inp, n, nl, f_op, f_a, f_b, f_o, f_c, wf, k2, ds, dv)
    _stage(x, k2, 0.5 * dt, inp, n, nl, f_op, f_a, f_b, f_o, f_c, wf, k3, ds, dv)
    _stage(x, k3, dt, inp, n, nl, f_op, f_a, f_b, f_o, f_c, wf, k4, ds, dv)
    for i in range(n):
        for j in range(nl):
            xn[i, j] = x[i, j] + dt / 6.0 * (k1[i, j] + 2.0 * k2[i, j] + 2.0 * k3[i, j] + k4[i, j])
