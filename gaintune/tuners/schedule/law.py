"""The scheduled PID law in Python: the twin of the C header of :mod:`gaintune.export.schedule`.

Same operations in the same order as the generated C (and, for a constant table, as the
simulator's kernel), so a test can match the compiled header to this to 1e-9 and this to
the simulator. The law is described in :mod:`gaintune.export.schedule`.
"""

from __future__ import annotations

import math
from bisect import bisect_right
from collections.abc import Sequence
from typing import NamedTuple

from gaintune.export.c import AW_CODE
from gaintune.export.schedule import ScheduleTable

__all__ = ["interp", "Coef", "ScheduledPid"]

_CLAMP, _BACKCALC = AW_CODE["clamping"], AW_CODE["back_calculation"]


def interp(grid: Sequence[float], table: Sequence[float], x: float) -> float:
    """Linear interpolation of ``table`` over the increasing ``grid`` at ``x``, clamped at the ends.

    Exact at every grid point; ``x`` below the first point, and NaN, give the first entry,
    above the last the last entry (the C header's ``<p>_sched_interp``, operation for operation).
    """
    if not x > grid[0]:
        return float(table[0])
    if x >= grid[-1]:
        return float(table[-1])
    i = bisect_right(grid, x) - 1
    w = (x - grid[i]) / (grid[i + 1] - grid[i])
    return float(table[i] + w * (table[i + 1] - table[i]))


class Coef(NamedTuple):
    """One sample's coefficients: parallel gains, filter, back-calculation gain, per-step factors."""

    kp: float
    ki: float
    kd: float
    tf: float
    kb: float
    al: float  # Tf/(Tf+dt)
    be: float  # Kd/(Tf+dt)


class ScheduledPid:
    """One PID loop with gains scheduled on ``x``: ``reset(x0)``, then ``u = step(r, y, x)`` every sample."""

    def __init__(self, table: ScheduleTable) -> None:
        self.t = table
        self.aw = AW_CODE[table.aw]
        self.reset(table.grid[0])

    def coef(self, x: float) -> Coef:
        """The coefficients at ``x`` (the filter and 1/Tt as :func:`gaintune.controllers.pid.pid_params` gives them)."""
        t, dt = self.t, self.t.dt
        kp, ki, kd = interp(t.grid, t.kp, x), interp(t.grid, t.ki, x), interp(t.grid, t.kd, x)
        if not t.has_d:
            tf = 0.0
        elif t.Tf is not None:
            tf = t.Tf if kd != 0.0 else 0.0
        else:
            tf = kd / (t.N * kp) if kd * kp > 0.0 else 0.0
        kb = 0.0
        if t.aw == "back_calculation" and t.has_i:
            if t.tracking_time is not None:
                kb = 1.0 / t.tracking_time
            else:
                ti = kp / ki if ki * kp > 0.0 else 1.0
                td = kd / kp if kd * kp > 0.0 else 0.0
                kb = 1.0 / (math.sqrt(ti * td) if td > 0.0 else ti)
        return Coef(kp, ki, kd, tf, kb, tf / (tf + dt), kd / (tf + dt))

    def reset(self, x0: float, i0: float | None = None) -> None:
        """Start at the operating point of ``x0``: the integrator holds the interpolated operating input.

        ``i0`` overrides that start (e.g. the exact operating input of a level between grid points).
        """
        self.I = interp(self.t.grid, self.t.i0, x0) if i0 is None else float(i0)
        self.D = 0.0
        self.ed_prev = 0.0
        self.awe = 0.0
        self.u_prev = self.I
        self.started = False

    def _pid(self, c: Coef, sp: float, y: float) -> float:
        """One sample of the discrete PID law with coefficients ``c`` (the C header's ``<p>_pid_step``)."""
        t, dt = self.t, self.t.dt
        e, ed = sp - y, t.c * sp - y
        if not self.started:
            self.ed_prev = ed  # no derivative kick
        dterm = c.al * self.D + c.be * (ed - self.ed_prev)
        self.ed_prev = ed
        self.D = dterm
        pterm = c.kp * (t.b * sp - y)
        iold = self.I
        it = iold + c.ki * dt * e
        if self.aw == _BACKCALC:
            it += c.kb * dt * self.awe
        vu = pterm + it + dterm
        vs = t.lo if vu < t.lo else (t.hi if vu > t.hi else vu)
        if self.aw == _CLAMP and vs != vu and e * (vu - vs) * c.ki > 0.0:
            it = iold  # conditional integration
            vu = pterm + it + dterm
            vs = t.lo if vu < t.lo else (t.hi if vu > t.hi else vu)
        self.I = it
        self.awe = vs - vu
        return vs

    def step(self, r: float, y: float, x: float) -> float:
        """The actuator value for reference ``r``, measurement ``y`` and scheduling value ``x``."""
        v = self._pid(self.coef(x), r, y)
        u = v
        rate = self.t.rate_limit
        if rate is not None:
            lo, hi = self.u_prev - rate * self.t.dt, self.u_prev + rate * self.t.dt
            u = lo if u < lo else (hi if u > hi else u)
        if self.aw == _BACKCALC:
            self.awe += u - v  # track what was applied
        self.u_prev = u
        self.started = True
        return u
