"""Spec forms for plants with several inputs and outputs, and for loops wired as a graph.

* :class:`SignalSpec`: a named plant input or output with its unit;
* :class:`TfEntrySpec`, :class:`TfMatrixSpec`: a transfer-function matrix with a delay per entry
  (the Wood-Berry form); an entry ``0`` is no path;
* :class:`ActuatorsEntrySpec`: one actuator per plant input (``actuators: {input: {...}}``);
* :class:`DecouplerSpec`: a static decoupler between the loops and the plant inputs, each entry fixed or
  tuned (:mod:`gaintune.spec.blocks`);
* :func:`check_architecture`: the loop graph (``drives``), gain ties and names, checked once the
  whole spec is known.

Loops form a graph: each loop measures a plant output and ``drives`` a plant input
(``drives: R``) or the setpoint of another loop (``drives: loop:<name>``). A spec where no
loop says ``drives`` is today's single cascade, outer loop first.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

from pydantic import Field, field_validator, model_validator

from gaintune.spec.base import _error_at, _finite, _Model
from gaintune.spec.blocks import BlockEntry, check_blocks, entry_value

if TYPE_CHECKING:  # pragma: no cover
    from gaintune.spec import TuningSpec

__all__ = ["SignalSpec", "TfEntrySpec", "TfMatrixSpec", "ActuatorsEntrySpec", "DecouplerSpec", "LOOP_PREFIX",
           "MAX_GRAPH_LOOPS", "check_architecture", "is_graph", "drive_target", "gain_unit", "chain_input"]

#: ``drives: loop:<name>``: the loop drives the setpoint of loop <name>.
LOOP_PREFIX = "loop:"
#: Largest number of loops in a graph spec (a single cascade stays at MAX_LOOPS levels).
MAX_GRAPH_LOOPS = 200


class SignalSpec(_Model):
    """A named plant input or output, with its unit (free text, e.g. ``lb/min``)."""

    name: str
    unit: str = ""

    @model_validator(mode="before")
    @classmethod
    def _plain_name(cls, data: Any) -> Any:
        return {"name": data} if isinstance(data, str) else data

    @field_validator("name")
    @classmethod
    def _identifier(cls, v: str) -> str:
        if not v.isidentifier():
            raise ValueError(f"signal name {v!r} must be an identifier (letters, digits and _, not starting "
                             "with a digit)")
        return v


def _unique(signals: list[SignalSpec], what: str) -> None:
    names = [s.name for s in signals]
    if len(set(names)) != len(names):
        dup = sorted({n for n in names if names.count(n) > 1})
        raise ValueError(f"{what} names must be unique, {dup} repeat")


class TfEntrySpec(_Model):
    """One entry ``num(s)/den(s) * exp(-delay s)`` of a transfer-function matrix (strictly proper)."""

    num: list[float | str] | str = Field(description="Numerator, descending powers of s, or a polynomial in s.")
    den: list[float | str] | str = Field(description="Denominator, descending powers of s, or a polynomial in s.")
    delay: float | str = Field(0.0, description="Delay of this path in seconds (the plant's time unit).")

    @field_validator("num", "den")
    @classmethod
    def _coefs(cls, v: Any) -> Any:
        if isinstance(v, list):
            if not v:
                raise ValueError("needs at least one coefficient")
            for x in v:
                _finite(x, "coefficient")
        return v

    @field_validator("delay")
    @classmethod
    def _delay(cls, v: float | str) -> float | str:
        if isinstance(v, float):
            _finite(v, "delay")
            if v < 0:
                raise ValueError(f"delay must be >= 0, got {v}")
        return v


class TfMatrixSpec(_Model):
    """A p x m transfer-function matrix: ``entries[i][j]`` maps input j to output i; ``0`` is no path."""

    inputs: list[SignalSpec] = Field(min_length=1, description="The m plant inputs, in column order.")
    outputs: list[SignalSpec] = Field(min_length=1, description="The p plant outputs, in row order.")
    entries: list[list[TfEntrySpec | float]] = Field(
        description="One row per output, one entry per input: {num, den, delay} or 0 (no path).")

    @model_validator(mode="after")
    def _shape(self) -> TfMatrixSpec:
        _unique(self.inputs, "inputs")
        _unique(self.outputs, "outputs")
        p, m = len(self.outputs), len(self.inputs)
        if len(self.entries) != p:
            raise _error_at(("entries",), f"has {len(self.entries)} rows but there are {p} outputs "
                            f"({', '.join(s.name for s in self.outputs)}); give one row per output", self.entries)
        for i, row in enumerate(self.entries):
            if len(row) != m:
                raise _error_at(("entries", i), f"has {len(row)} entries but there are {m} inputs "
                                f"({', '.join(s.name for s in self.inputs)}); give one entry per input "
                                "(0 where the input does not reach this output)", row)
            for j, e in enumerate(row):
                if not isinstance(e, TfEntrySpec) and e != 0:
                    raise _error_at(("entries", i, j), f"a number entry must be 0 (no path), got {e}; write a "
                                    "path as {num: [...], den: [...], delay: ...}", e)
        return self


class ActuatorsEntrySpec(_Model):
    """The actuator in front of one plant input: saturation, rate limit, delay, safe value."""

    limits: tuple[float, float] | None = Field(None, description="[low, high] saturation.")
    rate_limit: float | None = Field(None, gt=0, description="Maximum |du/dt| in units per second.")
    delay: float = Field(0.0, ge=0, description="Actuator delay in seconds, before the plant's own paths.")
    safe_value: float = Field(0.0, description="Value the safety monitor applies when it trips.")

    @field_validator("limits")
    @classmethod
    def _limits(cls, v: tuple[float, float] | None) -> tuple[float, float] | None:
        if v is not None and not v[0] < v[1]:
            raise ValueError(f"limits must be [low, high] with low < high, got {list(v)}")
        return v


class DecouplerSpec(_Model):
    """A static decoupler ``u = W v``: ``v`` are the loop outputs at the ``inputs`` it names, in order. An entry is a
    number (fixed) or ``{value, bounds, tune}`` (tuned, bounds of one sign: see ``decoupler.matrix[i][j]``)."""

    inputs: list[str] = Field(min_length=1, description="The plant inputs it feeds, in row and column order.")
    matrix: list[list[BlockEntry]] = Field(description="W, square: one row per input (the plant input), one column "
                                                       "per input (the loop output driving it); an entry is a number "
                                                       "or {value, bounds, tune}.")

    @field_validator("matrix", mode="before")
    @classmethod
    def _no_booleans(cls, v: Any) -> Any:
        # an entry may be a mapping with tune: true, so the generic (whole-field) check cannot look inside
        for i, row in enumerate(v if isinstance(v, list) else []):
            for j, e in enumerate(row if isinstance(row, list) else []):
                if isinstance(e, bool):
                    raise _error_at((i, j), f"must be a number or {{value, bounds, tune}}, got {str(e).lower()}", e)
        return v

    @model_validator(mode="after")
    def _square(self) -> DecouplerSpec:
        n = len(self.inputs)
        if len(set(self.inputs)) != n:
            raise _error_at(("inputs",), "names an input twice", self.inputs)
        if len(self.matrix) != n or any(len(r) != n for r in self.matrix):
            shape = f"{len(self.matrix)}x{'/'.join(str(len(r)) for r in self.matrix) or 0}"
            raise _error_at(("matrix",), f"must be {n}x{n} (one row and one column per input in 'inputs'), got "
                            f"{shape}", self.matrix)
        return self

    def values(self) -> list[list[float]]:
        """W as numbers: a tuned entry at its value, else at its bounds' geometric centre."""
        return [[entry_value(e) for e in row] for row in self.matrix]


