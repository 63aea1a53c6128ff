"""Resolved plant models built from a :class:`~gaintune.spec.PlantSpec`.

A :class:`Plant` knows its states, outputs and parameters and can produce,
for any parameter values:

* continuous-time matrices (A, B, C, D) - exact for LTI plants, the casadi
  Jacobian linearisation at the operating point for nonlinear ones;
* the operating point (x0, u0, y0) - zero for LTI plants;
* the delay in seconds.

Nonlinear plants additionally carry casadi functions ``f(x, u, p)`` and
``h(x, u, p)`` used by the simulator.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Literal

import numpy as np

from gaintune.errors import SpecError
from gaintune.plants import expr
from gaintune.plants.coefs import coef_matrix as _coef_matrix
from gaintune.plants.coefs import poly as _poly
from gaintune.plants.mimo_ode import add_defs
from gaintune.plants.params import NamedParams
from gaintune.spec import MAX_ORDER, OdeSpec, PlantSpec, StateSpaceSpec, TransferFunctionSpec

if TYPE_CHECKING:  # pragma: no cover
    import casadi as ca

__all__ = ["Plant", "LinearModel", "build_plant", "is_mimo_plant_spec", "is_mimo_plant"]


@dataclass(frozen=True)
class LinearModel:
    """A continuous-time LTI model with an input delay, around an operating point."""

    A: np.ndarray
    B: np.ndarray
    C: np.ndarray
    D: np.ndarray
    delay: float
    states: list[str]
    outputs: list[str]
    x0: np.ndarray
    u0: float
    y0: np.ndarray

    def to_control(self):  # -> control.StateSpace
        """The delay-free part as a python-control StateSpace (delay handled separately)."""
        import control

        return control.ss(self.A, self.B, self.C, self.D, states=self.states, outputs=self.outputs, inputs=["u"])

    def output_index(self, name: str) -> int:
        """Row of output ``name`` in C and D (ValueError when there is no such output)."""
        return self.outputs.index(name)


@dataclass
class Plant(NamedParams):
    """A plant with named states/outputs and parameterised dynamics."""

    kind: Literal["lti", "nonlinear"]
    states: list[str]
    outputs: list[str]
    params: dict[str, float]
    spec: PlantSpec
    # Nonlinear only: casadi functions of (x, u, p).
    f: ca.Function | None = None
    h: ca.Function | None = None
    _cache: dict = field(default_factory=dict, repr=False)

    def delay(self, values: dict[str, float] | None = None) -> float:
        """Input delay in seconds for these parameters (SpecError unless finite and >= 0)."""
        p = self.with_params(values)
        d = expr.to_float(self.spec.delay if self.spec.delay is not None else 0.0, p, "plant.delay")
        if not np.isfinite(d) or d < 0:
            raise SpecError("plant.delay", f"delay must be a finite number >= 0, got {d}")
        return d

    def linearize(self, values: dict[str, float] | None = None) -> LinearModel:
        """Continuous-time (A, B, C, D), delay and operating point for these parameters."""
        p = self.with_params(values)
        key = tuple(sorted(p.items()))
        if key in self._cache:
            return self._cache[key]
        if self.kind == "lti":
            lin = self._lti_model(p, _lti_matrices(self.spec, p))
        else:
            lin = _linearize_ode(self, p)
        return self._remember(key, lin)

    def _lti_model(self, p: dict[str, float], mats: tuple[np.ndarray, ...]) -> LinearModel:
        A, B, C, D = mats
        n, q = A.shape[0], C.shape[0]
        return LinearModel(A, B, C, D, self.delay(p), self.states, self.outputs, np.zeros(n), 0.0, np.zeros(q))

    def _remember(self, key: tuple, lin: LinearModel) -> LinearModel:
        if len(self._cache) > 256:
            self._cache.clear()
        self._cache[key] = lin
        return lin

    def param_vector(self, values: dict[str, float] | None = None) -> np.ndarray:
        """Nominal parameters updated by ``values``, as a float vector in :attr:`param_names` order."""
        p = self.with_params(values)
        return np.array([p[k] for k in self.params], dtype=float)


# ------------------------------------------------------------------- LTI


def _tf_matrices(tf: TransferFunctionSpec, p: dict[str, float]):
    num = _poly(tf.num, p, "plant.tf.num")
    den = _poly(tf.den, p, "plant.tf.den")
    if den[0] == 0:
        raise SpecError(
            "plant.tf.den", "leading denominator coefficient is zero; drop leading zeros or fix the highest power"
        )
    num = np.trim_zeros(num, "f") if np.any(num) else np.array([0.0])
    if len(num) > len(den):
        raise SpecError(
            "plant.tf", f"improper transfer function (numerator degree {len(num)-1} > denominator degree "
            f"{len(den)-1}): a plant needs at least as many poles as zeros; give the denominator degree >= "
            f"{len(num)-1}, e.g. with a fast lag (equal degrees, a biproper plant, are accepted)"
        )
    if len(den) - 1 > MAX_ORDER:
        raise SpecError("plant.tf.den", f"plant order {len(den)-1} exceeds the limit of {MAX_ORDER}")
    if len(den) == 1:
        raise SpecError("plant.tf.den", "a static gain has no dynamics to control; give a denominator of degree >= 1")
    return _tf2ss(num, den)


def _tf2ss(num: np.ndarray, den: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Controller canonical form of a proper SISO num/den, as ``scipy.signal.tf2ss`` builds it.

    Written out (the same operations, so bit-identical) because importing scipy.signal costs
    about 0.5 s, more than a whole ``gaintune verify`` of a PI loop should take.
    """
    num, den = num / den[0], den / den[0]
    n = len(den) - 1
    num = np.concatenate([np.zeros(n + 1 - len(num)), num])
    A = np.r_[-np.array([den[1:]]), np.eye(n - 1, n)]
    B = np.eye(n, 1)
    C = num[None, 1:] - np.outer(num[:1], den[1:])
    D = np.array([[num[0]]])
    return A, B, C, D


