"""REST API route tests (FastAPI TestClient, no worker processes; jobs run in-process with a fake search)."""

from __future__ import annotations

import threading
import time
import zipfile
from pathlib import Path

import pytest
from fastapi.testclient import TestClient

from gaintune.search.result import CurvePoint, Progress, Provenance, TuneResult
from gaintune_api.job_store import JobStore
from gaintune_api.main import create_app
from gaintune_api.settings import Settings
from gaintune_api.supervisor import Supervisor
from gaintune_api.worker import process_next

SPEC = {
    "name": "lag3",
    "plant": {"tf": {"num": [1], "den": "(s+1)^3"}},
    "loops": [{"type": "pi"}],
    "scenario": {"dt": 0.05, "horizon": 20.0},
    "search": {"budget": 200},
}
GOOD = {"loop0": {"Kp": 1.14, "Ki": 0.454}}
BAD = {"loop0": {"Kp": 20.0, "Ki": 20.0}}  # unstable: verification fails


#: Bounds every wait of a fake search, so that a broken test fails instead of hanging (never reached when it passes).
BACKSTOP = 60.0


def make_fake_tune(gains=GOOD, *, steps: int = 3, honour_cancel: bool = True, until_cancelled: bool = False,
                   release: threading.Event | None = None):
    """A stand-in for gaintune.search.tune: reports progress, verifies fixed gains, saves a dummy agent.

    Durations are set by events, not by sleeps: with ``until_cancelled`` the search runs (after its first
    progress report) until its ``cancel`` event is set; with ``release`` it waits for that event there.
    """

    def fake_tune(spec, *, progress=None, out_dir=None, verify=True, cancel=None, **kw):
        from gaintune.verification import verify as do_verify

        budget = spec.search.budget
        stopped = "budget"
        t0 = time.monotonic()
        sims = 0
        for k in range(steps):
            sims = (k + 1) * budget // steps
            keep = progress(Progress(sims=sims, budget=budget, best_cost=10.0 / (k + 1),
                                     elapsed=time.monotonic() - t0, eta=1.0)) if progress else True
            if honour_cancel and (keep is False or (cancel is not None and cancel.is_set())):
                stopped = "cancelled"
                break
            if k == 0 and until_cancelled:
                cancel.wait(BACKSTOP)
            if k == 0 and release is not None:
                release.wait(BACKSTOP)
        report = do_verify(spec, gains) if verify else None
        agent = None
        if out_dir is not None:
            agent = str(Path(out_dir) / "agent.zip")
            with zipfile.ZipFile(agent, "w") as z:
                z.writestr("policy.txt", "fake")
        return TuneResult(
            spec=spec.model_dump(mode="json"), algo=spec.search.algo, gains=gains, cost=1.5,
            metrics={"nominal": {"iae": 1.5}}, curve=[CurvePoint(sims=sims, best_cost=1.5, wall_time=0.1)], sims=sims,
            wall_time=time.monotonic() - t0, stopped=stopped, agent_path=agent,
            verification=None if report is None else report.model_dump(mode="json"),
            provenance=Provenance(spec_hash=spec.content_hash(), seed=spec.search.seed, versions={"gaintune": "test"}),
        )

    return fake_tune


def settings_for(tmp_path: Path, **kw) -> Settings:
    base = dict(db_path=tmp_path / "jobs.db", data_dir=tmp_path / "data", workers=0, warmup=False, compute_processes=0,
                heartbeat_interval=0.05, cancel_grace=1.0)
    base.update(kw)
    return Settings(_env_file=None, **base)


@pytest.fixture
def make_client(tmp_path):
    clients = []

    def make(**kw) -> TestClient:
        app = create_app(settings_for(tmp_path, **kw))
        c = TestClient(app, raise_server_exceptions=False)
        c.__enter__()
        clients.append(c)
        return c

    yield make
    for c in clients:
        c.__exit__(None, None, None)


@pytest.fixture
def client(make_client) -> TestClient:
    return make_client()


def run_next(client: TestClient, tune=None) -> str | None:
    app = client.app
    return process_next(app.state.store, app.state.settings, tune or make_fake_tune())


def submit(client: TestClient, spec=SPEC, **headers) -> dict:
    r = client.post("/v1/tune", json=spec, headers=headers)
    assert r.status_code == 202, r.text
    return r.json()


# ------------------------------------------------------------------ jobs


