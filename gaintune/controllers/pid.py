"""PID parameters: conversion from spec gains to the parallel form the simulator and analysis use.

Continuous-time law (2-DOF, parallel form, derivative filter)::

    u = Kp*(b*r - y) + Ki/s*(r - y) + Kd*s/(Tf*s + 1)*(c*r - y)

Ideal form gains (Kp, Ti, Td) convert as Ki = Kp/Ti, Kd = Kp*Td. The filter is
Tf = Td/N with Td = Kd/Kp (default N = 10), or a fixed Tf from the spec.

A reverse-acting loop has Kp, Ki, Kd all negative (ideal form: Kp < 0, Ti, Td > 0).
Every time constant (Ti = Kp/Ki, Td = Kd/Kp, Tf, the tracking time Tt) is then
still positive, and the discrete law below is exactly the mirror image of the
direct-acting loop on the negated plant: clamping's condition
``e*(v_unsat - v_sat)*Ki > 0`` and back-calculation (in output units) hold for
either sign.

Discrete-time implementation (sample time dt), documented once here and used
by :mod:`gaintune.sim.kernel`, the C export and the tests:

* integral, backward Euler: ``I[k] = I[k-1] + Ki*dt*e[k]``;
* derivative, backward Euler on the filter:
  ``D[k] = Tf/(Tf+dt)*D[k-1] + Kd/(Tf+dt)*(ed[k] - ed[k-1])`` with ``ed = c*r - y``
  (stable for every Tf >= 0);
* output ``v = Kp*(b*r - y) + I + D`` saturated to the loop's limits;
* anti-windup: clamping stops integration while the output is saturated and the
  error drives it further; back-calculation adds ``dt/Tt*(v_sat - v)`` to I.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from typing import Any, NamedTuple

import numpy as np

from gaintune.spec import LoopSpec

__all__ = ["PidParams", "pid_params", "pid_tf_coeffs"]


class PidParams(NamedTuple):
    """Parallel-form PID parameters of one loop (floats, or arrays over a batch).

    A named tuple rather than a dataclass: it is built on every simulation call.
    """

    Kp: Any
    Ki: Any
    Kd: Any
    Tf: Any
    b: float
    c: float
    Tt: Any  # back-calculation tracking time (the float inf when unused, also for a batch)


def pid_params(loop: LoopSpec, gains: Mapping[str, Any]) -> PidParams:
    """Resolve one loop's gains (by name; floats or equal-shape arrays) to parallel-form parameters."""
    t = loop.type
    has_i, has_d = "i" in t[1:], "d" in t[1:]
    kp = np.asarray(gains.get("Kp", 0.0), dtype=float)
    zero = np.zeros(kp.shape)
    # Few, plain NumPy calls: this runs once per simulation call, also for a single candidate.
    if loop.form == "ideal":
        with np.errstate(divide="ignore", invalid="ignore"):
            ki = kp / np.asarray(gains["Ti"], dtype=float) if has_i else zero
        kd = kp * np.asarray(gains["Td"], dtype=float) if has_d else zero
    else:
        ki = np.asarray(gains["Ki"], dtype=float) if has_i else zero
        kd = np.asarray(gains["Kd"], dtype=float) if has_d else zero
    # Kp, Ki, Kd share the loop's sign (all negative for a reverse-acting loop), so the times
    # Ti = Kp/Ki, Td = Kd/Kp and Tf = Td/N are positive for either direction: the tests below
    # compare signs (a product > 0), never a gain with 0.
    if not has_d:
        tf = zero
    elif loop.filter.Tf is not None:
        tf = np.where(kd != 0, loop.filter.Tf, 0.0)
    else:
        # Tf = Td/N = Kd/(N*Kp), and 0 (no filter, no derivative) unless Kd and Kp are nonzero with one sign
        same = kd * kp > 0
        tf = np.where(same, kd / ((loop.filter.N or 10.0) * np.where(same, kp, 1.0)), 0.0)
    tt: Any = math.inf
    if loop.anti_windup == "back_calculation" and has_i:
        if loop.tracking_time is not None:
            tt = np.full_like(kp, loop.tracking_time)
        else:
            pos_i, pos_d = ki * kp > 0, kd * kp > 0
            ti = np.where(pos_i, kp / np.where(pos_i, ki, 1.0), 1.0)
            td = np.where(pos_d, kd / np.where(pos_d, kp, 1.0), 0.0)
            tt = np.where(td > 0, np.sqrt(ti * td), ti)
    if kp.ndim == 0:
        return PidParams(float(kp), float(ki), float(kd), float(tf), loop.b, loop.c, float(tt))
    return PidParams(kp, ki, kd, tf, loop.b, loop.c, tt)


def pid_tf_coeffs(p: PidParams) -> tuple[np.ndarray, np.ndarray]:
    """Feedback-path transfer function C(s) = Kp + Ki/s + Kd*s/(Tf*s+1) as (num, den)."""
    # Common denominator s*(Tf*s + 1).
    kp_ki = np.polyadd(p.Kp * np.array([p.Tf, 1.0, 0.0]), p.Ki * np.array([0.0, p.Tf, 1.0]))
    num = np.polyadd(kp_ki, p.Kd * np.array([1.0, 0.0, 0.0]))
    den = np.array([p.Tf, 1.0, 0.0])
    if p.Ki == 0:  # drop the pole at the origin: C = (Kp*(Tf s+1) + Kd s)/(Tf s + 1)
        num = np.polyadd(p.Kp * np.array([p.Tf, 1.0]), p.Kd * np.array([1.0, 0.0]))
        den = np.array([p.Tf, 1.0])
    num = np.trim_zeros(num, "f")
    den = np.trim_zeros(den, "f")
    return (num if num.size else np.array([0.0])), den
