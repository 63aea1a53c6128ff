"""Trained tuners over the API: ``GET /v1/tuners``, ``POST /v1/tuners/{name}/query``, ``POST /v1/tuners`` (a job).

The tuners are the tiny ones of ``tests/conftest.py``; jobs run in-process (:func:`test_api_routes.run_next`).
"""

from __future__ import annotations

import json
import os
import shutil
import time
from pathlib import Path

import pytest
from test_api_routes import run_next

from gaintune.tuners import artefact
from gaintune.tuners.listing import shipped as shipped_list
from gaintune.tuners.tuner import Tuner
from gaintune_api import tuner_jobs

NAME = "fotd_pi_ms1.4"
PLANT = {"K": 2, "T": 60, "L": 10}
#: A small LTI family: PI on K/(s+1)^2, K from 0.5 to 2.
LAG2 = {"name": "lag2_family", "plant": {"tf": {"num": ["K"], "den": "(s+1)^2"}, "params": {"K": 1.0}},
        "loops": [{"type": "pi"}], "scenario": {"dt": 0.05, "horizon": 10.0},
        "randomize": {"params": {"K": [0.5, 2.0]}}}


@pytest.fixture
def shipped(tiny_fotd_tuner: Path, tmp_path: Path, monkeypatch) -> Path:
    """The installed tuners: the tiny FOTD one as ``fotd_pi_ms1.4``, and ``always_fails`` (only unstable gains)."""
    folder = tmp_path / "shipped"
    shutil.copytree(tiny_fotd_tuner, folder / NAME)
    bad = shutil.copytree(tiny_fotd_tuner, folder / "always_fails")
    doc = json.loads((bad / "tuner.json").read_text())
    doc["box"]["lo"], doc["box"]["hi"] = [200.0, 200.0], [400.0, 400.0]  # every Kp, Ki on the unit plant unstable
    (bad / "tuner.json").write_text(json.dumps(doc))
    monkeypatch.setattr(artefact, "SHIPPED_DIR", folder)
    return folder


def test_tuner_list_route_is_the_cli_list(client, shipped: Path) -> None:
    r = client.get("/v1/tuners")
    assert r.status_code == 200, r.text
    items = r.json()["items"]
    assert [i["name"] for i in items] == ["always_fails", NAME]
    assert items == json.loads(json.dumps(shipped_list()))  # the same data as `gaintune tuner list --json`
    fotd = items[1]
    assert (fotd["family"], fotd["controller"], fotd["ms_max"]) == ("fotd", "pi", 1.4)
    assert fotd["context"][0]["name"] == "L/T" and fotd["size_kb"] > 0 and fotd["validation"]["n"] == 2


def test_tuner_query_route_answers_a_plant_and_keeps_the_tuner_loaded(client, shipped: Path) -> None:
    r = client.post(f"/v1/tuners/{NAME}/query", json={"params": PLANT})
    assert r.status_code == 200, r.text
    a = r.json()
    assert a["gains"] == Tuner.load(shipped / NAME).query(PLANT).gains
    assert a["verdict"] in ("pass", "fail") and a["accepted_gains"] == (a["gains"] if a["verdict"] == "pass" else None)
    assert a["params"] == {"K": 2.0, "T": 60.0, "L": 10.0} and a["policy_ms"] > 0 and a["n_sims"] > 0
    r = client.post(f"/v1/tuners/{NAME}/query", json={"params": PLANT, "refine": 30})
    assert r.status_code == 200 and 0 < r.json()["refined_sims"] <= 30
    assert len(client.app.state.tuners) == 1  # loaded once, answered twice


def test_tuner_query_route_failing_verdict_is_200_with_no_accepted_gains(client, shipped: Path) -> None:
    r = client.post("/v1/tuners/always_fails/query", json={"params": PLANT})
    assert r.status_code == 200, r.text
    assert r.json()["verdict"] == "fail" and r.json()["accepted_gains"] is None and r.json()["gains"]


@pytest.mark.parametrize("name", ["nope", "job:nope", "..", "%2e%2e%2fshipped"])
def test_tuner_query_route_unknown_tuner_is_404(client, shipped: Path, name: str) -> None:
    r = client.post(f"/v1/tuners/{name}/query", json={"params": PLANT})
    assert r.status_code == 404 and r.headers["content-type"] == "application/problem+json", r.text