def test_submit_returns_202_with_location_and_queued_job(client):
    r = client.post("/v1/tune", json=SPEC)
    assert r.status_code == 202
    job = r.json()
    assert r.headers["location"] == f"/v1/jobs/{job['id']}"
    assert job["status"] == "queued" and job["result"] is None and job["spec_name"] == "lag3"
    assert client.get(r.headers["location"]).json()["id"] == job["id"]


def test_job_lifecycle_succeeded_with_accepted_gains_report_export_agent(client):
    job = submit(client)
    assert run_next(client) == "succeeded"
    j = client.get(f"/v1/jobs/{job['id']}").json()
    assert j["status"] == "succeeded"
    assert j["started_at"] and j["finished_at"] and j["attempts"] == 1
    assert j["progress"]["sims"] == j["progress"]["budget"] == 200 and j["progress"]["fraction"] == 1.0
    res = j["result"]
    assert res["verdict"] == "pass"
    assert res["accepted_gains"] == GOOD
    assert res["verification"]["verdict"] == "pass" and res["verification"]["loops"]
    assert res["provenance"]["spec_hash"] == job["spec_hash"]
    assert res["curve"] and res["metrics"]["nominal"]["iae"] == 1.5
    assert res["agent_available"] and set(j["links"]) >= {"self", "report", "export", "agent"}
    agent = client.get(f"/v1/jobs/{job['id']}/agent")
    assert agent.status_code == 200 and agent.headers["content-type"] == "application/zip"
    assert agent.content[:2] == b"PK"


def test_failed_verification_hides_gains_and_refuses_export(client):
    job = submit(client)
    assert run_next(client, make_fake_tune(BAD)) == "succeeded"
    res = client.get(f"/v1/jobs/{job['id']}").json()["result"]
    assert res["verdict"] == "fail"
    assert res["accepted_gains"] is None
    assert res["verification"]["reasons"]
    r = client.get(f"/v1/jobs/{job['id']}/export", params={"format": "json"})
    assert r.status_code == 409 and "allow_unverified" in r.json()["detail"]


@pytest.mark.parametrize("fmt", ["json", "yaml", "c", "matlab", "python"])
def test_export_formats(client, fmt):
    pytest.importorskip("gaintune.export")
    job = submit(client)
    run_next(client)
    r = client.get(f"/v1/jobs/{job['id']}/export", params={"format": fmt})
    assert r.status_code == 200, r.text
    assert "attachment" in r.headers["content-disposition"]
    assert "1.14" in r.text


def test_export_unknown_format_is_422(client):
    job = submit(client)
    run_next(client)
    r = client.get(f"/v1/jobs/{job['id']}/export", params={"format": "xml"})
    assert r.status_code == 422 and r.json()["errors"][0]["loc"] == "query.format"


#: dc_motor cascade gains that pass verification at the example's dt = 1 ms and are unstable at dt = 10 ms.
FLIP_GAINS = {"position": {"Kp": 10.0}, "speed": {"Kp": 1.2, "Ki": 14.4}, "current": {"Kp": 3.0, "Ki": 300.0}}


def _motor_spec() -> dict:
    from gaintune.plants.library import load_model

    spec = load_model("dc_motor").example_spec()
    spec["search"] = {"budget": 200}
    return spec


def test_api_export_dt_reverifies(client):
    pytest.importorskip("gaintune.export")
    job = submit(client, _motor_spec())
    assert run_next(client, make_fake_tune(FLIP_GAINS)) == "succeeded"
    url = f"/v1/jobs/{job['id']}/export"
    assert client.get(f"/v1/jobs/{job['id']}").json()["result"]["verdict"] == "pass"  # at 1 ms
    r = client.get(url, params={"format": "c"})  # default: the verified dt, stored verdict
    assert r.status_code == 200, r.text
    assert "#define GT_DT 0.001\n" in r.text and "#define GT_VERIFIED 1\n" in r.text
    assert "#define GT_VERIFIED_DT 0.001 " in r.text
    r = client.get(url, params={"format": "c", "dt": 0.01})  # 10 ms: re-verified, unstable -> refused
    assert r.status_code == 409 and r.headers["content-type"] == "application/problem+json"
    detail = r.json()["detail"]
    assert "dt = 0.01 s" in detail and "verdict: fail" in detail and "closed loop unstable" in detail
    assert "allow_unverified=true" in detail
    r = client.get(url, params={"format": "c", "dt": 0.01, "allow_unverified": "true"})
    assert r.status_code == 200, r.text
    assert "#define GT_DT 0.01\n" in r.text and "#define GT_VERIFIED 0\n" in r.text
    assert '#define GT_VERDICT "fail"' in r.text
    assert "verification: FAILED at dt = 0.01 s - closed loop unstable" in r.text
    r = client.get(url, params={"format": "json", "dt": 0.0005})  # finer: re-verified, passes
    assert r.status_code == 200, r.text
    doc = r.json()
    assert doc["verdict"] == "pass" and doc["accepted"] is True and doc["dt"] == doc["verified_dt"] == 0.0005
    r = client.get(url, params={"format": "matlab", "dt": 0.0005})
    assert r.status_code == 200 and "Ts = 0.0005;" in r.text and "'IFormula', 'BackwardEuler'" in r.text


