"""The ``plant`` section of a spec: a transfer function, state space, ODE or built-in model.

Numeric plant coefficients may be numbers or expressions over ``plant.params``
(parsed by :mod:`gaintune.plants.expr`, never ``eval``-ed), which is how
randomised LTI plants are expressed.
"""

from __future__ import annotations

from typing import Annotated, Any

from pydantic import AfterValidator, Field, field_validator, model_validator

from gaintune.spec.base import _error_at, _finite, _Model
from gaintune.spec.mimo import SignalSpec, TfMatrixSpec

__all__ = [
    "Coef",
    "FiniteParams",
    "TransferFunctionSpec",
    "StateSpaceSpec",
    "OdeSpec",
    "ModelRefSpec",
    "PlantSpec",
]

#: A plant coefficient: a number, or an expression over ``plant.params``.
Coef = float | str


def _check_coefs(values: Any, what: str) -> Any:
    if isinstance(values, list):
        for item in values:
            if isinstance(item, list):
                _check_coefs(item, what)
            else:
                _finite(item, what)
    return values


def _finite_params(v: dict[str, float]) -> dict[str, float]:
    for k, x in v.items():
        _finite(x, f"parameter {k!r}")
    return v


#: Parameter values by name, all finite.
FiniteParams = Annotated[dict[str, float], AfterValidator(_finite_params)]


class TransferFunctionSpec(_Model):
    """A SISO transfer function num(s)/den(s), proper: at most as many zeros as poles.
    A biproper one (equal degrees: direct feedthrough, e.g. 3(s+10)/(s+2)) needs no delay:
    the output is sampled before the control update, so its feedthrough sees the input
    held over the previous sample, u[k-1] (u[k-1-d] after d samples of delay; docs/simulation.md).
    More zeros than poles is refused.

    ``num``/``den`` are coefficient lists in descending powers of s (numbers or
    parameter expressions), or one polynomial expression in ``s`` such as
    ``"K"`` and ``"(T*s + 1)^3"``.
    """

    num: list[Coef] | str = Field(description="Numerator, descending powers of s, or a polynomial in s.")
    den: list[Coef] | str = Field(description="Denominator, descending powers of s, or a polynomial in s.")
    output: str = Field("y", description="Name of the single output.")

    @field_validator("num", "den")
    @classmethod
    def _coefs(cls, v: Any) -> Any:
        if isinstance(v, list) and not v:
            raise ValueError("needs at least one coefficient")
        return _check_coefs(v, "coefficient")


class StateSpaceSpec(_Model):
    """dx/dt = A x + B u, y = C x + D u with named outputs; B has one column per input.

    With one column (and no ``inputs``) this is a single-input plant; with ``inputs`` (one named
    input per column of B, each with its unit) and optional ``input_delays`` it is a MIMO plant.
    """

    A: list[list[Coef]]
    B: list[list[Coef]]
    C: list[list[Coef]]
    D: list[list[Coef]] | None = Field(None, description="Defaults to zeros. Feedthrough is sampled with the "
                                       "previous input held: y[k] = C x[k] + D u[k-1-d] (docs/simulation.md).")
    outputs: list[str] | None = Field(None, description="One name per row of C; default y0, y1, ...")
    states: list[str] | None = Field(None, description="One name per state; default x0, x1, ...")
    # the new fields are left out of dumps while unset, so single-input specs hash as before
    inputs: list[SignalSpec] | None = Field(
        None, exclude_if=lambda v: v is None,
        description="MIMO: one named input per column of B ({name, unit} or a name).")
    input_delays: list[Coef] | None = Field(
        None, exclude_if=lambda v: v is None, description="MIMO: a delay in seconds per input (default 0).")
    output_units: list[str] | None = Field(
        None, exclude_if=lambda v: v is None, description="The unit of each output, in the order of C's rows.")

    @model_validator(mode="after")
    def _mimo_names(self) -> StateSpaceSpec:
        if self.inputs is not None:
            names = [s.name for s in self.inputs]
            if len(set(names)) != len(names):
                raise _error_at(("inputs",), f"input names must be unique, {names}", names)
            if self.B and len(self.B[0]) != len(self.inputs):
                raise _error_at(("inputs",), f"names {len(self.inputs)} inputs but B has {len(self.B[0])} "
                                "columns; give one input per column of B", names)
        if self.input_delays is not None:
            m = len(self.inputs) if self.inputs is not None else (len(self.B[0]) if self.B else 0)
            if len(self.input_delays) != m:
                raise _error_at(("input_delays",), f"gives {len(self.input_delays)} delays for {m} inputs; give "
                                "one per input", self.input_delays)
            _check_coefs(self.input_delays, "delay")
        return self

    @property
    def is_mimo(self) -> bool:
        """Whether this is the several-input form (named ``inputs``, or ``input_delays``)."""
        return self.inputs is not None or self.input_delays is not None

    @field_validator("A", "B", "C", "D")
    @classmethod
    def _coefs(cls, v: Any) -> Any:
        return _check_coefs(v, "matrix entry")

    @field_validator("outputs", "states")
    @classmethod
    def _unique_names(cls, v: list[str] | None, info: Any) -> list[str] | None:
        # loops measure outputs and reports list states by name: a repeated name would merge two of them
        if v is not None and len(set(v)) != len(v):
            dup = sorted({n for n in v if v.count(n) > 1})
            raise ValueError(f"{info.field_name} names must be unique, {dup} repeat")
        return v


