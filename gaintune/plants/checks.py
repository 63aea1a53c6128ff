"""Cross-checks between a validated spec and its built plant.

The pydantic schema cannot know a plant's outputs, states or parameters until
the plant is built. :func:`validate_against_plant` checks every name the spec
uses against the plant and raises :class:`~gaintune.errors.SpecError` with the
field path (``loops[0].measure``, ``randomize.params.J``, ...) on the first
problem.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from gaintune.errors import SpecError

if TYPE_CHECKING:
    from gaintune.plants.plant import Plant
    from gaintune.spec import TuningSpec

__all__ = ["validate_against_plant"]


def _known(names: list[str]) -> str:
    return ", ".join(names) or "none"


def validate_against_plant(spec: TuningSpec, plant: Plant) -> None:
    """Check the names and ranges a spec uses against the built plant.

    Checks that

    * every loop's ``measure`` is a plant output;
    * every ``randomize.params`` key is a plant parameter, and the plant still
      builds with the same order at both ends of each parameter's range
      (structural parameters such as the ``n`` of ``lag_n`` must not vary);
    * every ``safety.state_bounds`` key is a plant state;
    * every ``safety.fallback_gains`` key is a loop name;
    * the operating-point input of a nonlinear plant lies inside the actuator limits.

    Raises
    ------
    SpecError
        Naming the offending field, the unknown name and the names that are valid.
    """
    from gaintune.plants.mimo import MimoPlant

    if isinstance(plant, MimoPlant) or any(lp.drives is not None for lp in spec.loops) or any(
            sc.disturbance.state is not None for sc in spec.scenarios):
        _validate_mimo(spec, plant)
        if isinstance(plant, MimoPlant):
            return
    for i, loop in enumerate(spec.loops):
        if loop.measure is not None and loop.measure not in plant.outputs:
            raise SpecError(
                f"loops[{i}].measure",
                f"plant has no output {loop.measure!r}; outputs: {_known(plant.outputs)}",
            )

    nominal = plant.linearize()
    for name, dist in spec.randomize.params.items():
        field = f"randomize.params.{name}"
        if name not in plant.params:
            raise SpecError(field, f"plant has no parameter {name!r}; parameters: {_known(plant.param_names)}")
        for value in dict.fromkeys(dist.box):
            try:
                lin = plant.linearize({name: value})
            except SpecError as exc:
                raise SpecError(field, f"plant is invalid at {name} = {value}: {exc}") from None
            if lin.A.shape != nominal.A.shape:
                raise SpecError(
                    field,
                    f"changes the plant order ({nominal.A.shape[0]} -> {lin.A.shape[0]} at {name} = {value}); "
                    "structural parameters cannot be randomised",
                )

    for name in spec.safety.state_bounds:
        if name not in plant.states:
            raise SpecError(
                f"safety.state_bounds.{name}", f"plant has no state {name!r}; states: {_known(plant.states)}"
            )

    loop_names = [lp.name or f"loop{i}" for i, lp in enumerate(spec.loops)]
    for name in spec.safety.fallback_gains or {}:
        if name not in loop_names:
            raise SpecError(f"safety.fallback_gains.{name}", f"no loop named {name!r}; loops: {_known(loop_names)}")

    limits = spec.actuator.limits
    if limits is not None and not limits[0] <= nominal.u0 <= limits[1]:
        raise SpecError(
            "actuator.limits",
            f"the operating-point input u0 = {nominal.u0:.6g} lies outside {list(limits)}; "
            "the plant cannot be held at its operating point",
        )


def _validate_mimo(spec: TuningSpec, plant) -> None:
    """The names a MIMO spec (or a loop graph) uses, against the built plant's inputs, outputs and states."""
    from gaintune.plants.mimo import as_mimo
    from gaintune.spec.mimo import drive_target

    mp = as_mimo(plant)
    inputs = mp.input_names
    if len(inputs) > 1 and all(lp.drives is None for lp in spec.loops):
        raise SpecError("loops", f"the plant has {len(inputs)} inputs ({_known(inputs)}): say what each loop "
                        "drives (drives: <input> or drives: loop:<name>)")

    def need_input(name: str | None, field: str) -> None:
        if name is not None and name not in inputs:
            raise SpecError(field, f"plant has no input {name!r}; inputs: {_known(inputs)}")

    for i, loop in enumerate(spec.loops):
        if loop.measure is not None and loop.measure not in mp.outputs:
            raise SpecError(f"loops[{i}].measure", f"plant has no output {loop.measure!r}; outputs: "
                            f"{_known(mp.outputs)}")
        if loop.drives is not None and drive_target(loop.drives)[0] == "input":
            need_input(drive_target(loop.drives)[1], f"loops[{i}].drives")
    for name in spec.actuators or {}:
        need_input(name, f"actuators.{name}")
    for k, name in enumerate(spec.decoupler.inputs if spec.decoupler is not None else []):
        need_input(name, f"decoupler.inputs[{k}]")
    for s, sc in enumerate(spec.scenarios):
        need_input(sc.disturbance.input, f"scenarios[{s}].disturbance.input")
        if sc.disturbance.state is not None and sc.disturbance.state not in mp.states:
            raise SpecError(f"scenarios[{s}].disturbance.state", f"plant has no state {sc.disturbance.state!r}; "
                            f"states: {_known(mp.states)}")
    for name in spec.randomize.params:
        if name not in mp.params:
            raise SpecError(f"randomize.params.{name}", f"plant has no parameter {name!r}; parameters: "
                            f"{_known(mp.param_names)}")
    for name in spec.safety.state_bounds:
        if name not in mp.states:
            raise SpecError(f"safety.state_bounds.{name}", f"plant has no state {name!r}; states: {_known(mp.states)}")