# ------------------------------------------------------------ architecture


def is_graph(spec: TuningSpec) -> bool:
    """Whether any loop says what it drives (else the loops are one cascade, outer first)."""
    return any(lp.drives is not None for lp in spec.loops)


def drive_target(drives: str) -> tuple[str, str]:
    """``("loop", name)`` for ``loop:<name>``, else ``("input", name)``."""
    if drives.startswith(LOOP_PREFIX):
        return "loop", drives[len(LOOP_PREFIX):]
    return "input", drives


def _plant_signals(spec: TuningSpec) -> tuple[list[SignalSpec] | None, list[SignalSpec] | None]:
    """(inputs, outputs) of an inline plant, None where only the built plant knows them (a model)."""
    pl = spec.plant
    if pl.tf_matrix is not None:
        return pl.tf_matrix.inputs, pl.tf_matrix.outputs
    if pl.ss is not None:
        outs = pl.ss.outputs or [f"y{i}" for i in range(len(pl.ss.C))]
        units = pl.ss.output_units or [""] * len(outs)
        outputs = [SignalSpec(name=n, unit=u) for n, u in zip(outs, units, strict=False)]
        return (pl.ss.inputs or [SignalSpec(name="u")]), outputs
    if pl.tf is not None:
        return [SignalSpec(name="u")], [SignalSpec(name=pl.tf.output)]
    if pl.ode is not None:
        ode_units = pl.ode.output_units or {}
        return (pl.ode.inputs or [SignalSpec(name=pl.ode.input)],
                [SignalSpec(name=n, unit=ode_units.get(n, "")) for n in pl.ode.outputs])
    return None, None