@pytest.mark.parametrize("body, loc, needle", [
    ({"params": {"K": 2, "T": 60}}, "params.L", "the fotd family needs K, T, L"),
    ({"params": {**PLANT, "Z": 1}}, "params.Z", "not a parameter of the fotd family"),
    ({"params": {**PLANT, "L": 1000}}, "params.tau", "L/T = 16.7 is outside the family"),
    ({"params": {**PLANT, "K": -1}}, "params.K", "must be > 0"),
    # test_a_time_scale_of_1e200_is_refused_not_an_overflow: it was an OverflowError's text
    ({"params": {"K": 1, "T": 1e200, "L": 1e200}}, "params", "time scale L + T = 2e+200 s is outside"),
    ({"params": {**PLANT, "K": 1e308}}, "params.K", "gain K = 1e+308 is outside the 1e-10 to 1e+10"),
    ({"params": PLANT, "refine": 10**6}, "refine", "exceeds this server's limit of 2000"),
    ({"params": {**PLANT, "K": "x"}}, "params.K", ""),
    ({"params": PLANT, "extra": 1}, "extra", ""),
])
def test_tuner_query_route_bad_parameter_is_422_naming_it(client, shipped: Path, body: dict, loc: str,
                                                          needle: str) -> None:
    r = client.post(f"/v1/tuners/{NAME}/query", json=body)
    assert r.status_code == 422 and r.headers["content-type"] == "application/problem+json", r.text
    err = r.json()["errors"][0]
    assert err["loc"].endswith(loc) and needle in err["msg"], err


def test_policy_route_is_gone(client) -> None:
    """One name for one thing: no route answers a tuning job's robust design as a tuner any more."""
    r = client.post("/v1/jobs/abc/policy", json={})
    assert r.status_code in (404, 405)
    paths = client.get("/openapi.json").json()["paths"]
    assert not [p for p in paths if "policy" in p]
    assert {"/v1/tuners", "/v1/tuners/{name}/query"} <= set(paths)
    settings = client.app.state.settings
    assert not hasattr(settings, "max_policy_points") and not hasattr(settings, "policy_cache_size")


@pytest.mark.parametrize("body, loc", [
    ({"episodes": 10}, "family"),
    ({"spec": LAG2, "family": "fotd"}, "family"),
    ({"spec": LAG2, "ctype": "pid"}, "ctype"),
    ({"family": "fotd", "episodes": 10**9}, "episodes"),
    ({"spec": {**LAG2, "randomize": {}}}, "spec.randomize.params"),
    ({"spec": {**LAG2, "loops": [{"type": "pi", "measure": "zz"}]}}, "spec.loops"),
    ({"family": "xyz"}, "family"),
    ({"family": "fotd", "ms_max": 0.9}, "ms_max"),
])
def test_tuner_train_route_bad_request_is_422_naming_the_field(client, body: dict, loc: str) -> None:
    r = client.post("/v1/tuners", json=body)
    assert r.status_code == 422, r.text
    assert any(e["loc"].removeprefix("body.").startswith(loc) for e in r.json()["errors"]), r.json()["errors"]
    assert client.get("/v1/jobs").json()["total"] == 0


