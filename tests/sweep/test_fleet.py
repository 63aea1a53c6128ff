"""The fleet file: schema, expansion into keyed items, and bad fleets refused with exit 2 naming the field."""

from __future__ import annotations

import copy
from pathlib import Path

import pytest
import yaml
from sweep_fleets import TINY_SPEC, grid_fleet, write_fleet
from typer.testing import CliRunner

from gaintune import cli
from gaintune.errors import GaintuneError
from gaintune.sweep.fleet import FleetError, expand, item_key, load_fleet, set_path

runner = CliRunner()


def _items(path: Path):
    fleet, root = load_fleet(path)
    return expand(fleet, root)


def test_grid_expands_to_every_combination_with_short_labels(tmp_path):
    path = write_fleet(tmp_path, {"base": TINY_SPEC, "grid": {"plant.params.K": [0.5, 1.0, 2.0],
                                                               "plant.params.L": [0.5, 1.0]}})
    items = _items(path)
    assert len(items) == 6 and all(i.error is None for i in items)
    assert items[0].label == "K=0.5, L=0.5" and items[-1].label == "K=2, L=1"
    assert [i.doc["plant"]["params"]["K"] for i in items] == [0.5, 0.5, 1.0, 1.0, 2.0, 2.0]
    assert len({i.key for i in items}) == 6


def test_item_keys_are_content_hashes_stable_across_loads(tmp_path):
    a = _items(grid_fleet(tmp_path, [0.5, 1.0], "a.yaml"))
    b = _items(grid_fleet(tmp_path, [1.0, 0.5], "b.yaml"))  # the same problems, listed the other way round
    assert {i.key for i in a} == {i.key for i in b}
    assert a[0].key == item_key("tune", a[0].doc)


def test_cases_and_overrides_apply_to_the_base(tmp_path):
    path = write_fleet(tmp_path, {"base": TINY_SPEC, "overrides": {"search.budget": 50},
                                  "cases": [{"plant.params.K": 3.0}, {"plant.params.T": 4.0, "loops.0.type": "pid"}]})
    items = _items(path)
    assert [i.doc["search"]["budget"] for i in items] == [50, 50]
    assert items[0].doc["plant"]["params"]["K"] == 3.0 and items[1].doc["loops"][0]["type"] == "pid"


def test_specs_list_files_globs_and_inline_documents(tmp_path):
    (tmp_path / "valves").mkdir()
    for k in (1.0, 2.0):
        spec = copy.deepcopy(TINY_SPEC)
        spec["plant"]["params"]["K"] = k
        (tmp_path / "valves" / f"v{k:g}.yaml").write_text(yaml.safe_dump(spec))
    path = write_fleet(tmp_path, {"specs": ["valves/*.yaml", {**TINY_SPEC, "name": "inline"}]})
    items = _items(path)
    assert [i.label for i in items] == ["valves/v1.yaml", "valves/v2.yaml", "inline"]
    assert all(i.error is None for i in items)


def test_a_bad_document_fails_only_its_item(tmp_path):
    bad = {**TINY_SPEC, "loops": [{"type": "pix"}]}
    path = write_fleet(tmp_path, {"specs": [TINY_SPEC, bad, "missing.yaml"]})
    items = _items(path)
    assert items[0].error is None
    assert items[1].error is not None and "loops.0.type" in items[1].error
    assert items[2].error is not None and "file not found" in items[2].error


def test_query_items_check_their_params(tmp_path):
    path = write_fleet(tmp_path, {"kind": "query", "tuner": "fotd_pi_ms1.4", "base": {"params": {"T": 60, "L": 10}},
                                  "grid": {"params.K": [1.0, "two"]}})
    good, bad = _items(path)
    assert good.error is None and good.doc == {"tuner": "fotd_pi_ms1.4", "params": {"T": 60.0, "L": 10.0, "K": 1.0},
                                               "refine": 0, "seed": 0}
    assert bad.error is not None and "params.K" in bad.error