def _ss_matrices(ss: StateSpaceSpec, p: dict[str, float]):
    A = _coef_matrix(ss.A, p, "plant.ss.A")
    B = _coef_matrix(ss.B, p, "plant.ss.B")
    C = _coef_matrix(ss.C, p, "plant.ss.C")
    n = A.shape[0]
    if A.shape != (n, n):
        raise SpecError("plant.ss.A", f"must be square, got {A.shape[0]}x{A.shape[1]}")
    if n > MAX_ORDER:
        raise SpecError("plant.ss.A", f"plant order {n} exceeds the limit of {MAX_ORDER}")
    if B.shape != (n, 1):
        raise SpecError("plant.ss.B", f"must be {n}x1 (one actuator input), got {B.shape[0]}x{B.shape[1]}; "
                           "for a plant with several inputs name them: ss.inputs, one per column of B")
    if C.shape[1] != n:
        raise SpecError("plant.ss.C", f"must have {n} columns to match A, got {C.shape[1]}")
    q = C.shape[0]
    D = np.zeros((q, 1)) if ss.D is None else _coef_matrix(ss.D, p, "plant.ss.D")
    if D.shape != (q, 1):
        raise SpecError("plant.ss.D", f"must be {q}x1, got {D.shape[0]}x{D.shape[1]}")
    return A, B, C, D


def _lti_matrices(spec: PlantSpec, p: dict[str, float]):
    if spec.tf is not None:
        return _tf_matrices(spec.tf, p)
    assert spec.ss is not None
    return _ss_matrices(spec.ss, p)


# ------------------------------------------------------------- nonlinear