def test_tuner_job_trains_end_to_end_and_resumes_after_a_killed_attempt(client, tiny_training: dict,
                                                                         monkeypatch) -> None:
    """A POST /v1/tuners job whose first worker died after a checkpoint: the re-queued job resumes from it,
    finishes, and its tuner answers at links.query; report and export are 409 (a tuner has no gains)."""
    monkeypatch.setattr(tuner_jobs, "TRAIN_DEFAULTS", tiny_training)
    r = client.post("/v1/tuners", json={"spec": LAG2, "episodes": 1024})
    assert r.status_code == 202, r.text
    job = r.json()
    assert job["kind"] == "tuner" and job["status"] == "queued" and job["spec_name"] == "lag2_family"
    store, files = client.app.state.store, client.app.state.files

    # attempt 1: the worker trains into its staging folder and dies after its first checkpoint
    claimed = store.claim(os.getpid())  # a live pid: the supervisor leaves the attempt alone
    req = tuner_jobs.TunerTrainRequest.model_validate_json(claimed.spec)
    staging = files.stage(claimed.id, claimed.attempts, claimed.claim)
    seen: list[int] = []

    def killed(done: int, total: int, info: dict) -> None:
        # a worker heartbeats while it trains: without it a loaded machine let the lease run out mid-training
        store.heartbeat(claimed.id, claimed.claim, None)
        if seen:
            raise SystemExit(137)
        if "ratio" in info:
            seen.append(done)

    from gaintune.tuners.train import train

    with pytest.raises(SystemExit):
        train(tuner_jobs.problem_of(req), staging / tuner_jobs.TUNER_DIR, tuner_jobs.train_settings(req),
              on_progress=killed)
    assert seen == [512]
    assert store.recover([claimed.id], "requeue", "its worker died", 3)[0][1] == "queued"  # as the supervisor does

    assert run_next(client) == "succeeded"  # attempt 2
    j = client.get(f"/v1/jobs/{job['id']}").json()
    assert j["status"] == "succeeded" and j["attempts"] == 2 and j["result"] is None
    t = j["tuner"]
    assert t["training"]["resumed"] == 1 and t["training"]["episodes"] == 1024 and t["kind"] == "spec"
    assert t["params"] == ["K"] and t["validation"]["n"] == 2
    p = j["progress"]
    assert p["episodes"] == p["episodes_total"] == 1024 and p["fraction"] == 1.0 and p["phase"] == "done"
    assert j["links"]["query"] == f"/v1/tuners/job:{job['id']}/query"
    r = client.post(j["links"]["query"], json={"params": {"K": 1.4}})
    assert r.status_code == 200 and r.json()["params"] == {"K": 1.4}, r.text
    r = client.post(j["links"]["query"], json={"params": {"K": 9}})
    assert r.status_code == 422 and r.json()["errors"][0]["loc"] == "params.K"
    assert client.get(j["links"]["agent"]).status_code == 200
    for url in (f"/v1/jobs/{job['id']}/report", f"/v1/jobs/{job['id']}/export"):
        r = client.get(url)
        assert r.status_code == 409 and "trained a tuner" in r.json()["detail"], r.text
    assert client.get("/v1/jobs").json()["items"][0]["kind"] == "tuner"
    listed = client.get("/v1/tuners").json()["items"]
    assert listed[-1] == {**t, "name": f"job:{job['id']}"}  # the trained tuner, under the name its queries take


def test_tuner_list_route_lists_the_tuners_this_keys_finished_jobs_trained(client, shipped: Path) -> None:
    """A finished tuner job is listed as job:{id} after the ready-made tuners; a queued one, or another key's, not."""
    store = client.app.state.store
    theirs, _ = store.create("someone-else", "{}", "h", "lag2_family", idem_key=None, max_queue=100, kind="tuner")
    mine = client.post("/v1/tuners", json={"spec": LAG2, "episodes": 64}).json()["id"]
    queued = client.post("/v1/tuners", json={"spec": LAG2, "episodes": 65}).json()["id"]
    summary = {**shipped_list()[1], "name": "lag2_family"}
    for _ in (theirs.id, mine):  # claimed in the order they were queued
        row = store.claim(os.getpid())
        assert store.finish(row.id, row.claim, "succeeded", result={"kind": "tuner", "tuner": summary}) == "succeeded"
    names = [i["name"] for i in client.get("/v1/tuners").json()["items"]]
    assert names == ["always_fails", NAME, f"job:{mine}"] and f"job:{queued}" not in names


def test_tuner_job_cancel_stops_the_training(make_client, tmp_path: Path, tiny_training: dict, monkeypatch) -> None:
    """The training is held after its first progress report until the job is cancelled: only the cancel request
    can have stopped it (the next progress report ends it); the job ends cancelled without a tuner."""
    from test_api_routes import BACKSTOP, _run_in_thread, _wait_status

    monkeypatch.setattr(tuner_jobs, "TRAIN_DEFAULTS", tiny_training)
    hold = tmp_path / "hold"
    hold.write_text("")
    client = make_client(test_hold_file=hold)
    job = client.post("/v1/tuners", json={"spec": LAG2, "episodes": 4096}).json()
    th, out = _run_in_thread(client, None)
    j = _wait_status(client, job["id"], {"running"})
    deadline = time.monotonic() + BACKSTOP  # a failure if reached, never a measure
    while not (j.get("progress") or {}).get("episodes"):  # it holds at its first report
        assert th.is_alive() and time.monotonic() < deadline, (out, j)
        time.sleep(0.05)
        j = client.get(f"/v1/jobs/{job['id']}").json()
    assert j["progress"]["episodes"] < 4096 and j["progress"]["phase"] == "train"
    assert client.delete(f"/v1/jobs/{job['id']}").status_code == 202
    j = _wait_status(client, job["id"], {"cancelled"})
    th.join(60)
    assert out["status"] == "cancelled" and j["tuner"] is None and j["error"] == "cancelled on request"
