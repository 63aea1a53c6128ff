"""The REST API takes MIMO specs (several inputs, loop graphs) and keeps them unchanged; bad ones are 422."""

from __future__ import annotations

import json

import pytest
from fastapi.testclient import TestClient

from gaintune.plants.library import load_model
from gaintune.spec import load_spec
from gaintune_api.main import create_app
from gaintune_api.settings import Settings


@pytest.fixture(scope="module")
def client(tmp_path_factory):
    d = tmp_path_factory.mktemp("api")
    s = Settings(_env_file=None, db_path=d / "jobs.db", data_dir=d, workers=0, warmup=False, compute_processes=0)
    with TestClient(create_app(s), raise_server_exceptions=False) as c:
        yield c


def wood_berry() -> dict:
    spec = load_model("wood_berry").example_spec()
    spec["search"] = {"budget": 500}
    return json.loads(json.dumps(spec))


def test_mimo_spec_is_queued_and_stored_unchanged(client: TestClient) -> None:
    spec = wood_berry()
    r = client.post("/v1/tune", json=spec)
    assert r.status_code == 202, r.text
    row = client.app.state.store.get(r.json()["id"])
    assert json.loads(row.spec) == load_spec(spec).model_dump(mode="json")
    stored = json.loads(row.spec)
    assert stored["loops"][1]["drives"] == "S" and stored["scenarios"][1]["reference"]["loop"] == "xB"
    assert stored["requirements"]["mimo_ms_max"] == 2.1
    assert load_spec(stored).content_hash() == load_spec(spec).content_hash()


@pytest.mark.parametrize("change, loc", [
    (lambda s: s["loops"][0].update(drives="Q"), "loops[0].drives"),
    (lambda s: s["loops"][1].update(drives="loop:xD") or s["loops"][0].update(drives="loop:xB"), "loops"),
    (lambda s: s.update(ties=[["xD.Kp", "xB.Ki"]]), "ties"),
    (lambda s: s["loops"][1].update(drives="R"), "loops"),
])
def test_bad_mimo_spec_is_422_naming_the_field(client: TestClient, change, loc: str) -> None:
    spec = wood_berry()
    change(spec)
    r = client.post("/v1/tune", json=spec)
    assert r.status_code == 422, r.text
    body = r.json()
    assert "Traceback" not in r.text
    assert any(e["loc"].startswith(loc) for e in body["errors"]), body["errors"]


def test_simulate_takes_a_mimo_spec(client: TestClient) -> None:
    spec = wood_berry()
    gains = {"xD": {"Kp": 0.375, "Ki": 0.375 / 8.29}, "xB": {"Kp": -0.075, "Ki": -0.075 / 23.6}}
    r = client.post("/v1/simulate", json={"spec": spec, "gains": gains, "max_points": 50})
    assert r.status_code == 200, r.text
    scs = r.json()["scenarios"]
    assert [s["name"] for s in scs] == ["step_xD", "step_xB"]
    tr, m = scs[0]["traces"], scs[0]["metrics"]
    assert {"y.xD", "y.xB", "u.R", "u.S"} <= set(tr) and len(tr["y.xD"]) <= 50
    assert m["iae"] == m["iae.xD"] + m["iae.xB"] and m["diverged"] is False


BLT = {"xD": {"Kp": 0.375, "Ki": 0.375 / 8.29}, "xB": {"Kp": -0.075, "Ki": -0.075 / 23.6}}


def test_verify_gives_the_mimo_verdict_naming_the_requirement(client: TestClient) -> None:
    r = client.post("/v1/verify", json={"spec": wood_berry(), "gains": BLT})
    assert r.status_code == 200, r.text
    rep = r.json()
    assert rep["verdict"] == "fail" and rep["reasons"][0].startswith("mimo_ms_max: ms = ")
    assert rep["mimo"]["ms"] > 2.1 and rep["mimo"]["disk_output"]["alpha"] > 0
    spec = wood_berry()
    spec["requirements"].update(mimo_ms_max=2.6, targets={"gm_min_db": {"nope": 3}})
    bad = client.post("/v1/verify", json={"spec": spec, "gains": BLT})
    assert bad.status_code == 422 and "requirements.targets" in bad.text and "Traceback" not in bad.text
    spec["requirements"].pop("targets")
    assert client.post("/v1/verify", json={"spec": spec, "gains": BLT}).json()["verdict"] == "pass"


def test_tune_job_end_to_end_carries_the_mimo_verdict(client: TestClient) -> None:
    from gaintune_api.worker import process_next

    spec = wood_berry()
    spec["search"] = {"budget": 600, "seed": 0}
    r = client.post("/v1/tune", json=spec)
    assert r.status_code == 202, r.text
    job_id = r.json()["id"]
    for _ in range(5):  # earlier tests of this module queued jobs too: run the queue up to this one
        if client.get(f"/v1/jobs/{job_id}").json()["status"] == "succeeded":
            break
        assert process_next(client.app.state.store, client.app.state.settings) == "succeeded"
    job = client.get(f"/v1/jobs/{job_id}").json()
    res = job["result"]
    v = res["verification"]
    assert set(v["gains"]) == {"xD", "xB"} and v["mimo"]["ms"] > 1 and res["verdict"] == v["verdict"]
    assert res["accepted_gains"] == (v["gains"] if v["verdict"] == "pass" else None)
    assert {f["break_point"] for f in v["loops"]} == {"plant_input", "plant_output"}
    assert (v["verdict"] == "pass") == (v["mimo"]["ms"] <= 2.1)
