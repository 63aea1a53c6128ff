"""Bad model files and a bad $GAINTUNE_MODELS folder are a SpecError naming the file or field, never a crash."""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path

import pytest
from typer.testing import CliRunner

from gaintune import cli
from gaintune.errors import SpecError
from gaintune.plants.library import list_models, load_model


@pytest.fixture
def models(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> Iterator[Path]:
    """An empty folder that $GAINTUNE_MODELS points at, with load_model's cache cleared around the test."""
    folder = tmp_path / "models"
    folder.mkdir()
    monkeypatch.setenv("GAINTUNE_MODELS", str(folder))
    load_model.cache_clear()
    yield folder
    load_model.cache_clear()


@pytest.mark.parametrize(("text", "got"), [("", "is empty"), ("- 1\n", "is a YAML list"),
                                           ("42\n", "is a single YAML value")],
                         ids=["empty", "list", "scalar"])
def test_non_mapping_model_file_is_spec_error_not_attributeerror(models: Path, text: str, got: str) -> None:
    """Before: an empty, list or scalar model file crashed load_model with AttributeError (no setdefault)."""
    (models / "water_tank.yaml").write_text(text)
    with pytest.raises(SpecError, match="must be a YAML mapping of a model definition") as info:
        load_model("water_tank")
    assert info.value.field == "models/water_tank.yaml"
    assert got in info.value.message and str(models / "water_tank.yaml") in info.value.message


def test_invalid_yaml_model_file_names_file_and_line(models: Path) -> None:
    """Before: invalid YAML in a model file escaped as a bare yaml.YAMLError with no field or file."""
    path = models / "water_tank.yaml"
    path.write_text("title: x\nplant: [1, 2\n")
    with pytest.raises(SpecError, match="is not valid YAML") as info:
        load_model("water_tank")
    assert info.value.field == "models/water_tank.yaml"
    assert f'in "{path}", line 2, column 8' in info.value.message
    assert "<unicode string>" not in info.value.message


def test_deeply_nested_model_file_is_spec_error_not_recursionerror(models: Path) -> None:
    """Before: thousands of nested brackets in a model file crashed the YAML parser with RecursionError."""
    (models / "water_tank.yaml").write_text("a: " + "[" * 5000 + "\n")
    with pytest.raises(SpecError, match="nested too deeply") as info:
        load_model("water_tank")
    assert info.value.field == "models/water_tank.yaml"


def test_model_path_that_is_a_folder_says_not_a_file(models: Path) -> None:
    """Before: a folder named water_tank.yaml gave "unknown model 'water_tank'; built-in models: water_tank"."""
    (models / "water_tank.yaml").mkdir()
    with pytest.raises(SpecError, match="is not a file") as info:
        load_model("water_tank")
    assert info.value.field == "models/water_tank.yaml"
    assert "unknown model" not in info.value.message
    assert list_models() == []


def test_missing_models_folder_says_folder_does_not_exist(models: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """Before: a $GAINTUNE_MODELS folder that does not exist gave "built-in models: " with nothing after it."""
    missing = models / "nowhere"
    monkeypatch.setenv("GAINTUNE_MODELS", str(missing))
    with pytest.raises(SpecError, match="unknown model 'water_tank'") as info:
        load_model("water_tank")
    assert info.value.field == "plant.model.name"
    assert f"built-in models: none (the models folder {missing}" in info.value.message
    assert "does not exist" in info.value.message and "GAINTUNE_MODELS" in info.value.message


def test_empty_models_folder_says_none_not_blank(models: Path) -> None:
    """Before: an empty $GAINTUNE_MODELS folder gave "built-in models: " with nothing after it."""
    with pytest.raises(SpecError, match="unknown model 'water_tank'") as info:
        load_model("water_tank")
    assert info.value.field == "plant.model.name"
    assert f"built-in models: none (the models folder {models}" in info.value.message
    assert "holds no NAME.yaml files" in info.value.message
    assert not info.value.message.rstrip().endswith("built-in models:")


@pytest.mark.parametrize("text", ["", "- 1\n"], ids=["empty", "list"])
def test_cli_non_mapping_model_file_exits_2_without_traceback(models: Path, text: str) -> None:
    """Before: `gaintune tuner query water_tank_h0` on an empty or list model file died with a traceback, exit 1."""
    (models / "water_tank.yaml").write_text(text)
    res = CliRunner().invoke(cli.app, ["tuner", "query", "water_tank_h0", "-p", "H0=5"])
    assert res.exit_code == 2, res.output
    assert "error: models/water_tank.yaml: " in res.stderr
    assert "must be a YAML mapping of a model definition" in res.stderr
    assert "Traceback" not in res.output and "Traceback" not in res.stderr
    assert isinstance(res.exception, SystemExit)  # a clean exit, not an escaped AttributeError
