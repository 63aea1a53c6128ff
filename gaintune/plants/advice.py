"""Warnings about a plant that an engineer should hear before trusting any tuning of it.

Not errors: the spec is valid and tuning proceeds. :func:`plant_warnings` returns plain
sentences that the tune result's diagnosis, the CLI and the report show.

* **Open-loop unstable plant.** The loop has to stabilise it, and the delay limits how well:
  for a real right-half-plane pole p and a delay theta, every stabilising controller gives
  ``||T||inf >= e^{p theta}`` (Skogestad & Postlethwaite, Multivariable Feedback Control,
  2nd ed., sec. 5.9), so tight Mt (and Ms) limits may be unreachable.
* **Operating point that is not an equilibrium.** With ``plant.ode.u0`` given, ``x0`` need not
  satisfy ``f(x0, u0) = 0``; the loop then starts with a transient and the linearisation the
  margins are computed on describes a point the plant leaves.
"""

from __future__ import annotations

import math

import numpy as np

from gaintune.plants.plant import Plant

__all__ = ["plant_warnings", "EQUILIBRIUM_TOL"]

#: ``|f(x0, u0)|`` above this (relative to 1 + |x0|) marks a non-equilibrium operating point.
EQUILIBRIUM_TOL = 1e-6


def plant_warnings(plant: Plant) -> list[str]:
    """Sentences describing an open-loop unstable plant or a non-equilibrium operating point."""
    out: list[str] = []
    lin = plant.linearize()
    poles = np.linalg.eigvals(lin.A) if lin.A.size else np.zeros(0)
    scale = max(1.0, float(np.max(np.abs(poles)))) if poles.size else 1.0
    rhp = poles[poles.real > 1e-9 * scale]
    if rhp.size:
        p = float(np.max(rhp.real))
        text = ", ".join(f"{z.real:.4g}{z.imag:+.4g}j" if abs(z.imag) > 1e-12 else f"{z.real:.4g}" for z in rhp)
        msg = f"the plant is open-loop unstable (pole(s) {text}): the loop must stabilise it"
        if lin.delay > 0:
            msg += (f"; with the delay {lin.delay:.4g} s every stabilising controller has Mt >= e^(p*theta) = "
                    f"{math.exp(p * lin.delay):.4g}, so tight Mt/Ms limits may be unreachable")
        out.append(msg)
    if plant.kind == "nonlinear" and plant.f is not None:
        pv = plant.param_vector()
        f0 = np.asarray(plant.f(lin.x0, lin.u0, pv), dtype=float).ravel()
        if np.linalg.norm(f0) > EQUILIBRIUM_TOL * (1.0 + float(np.abs(lin.x0).sum())):
            worst = int(np.argmax(np.abs(f0)))
            out.append(
                f"the operating point is not an equilibrium: d{plant.states[worst]}/dt = {f0[worst]:.4g} at x0 with "
                f"u0 = {lin.u0:.4g}; the loop starts with a transient and the margins describe a point the plant "
                "leaves. Give an equilibrium x0, or omit plant.ode.u0 to have it solved"
            )
    return out