def check_architecture(spec: TuningSpec) -> None:
    """Check the loop graph, the actuators, the decoupler, the ties and the scenario names of ``spec``.

    Raises a located ValidationError (through pydantic) naming the field and the fix.
    """
    names = spec.loop_names
    inputs, outputs = _plant_signals(spec)
    in_names = None if inputs is None else [s.name for s in inputs]
    out_names = None if outputs is None else [s.name for s in outputs]
    several = spec.plant.tf_matrix is not None or (spec.plant.ss is not None and spec.plant.ss.is_mimo) or (
        spec.plant.ode is not None and spec.plant.ode.is_mimo)
    if out_names is not None and several:  # single-input plants: checked against the built plant, as before
        for i, lp in enumerate(spec.loops):
            if lp.measure is not None and lp.measure not in out_names:
                raise _error_at(("loops", i, "measure"), f"the plant has no output {lp.measure!r}; outputs: "
                                f"{', '.join(out_names)}", lp.measure)
    if is_graph(spec):
        _check_graph(spec, names, in_names)
    elif len(spec.loops) > 6:
        raise _error_at(("loops",), f"a single cascade holds at most 6 loops, got {len(spec.loops)}; for loops side "
                        "by side, say what each loop drives (drives: <input> or drives: loop:<name>)", len(spec.loops))
    if in_names is not None:
        if spec.actuators is not None:
            for key in spec.actuators:
                if key not in in_names:
                    raise _error_at(("actuators", key), f"the plant has no input {key!r}; inputs: "
                                    f"{', '.join(in_names)}", key)
        if spec.decoupler is not None:
            for k, key in enumerate(spec.decoupler.inputs):
                if key not in in_names:
                    raise _error_at(("decoupler", "inputs", k), f"the plant has no input {key!r}; inputs: "
                                    f"{', '.join(in_names)}", key)
    _check_scenarios(spec, names, in_names)
    _check_ties(spec, names, inputs, outputs)
    driven = {drive_target(lp.drives)[1] for lp in spec.loops if lp.drives and lp.drives.startswith(LOOP_PREFIX)}
    check_blocks(spec, names, in_names, {n for n in names if n not in driven} if is_graph(spec) else {names[0]})