class OdeSpec(_Model):
    """A nonlinear plant dx/dt = f(x, u, p), y = h(x, u, p) written as expressions.

    One input (``input``, default ``u``), or several: ``inputs`` names them (each with its unit),
    and ``u0`` is then a map from input name to its operating value (solved in the least-squares
    sense for equilibrium at ``x0`` when omitted).
    """

    states: list[str] = Field(min_length=1)
    input: str = Field("u", description="Name of the actuator input in the expressions.")
    rhs: dict[str, str] = Field(description="d(state)/dt expression for every state.")
    outputs: dict[str, str] = Field(description="Output name -> expression.")
    x0: dict[str, Coef] = Field(default_factory=dict, description="Operating-point state (default 0, or solved).")
    u0: Coef | dict[str, Coef] | None = Field(
        None, description="Operating-point input; solved from x0 for equilibrium if omitted. Several inputs: a map "
        "input name -> value (all of them, or omitted).")
    # left out of dumps while unset, so single-input specs hash as before
    inputs: list[SignalSpec] | None = Field(
        None, exclude_if=lambda v: v is None,
        description="Several inputs: the named inputs ({name, unit} or a name), used in the expressions; "
        "replaces 'input'.")
    output_units: dict[str, str] | None = Field(
        None, exclude_if=lambda v: v is None, description="The unit of each output, by output name.")
    defs: dict[str, str] | None = Field(
        None, exclude_if=lambda v: v is None,
        description="Named intermediate expressions, evaluated in order (e.g. a mass matrix's entries): each may "
        "use the states, the inputs, the parameters and the names defined before it; rhs and outputs may use them "
        "all.")

    @property
    def is_mimo(self) -> bool:
        """Whether this is the several-input form (``inputs`` given)."""
        return self.inputs is not None

    @property
    def input_names(self) -> list[str]:
        """The names of the inputs in the expressions, in order."""
        return [s.name for s in self.inputs] if self.inputs is not None else [self.input]

    def _check_inputs(self) -> None:
        if self.inputs is None:
            if isinstance(self.u0, dict):
                raise _error_at(("u0",), "a map of input values needs several inputs ('inputs'); give one number "
                                "for the single input", self.u0)
            return
        names = self.input_names
        if len(set(names)) != len(names):
            raise _error_at(("inputs",), f"input names must be unique, {names}", names)
        if "input" in self.model_fields_set:
            raise _error_at(("input",), "give either 'input' (one input) or 'inputs' (several), not both", self.input)
        for k, name in enumerate(names):
            if name in self.states:
                raise _error_at(("inputs", k), f"input {name!r} has the name of a state; rename one", name)
        if self.u0 is not None:
            if not isinstance(self.u0, dict):
                raise _error_at(("u0",), f"with several inputs u0 maps each input to its value, e.g. "
                                f"{{{names[0]}: 1.0, ...}}, or leave it out to solve it", self.u0)
            missing = [n for n in names if n not in self.u0]
            extra = [n for n in self.u0 if n not in names]
            if missing or extra:
                raise _error_at(("u0",), f"gives {len(self.u0)} values for {len(names)} inputs"
                                + (f"; missing {missing}" if missing else "") + (f"; unknown {extra}" if extra else "")
                                + f"; give one value per input ({', '.join(names)})", self.u0)
        unknown = [o for o in (self.output_units or {}) if o not in self.outputs]
        if unknown:
            raise _error_at(("output_units",), f"names unknown output(s) {unknown}; outputs: "
                            f"{', '.join(self.outputs)}", unknown)

    def _check_defs(self) -> None:
        for name in self.defs or {}:
            if not name.isidentifier() or name.startswith("_"):
                raise _error_at(("defs", name), f"{name!r} must be an identifier (letters, digits and _, not "
                                "starting with a digit or _)", name)
            if name in self.states or name in self.input_names:
                raise _error_at(("defs", name), f"{name!r} is already a state or an input; rename the definition",
                                name)

    @model_validator(mode="after")
    def _rhs_matches_states(self) -> OdeSpec:
        if len(set(self.states)) != len(self.states):
            repeated = sorted({n for n in self.states if self.states.count(n) > 1})
            raise ValueError(f"states names must be unique, {repeated} repeat")
        self._check_inputs()
        self._check_defs()
        if self.inputs is None and self.input in self.states:
            # the expressions would read the name as the input: the state would vanish from the model
            i = self.states.index(self.input)
            raise _error_at(("states", i), f"state {self.input!r} has the name of the input (input: {self.input}); "
                            "in the expressions that name means the input, so rename the state or set 'input' to "
                            "another name", self.input)
        missing = [s for s in self.states if s not in self.rhs]
        extra = [s for s in self.rhs if s not in self.states]
        if missing:
            raise ValueError(f"rhs has no expression for state(s) {missing}; add 'rhs: {{{missing[0]}: ...}}'")
        if extra:
            raise ValueError(f"rhs names unknown state(s) {extra}; declare them in 'states'")
        if not self.outputs:
            raise ValueError("outputs must name at least one output expression")
        return self