def _build_ode(ode: OdeSpec, params: dict[str, float]):
    import casadi as ca  # deferred on purpose: only ODE plants need casadi (~15 ms at start-up for LTI runs)

    x = ca.SX.sym("x", len(ode.states))
    u = ca.SX.sym("u")
    pv = ca.SX.sym("p", len(params))
    scope = {name: x[i] for i, name in enumerate(ode.states)}
    scope[ode.input] = u
    for i, name in enumerate(params):
        if name in scope:
            raise SpecError(f"plant.params.{name}", "parameter name clashes with a state or the input")
        scope[name] = pv[i]
    add_defs(ode, scope)
    rhs = ca.vertcat(*[expr.to_casadi(ode.rhs[s], scope, f"plant.ode.rhs.{s}") for s in ode.states])
    out = ca.vertcat(*[expr.to_casadi(e, scope, f"plant.ode.outputs.{k}") for k, e in ode.outputs.items()])
    f = ca.Function("f", [x, u, pv], [rhs], ["x", "u", "p"], ["xdot"])
    h = ca.Function("h", [x, u, pv], [out], ["x", "u", "p"], ["y"])
    return f, h


def _solve_u0(plant: Plant, ode: OdeSpec, x0: np.ndarray, pv: np.ndarray) -> float:
    """Solve f(x0, u, p) = 0 for u in the least-squares sense (the operating input)."""
    from scipy.optimize import least_squares  # deferred: only ODE plants without u0 need it (~0.15 s)

    f = plant.f
    assert f is not None  # an ODE plant always has its right-hand side

    def residual(u: float) -> np.ndarray:
        return np.asarray(f(x0, u, pv), dtype=float).ravel()

    # least_squares starts from u = 0 and raises a bare ValueError if the model is not finite there
    # (log(0), sqrt(-1), overflow): name the state and the fix instead.
    start = residual(0.0)
    if not np.all(np.isfinite(start)):
        i = int(np.flatnonzero(~np.isfinite(start))[0])
        raise SpecError(
            "plant.ode.x0",
            f"the model is not finite at x0 = {dict(zip(ode.states, x0.tolist(), strict=True))} with u = 0 "
            f"(d{ode.states[i]}/dt = {start[i]}); give an x0 inside the model's domain, or set u0",
        )
    with np.errstate(invalid="ignore", over="ignore"):  # finite-difference steps may leave the domain
        res = least_squares(lambda u: residual(u[0]), x0=[0.0])
    u0 = float(res.x[0])
    # 'not <=' also rejects NaN (the solver can wander out of the model's domain).
    if not np.linalg.norm(residual(u0)) <= 1e-6 * (1 + np.abs(x0).sum()):
        raise SpecError(
            "plant.ode.x0", "x0 is not an equilibrium for any constant input; give an equilibrium x0 or set u0"
        )
    return u0


def _linearize_ode(plant: Plant, p: dict[str, float]) -> LinearModel:
    ode = plant.spec.ode
    assert ode is not None and plant.f is not None and plant.h is not None
    pv = plant.param_vector(p)
    n = plant.order
    x0 = np.array([expr.to_float(ode.x0.get(s, 0.0), p, f"plant.ode.x0.{s}") for s in ode.states])
    for s, v in zip(ode.states, x0, strict=True):
        if not np.isfinite(v):
            raise SpecError(f"plant.ode.x0.{s}", f"must be a finite number, got {v}")
    if ode.u0 is not None:
        assert not isinstance(ode.u0, dict)  # a map is refused by the spec unless there are several inputs
        u0 = expr.to_float(ode.u0, p, "plant.ode.u0")
        if not np.isfinite(u0):
            raise SpecError("plant.ode.u0", f"must be a finite number, got {u0}")
    else:
        u0 = _solve_u0(plant, ode, x0, pv)
    import casadi as ca  # deferred (see _build_ode)

    xs, us, ps = ca.SX.sym("x", n), ca.SX.sym("u"), ca.SX.sym("p", len(pv))
    fx = plant.f(xs, us, ps)
    hx = plant.h(xs, us, ps)
    jacobians = [ca.jacobian(fx, xs), ca.jacobian(fx, us), ca.jacobian(hx, xs), ca.jacobian(hx, us), hx]
    jac = ca.Function("linearization", [xs, us, ps], jacobians)
    A, B, C, D, y0 = (np.array(m, dtype=float) for m in jac(x0, u0, pv))
    for name, m in (("A", A), ("B", B), ("C", C), ("D", D), ("y0", y0)):
        if not np.all(np.isfinite(m)):
            raise SpecError(
                "plant.ode", f"linearisation gives non-finite {name} at the operating point; check x0 and params"
            )
    return LinearModel(
        A, B.reshape(n, 1), C, D.reshape(-1, 1), plant.delay(p), plant.states, plant.outputs, x0, u0, y0.ravel()
    )


