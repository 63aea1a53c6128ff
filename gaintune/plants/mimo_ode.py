"""Nonlinear ODE plants with several inputs: casadi functions, operating point and linearisation.

``plant.ode`` with ``inputs`` is ``dx/dt = f(x, u, p)``, ``y = h(x, u, p)`` with ``u`` a vector
of the named inputs. Its operating point is ``x0`` (default 0) and ``u0`` (given per input, or
solved in the least-squares sense for ``f(x0, u0, p) = 0``, as the single-input path solves its
one input); its linearisation there (casadi's exact Jacobians, as
:func:`gaintune.plants.plant._linearize_ode`) is a :class:`~gaintune.lti.mimo.DelayedSS` in
deviations from that point, which the MIMO verification and the loop-direction rules read.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

import numpy as np

from gaintune.errors import SpecError
from gaintune.lti.mimo import DelayedSS
from gaintune.plants import expr
from gaintune.spec import OdeSpec

if TYPE_CHECKING:  # pragma: no cover
    import casadi as ca

__all__ = ["OdeFunctions", "build_ode_functions", "add_defs", "OdePoint", "ode_point", "linearize_mimo_ode"]


@dataclass(frozen=True)
class OdeFunctions:
    """casadi ``f(x, u, p)`` and ``h(x, u, p)`` of a several-input ODE (u a vector, inputs in order)."""

    f: ca.Function
    h: ca.Function


@dataclass(frozen=True)
class OdePoint:
    """Operating point: states ``x0`` (n,), inputs ``u0`` (m,), outputs ``y0`` (p,)."""

    x0: np.ndarray
    u0: np.ndarray
    y0: np.ndarray


def build_ode_functions(ode: OdeSpec, params: dict[str, float]) -> OdeFunctions:
    """Parse the expressions (never ``eval``) into casadi functions; SpecError naming the expression."""
    import casadi as ca  # deferred on purpose: only ODE plants need casadi

    names = ode.input_names
    x = ca.SX.sym("x", len(ode.states))
    u = ca.SX.sym("u", len(names))
    pv = ca.SX.sym("p", len(params))
    scope: dict[str, Any] = {name: x[i] for i, name in enumerate(ode.states)}
    scope |= {name: u[j] for j, name in enumerate(names)}
    for i, name in enumerate(params):
        if name in scope:
            raise SpecError(f"plant.params.{name}", "parameter name clashes with a state or an input")
        scope[name] = pv[i]
    add_defs(ode, scope)
    rhs = ca.vertcat(*[expr.to_casadi(ode.rhs[s], scope, f"plant.ode.rhs.{s}") for s in ode.states])
    out = ca.vertcat(*[expr.to_casadi(e, scope, f"plant.ode.outputs.{k}") for k, e in ode.outputs.items()])
    f = ca.Function("f", [x, u, pv], [rhs], ["x", "u", "p"], ["xdot"])
    h = ca.Function("h", [x, u, pv], [out], ["x", "u", "p"], ["y"])
    return OdeFunctions(f, h)


def add_defs(ode: OdeSpec, scope: dict[str, Any]) -> None:
    """Add the ODE's named intermediate expressions (``defs``, in order) to ``scope``.

    Each is built once and shared by every expression that names it (one node of the casadi graph,
    so the simulator's tape computes it once per evaluation).
    """
    for name, text in (ode.defs or {}).items():
        if name in scope:
            raise SpecError(f"plant.ode.defs.{name}", "the name is already a state, an input or a parameter; "
                            "rename the definition")
        scope[name] = expr.to_casadi(text, scope, f"plant.ode.defs.{name}")


def _x0(ode: OdeSpec, p: dict[str, float]) -> np.ndarray:
    x0 = np.array([expr.to_float(ode.x0.get(s, 0.0), p, f"plant.ode.x0.{s}") for s in ode.states])
    for s, v in zip(ode.states, x0, strict=True):
        if not np.isfinite(v):
            raise SpecError(f"plant.ode.x0.{s}", f"must be a finite number, got {v}")
    return x0


def _solve_u0(fn: OdeFunctions, ode: OdeSpec, x0: np.ndarray, pv: np.ndarray) -> np.ndarray:
    """Solve f(x0, u, p) = 0 for the input vector u, least squares from u = 0."""
    from scipy.optimize import least_squares  # deferred: ~0.15 s to import

    m = len(ode.input_names)

    def residual(u: np.ndarray) -> np.ndarray:
        return np.asarray(fn.f(x0, u, pv), dtype=float).ravel()

    start = residual(np.zeros(m))
    if not np.all(np.isfinite(start)):
        i = int(np.flatnonzero(~np.isfinite(start))[0])
        raise SpecError("plant.ode.x0", f"the model is not finite at x0 with every input 0 (d{ode.states[i]}/dt = "
                        f"{start[i]}); give an x0 inside the model's domain, or set u0")
    with np.errstate(invalid="ignore", over="ignore"):
        res = least_squares(residual, x0=np.zeros(m), xtol=1e-14, ftol=1e-14, gtol=1e-14)
    u0 = np.asarray(res.x, dtype=float)
    if not np.linalg.norm(residual(u0)) <= 1e-6 * (1 + np.abs(x0).sum()):
        raise SpecError("plant.ode.x0", "x0 is not an equilibrium for any constant inputs; give an equilibrium x0 "
                        "or set u0 (one value per input)")
    return u0


def ode_point(fn: OdeFunctions, ode: OdeSpec, p: dict[str, float], pv: np.ndarray) -> OdePoint:
    """The operating point at parameters ``p`` (their vector ``pv``, in the plant's order)."""
    x0 = _x0(ode, p)
    if isinstance(ode.u0, dict):
        u0 = np.array([expr.to_float(ode.u0[n], p, f"plant.ode.u0.{n}") for n in ode.input_names])
        bad = [n for n, v in zip(ode.input_names, u0, strict=True) if not np.isfinite(v)]
        if bad:
            raise SpecError(f"plant.ode.u0.{bad[0]}", "must be a finite number")
    elif ode.u0 is not None:  # a single-input ODE viewed as MIMO
        u0 = np.array([expr.to_float(ode.u0, p, "plant.ode.u0")])
        if not np.isfinite(u0[0]):
            raise SpecError("plant.ode.u0", f"must be a finite number, got {u0[0]}")
    else:
        u0 = _solve_u0(fn, ode, x0, pv)
    y0 = np.asarray(fn.h(x0, u0, pv), dtype=float).ravel()
    return OdePoint(x0, u0, y0)


def linearize_mimo_ode(fn: OdeFunctions, ode: OdeSpec, p: dict[str, float], pv: np.ndarray,
                       inputs: tuple[str, ...], outputs: tuple[str, ...]) -> tuple[DelayedSS, OdePoint]:
    """The linearisation at the operating point, in deviations from it, and the point itself."""
    import casadi as ca

    op = ode_point(fn, ode, p, pv)
    n, m = len(ode.states), len(inputs)
    xs, us, ps = ca.SX.sym("x", n), ca.SX.sym("u", m), ca.SX.sym("p", len(pv))
    fx, hx = fn.f(xs, us, ps), fn.h(xs, us, ps)
    jac = ca.Function("lin", [xs, us, ps], [ca.jacobian(fx, xs), ca.jacobian(fx, us), ca.jacobian(hx, xs),
                                            ca.jacobian(hx, us)])
    A, B, C, D = (np.array(v, dtype=float).reshape(shape) for v, shape in
                  zip(jac(op.x0, op.u0, pv), ((n, n), (n, m), (len(outputs), n), (len(outputs), m)), strict=True))
    for name, mat in (("A", A), ("B", B), ("C", C), ("D", D), ("the outputs", op.y0)):
        if not np.all(np.isfinite(mat)):
            raise SpecError("plant.ode", f"the linearisation gives non-finite {name} at the operating point; check "
                            "x0, u0 and params")
    if np.any(D):
        raise SpecError("plant.ode.outputs", "with several inputs the outputs must not depend on the inputs "
                        "directly (no feedthrough) so far")
    return DelayedSS(A, B, C, D, inputs=inputs, outputs=outputs, input_delays=np.zeros(m)), op