def _check_graph(spec: TuningSpec, names: list[str], in_names: list[str] | None) -> None:
    driven_by: dict[str, int] = {}
    for i, lp in enumerate(spec.loops):
        if lp.drives is None:
            raise _error_at(("loops", i, "drives"), "missing: once one loop says what it drives, every loop must "
                            "(drives: <plant input> or drives: loop:<name>)", None)
        kind, target = drive_target(lp.drives)
        if kind == "loop":
            if target not in names:
                raise _error_at(("loops", i, "drives"), f"no loop named {target!r}; loops: {', '.join(names)}",
                                lp.drives)
            if target == names[i]:
                raise _error_at(("loops", i, "drives"), "a loop cannot drive its own setpoint", lp.drives)
            if spec.loops[names.index(target)].is_lq:
                raise _error_at(("loops", i, "drives"), f"loop {target!r} is state feedback; only PID loops take "
                                "a setpoint from another loop", lp.drives)
        elif in_names is not None and target not in in_names:
            raise _error_at(("loops", i, "drives"), f"the plant has no input {target!r}; inputs: "
                            f"{', '.join(in_names)} (or drives: loop:<name> for another loop's setpoint)", lp.drives)
        if lp.is_lq:
            raise _error_at(("loops", i, "type"), "state-feedback loops (lqr, lqi) are not supported in a loop "
                            "graph yet; use PID loops", lp.type)
        if lp.drives in driven_by:
            j = driven_by[lp.drives]
            raise _error_at(("loops", i, "drives"), f"loops[{j}] ({names[j]}) already drives {lp.drives!r}; each "
                            "input or setpoint is driven by one loop (combine them with a decoupler instead)",
                            lp.drives)
        driven_by[lp.drives] = i
    # a cycle: following drives from any loop must end at a plant input
    for i in range(len(spec.loops)):
        seen = [i]
        k = i
        while True:
            kind, target = drive_target(spec.loops[k].drives or "")
            if kind != "loop":
                break
            k = names.index(target)
            if k in seen:
                cycle = " -> ".join(names[q] for q in [*seen[seen.index(k):], k])
                raise _error_at(("loops", i, "drives"), f"the loops form a cycle ({cycle}); every chain of drives "
                                "must end at a plant input", spec.loops[i].drives)
            seen.append(k)


def _check_scenarios(spec: TuningSpec, names: list[str], in_names: list[str] | None) -> None:
    for s, sc in enumerate(spec.scenarios):
        ref = sc.reference.loop
        if ref is not None and ref not in names:
            raise _error_at(("scenarios", s, "reference", "loop"), f"no loop named {ref!r}; loops: "
                            f"{', '.join(names)}", ref)
        if ref is not None and is_graph(spec):
            kind, _ = drive_target(spec.loops[names.index(ref)].drives or "")
            driven = any(lp.drives == f"{LOOP_PREFIX}{ref}" for lp in spec.loops)
            if driven:
                raise _error_at(("scenarios", s, "reference", "loop"), f"loop {ref!r} takes its setpoint from "
                                "another loop; a reference goes to the outer loop of a chain", ref)
        din = sc.disturbance.input
        _check_state_disturbance(spec, s)
        if din is not None and in_names is not None and din not in in_names:
            raise _error_at(("scenarios", s, "disturbance", "input"), f"the plant has no input {din!r}; inputs: "
                            f"{', '.join(in_names)}", din)


def _state_names(spec: TuningSpec) -> list[str] | None:
    pl = spec.plant
    if pl.ode is not None:
        return list(pl.ode.states)
    if pl.ss is not None:
        return list(pl.ss.states or [f"x{i}" for i in range(len(pl.ss.A))])
    return None


def _check_state_disturbance(spec: TuningSpec, s: int) -> None:
    dist = spec.scenarios[s].disturbance
    if dist.state is None:
        return
    where = ("scenarios", s, "disturbance", "state")
    if dist.input is not None:
        raise _error_at(where, "give either disturbance.input or disturbance.state, not both", dist.state)
    if dist.entry != "input":
        raise _error_at(where, "a state disturbance enters the plant (entry: input, the default)", dist.state)
    states = _state_names(spec)
    if spec.plant.tf is not None or spec.plant.tf_matrix is not None:
        raise _error_at(where, "a transfer function has no named states; write the plant as state space or an "
                        "ODE to disturb a state, or use disturbance.input", dist.state)
    if states is not None and dist.state not in states:
        raise _error_at(where, f"the plant has no state {dist.state!r}; states: {', '.join(states)}", dist.state)