class ModelRefSpec(_Model):
    """A built-in model from ``models/`` with parameter overrides."""

    name: str = Field(description="File stem in models/, e.g. 'dc_motor'.")
    params: FiniteParams = Field(default_factory=dict, description="Overrides of the model's nominal parameters.")


class PlantSpec(_Model):
    """Exactly one of ``tf``, ``tf_matrix``, ``ss``, ``ode`` or ``model``, plus delay and parameters."""

    tf: TransferFunctionSpec | None = None
    tf_matrix: TfMatrixSpec | None = Field(
        None, exclude_if=lambda v: v is None,
        description="A transfer-function matrix with named inputs and outputs and a delay per entry (MIMO).")
    ss: StateSpaceSpec | None = None
    ode: OdeSpec | None = None
    model: ModelRefSpec | str | None = None
    delay: Coef | None = Field(
        None, description="Input/output time delay in seconds (number or parameter expression); default 0, or the "
        "model's."
    )
    params: FiniteParams = Field(default_factory=dict, description="Nominal parameter values.")

    @field_validator("delay")
    @classmethod
    def _delay(cls, v: Coef | None) -> Coef | None:
        if isinstance(v, float):
            _finite(v, "delay")
            if v < 0:
                raise ValueError(f"delay must be >= 0 seconds, got {v}")
        return v

    @model_validator(mode="after")
    def _exactly_one(self) -> PlantSpec:
        given = [k for k in ("tf", "tf_matrix", "ss", "ode", "model") if getattr(self, k) is not None]
        if len(given) != 1:
            raise ValueError(
                f"plant needs exactly one of tf, tf_matrix, ss, ode or model; got {given or 'none'}"
            )
        if self.delay is not None and (self.tf_matrix is not None or (self.ss is not None and self.ss.is_mimo)
                                       or (self.ode is not None and self.ode.is_mimo)):
            raise _error_at(("delay",), "a plant with several inputs has its delays per path: give each entry "
                            "its delay (tf_matrix) or ss.input_delays (an ODE: actuators.<input>.delay), and drop "
                            "plant.delay", self.delay)
        if isinstance(self.model, str):
            self.model = ModelRefSpec(name=self.model)
        self._check_param_names()
        return self

    def _check_param_names(self) -> None:
        """A parameter named like a name the expressions already use would be shadowed by it (or shadow it)."""
        taken: dict[str, str] = {}
        if self.ode is not None:
            taken = {name: f"ode.states[{i}]" for i, name in enumerate(self.ode.states)}
            for name in self.ode.input_names:
                taken[name] = "ode.inputs" if self.ode.is_mimo else "ode.input"
        elif self.tf is not None or self.tf_matrix is not None:
            taken["s"] = "the Laplace variable s of tf expressions"
        for name in self.params:
            if name in taken:
                raise _error_at(("params", name), f"parameter {name!r} clashes with {taken[name]} (the same name); "
                                "in the expressions one would hide the other, so rename the parameter",
                                self.params[name])
