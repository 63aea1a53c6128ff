"""PID parameters: conversion from spec gains to the parallel form the simulator and analysis use.

Continuous-time law (2-DOF, parallel form, derivative filter)::

    u = Kp*(b*r - y) + Ki/s*(r - y) + Kd*s/(Tf*s + 1)*(c*r - y)

Ideal form gains (Kp, Ti, Td) convert as Ki = Kp/Ti, Kd = Kp*Td. The filter is
Tf = Td/N with Td = Kd/Kp (default N = 10), or a fixed Tf from the spec.

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
from dataclasses import dataclass

import numpy as np

from gaintune.spec import LoopSpec

__all__ = ["PidParams", "pid_params", "pid_tf_coeffs"]


@dataclass(frozen=True)
class PidParams:
    """Parallel-form PID parameters of one loop."""

    Kp: float
    Ki: float
    Kd: float
    Tf: float
    b: float
    c: float
    Tt: float  # back-calculation tracking time (inf when unused)


def pid_params(loop: LoopSpec, gains: dict[str, float]) -> PidParams:
    """Resolve one loop's gains (by name) to parallel-form parameters."""
    t = loop.type
    kp = gains.get("Kp", 0.0)
    if loop.form == "ideal":
        ti = gains.get("Ti", math.inf)
        td = gains.get("Td", 0.0)
        ki = kp / ti if "i" in t[1:] and ti > 0 else 0.0
        kd = kp * td if "d" in t[1:] else 0.0
    else:
        ki = gains.get("Ki", 0.0) if "i" in t[1:] else 0.0
        kd = gains.get("Kd", 0.0) if "d" in t[1:] else 0.0
    if kd > 0:
        tf = loop.filter.Tf if loop.filter.Tf is not None else (kd / kp / (loop.filter.N or 10.0) if kp > 0 else 0.0)
    else:
        tf = 0.0
    tt = math.inf
    if loop.anti_windup == "back_calculation" and ki > 0:
        if loop.tracking_time is not None:
            tt = loop.tracking_time
        else:
            ti = kp / ki if kp > 0 else 1.0
            td = kd / kp if kp > 0 and kd > 0 else 0.0
            tt = math.sqrt(ti * td) if td > 0 else ti
    return PidParams(kp, ki, kd, tf, loop.b, loop.c, tt)


def pid_tf_coeffs(p: PidParams) -> tuple[np.ndarray, np.ndarray]:
    """Feedback-path transfer function C(s) = Kp + Ki/s + Kd*s/(Tf*s+1) as (num, den)."""
    # Common denominator s*(Tf*s + 1).
    num = np.polyadd(np.polyadd(p.Kp * np.array([p.Tf, 1.0, 0.0]), p.Ki * np.array([0.0, p.Tf, 1.0])), p.Kd * np.array([1.0, 0.0, 0.0]))
    den = np.array([p.Tf, 1.0, 0.0])
    if p.Ki == 0:  # drop the pole at the origin: C = (Kp*(Tf s+1) + Kd s)/(Tf s + 1)
        num = np.polyadd(p.Kp * np.array([p.Tf, 1.0]), p.Kd * np.array([1.0, 0.0]))
        den = np.array([p.Tf, 1.0])
    num = np.trim_zeros(num, "f")
    den = np.trim_zeros(den, "f")
    return (num if num.size else np.array([0.0])), den
