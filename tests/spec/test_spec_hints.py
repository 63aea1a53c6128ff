"""Spec errors name the fix: valid keys and the closest match for an unknown key; one line for a union."""

from __future__ import annotations

import json

import pytest
from fastapi.testclient import TestClient
from pydantic import ValidationError
from typer.testing import CliRunner

from gaintune.cli import app as cli
from gaintune.spec import load_spec
from gaintune.spec.hints import explain

BASE = {"plant": {"tf": {"num": [1], "den": "(s+1)^3"}}, "loops": [{"type": "pi"}]}
MATRIX = {"plant": {"tf": {"num": [[1], [2]], "den": [[1, 1], [1, 2]]}}, "loops": [{"type": "pi"}]}


def _explained(data):
    with pytest.raises(ValidationError) as err:
        load_spec(data)
    return explain(err.value.errors(include_url=False))


def test_unknown_key_ms_suggests_ms_max_and_lists_the_keys():
    (e,) = _explained({**BASE, "requirements": {"ms": 1.4}})
    assert e["loc"] == "requirements.ms"
    assert "did you mean ms_max" in e["msg"] and "pm_min_deg" in e["msg"] and "Extra inputs" not in e["msg"]


def test_unknown_key_in_a_list_item_and_at_the_top_are_explained():
    errs = _explained({**BASE, "loops": [{"type": "pi", "gainz": {}}], "sarch": {}})
    msgs = {e["loc"]: e["msg"] for e in errs}
    assert "did you mean gains" in msgs["loops.0.gainz"]
    assert "did you mean search" in msgs["sarch"]


def test_transfer_function_matrix_is_one_line_per_field():
    errs = _explained(MATRIX)
    assert [e["loc"] for e in errs] == ["plant.tf.num", "plant.tf.den"]
    assert all("transfer-function matrix" in e["msg"] for e in errs)


def test_cli_names_the_valid_keys(tmp_path):
    path = tmp_path / "spec.json"
    path.write_text(json.dumps({**BASE, "requirements": {"ms": 1.4}}))
    res = CliRunner().invoke(cli, ["verify", str(path), "--gains", '{"loop0": {"Kp": 1, "Ki": 0.5}}'])
    assert res.exit_code == 2
    assert "did you mean ms_max" in res.output


def test_api_names_the_valid_keys_for_tune_and_verify(tmp_path):
    from gaintune_api.main import create_app
    from gaintune_api.settings import Settings

    settings = Settings(_env_file=None, db_path=tmp_path / "j.db", data_dir=tmp_path / "d", workers=0, warmup=False,
                        compute_processes=0)
    with TestClient(create_app(settings)) as c:
        r = c.post("/v1/tune", json={**BASE, "requirements": {"ms": 1.4}})
        assert r.status_code == 422
        (e,) = r.json()["errors"]
        assert e["loc"] == "requirements.ms" and "did you mean ms_max" in e["msg"]
        r = c.post("/v1/verify", json={"spec": MATRIX, "gains": {"loop0": {"Kp": 1, "Ki": 1}}})
        assert r.status_code == 422
        assert [e["loc"] for e in r.json()["errors"]] == ["spec.plant.tf.num", "spec.plant.tf.den"]


def test_a_nan_coefficient_is_not_called_a_transfer_function_matrix():
    """Regression: num: [.nan] was explained as 'a transfer-function matrix (a list of lists) is not supported'
    (any list input was read as a matrix); a real matrix still is."""
    from pydantic import ValidationError

    from gaintune.spec import load_spec
    from gaintune.spec.hints import explain

    def lines(num):
        with pytest.raises(ValidationError) as e:
            load_spec({"plant": {"tf": {"num": num, "den": "s+1"}}, "loops": [{"type": "pi"}]})
        return [d["msg"] for d in explain(e.value.errors(include_url=False)) if d["loc"] == "plant.tf.num"]

    (nan,) = lines([float("nan")])
    assert "matrix" not in nan and "finite number" in nan
    (matrix,) = lines([[1.0], [2.0]])
    assert "a transfer-function matrix (a list of lists) is not supported" in matrix
