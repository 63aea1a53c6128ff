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

import yaml
from pydantic import BaseModel, ConfigDict, Field, ValidationError

from gaintune.errors import SpecError
from gaintune.files import read_text_bounded
from gaintune.spec import PlantSpec

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
    """Names (file stems) of the built-in models in :func:`models_dir`, sorted."""
    return sorted(p.stem for p in models_dir().glob("*.yaml"))


@lru_cache(maxsize=64)
def load_model(name: str) -> ModelDef:
    """Load a built-in model by file stem; unknown names raise SpecError listing the known ones."""
    if not name.replace("_", "").isalnum():
        raise SpecError("plant.model.name", f"invalid model name {name!r}")
    path = models_dir() / f"{name}.yaml"
    if not path.is_file():
        raise SpecError("plant.model.name", f"unknown model {name!r}; built-in models: {', '.join(list_models())}")
    data = yaml.safe_load(read_text_bounded(path, f"models/{name}.yaml"))
    data.setdefault("name", name)
    params = {k: (v["value"] if isinstance(v, dict) else v) for k, v in data.get("parameters", {}).items()}
    data.setdefault("plant", {})
    data["plant"] = dict(data["plant"], params={**params, **data["plant"].get("params", {})})
    try:
        return ModelDef.model_validate(data)
    except ValidationError as exc:  # a broken model file is a packaging bug, but say where
        raise SpecError(f"models/{name}.yaml", str(exc)) from None
