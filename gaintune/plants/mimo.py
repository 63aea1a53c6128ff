"""Plants with several inputs and outputs, built from a spec into the shared MIMO LTI forms.

A :class:`MimoPlant` has named inputs and outputs (each with its unit), parameters as SISO
plants have, and gives its :mod:`gaintune.lti.mimo` form for any parameter values
(:meth:`MimoPlant.lti`): a :class:`~gaintune.lti.mimo.TfMatrix` (``plant.tf_matrix``, a delay per
entry) or a :class:`~gaintune.lti.mimo.DelayedSS` (``plant.ss`` with several input columns and
per-input delays). :func:`as_mimo` views a single-input LTI plant in the same form, for loop
graphs on a single-input plant.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np

from gaintune.errors import SpecError
from gaintune.lti.mimo import DelayedSS, TfEntry, TfMatrix
from gaintune.plants import expr
from gaintune.plants.coefs import coef_matrix, poly
from gaintune.plants.params import NamedParams
from gaintune.spec import MAX_ORDER, PlantSpec, SignalSpec, TfEntrySpec

__all__ = ["MimoPlant", "build_mimo_plant", "as_mimo", "MAX_MIMO_STATES"]

#: Largest total state count of a MIMO plant (every entry's realisation together).
MAX_MIMO_STATES = 200


@dataclass
class MimoPlant(NamedParams):
    """A linear plant with named inputs and outputs.

    Attributes
    ----------
    inputs, output_signals
        The named inputs and outputs with their units.
    outputs
        The output names (as :class:`gaintune.plants.plant.Plant` has them).
    states
        State names of the realisation the simulator uses.
    """

    kind = "mimo"
    inputs: list[SignalSpec]
    output_signals: list[SignalSpec]
    states: list[str]
    params: dict[str, float]
    spec: PlantSpec
    _siso: Any = None  # a single-input plant viewed as MIMO (as_mimo)
    ode: Any = None  # a several-input ODE: its casadi functions (gaintune.plants.mimo_ode.OdeFunctions)
    _cache: dict = field(default_factory=dict, repr=False)

    @property
    def nonlinear(self) -> bool:
        """Whether the plant is a nonlinear ODE (simulated as such, linearised for the analyses)."""
        return self.ode is not None

    def operating_point(self, values: dict[str, float] | None = None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(x0, u0, y0): the ODE's operating point, zeros for a linear plant (its signals are deviations)."""
        if self.ode is None:
            return np.zeros(self.order), np.zeros(len(self.inputs)), np.zeros(len(self.output_signals))
        self.lti(values)
        op = self._cache[("op", *sorted(self.with_params(values).items()))]
        return op.x0, op.u0, op.y0

    @property
    def outputs(self) -> list[str]:
        """Output names, in row order."""
        return [s.name for s in self.output_signals]

    @property
    def input_names(self) -> list[str]:
        """Input names, in column order."""
        return [s.name for s in self.inputs]

    def param_vector(self, values: dict[str, float] | None = None) -> np.ndarray:
        """Parameters as a float vector in :attr:`param_names` order."""
        p = self.with_params(values)
        return np.array([p[k] for k in self.params], dtype=float)

    def delay(self, values: dict[str, float] | None = None) -> float:
        """0: the delays of a MIMO plant are per path (:meth:`lti`)."""
        return 0.0

    def lti(self, values: dict[str, float] | None = None) -> TfMatrix | DelayedSS:
        """The plant's :mod:`gaintune.lti.mimo` form for these parameters (memoised)."""
        if self._siso is not None:
            return _siso_lti(self._siso, self.with_params(values))  # this view's parameters (a robust draw's)
        p = self.with_params(values)
        key = tuple(sorted(p.items()))
        hit = self._cache.get(key)
        if hit is None:
            if len(self._cache) > 256:
                self._cache.clear()
            if self.ode is not None:
                from gaintune.plants.mimo_ode import linearize_mimo_ode

                assert self.spec.ode is not None
                pv = np.array([p[k] for k in self.params], dtype=float)
                hit, op = linearize_mimo_ode(self.ode, self.spec.ode, p, pv, tuple(self.input_names),
                                             tuple(self.outputs))
                self._cache[("op", *key)] = op
                self._cache[key] = hit
            else:
                hit = self._cache[key] = _build_lti(self.spec, p, tuple(self.input_names), tuple(self.outputs))
        return hit

    def linearize(self, values: dict[str, float] | None = None):
        """Not defined for several inputs: the single-input analyses refuse such a plant by name."""
        raise SpecError("plant", "this plant has several inputs (" + ", ".join(self.input_names) + "); this "
                        "command handles single-input plants only so far (tune and simulate take MIMO specs)")