@pytest.mark.parametrize(("dt", "msg"), [("0", "greater than 0"), ("-0.01", "greater than 0"), ("abc", "number"),
                                         ("inf", "finite"), ("1e-7", "steps"), ("1.5", "fewer than 2 samples")])
def test_api_export_bad_dt_is_422_naming_dt(client, dt, msg):
    pytest.importorskip("gaintune.export")
    job = submit(client, _motor_spec())
    run_next(client, make_fake_tune(FLIP_GAINS))
    r = client.get(f"/v1/jobs/{job['id']}/export", params={"format": "c", "dt": dt})
    assert r.status_code == 422, r.text
    err = r.json()["errors"][0]
    assert err["loc"] == "query.dt" and msg in err["msg"], err


def test_api_export_dt_over_server_step_limit_is_422(make_client):
    pytest.importorskip("gaintune.export")
    client = make_client(max_steps=5000)
    job = submit(client, _motor_spec())  # 2 s at 1 ms = 2000 steps
    run_next(client, make_fake_tune(FLIP_GAINS))
    r = client.get(f"/v1/jobs/{job['id']}/export", params={"format": "c", "dt": 0.0001})  # 20000 steps
    assert r.status_code == 422
    assert r.json()["errors"][0]["loc"] == "query.dt" and "5000" in r.json()["errors"][0]["msg"]


def test_report_html(client):
    pytest.importorskip("gaintune.report")
    job = submit(client)
    run_next(client)
    r = client.get(f"/v1/jobs/{job['id']}/report")
    assert r.status_code == 200, r.text
    assert r.headers["content-type"].startswith("text/html") and "<html" in r.text.lower()
    assert client.get(f"/v1/jobs/{job['id']}/report").status_code == 200  # cached file


def test_report_and_export_missing_module_is_501(client, monkeypatch):
    import importlib

    job = submit(client)
    run_next(client)
    real = importlib.import_module

    def fake_import(name, *a, **kw):
        if name in ("gaintune.report", "gaintune.export"):
            raise ImportError(f"No module named {name!r}")
        return real(name, *a, **kw)

    monkeypatch.setattr(importlib, "import_module", fake_import)
    for path in ("report", "export"):
        r = client.get(f"/v1/jobs/{job['id']}/{path}")
        assert r.status_code == 501, r.text
        assert r.headers["content-type"] == "application/problem+json" and "not available" in r.json()["detail"]


def test_artifacts_before_result_are_409(client):
    job = submit(client)
    for path in ("report", "agent", "export"):
        r = client.get(f"/v1/jobs/{job['id']}/{path}")
        assert r.status_code == 409, path


def test_unknown_job_is_404_problem(client):
    for method, path in [("get", "/v1/jobs/nope"), ("delete", "/v1/jobs/nope"), ("get", "/v1/jobs/nope/report"),
                         ("get", "/v1/jobs/nope/agent"), ("get", "/v1/jobs/nope/export")]:
        r = getattr(client, method)(path)
        assert r.status_code == 404, path
        body = r.json()
        assert body["status"] == 404 and body["title"] and r.headers["content-type"] == "application/problem+json"


