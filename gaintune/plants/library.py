"""Built-in plant models: definition files in the repository's ``models/`` folder.

Each file is YAML with a title, a description, documented parameters (value,
unit, description), documented outputs, a ``plant`` section in the same schema
as a spec's plant, and an optional ``example`` spec fragment (loops, actuator,
scenarios) that makes it tunable as is.
"""

from __future__ import annotations

import copy
import os
from functools import lru_cache
from pathlib import Path
from typing import Any

from pydantic import BaseModel, ConfigDict, Field, ValidationError

from gaintune.errors import SpecError
from gaintune.files import read_text_bounded
from gaintune.spec import PlantSpec
from gaintune.spec.yamlload import load_yaml

__all__ = ["ParamDoc", "ModelDef", "models_dir", "list_models", "load_model"]


class ParamDoc(BaseModel):
    """One documented model parameter: its nominal value, unit and meaning."""

    model_config = ConfigDict(extra="forbid")
    value: float
    unit: str = "-"
    description: str = ""


class SignalDoc(BaseModel):
    """One documented model signal (the input or an output): unit and meaning."""

    model_config = ConfigDict(extra="forbid")
    unit: str = "-"
    description: str = ""


class ModelDef(BaseModel):
    """One built-in model definition file."""

    model_config = ConfigDict(extra="forbid")
    name: str
    title: str
    description: str = ""
    parameters: dict[str, ParamDoc] = Field(default_factory=dict)
    input: SignalDoc = Field(default_factory=SignalDoc)
    inputs: dict[str, SignalDoc] = Field(default_factory=dict, description="Plants with several inputs.")
    outputs: dict[str, SignalDoc] = Field(default_factory=dict)
    plant: PlantSpec
    example: dict[str, Any] = Field(default_factory=dict)

    def example_spec(self) -> dict[str, Any]:
        """A complete spec dict using this model with its example loops."""
        spec: dict[str, Any] = {"name": self.name, "plant": {"model": {"name": self.name}}}
        # a deep copy: the model is cached (load_model), and a caller's edit of the spec must not change it
        spec.update(copy.deepcopy(self.example))
        spec.setdefault("loops", [{"type": "pid"}])
        return spec


def models_dir() -> Path:
    """The models folder: $GAINTUNE_MODELS, else ``models/`` beside the package."""
    env = os.environ.get("GAINTUNE_MODELS")
    return Path(env) if env else Path(__file__).resolve().parents[2] / "models"


def list_models() -> list[str]:
    """Names (file stems) of the built-in models in :func:`models_dir`, sorted.

    Returns
    -------
    list[str]
        Stems of the ``*.yaml`` files; empty when the folder is missing or holds none. A folder
        named ``*.yaml`` is no model, so it is not listed.
    """
    return sorted(p.stem for p in models_dir().glob("*.yaml") if p.is_file())


def _unknown_model(name: str) -> SpecError:
    """The error for a model name with no file: the known models, or why there are none."""
    folder = models_dir()
    # a missing folder or an empty list must say so: "built-in models: " with nothing after it is no help
    via = ", from GAINTUNE_MODELS," if os.environ.get("GAINTUNE_MODELS") else ""
    fix = "point GAINTUNE_MODELS at a folder of model files (NAME.yaml) or unset it"
    if not folder.is_dir():
        what = "does not exist" if not folder.exists() else "is not a folder"
        return SpecError("plant.model.name", f"unknown model {name!r}; built-in models: none (the models folder "
                         f"{folder}{via} {what}); {fix}")
    known = list_models()
    if not known:
        return SpecError("plant.model.name", f"unknown model {name!r}; built-in models: none (the models folder "
                         f"{folder}{via} holds no NAME.yaml files); {fix}")
    return SpecError("plant.model.name", f"unknown model {name!r}; built-in models: {', '.join(known)}")


@lru_cache(maxsize=64)
def load_model(name: str) -> ModelDef:
    """Load a built-in model by its file stem.

    Parameters
    ----------
    name
        The model name: ``NAME.yaml`` in :func:`models_dir`.

    Returns
    -------
    ModelDef
        The validated model definition (cached: callers must not modify it).

    Raises
    ------
    SpecError
        Field ``plant.model.name`` for an invalid or unknown name (listing the known models);
        field ``models/NAME.yaml`` when the file is not a regular file, too large, not UTF-8,
        not valid YAML, not a YAML mapping, or not a valid model definition.
    """
    if not name.replace("_", "").isalnum():
        raise SpecError("plant.model.name", f"invalid model name {name!r}")
    path = models_dir() / f"{name}.yaml"
    field = f"models/{name}.yaml"
    if not os.path.lexists(path):
        raise _unknown_model(name)
    if not path.is_file():
        # it exists, so "unknown model" would contradict the list of models; read_text_bounded would
        # refuse a pipe or device too, but a folder fails there with a bare IsADirectoryError
        raise SpecError(field, f"{path} is not a file (a folder, a device, a pipe or a broken link); "
                        "a model is a regular file NAME.yaml holding its YAML definition")
    text = read_text_bounded(path, field)
    try:
        data = load_yaml(text)  # bounded alias expansion, as for specs
    except ValueError as exc:
        # the parser says where (line, column) in "<unicode string>": name the file instead
        problem = str(exc).replace("<unicode string>", str(path))
        raise SpecError(field, f"{path} is not valid YAML: {problem}") from None
    except RecursionError:  # PyYAML composes nested nodes recursively
        raise SpecError(field, f"{path} is nested too deeply (thousands of levels of lists or mappings); "
                        "a model definition needs a few") from None
    if not isinstance(data, dict):
        got = "empty" if data is None else "a YAML list" if isinstance(data, list) else "a single YAML value"
        raise SpecError(field, f"{path} is {got}; a model file must be a YAML mapping of a model definition "
                        "(title, parameters, plant, ...), like the files in the repository's models/ folder")
    data.setdefault("name", name)
    # the parameters' values become the plant's default params; malformed sections are left as they are
    # for the schema below to report by field
    raw_params = data.get("parameters")
    params = ({k: (v["value"] if isinstance(v, dict) else v) for k, v in raw_params.items()
               if not isinstance(v, dict) or "value" in v} if isinstance(raw_params, dict) else {})
    plant = data.setdefault("plant", {})
    if isinstance(plant, dict) and isinstance(plant.get("params", {}), dict):
        data["plant"] = dict(plant, params={**params, **plant.get("params", {})})
    try:
        return ModelDef.model_validate(data)
    except ValidationError as exc:  # a broken model file is a packaging bug, but say where
        raise SpecError(field, str(exc)) from None
