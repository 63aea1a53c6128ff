"""Render the spec reference (docs/spec.md) from the pydantic schema itself, so docs never drift."""

from __future__ import annotations

import inspect
import re
import typing

from pydantic import BaseModel
from pydantic_core import PydanticUndefined

from gaintune import spec as S

__all__ = ["render_markdown"]

_SECTIONS: list[tuple[str, type[BaseModel]]] = [
    ("spec (top level)", S.TuningSpec),
    ("plant", S.PlantSpec),
    ("plant.tf", S.TransferFunctionSpec),
    ("plant.ss", S.StateSpaceSpec),
    ("plant.ode", S.OdeSpec),
    ("plant.model", S.ModelRefSpec),
    ("loops[i]", S.LoopSpec),
    ("loops[i].gains.<name>", S.GainSpec),
    ("loops[i].filter", S.DerivativeFilterSpec),
    ("actuator", S.ActuatorSpec),
    ("scenarios[i]", S.ScenarioSpec),
    ("scenarios[i].reference", S.ProfileSpec),
    ("scenarios[i].disturbance", S.DisturbanceSpec),
    ("objective", S.ObjectiveSpec),
    ("requirements", S.RequirementsSpec),
    ("randomize", S.RandomizeSpec),
    ("randomize.* distributions", S.DistSpec),
    ("safety", S.SafetySpec),
    ("search", S.SearchSpec),
    ("search.robust", S.RobustSpec),
    ("verify", S.VerifySpec),
]


def _type(t: object) -> str:
    text = str(t).replace("typing.", "").replace("NoneType", "None")
    # spec models print as gaintune.spec.<section>.<Class>; the reference names them by class only
    text = re.sub(r"gaintune\.spec\.(?:[a-z_]+\.)?", "", text)
    for cls in ("<class '", "'>"):
        text = text.replace(cls, "")
    return text.replace("|", "\\|")


def _default(field) -> str:
    if field.default is not PydanticUndefined:
        return f"`{field.default!r}`"
    if field.default_factory is not None:
        try:
            value = field.default_factory()
        except TypeError:
            return "(see type)"
        if isinstance(value, BaseModel):
            return "defaults"
        if isinstance(value, list) and value and isinstance(value[0], BaseModel):
            return "one item with defaults"
        return f"`{value!r}`"
    return "**required**"


def render_markdown() -> str:
    """The spec reference as Markdown."""
    lines = [
        "# Spec reference",
        "",
        "Generated from `gaintune/spec.py` by `python -m gaintune.spec_doc > docs/spec.md` (a test checks it is current).",
        f"Limits: horizon/dt <= {S.MAX_STEPS} steps, delay/dt (plant.delay, the top of randomize.delay) <= {S.MAX_DELAY_STEPS} samples, plant order <= {S.MAX_ORDER}, cascade depth <= {S.MAX_LOOPS}.",
        "",
    ]
    for title, model in _SECTIONS:
        doc = inspect.cleandoc(model.__doc__ or "").split("\n\n")[0].replace("\n", " ")
        lines += [f"## `{title}`", "", doc, "", "| field | type | default | description |", "|---|---|---|---|"]
        hints = typing.get_type_hints(model)
        for name, field in model.model_fields.items():
            desc = (field.description or "").replace("|", "\\|")
            lines.append(f"| `{name}` | {_type(hints.get(name, field.annotation))} | {_default(field)} | {desc} |")
        lines.append("")
    return "\n".join(lines)


if __name__ == "__main__":
    print(render_markdown())