# ------------------------------------------------------------------ build


def _entry(e: TfEntrySpec | float, p: dict[str, float], where: str) -> TfEntry:
    if not isinstance(e, TfEntrySpec):
        return TfEntry(np.array([0.0]), np.array([1.0]), 0.0)
    num = poly(e.num, p, f"{where}.num")
    den = poly(e.den, p, f"{where}.den")
    if den[0] == 0:
        raise SpecError(f"{where}.den", "leading denominator coefficient is zero; drop leading zeros")
    num = np.trim_zeros(num, "f") if np.any(num) else np.array([0.0])
    if len(den) < 2:
        raise SpecError(f"{where}.den", "a static gain has no dynamics; give a denominator of degree >= 1")
    if len(num) >= len(den) and np.any(num):
        raise SpecError(f"{where}", f"the entry must be strictly proper (numerator degree {len(num) - 1} < "
                        f"denominator degree {len(den) - 1}); a direct feedthrough is not supported in a "
                        "transfer-function matrix")
    if len(den) - 1 > MAX_ORDER:
        raise SpecError(f"{where}.den", f"entry order {len(den) - 1} exceeds the limit of {MAX_ORDER}")
    delay = expr.to_float(e.delay, p, f"{where}.delay")
    if not (np.isfinite(delay) and delay >= 0):
        raise SpecError(f"{where}.delay", f"must be a finite number >= 0, got {delay}")
    return TfEntry(num / den[0], den / den[0], delay)


def _build_lti(spec: PlantSpec, p: dict[str, float], inputs: tuple[str, ...],
               outputs: tuple[str, ...]) -> TfMatrix | DelayedSS:
    if spec.tf_matrix is not None:
        rows = tuple(tuple(_entry(e, p, f"plant.tf_matrix.entries[{i}][{j}]") for j, e in enumerate(row))
                     for i, row in enumerate(spec.tf_matrix.entries))
        return TfMatrix(rows, inputs, outputs)
    assert spec.ss is not None
    ss = spec.ss
    A = coef_matrix(ss.A, p, "plant.ss.A")
    B = coef_matrix(ss.B, p, "plant.ss.B")
    C = coef_matrix(ss.C, p, "plant.ss.C")
    n, m = A.shape[0], B.shape[1]
    if A.shape != (n, n):
        raise SpecError("plant.ss.A", f"must be square, got {A.shape[0]}x{A.shape[1]}")
    if n > MAX_ORDER:
        raise SpecError("plant.ss.A", f"plant order {n} exceeds the limit of {MAX_ORDER}")
    if B.shape[0] != n:
        raise SpecError("plant.ss.B", f"must have {n} rows to match A, got {B.shape[0]}")
    if C.shape[1] != n:
        raise SpecError("plant.ss.C", f"must have {n} columns to match A, got {C.shape[1]}")
    D = np.zeros((C.shape[0], m)) if ss.D is None else coef_matrix(ss.D, p, "plant.ss.D")
    if D.shape != (C.shape[0], m):
        raise SpecError("plant.ss.D", f"must be {C.shape[0]}x{m}, got {D.shape[0]}x{D.shape[1]}")
    if np.any(D):
        raise SpecError("plant.ss.D", "a plant with several inputs must be strictly proper (D = 0) so far")
    delays = np.zeros(m)
    for j, d in enumerate(ss.input_delays or []):
        delays[j] = expr.to_float(d, p, f"plant.ss.input_delays[{j}]")
        if not (np.isfinite(delays[j]) and delays[j] >= 0):
            raise SpecError(f"plant.ss.input_delays[{j}]", f"must be a finite number >= 0, got {delays[j]}")
    return DelayedSS(A, B, C, D, inputs=inputs, outputs=outputs, input_delays=delays)


def _signals(spec: PlantSpec) -> tuple[list[SignalSpec], list[SignalSpec]]:
    if spec.ode is not None:
        ode_units = spec.ode.output_units or {}
        return list(spec.ode.inputs or []), [SignalSpec(name=n, unit=ode_units.get(n, "")) for n in spec.ode.outputs]
    if spec.tf_matrix is not None:
        return list(spec.tf_matrix.inputs), list(spec.tf_matrix.outputs)
    ss = spec.ss
    assert ss is not None
    m = len(ss.B[0]) if ss.B else 0
    inputs = list(ss.inputs) if ss.inputs is not None else [SignalSpec(name=f"u{j}") for j in range(m)]
    names = ss.outputs or [f"y{i}" for i in range(len(ss.C))]
    if len(names) != len(ss.C):
        raise SpecError("plant.ss.outputs", f"names {len(names)} outputs but C has {len(ss.C)} rows")
    units = ss.output_units or [""] * len(names)
    if len(units) != len(names):
        raise SpecError("plant.ss.output_units", f"gives {len(units)} units for {len(names)} outputs")
    return inputs, [SignalSpec(name=n, unit=u) for n, u in zip(names, units, strict=True)]