def test_list_jobs_paginates_and_filters(client):
    ids = [submit(client, {**SPEC, "name": f"j{i}"})["id"] for i in range(5)]
    run_next(client)  # oldest (ids[0]) succeeds
    page = client.get("/v1/jobs", params={"limit": 2}).json()
    assert page["total"] == 5 and [j["id"] for j in page["items"]] == ids[::-1][:2] and page["next_offset"] == 2
    last = client.get("/v1/jobs", params={"limit": 2, "offset": 4}).json()
    assert [j["id"] for j in last["items"]] == [ids[0]] and last["next_offset"] is None
    done = client.get("/v1/jobs", params={"status": "succeeded"}).json()
    assert [j["id"] for j in done["items"]] == [ids[0]]
    assert client.get("/v1/jobs", params={"status": "queued"}).json()["total"] == 4
    assert client.get("/v1/jobs", params={"status": "bogus"}).status_code == 422
    assert client.get("/v1/jobs", params={"limit": 0}).status_code == 422


def test_idempotency_key_returns_same_job(client):
    a = client.post("/v1/tune", json=SPEC, headers={"Idempotency-Key": "abc"})
    b = client.post("/v1/tune", json=SPEC, headers={"Idempotency-Key": "abc"})
    assert a.status_code == b.status_code == 202
    assert a.json()["id"] == b.json()["id"] and b.headers["idempotent-replayed"] == "true"
    assert client.get("/v1/jobs").json()["total"] == 1
    c = client.post("/v1/tune", json={**SPEC, "name": "other"}, headers={"Idempotency-Key": "abc"})
    assert c.status_code == 409
    d = client.post("/v1/tune", json=SPEC, headers={"Idempotency-Key": "xyz"})
    assert d.json()["id"] != a.json()["id"]


def test_queue_full_is_503_with_retry_after(make_client):
    client = make_client(max_queue=2, retry_after=7)
    submit(client)
    submit(client)
    r = client.post("/v1/tune", json=SPEC)
    assert r.status_code == 503 and r.headers["retry-after"] == "7"
    assert r.json()["status"] == 503


def test_cancel_queued_job(client):
    job = submit(client)
    r = client.delete(f"/v1/jobs/{job['id']}")
    assert r.status_code == 200 and r.json()["status"] == "cancelled"
    assert run_next(client) is None  # nothing left to run
    assert client.delete(f"/v1/jobs/{job['id']}").status_code == 409


def _run_in_thread(client, tune):
    out = {}
    th = threading.Thread(target=lambda: out.setdefault("status", run_next(client, tune)), daemon=True)
    th.start()
    return th, out


def _wait_status(client, job_id, statuses, backstop=BACKSTOP):
    """Poll the job until its status is one of ``statuses`` (``backstop`` s at most: a failure, never a measure)."""
    deadline = time.monotonic() + backstop
    while time.monotonic() < deadline:
        j = client.get(f"/v1/jobs/{job_id}").json()
        if j["status"] in statuses:
            return j
        time.sleep(0.05)
    raise AssertionError(f"job stayed {j['status']}")


def test_cancel_running_job_stops_search(client):
    """The search runs until it is cancelled: only the cancel request can have stopped it."""
    job = submit(client)
    th, out = _run_in_thread(client, make_fake_tune(until_cancelled=True))
    _wait_status(client, job["id"], {"running"})
    r = client.delete(f"/v1/jobs/{job['id']}")
    assert r.status_code == 202 and r.json()["cancel_requested"]
    j = _wait_status(client, job["id"], {"cancelled"})
    th.join(BACKSTOP)
    assert out["status"] == "cancelled"
    assert j["result"]["stopped"] == "cancelled" and j["error"] == "cancelled on request"


def test_cancel_ignored_by_search_is_forced_after_grace(client):
    """The search ignores the cancel and is held until the job is cancelled: the monitor must end it alone."""
    job = submit(client)
    release = threading.Event()
    th, _ = _run_in_thread(client, make_fake_tune(honour_cancel=False, release=release))
    _wait_status(client, job["id"], {"running"})
    client.delete(f"/v1/jobs/{job['id']}")
    j = _wait_status(client, job["id"], {"cancelled"})  # cancel_grace = 1 s, then the monitor writes it
    assert "did not stop" in j["error"]
    release.set()
    th.join(BACKSTOP)
    assert not th.is_alive()
    assert client.get(f"/v1/jobs/{job['id']}").json()["status"] == "cancelled"  # late result does not overwrite


def test_wall_time_limit_fails_job(make_client):
    """The search runs until it is stopped: only the wall-time limit can stop it."""
    client = make_client(job_wall_time=0.3)
    job = submit(client)
    assert run_next(client, make_fake_tune(until_cancelled=True)) == "failed"
    j = client.get(f"/v1/jobs/{job['id']}").json()
    assert j["status"] == "failed" and "wall-time limit" in j["error"]