def gain_unit(spec: TuningSpec, loop: int, gain: str, inputs: list[SignalSpec] | None,
              outputs: list[SignalSpec] | None) -> str | None:
    """The unit of gain ``gain`` of loop ``loop`` (None where the plant's units are not known here).

    Kp is (driven unit)/(measured unit); Ki that per second, Kd that times seconds; Ti, Td are seconds.
    """
    if gain in ("Ti", "Td"):
        return "s"
    if inputs is None or outputs is None:
        return None
    units_in = {s.name: s.unit for s in inputs}
    units_out = {s.name: s.unit for s in outputs}
    names = spec.loop_names

    def measured(k: int) -> str:
        lp = spec.loops[k]
        return units_out.get(lp.measure or outputs[0].name, "")

    def driven(k: int) -> str:
        lp = spec.loops[k]
        if lp.drives is None:  # cascade: the next loop's setpoint, the innermost the (first) input
            return measured(k + 1) if k + 1 < len(spec.loops) else inputs[0].unit
        kind, target = drive_target(lp.drives)
        return measured(names.index(target)) if kind == "loop" else units_in.get(target, "")

    base = f"({driven(loop)})/({measured(loop)})"
    return base + {"Kp": "", "Ki": "/s", "Kd": "*s"}.get(gain, f"[{gain}]")


def _check_ties(spec: TuningSpec, names: list[str], inputs: list[SignalSpec] | None,
                outputs: list[SignalSpec] | None) -> None:
    seen: dict[str, int] = {}
    for t, tie in enumerate(spec.ties or []):
        if len(tie) < 2:
            raise _error_at(("ties", t), "a tie needs at least two gains, e.g. [j1.Kp, j2.Kp]", tie)
        kinds, units = [], []
        for k, ref in enumerate(tie):
            loop, _, gain = ref.partition(".")
            if loop not in names or not gain:
                raise _error_at(("ties", t, k), f"{ref!r} is not <loop>.<gain>; loops: {', '.join(names)}", ref)
            i = names.index(loop)
            if spec.loops[i].is_lq:
                raise _error_at(("ties", t, k), "ties join PID gains only", ref)
            from gaintune.spec.loops import GAIN_NAMES

            allowed = GAIN_NAMES[(spec.loops[i].type, spec.loops[i].form)]
            if gain not in allowed:
                raise _error_at(("ties", t, k), f"loop {loop!r} has no gain {gain!r}; its gains: "
                                f"{', '.join(allowed)}", ref)
            if ref in seen:
                raise _error_at(("ties", t, k), f"{ref} is already in ties[{seen[ref]}]; list it in one tie", ref)
            seen[ref] = t
            kinds.append(gain)
            units.append(gain_unit(spec, i, gain, inputs, outputs))
        if len(set(kinds)) > 1:
            raise _error_at(("ties", t), f"ties gains of different kinds ({', '.join(tie)}); a tie joins one gain "
                            "(e.g. every Kp) of loops of the same form", tie)
        known = [u for u in units if u is not None]
        if len(set(known)) > 1:
            detail = ", ".join(f"{r} in {u}" for r, u in zip(tie, units, strict=True))
            raise _error_at(("ties", t), f"ties gains with different units ({detail}); one value cannot serve "
                            "them all: tie loops that measure and drive signals of the same units", tie)


def chain_input(spec: TuningSpec, loop: int) -> str | None:
    """The plant input at the end of loop ``loop``'s chain of drives (None for a cascade without drives)."""
    names = spec.loop_names
    k, hops = loop, 0
    while hops <= len(names):
        drives = spec.loops[k].drives
        if drives is None:
            return None
        kind, target = drive_target(drives)
        if kind == "input":
            return target
        k, hops = names.index(target), hops + 1
    return None  # a cycle: refused by check_architecture
