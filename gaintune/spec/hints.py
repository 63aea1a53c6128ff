"""Spec errors a person can act on: the valid keys for an unknown one, one line for a union's noise.

pydantic reports an unknown key as "Extra inputs are not permitted", and a value that fits none of
a union's forms as one error per form and per element (a transfer-function matrix gave 10 lines).
:func:`explain` turns the raw errors of a :class:`~gaintune.spec.TuningSpec` validation into
``[{loc, msg}]`` entries that name the fix: "did you mean ms_max?" with the keys that section takes,
and one line per field saying which forms it accepts. The CLI and the API both use it.
"""

from __future__ import annotations

import difflib
import types
import typing
from typing import Any

from pydantic import BaseModel

__all__ = ["explain", "section_keys"]

_SCALAR_TAGS = {"float", "int", "str", "bool", "list", "dict", "none"}


def _is_union_tag(part: Any) -> bool:
    """A location part pydantic adds for a union member (``'str'``, ``'list[union[float,str]]'``)."""
    return isinstance(part, str) and (part in _SCALAR_TAGS or "[" in part or part.startswith("function-"))


def _models_in(annotation: Any) -> list[type[BaseModel]]:
    """The pydantic models an annotation can hold (through Optional, unions, lists and dicts)."""
    if isinstance(annotation, type) and issubclass(annotation, BaseModel):
        return [annotation]
    out: list[type[BaseModel]] = []
    origin = typing.get_origin(annotation)
    if origin is typing.Annotated:
        return _models_in(typing.get_args(annotation)[0])
    if origin in (typing.Union, types.UnionType, list, tuple, dict) or origin is not None:
        for arg in typing.get_args(annotation):
            out += _models_in(arg)
    return out


def _model_at(root: type[BaseModel], path: tuple) -> type[BaseModel] | None:
    """The model that validates the mapping at ``path`` below ``root`` (None when it cannot be told)."""
    model = root
    for part in path:
        if isinstance(part, int) or _is_union_tag(part):
            continue  # list index, dict key of a free mapping, or a union member: same model
        field = model.model_fields.get(part) or next(
            (f for f in model.model_fields.values() if f.alias == part), None)
        if field is None:
            return None
        models = _models_in(field.annotation)
        if len(models) != 1:
            return None
        model = models[0]
    return model


def section_keys(model: type[BaseModel]) -> list[str]:
    """The keys a spec section accepts (field names, and aliases where a field has one)."""
    return [f.alias or name for name, f in model.model_fields.items()]


def _unknown_key(root: type[BaseModel], loc: tuple) -> str | None:
    model = _model_at(root, loc[:-1])
    if model is None or not isinstance(loc[-1], str):
        return None
    keys = section_keys(model)
    close = difflib.get_close_matches(loc[-1], keys, n=2, cutoff=0.5)
    hint = f"did you mean {' or '.join(close)}? " if close else ""
    return f"unknown key '{loc[-1]}'; {hint}this section takes: {', '.join(keys)}"


def _union_line(loc: tuple, errs: list[dict[str, Any]]) -> str:
    field = ".".join(str(p) for p in loc)
    if field.startswith("plant.tf.") and any(isinstance(e.get("input"), list)
                                             and any(isinstance(x, list) for x in e["input"]) for e in errs):
        return ("a transfer-function matrix (a list of lists) is not supported: a plant has one actuator input; "
                "give num and den each as one polynomial, a list of coefficients or a string such as '(s+1)^3'")
    return "fits none of the accepted forms: " + "; ".join(sorted({_first_line(e.get("msg")) for e in errs}))


def _first_line(msg: Any) -> str:
    return str(msg).splitlines()[0]


def explain(errors: list[dict[str, Any]], root: type[BaseModel] | None = None) -> list[dict[str, str]]:
    """``[{loc, msg}]`` for pydantic ``errors`` of a spec validation (locations relative to ``root``).

    ``root`` defaults to :class:`~gaintune.spec.TuningSpec`. Unknown keys name the keys of their
    section and the closest match; the errors of one union field collapse to one line.
    """
    if root is None:
        from gaintune.spec import TuningSpec

        root = TuningSpec
    out: list[dict[str, str]] = []
    unions: dict[tuple, list[dict[str, Any]]] = {}
    for err in errors:
        loc = tuple(err.get("loc", ()))
        cut = next((i for i, p in enumerate(loc) if _is_union_tag(p)), None)
        if cut is not None:
            unions.setdefault(loc[:cut], []).append(err)
            continue
        msg = str(err.get("msg", "invalid"))
        if err.get("type") == "extra_forbidden" and loc:
            msg = _unknown_key(root, loc) or msg
        elif err.get("type") == "value_error":
            msg = msg.removeprefix("Value error, ")
        out.append({"loc": ".".join(str(p) for p in loc), "msg": msg})
    for loc, errs in unions.items():
        out.append({"loc": ".".join(str(p) for p in loc), "msg": _union_line(loc, errs)})
    return out