def test_search_exception_fails_job_without_trace(client):
    job = submit(client)

    def broken(spec, **kw):
        raise RuntimeError("boom")

    assert run_next(client, broken) == "failed"
    j = client.get(f"/v1/jobs/{job['id']}").json()
    assert j["status"] == "failed" and "RuntimeError: boom" in j["error"] and "Traceback" not in j["error"]


def test_running_progress_is_visible(client):
    """The search is held after its first progress report: the job is still running when the progress is read."""
    job = submit(client)
    release = threading.Event()
    th, out = _run_in_thread(client, make_fake_tune(release=release))
    deadline = time.monotonic() + BACKSTOP
    j = client.get(f"/v1/jobs/{job['id']}").json()
    while j["progress"] is None and time.monotonic() < deadline:
        time.sleep(0.05)
        j = client.get(f"/v1/jobs/{job['id']}").json()
    release.set()
    th.join(BACKSTOP)
    prog = j["progress"]
    assert j["status"] == "running" and prog is not None
    assert prog["budget"] == 200 and prog["sims"] == 200 // 3 and prog["best_cost"] == 10.0
    assert out["status"] == "succeeded"


# -------------------------------------------------------------- recovery


def _fake_running(store: JobStore, pid: int) -> str:
    row, _ = store.create("anonymous", '{"plant": {"tf": {"num": [1], "den": [1, 1]}}, "loops": [{"type": "p"}]}',
                          "h", "x", idem_key=None, max_queue=10)
    claimed = store.claim(pid)
    assert claimed.id == row.id
    return row.id


@pytest.mark.parametrize("policy,expected", [("requeue", "queued"), ("fail", "failed")])
def test_recovery_policy_for_dead_worker(tmp_path, policy, expected):
    s = settings_for(tmp_path, recover=policy)
    store = JobStore(s.db_path)
    store.init()
    job_id = _fake_running(store, pid=2**22 + 12345)  # no such process
    changed = Supervisor(s, store).recover("test")
    assert changed == [job_id]
    row = store.get(job_id)
    assert row.status == expected and row.claim is None
    assert ("re-queued" if policy == "requeue" else "interrupted") in row.error


def test_recovery_gives_up_after_max_attempts(tmp_path):
    s = settings_for(tmp_path, recover="requeue", max_attempts=1)
    store = JobStore(s.db_path)
    store.init()
    job_id = _fake_running(store, pid=2**22 + 12345)
    Supervisor(s, store).recover("test")
    assert store.get(job_id).status == "failed"


def test_recovered_job_ignores_writes_from_old_claim(tmp_path):
    s = settings_for(tmp_path)
    store = JobStore(s.db_path)
    store.init()
    job_id = _fake_running(store, pid=2**22 + 12345)
    old = store.get(job_id).claim
    Supervisor(s, store).recover("test")
    assert store.heartbeat(job_id, old, {"sims": 1}) == (False, True)
    assert not store.finish(job_id, old, "succeeded", result={"x": 1})
    assert store.get(job_id).status == "queued"


def test_restart_finds_jobs(tmp_path):
    s = settings_for(tmp_path)
    with TestClient(create_app(s)) as c:
        job = submit(c)
    with TestClient(create_app(s)) as c:
        assert c.get(f"/v1/jobs/{job['id']}").json()["status"] == "queued"


# ------------------------------------------------------------ auth


def test_api_keys_required_and_jobs_isolated(make_client):
    client = make_client(api_keys=["alpha", "beta"])
    assert client.post("/v1/tune", json=SPEC).status_code == 401
    assert client.post("/v1/tune", json=SPEC, headers={"X-API-Key": "wrong"}).status_code == 401
    r = client.post("/v1/tune", json=SPEC, headers={"X-API-Key": "alpha"})
    assert r.status_code == 202
    job_id = r.json()["id"]
    assert client.get(f"/v1/jobs/{job_id}", headers={"X-API-Key": "alpha"}).status_code == 200
    assert client.get(f"/v1/jobs/{job_id}", headers={"X-API-Key": "beta"}).status_code == 404
    assert client.delete(f"/v1/jobs/{job_id}", headers={"X-API-Key": "beta"}).status_code == 404
    assert client.get("/v1/jobs", headers={"X-API-Key": "beta"}).json()["total"] == 0
    assert client.get("/v1/jobs", headers={"X-API-Key": "alpha"}).json()["total"] == 1
    # Idempotency keys are scoped per API key.
    a = client.post("/v1/tune", json=SPEC, headers={"X-API-Key": "alpha", "Idempotency-Key": "k"})
    b = client.post("/v1/tune", json=SPEC, headers={"X-API-Key": "beta", "Idempotency-Key": "k"})
    assert a.json()["id"] != b.json()["id"]
    for path in ("/v1/plants", "/v1/jobs", "/metrics"):
        assert client.get(path).status_code == 401, path
    assert client.post("/v1/verify", json={"spec": SPEC, "gains": GOOD}).status_code == 401
    assert client.get("/healthz").status_code == 200 and client.get("/readyz").status_code == 200


