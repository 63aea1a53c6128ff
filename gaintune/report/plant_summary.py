"""The report's plant summary: kind, structure (the transfer function as text), units and parameters."""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

from gaintune.fmt import fmt as _fmt
from gaintune.spec import TuningSpec

if TYPE_CHECKING:  # the plant module loads with the report's simulations, not before
    from gaintune.plants.plant import Plant

__all__ = ["plant_summary"]


def plant_summary(spec: TuningSpec, plant: Plant) -> dict[str, Any]:
    """What the report says about the plant: title, structure, states, outputs, parameters, delay and units."""
    p = spec.plant
    units: dict[str, str] = {}
    out: dict[str, Any] = {"kind": plant.kind, "states": plant.states, "outputs": plant.outputs,
                           "params": dict(plant.with_params(None)) if plant.param_names else {}}
    if p.model is not None:
        from gaintune.plants.library import load_model

        m = load_model(p.model if isinstance(p.model, str) else p.model.name)
        out["title"] = f"{m.title} (built-in model '{m.name}')"
        out["description"] = m.description
        units = {k: v.unit for k, v in m.outputs.items() if v.unit and v.unit != "-"}
        if m.input.unit and m.input.unit != "-":
            out["input_unit"] = m.input.unit
        out["param_units"] = {k: v.unit for k, v in m.parameters.items()}
        if m.plant.tf is not None:
            out["structure"] = f"G(s) = {_wrap(_poly(m.plant.tf.num))} / {_wrap(_poly(m.plant.tf.den))}"
        elif m.plant.ss is not None:
            out["structure"] = f"state space, states {plant.states}, outputs {plant.outputs}"
        else:
            out["structure"] = f"nonlinear ODE, states {plant.states}, outputs {plant.outputs}"
    elif p.tf is not None:
        out["title"] = "Transfer function"
        out["structure"] = f"G(s) = {_wrap(_poly(p.tf.num))} / {_wrap(_poly(p.tf.den))}"
    elif p.ss is not None:
        out["title"] = "State space"
        out["structure"] = f"states {plant.states}, outputs {plant.outputs}"
    else:
        out["title"] = "Nonlinear ODE"
        out["structure"] = f"states {plant.states}, outputs {plant.outputs} (margins from the linearisation)"
    out["delay"] = plant.delay()
    out["units"] = units
    return out


def _wrap(text: str) -> str:
    return text if text.replace("_", "").replace(".", "").isalnum() else f"({text})"


def _poly(v: Any) -> str:
    if isinstance(v, str):
        return v
    n = len(v) - 1
    terms = []
    for i, c in enumerate(v):
        k = n - i
        cs = _fmt(c) if not isinstance(c, str) else (c if c.replace("_", "").isalnum() or len(v) == 1 else f"({c})")
        terms.append(cs if k == 0 else f"{cs} s" + (f"^{k}" if k > 1 else ""))
    return " + ".join(terms)