# ------------------------------------------------------------------ build


def _resolve_model(spec: PlantSpec) -> PlantSpec:
    """Expand a ``model:`` reference into the model file's plant, with overrides applied."""
    from gaintune.plants.library import load_model

    ref = spec.model
    assert ref is not None and not isinstance(ref, str)
    model = load_model(ref.name)
    base = model.plant
    params = dict(base.params)
    params.update(spec.params)
    for k, v in ref.params.items():
        if k not in params:
            raise SpecError(
                f"plant.model.params.{k}", f"model {ref.name!r} has no parameter {k!r}; known: {', '.join(params)}"
            )
        params[k] = v
    delay = spec.delay if spec.delay is not None else base.delay
    return base.model_copy(update={"params": params, "delay": delay})


def is_mimo_plant_spec(spec: PlantSpec) -> bool:
    """Whether ``spec`` (a resolved plant, not a model reference) has the several-input form.

    This and :func:`is_mimo_plant` are here, not in :mod:`gaintune.plants.mimo`: a single-input
    problem does not import that module.
    """
    return spec.tf_matrix is not None or (spec.ss is not None and spec.ss.is_mimo) or (
        spec.ode is not None and spec.ode.is_mimo)


def is_mimo_plant(plant: object) -> bool:
    """Whether ``plant`` is a :class:`gaintune.plants.mimo.MimoPlant` (its ``kind`` is ``"mimo"``)."""
    return getattr(plant, "kind", None) == "mimo"


def build_plant(spec: PlantSpec) -> Plant:
    """Validate a plant spec numerically at its nominal parameters and build a :class:`Plant`.

    Raises
    ------
    SpecError
        For improper or ill-formed models, non-finite values, unknown names or forbidden expressions.
    """
    if spec.model is not None:
        spec = _resolve_model(spec)
    if is_mimo_plant_spec(spec):  # several inputs: the shared MIMO form (gaintune.lti.mimo)
        from gaintune.plants.mimo import build_mimo_plant

        return build_mimo_plant(spec)  # type: ignore[return-value]  # a MimoPlant stands in where its forms apply
    params = dict(spec.params)
    if spec.ode is not None:
        ode = spec.ode
        if len(ode.states) > MAX_ORDER:
            raise SpecError("plant.ode.states", f"plant order {len(ode.states)} exceeds the limit of {MAX_ORDER}")
        f, h = _build_ode(ode, params)
        plant = Plant("nonlinear", list(ode.states), list(ode.outputs), params, spec, f, h)
    else:
        A, B, C, D = _lti_matrices(spec, params)
        if spec.tf is not None:
            outputs = [spec.tf.output]
        else:
            assert spec.ss is not None
            outputs = spec.ss.outputs or [f"y{i}" for i in range(C.shape[0])]
            if len(outputs) != C.shape[0]:
                raise SpecError("plant.ss.outputs", f"names {len(outputs)} outputs but C has {C.shape[0]} rows")
        named = spec.ss.states if spec.ss is not None and spec.ss.states else None
        states = named or [f"x{i}" for i in range(A.shape[0])]
        if len(states) != A.shape[0]:
            raise SpecError("plant.ss.states", f"names {len(states)} states but A is {A.shape[0]}x{A.shape[0]}")
        plant = Plant("lti", states, outputs, params, spec)
    for name in (*plant.outputs, *plant.states):
        if not name.isidentifier():
            raise SpecError("plant", f"name {name!r} must be an identifier")
    plant.delay()  # validates the delay expression
    if plant.kind == "lti":  # the nominal model from the matrices just built and checked (not built twice)
        p = plant.with_params(None)
        plant._remember(tuple(sorted(p.items())), plant._lti_model(p, (A, B, C, D)))
    else:
        plant.linearize()  # validates the model at nominal parameters
    return plant