def test_env_settings(monkeypatch, tmp_path):
    monkeypatch.setenv("GAINTUNE_API_KEYS", "k1, k2")
    monkeypatch.setenv("GAINTUNE_RECOVER", "fail")
    monkeypatch.setenv("GAINTUNE_MAX_BUDGET", "500")
    s = Settings(_env_file=None)
    assert s.api_keys == ["k1", "k2"] and s.recover == "fail" and s.max_budget == 500
    monkeypatch.setenv("GAINTUNE_API_KEYS", '["a"]')
    assert Settings(_env_file=None).api_keys == ["a"]


def test_cors(make_client):
    client = make_client(cors_origins=["https://ui.example"])
    r = client.options("/v1/plants", headers={"Origin": "https://ui.example", "Access-Control-Request-Method": "GET"})
    assert r.headers["access-control-allow-origin"] == "https://ui.example"


# ------------------------------------------------------ verify / simulate


def test_verify_pass_and_fail(client):
    r = client.post("/v1/verify", json={"spec": SPEC, "gains": GOOD})
    assert r.status_code == 200
    rep = r.json()
    assert rep["verdict"] == "pass" and rep["gains"] == GOOD and rep["loops"]
    again = client.post("/v1/verify", json={"spec": SPEC, "gains": GOOD})
    assert again.json() == rep and again.headers["x-cache"] == "hit"
    bad = client.post("/v1/verify", json={"spec": SPEC, "gains": BAD}).json()
    assert bad["verdict"] == "fail" and bad["reasons"]


@pytest.mark.parametrize(
    "gains,loc",
    [
        ({"loop0": {"Kp": -1.0, "Ki": 0.4}}, "gains.loop0.Kp"),
        ({"loop0": {"Kp": 1.0}}, "gains.loop0.Ki"),
        ({"loop0": {"Kp": 1.0, "Ki": 1.0, "Kd": 1.0}}, "gains.loop0"),
        ({"outer": {"Kp": 1.0}}, "gains"),
        ({"loop0": {"Kp": "nan", "Ki": 1.0}}, "gains.loop0.Kp"),
        ({"loop0": {"Kp": "abc", "Ki": 1.0}}, "gains.loop0.Kp"),
    ],
)
def test_verify_bad_gains_are_422_with_loc(client, gains, loc):
    r = client.post("/v1/verify", json={"spec": SPEC, "gains": gains})
    assert r.status_code == 422, r.text
    assert r.json()["errors"][0]["loc"] == loc


def test_verify_sync_limits(client):
    spec = {**SPEC, "verify": {"n_freq": 90000}}
    r = client.post("/v1/verify", json={"spec": spec, "gains": GOOD})
    assert r.status_code == 422 and r.json()["errors"][0]["loc"] == "spec.verify.n_freq"


def test_simulate_traces_decimated(client):
    spec = {**SPEC, "scenario": {"dt": 0.001, "horizon": 20.0}}
    r = client.post("/v1/simulate", json={"spec": spec, "gains": GOOD, "max_points": 500})
    assert r.status_code == 200, r.text
    sc = r.json()["scenarios"][0]
    assert sc["n_steps"] == 20000 and len(sc["t"]) <= 500 and sc["stride"] > 1
    assert set(sc["traces"]) == {"y.loop0", "sp.loop0", "u"}
    assert all(len(v) == len(sc["t"]) for v in sc["traces"].values())
    assert abs(sc["t"][-1] - 19.999) < 1e-9
    assert sc["metrics"]["iae"] > 0 and sc["metrics"]["diverged"] is False
    capped = client.post("/v1/simulate", json={"spec": spec, "gains": GOOD, "max_points": 100000}).json()
    assert len(capped["scenarios"][0]["t"]) <= 2000 and capped["max_points"] == 2000


