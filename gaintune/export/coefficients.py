"""The resolved controller of every loop and its discrete transfer functions, shared by the export formats.

:func:`loop_coefficients` gives, per loop, the controller the simulator runs (parallel
and ideal PID form, limits, anti-windup, LQ gains, operating point);
:func:`discrete_pid_tf` gives one PID loop's discrete law as a transfer function in ``z``.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from gaintune.export.common import Gains
from gaintune.spec import TuningSpec

__all__ = ["loop_coefficients", "discrete_pid_tf"]


def loop_coefficients(spec: TuningSpec, gains: Gains) -> list[dict[str, Any]]:
    """Per loop (outer first): the resolved controller the simulator runs.

    PID loops give parallel-form ``Kp, Ki, Kd, Tf, b, c``, ideal ``Ti, Td, N``,
    limits, anti-windup mode and ``Tt``; LQ loops give ``K, Kint, Nr`` and the
    operating point. Every loop also gets ``i0`` (integrator start) and ``y0``.
    """
    from gaintune.controllers.direction import measured_indices
    from gaintune.controllers.layout import GainLayout
    from gaintune.controllers.lq import lq_gains
    from gaintune.controllers.pid import pid_params
    from gaintune.plants.plant import build_plant

    plant = build_plant(spec.plant)
    layout = GainLayout(spec, plant.states)
    full = layout.from_dict(gains)
    named = layout.to_dict(full)
    lin = plant.linearize()
    meas = measured_indices(spec, plant.outputs)
    act = spec.actuator.limits or (-math.inf, math.inf)
    out = []
    n_loops = len(spec.loops)
    for i, (name, loop) in enumerate(zip(spec.loop_names, spec.loops, strict=True)):
        g = named[name]
        inner = i == n_loops - 1
        lo, hi = act if inner else (loop.output_limits or (-math.inf, math.inf))
        i0 = float(lin.u0) if inner else float(lin.y0[meas[i + 1]])
        d: dict[str, Any] = {
            "name": loop.name,
            "type": loop.type,
            "form": loop.form,
            "measure": plant.outputs[meas[i]],
            "gains": dict(g),
            "lo": float(lo),
            "hi": float(hi),
            "i0": i0,
            "y0": float(lin.y0[meas[i]]),
        }
        if loop.is_lq:
            s = lq_gains(loop, g, lin, meas[i])
            d.update(K=[float(k) for k in s.K], Kint=s.Kint, Nr=s.Nr, x0=[float(v) for v in lin.x0],
                     u0=float(lin.u0), states=list(plant.states), aw="clamping")
        else:
            p = pid_params(loop, g)
            kb = 1.0 / p.Tt if math.isfinite(p.Tt) else 0.0
            d.update(Kp=p.Kp, Ki=p.Ki, Kd=p.Kd, Tf=p.Tf, b=p.b, c=p.c, aw=loop.anti_windup,
                     Tt=p.Tt if math.isfinite(p.Tt) else None, kb=kb)
            # a reverse-acting loop has Kp, Ki, Kd all negative: Ti and Td stay positive
            d["Ti"] = p.Kp / p.Ki if p.Ki * p.Kp > 0 else math.inf
            d["Td"] = p.Kd / p.Kp if p.Kp != 0 else 0.0
            d["N"] = (d["Td"] / p.Tf) if p.Tf > 0 else math.inf
        out.append(d)
    return out


def discrete_pid_tf(coef: dict[str, Any], dt: float, path: str = "feedback") -> tuple[list[float], list[float]]:
    """(num, den) in descending powers of z of one PID loop's discrete law (the simulator's, exactly).

    ``u = Cr(z) r - Cy(z) y`` with ``Cy = Kp + Ki*dt*z/(z-1) + Kd*(z-1)/((Tf+dt)*z - Tf)``
    (``path="feedback"``) and ``Cr = b*Kp + Ki*dt*z/(z-1) + c*Kd*(z-1)/((Tf+dt)*z - Tf)``
    (``path="setpoint"``). Factors of an absent term (``Ki = 0``, ``Kd = 0``) are left out.
    """
    wp, wd = (1.0, 1.0) if path == "feedback" else (float(coef["b"]), float(coef["c"]))
    kp, ki, kd, tf = float(coef["Kp"]), float(coef["Ki"]), float(coef["Kd"]), float(coef["Tf"])
    terms: list[tuple[np.ndarray, np.ndarray]] = [(np.array([wp * kp]), np.array([1.0]))]
    if ki != 0.0:
        terms.append((np.array([ki * dt, 0.0]), np.array([1.0, -1.0])))
    if kd != 0.0:
        terms.append((wd * kd * np.array([1.0, -1.0]), np.array([tf + dt, -tf])))
    num, den = np.array([0.0]), np.array([1.0])
    for n, d in terms:  # num/den + n/d
        num, den = np.polyadd(np.polymul(num, d), np.polymul(n, den)), np.polymul(den, d)
    return [float(v) for v in num], [float(v) for v in den]