def test_set_path_through_a_value_names_the_path():
    doc = {"plant": {"params": 3}}
    with pytest.raises(GaintuneError, match="plant.params is a value"):
        set_path(doc, "plant.params.K", 1.0)
    with pytest.raises(GaintuneError, match="not an index"):
        set_path({"loops": [{}]}, "loops.3.type", "pi")


def test_a_glob_matching_nothing_is_a_fleet_error(tmp_path):
    with pytest.raises(FleetError, match="matches no file") as info:
        _items(write_fleet(tmp_path, {"specs": ["nothing/*.yaml"]}))
    assert info.value.field == "specs.0"


@pytest.mark.parametrize("fleet, message", [
    ({"specz": [TINY_SPEC]}, "error: fleet.specz: Extra inputs are not permitted"),
    ({"specs": [TINY_SPEC], "base": TINY_SPEC}, "error: fleet: give either specs"),
    ({"base": TINY_SPEC, "grid": {"plant.params.K": []}}, "error: fleet.grid: plant.params.K: give at least one"),
    ({"base": TINY_SPEC, "grid": {"plant.params.K": [1], "plant.params.T": [1]}, "cases": [{}]},
     "error: fleet: give either grid or cases"),
    ({"kind": "query", "base": {"params": {"K": 1}}}, "error: fleet: kind query needs tuner"),
    ({"base": "nope.yaml"}, "error: base: no file at"),
    ({"kind": "search", "specs": [TINY_SPEC]}, "error: fleet.kind: Input should be 'tune' or 'query'"),
    (["a", "list"], "error: fleet: must be a mapping"),
])
def test_bad_fleet_files_exit_2_naming_the_field(tmp_path, fleet, message):
    path = tmp_path / "fleet.yaml"
    path.write_text(yaml.safe_dump(fleet))
    res = runner.invoke(cli.app, ["sweep", str(path), "--out", str(tmp_path / "out")])
    assert res.exit_code == 2, res.output
    assert message in res.output and "Traceback" not in res.output
    assert not (tmp_path / "out").exists()  # nothing ran


@pytest.mark.parametrize("args, message", [
    (["--backend", "spark"], "error: backend: must be local or ray"),
    (["--address", "auto"], "error: address: a Ray cluster's address goes with --backend ray"),
    (["--store", "csv"], "error: store: must be sqlite or dir"),
])
def test_bad_options_exit_2_naming_the_option(tmp_path, args, message):
    res = runner.invoke(cli.app, ["sweep", str(grid_fleet(tmp_path, [1.0])), *args])
    assert res.exit_code == 2 and message in res.output, res.output


def test_missing_or_unparsable_fleet_file_exits_2(tmp_path):
    res = runner.invoke(cli.app, ["sweep", str(tmp_path / "none.yaml")])
    assert res.exit_code == 2 and "error: fleet: file not found" in res.output
    (tmp_path / "bad.yaml").write_text("base: [unclosed\n")
    res = runner.invoke(cli.app, ["sweep", str(tmp_path / "bad.yaml")])
    assert res.exit_code == 2 and "is not valid YAML/JSON" in res.output


def test_ray_backend_without_ray_installed_exits_2_naming_the_extra(tmp_path, monkeypatch):
    import sys

    monkeypatch.setitem(sys.modules, "ray", None)  # import ray now raises ImportError
    res = runner.invoke(cli.app, ["sweep", str(grid_fleet(tmp_path, [1.0])), "--backend", "ray"])
    assert res.exit_code == 2 and "pip install 'gaintune[ray]'" in res.output, res.output


def test_summary_of_a_folder_without_a_sweep_exits_2(tmp_path):
    res = runner.invoke(cli.app, ["sweep", "summary", str(tmp_path)])
    assert res.exit_code == 2 and "holds no sweep" in res.output


def test_a_sweep_folder_of_the_other_store_kind_exits_2(tmp_path):
    (tmp_path / "out" / "results").mkdir(parents=True)  # a --store dir sweep was here
    res = runner.invoke(cli.app, ["sweep", str(grid_fleet(tmp_path, [1.0])), "--out", str(tmp_path / "out")])
    assert res.exit_code == 2 and "error: store: " in res.output and "--store dir" in res.output, res.output