def test_simulate_and_verify_a_spec_without_dt_use_the_plant_derived_scenario(client):
    # issue 25: a scenario without dt/horizon gets them from the plant (2e^{-10s}/(60s+1): 0.35 s, 700 s)
    spec = {"plant": {"tf": {"num": [2], "den": "60*s + 1"}, "delay": 10}, "loops": [{"type": "pi"}]}
    gains = {"loop0": {"Kp": 1.37, "Ki": 0.027}}
    r = client.post("/v1/simulate", json={"spec": spec, "gains": gains})
    assert r.status_code == 200, r.text
    sc = r.json()["scenarios"][0]
    assert (sc["dt"], sc["n_steps"]) == (0.35, 2000) and sc["metrics"]["sse"] < 1e-3
    r = client.post("/v1/verify", json={"spec": spec, "gains": gains})
    assert r.status_code == 200, r.text
    assert r.json()["dt"] == 0.35 and any("derived from the plant" in n for n in r.json()["notes"])


def test_simulate_unknown_scenario_is_422(client):
    r = client.post("/v1/simulate", json={"spec": SPEC, "gains": GOOD, "scenarios": ["nope"]})
    assert r.status_code == 422 and r.json()["errors"][0]["loc"] == "scenarios"


# ------------------------------------------------------------ plants, ops


def test_plants_listing_has_parameters_and_units(client):
    items = client.get("/v1/plants").json()["items"]
    motor = next(p for p in items if p["name"] == "dc_motor")
    assert motor["parameters"]["R"]["unit"] == "ohm" and motor["outputs"]["speed"]["unit"] == "rad/s"
    assert motor["order"] == 3 and motor["example_spec"]["loops"]
    assert client.get("/v1/plants/dc_motor").json()["title"] == motor["title"]
    assert client.get("/v1/plants/../etc").status_code == 404
    assert client.get("/v1/plants/nope").status_code == 404


def test_metrics_prometheus_text(client):
    submit(client)
    client.get("/v1/jobs")
    text = client.get("/metrics").text
    assert 'gaintune_jobs{state="queued"} 1' in text
    assert "gaintune_queue_depth 1" in text
    assert 'gaintune_http_request_duration_seconds_count{method="GET",route="/v1/jobs",status="200"} 1' in text
    assert "# TYPE gaintune_http_request_duration_seconds histogram" in text


def test_health_and_openapi(client):
    assert client.get("/healthz").json() == {"status": "ok"}
    assert client.get("/readyz").json()["status"] == "ready"
    schema = client.get("/openapi.json").json()
    assert "/v1/tune" in schema["paths"] and "TuningSpec" in schema["components"]["schemas"]


def test_compute_pool_matches_in_process_and_leaves_no_process(make_client, tmp_path):
    """verify/simulate in a warm worker process give the in-process answers; workers stop with the app."""
    import os

    local = make_client()
    (tmp_path / "pooled").mkdir()
    pooled_app = create_app(settings_for(tmp_path / "pooled", compute_processes=1))
    with TestClient(pooled_app, raise_server_exceptions=False) as pooled:
        pool = pooled.app.state.compute_pool
        assert pool is not None and pool.warm[0].result(timeout=120) != os.getpid()
        pids = pool.pids
        assert len(pids) == 1
        for g in (GOOD, BAD, {"loop0": {"Kp": 1.3, "Ki": 0.45}}):
            a = local.post("/v1/verify", json={"spec": SPEC, "gains": g}).json()
            b = pooled.post("/v1/verify", json={"spec": SPEC, "gains": g}).json()
            a.pop("elapsed_s"), b.pop("elapsed_s")
            assert a == b
        r = pooled.post("/v1/verify", json={"spec": SPEC, "gains": {"loop0": {"Kp": -1.0, "Ki": 0.4}}})
        assert r.status_code == 422 and r.json()["errors"][0]["loc"] == "gains.loop0.Kp"
        body = {"spec": SPEC, "gains": GOOD, "max_points": 50}
        assert local.post("/v1/simulate", json=body).json() == pooled.post("/v1/simulate", json=body).json()
    assert pooled.app.state.compute_pool is None
    for pid in pids:  # joined by the shutdown: gone, not even a zombie
        try:
            os.kill(pid, 0)
        except ProcessLookupError:
            continue
        raise AssertionError(f"compute worker {pid} still alive after shutdown")
