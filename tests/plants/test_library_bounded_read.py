"""Model files (models/*.yaml, or $GAINTUNE_MODELS) are read bounded: a runaway file is refused naming the limit."""

from __future__ import annotations

from pathlib import Path

import pytest

from gaintune.errors import SpecError
from gaintune.files import MAX_INPUT_BYTES
from gaintune.plants.library import load_model


def test_oversized_model_file_refused_naming_limit(tmp_path: Path, monkeypatch) -> None:
    with open(tmp_path / "huge.yaml", "wb") as f:  # sparse: no 10 MB of disk
        f.truncate(MAX_INPUT_BYTES + 1)
    monkeypatch.setenv("GAINTUNE_MODELS", str(tmp_path))
    load_model.cache_clear()
    try:
        with pytest.raises(SpecError, match="the limit is 10 MB") as info:
            load_model("huge")
        assert info.value.field == "models/huge.yaml"
    finally:
        load_model.cache_clear()