def build_mimo_plant(spec: PlantSpec) -> MimoPlant:
    """Build and check a MIMO plant spec (already resolved from a model reference) at nominal parameters.

    Raises
    ------
    SpecError
        For improper entries, non-finite values, bad shapes and names, or forbidden expressions.
    """
    inputs, outputs = _signals(spec)
    params = dict(spec.params)
    if spec.ode is not None:
        return _build_ode_plant(spec, inputs, outputs, params)
    lti = _build_lti(spec, params, tuple(s.name for s in inputs), tuple(s.name for s in outputs))
    if isinstance(lti, TfMatrix):
        states = [f"x_{outputs[i].name}_{inputs[j].name}_{k}" for i, row in enumerate(lti.entries)
                  for j, e in enumerate(row) for k in range(0 if e.is_zero else len(e.den) - 1)]
    else:
        states = list(spec.ss.states) if spec.ss is not None and spec.ss.states else [
            f"x{i}" for i in range(lti.A.shape[0])]
        if len(states) != lti.A.shape[0]:
            raise SpecError("plant.ss.states", f"names {len(states)} states but A is {lti.A.shape[0]}x{lti.A.shape[0]}")
    if len(states) > MAX_MIMO_STATES:
        raise SpecError("plant", f"{len(states)} states in all exceeds the limit of {MAX_MIMO_STATES}")
    plant = MimoPlant(inputs, outputs, states, params, spec)
    plant._cache[tuple(sorted(params.items()))] = lti
    return plant


def _build_ode_plant(spec: PlantSpec, inputs: list[SignalSpec], outputs: list[SignalSpec],
                     params: dict[str, float]) -> MimoPlant:
    from gaintune.plants.mimo_ode import build_ode_functions

    ode = spec.ode
    assert ode is not None
    if len(ode.states) > MAX_ORDER:
        raise SpecError("plant.ode.states", f"plant order {len(ode.states)} exceeds the limit of {MAX_ORDER}")
    for name in ode.outputs:
        if not name.isidentifier():
            raise SpecError("plant.ode.outputs", f"output name {name!r} must be an identifier")
    plant = MimoPlant(inputs, outputs, list(ode.states), params, spec,
                      ode=build_ode_functions(ode, params))
    plant.lti()  # the operating point and the linearisation at nominal parameters: checked now
    return plant


def as_mimo(plant) -> MimoPlant:
    """A single-input LTI plant (a :class:`gaintune.plants.plant.Plant`) as a one-input MIMO plant.

    Its input is named ``u`` and its delay is the input's delay. Nonlinear plants are refused.
    """
    if isinstance(plant, MimoPlant):
        return plant
    if plant.kind != "lti":
        return _ode_as_mimo(plant)
    if np.any(plant.linearize().D):
        raise SpecError("plant", "loops that say what they drive need a strictly proper plant (no direct "
                        "feedthrough) so far")
    return MimoPlant([SignalSpec(name="u")], [SignalSpec(name=n) for n in plant.outputs], list(plant.states),
                     dict(plant.params), plant.spec, _siso=plant)


def _ode_as_mimo(plant) -> MimoPlant:
    """A single-input ODE plant as a one-input nonlinear MIMO plant (its casadi f, h take a 1-vector u)."""
    from gaintune.plants.mimo_ode import OdeFunctions

    ode = plant.spec.ode
    if plant.delay() != 0:
        raise SpecError("plant.delay", "an ODE plant in a loop graph (or with a state disturbance) takes its delay "
                        "as the actuator's: drop plant.delay and set actuators.<input>.delay")
    out = MimoPlant([SignalSpec(name=ode.input)], [SignalSpec(name=n) for n in plant.outputs], list(plant.states),
                    dict(plant.params), plant.spec, ode=OdeFunctions(plant.f, plant.h))
    out.lti()  # the operating point and the linearisation, checked now
    return out


def _siso_lti(plant, values: dict[str, float] | None) -> DelayedSS:
    lin = plant.linearize(values)
    return DelayedSS(lin.A, lin.B, lin.C, np.zeros_like(lin.D), inputs=("u",), outputs=tuple(lin.outputs),
                     input_delays=np.array([lin.delay]))
