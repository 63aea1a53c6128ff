"""Issue 14 in-process: fencing of stale attempts, named storage faults, leases across a database outage,
settings warnings, docs auth and honest recovery logs. Real-server chaos tests: test_api_chaos.py.

Storage faults are injected with the tests-only ``test_storage_fault_file`` (gaintune_api.storage_faults.FaultInjector):
deterministic, and effective as root, where ``chmod`` does not make anything read-only.
"""

from __future__ import annotations

import asyncio
import hashlib
import logging
import sqlite3
import threading
import time
import zipfile
from pathlib import Path

import pytest
from fastapi.testclient import TestClient
from test_api_routes import GOOD, SPEC, make_fake_tune, settings_for

from gaintune_api.job_store import JobStore, loads
from gaintune_api.jobfiles import JobFiles
from gaintune_api.main import create_app
from gaintune_api.settings import unknown_settings
from gaintune_api.storage_faults import FaultInjector, StorageFault, classify
from gaintune_api.supervisor import Supervisor
from gaintune_api.worker import process_next, run_job


def wait_until(cond, timeout: float = 30.0, what: str = "condition"):
    """Poll ``cond`` (bounded); return its first truthy value."""
    t0 = time.monotonic()
    while time.monotonic() - t0 < timeout:
        v = cond()
        if v:
            return v
        time.sleep(0.02)
    raise AssertionError(f"timed out waiting for {what}")


@pytest.fixture
def faulty(tmp_path):
    """(client, fault_file): an in-process app whose storage faults the test switches on by writing words."""
    fault = tmp_path / "faults"
    app = create_app(settings_for(tmp_path, test_storage_fault_file=fault))
    with TestClient(app, raise_server_exceptions=False) as c:
        yield c, fault


def _submit(c: TestClient, spec=SPEC) -> str:
    r = c.post("/v1/tune", json=spec)
    assert r.status_code == 202, r.text
    return r.json()["id"]


def _zip(path: Path, text: str) -> None:
    with zipfile.ZipFile(path, "w") as z:
        z.writestr("policy.txt", text)


# ------------------------------------------------------------------ fencing (defect 1)


def test_stale_attempt_overwrote_finished_job_artifacts_is_fenced(tmp_path):
    """Attempt 1 is recovered (its worker froze), attempt 2 finishes; attempt 1's late commit changes nothing."""
    s = settings_for(tmp_path)
    store, files = JobStore(s.db_path), JobFiles(s.jobs_dir)
    store.init()
    row, _ = store.create("anonymous", '{"plant": {"tf": {"num": [1], "den": [1, 1]}}, "loops": [{"type": "p"}]}',
                          "h", "x", idem_key=None, max_queue=10)
    a1 = store.claim(111)
    stage1 = files.stage(row.id, a1.attempts, a1.claim)
    _zip(stage1 / "agent.zip", "attempt 1")
    assert store.recover([row.id], "requeue", "lease expired", 3)[0][1] == "queued"
    a2 = store.claim(222)
    assert a2.attempts == 2 and a2.claim != a1.claim
    stage2 = files.stage(row.id, a2.attempts, a2.claim)
    _zip(stage2 / "agent.zip", "attempt 2")
    final = str(files.job_dir(row.id) / "agent.zip")
    assert store.finish(row.id, a2.claim, "succeeded", result={"agent_path": final},
                        promote=files.promoter(row.id, stage2, a2.attempts, a2.claim))
    before = (files.job_dir(row.id) / "agent.zip").read_bytes()
    # the frozen attempt resumes: its heartbeat, progress and commit (with its files) are all refused
    assert store.heartbeat(row.id, a1.claim, {"sims": 5}) == (False, True)
    assert not store.finish(row.id, a1.claim, "succeeded", result={"agent_path": final, "stale": True},
                            promote=files.promoter(row.id, stage1, a1.attempts, a1.claim))
    assert (files.job_dir(row.id) / "agent.zip").read_bytes() == before
    done = store.get(row.id)
    assert loads(done.result) == {"agent_path": final} and done.status == "succeeded"
    manifest = loads(done.artifacts)
    assert manifest["attempt"] == 2
    assert manifest["files"]["agent.zip"]["sha256"] == hashlib.sha256(before).hexdigest()


def test_stale_worker_resuming_mid_search_writes_nothing(faulty):
    """Through the worker: while attempt 1 is 'frozen' inside its search, the job is recovered and finished by
    attempt 2; when attempt 1 resumes, it stops (lost claim) and neither its row nor its agent lands."""
    c, _ = faulty
    app = c.app
    store, settings, files = app.state.store, app.state.settings, app.state.files
    job_id = _submit(c)
    stale = store.claim(111)
    frozen = threading.Event()
    resume = threading.Event()

    def frozen_tune(spec, *, progress=None, out_dir=None, cancel=None, **kw):
        frozen.set()
        resume.wait(30)  # "SIGSTOP": meanwhile the job is recovered and finished elsewhere
        return make_fake_tune()(spec, progress=progress, out_dir=out_dir, cancel=cancel, **kw)

    out: dict = {}
    th = threading.Thread(target=lambda: out.setdefault("status", run_job(store, stale, settings, frozen_tune,
                                                                          hard_exit=False)))
    th.start()
    wait_until(frozen.is_set, what="attempt 1 inside its search")
    assert store.recover([job_id], "requeue", "lease expired", 3)
    assert process_next(store, settings, make_fake_tune()) == "succeeded"
    agent = c.get(f"/v1/jobs/{job_id}/agent")
    assert agent.status_code == 200
    resume.set()
    th.join(30)
    assert out["status"] == "lost"
    again = c.get(f"/v1/jobs/{job_id}/agent")
    assert again.content == agent.content and again.headers["repr-digest"] == agent.headers["repr-digest"]
    j = c.get(f"/v1/jobs/{job_id}").json()
    assert j["status"] == "succeeded" and j["attempts"] == 2
    assert not list((files.job_dir(job_id) / ".attempts").glob("1-*"))  # the stale staging folder is discarded


def test_agent_file_tampered_is_500_mismatch_and_deleted_is_410_gone(client_and_job):
    c, job_id, path = client_and_job
    ok = c.get(f"/v1/jobs/{job_id}/agent")
    digest = hashlib.sha256(ok.content).hexdigest()
    assert ok.status_code == 200 and ok.headers["etag"] == f'"{digest}"'
    path.write_bytes(b"PK tampered")
    bad = c.get(f"/v1/jobs/{job_id}/agent")
    assert bad.status_code == 500 and bad.json()["cause"] == "artifact-mismatch"
    path.unlink()
    gone = c.get(f"/v1/jobs/{job_id}/agent")
    assert gone.status_code == 410, gone.text
    assert "gone" in gone.json()["detail"] and gone.headers["content-type"] == "application/problem+json"


@pytest.fixture
def client_and_job(tmp_path):
    app = create_app(settings_for(tmp_path))
    with TestClient(app, raise_server_exceptions=False) as c:
        job_id = _submit(c)
        assert process_next(app.state.store, app.state.settings, make_fake_tune()) == "succeeded"
        yield c, job_id, app.state.files.job_dir(job_id) / "agent.zip"


# ------------------------------------------------------------- storage faults (2, 4)


@pytest.mark.parametrize("fault,cause", [("data:readonly", "data directory is read-only"),
                                         ("data:full", "data directory is full")])
def test_read_only_or_full_data_dir_fails_the_job_once_naming_the_cause(faulty, fault, cause):
    c, faults = faulty
    job_id = _submit(c)
    faults.write_text(fault)
    app = c.app
    assert process_next(app.state.store, app.state.settings, make_fake_tune()) == "failed"
    j = c.get(f"/v1/jobs/{job_id}").json()
    assert j["status"] == "failed" and j["attempts"] == 1
    assert cause in j["error"] and "storage fault" in j["error"] and "worker process died" not in j["error"]
    assert process_next(app.state.store, app.state.settings, make_fake_tune()) is None  # failed once: not re-queued


def test_disk_full_during_search_fails_job_naming_the_cause(faulty):
    c, _ = faulty
    job_id = _submit(c)

    def full_tune(spec, **kw):
        raise OSError(28, "No space left on device", "/data/jobs/x/agent.zip")

    app = c.app
    assert process_next(app.state.store, app.state.settings, full_tune) == "failed"
    err = c.get(f"/v1/jobs/{job_id}").json()["error"]
    assert "data directory is full" in err and "ENOSPC" in err


@pytest.mark.parametrize("fault,status,cause", [("db:readonly", 503, "database-read-only"),
                                                ("db:full", 507, "database-full")])
def test_storage_fault_is_answered_503_or_507_naming_the_cause(faulty, fault, status, cause):
    c, faults = faulty
    job_id = _submit(c)
    faults.write_text(fault)
    for r in (c.post("/v1/tune", json=SPEC), c.delete(f"/v1/jobs/{job_id}")):
        assert r.status_code == status, r.text
        body = r.json()
        assert body["cause"] == cause and body["type"].endswith("/storage-fault")
        assert r.headers["retry-after"] == "30" and r.headers["content-type"] == "application/problem+json"
        assert "job database" in body["detail"]
    assert c.get(f"/v1/jobs/{job_id}").status_code == 200  # reads still work
    ready = c.get("/readyz")
    assert ready.status_code == 503 and ready.json()["database_writable"] is False
    assert any(cause in reason for reason in ready.json()["reasons"])
    faults.unlink()
    assert c.get("/readyz").status_code == 200
    assert c.post("/v1/tune", json=SPEC).status_code == 202


@pytest.mark.parametrize("fault,cause", [("db:readonly", "database-read-only"), ("db:full", "database-full"),
                                         ("data:readonly", "data-dir-read-only"), ("data:full", "data-dir-full")])
def test_readyz_is_not_ready_on_read_only_or_full_storage(faulty, fault, cause):
    c, faults = faulty
    assert c.get("/readyz").status_code == 200
    faults.write_text(fault)
    r = c.get("/readyz")
    body = r.json()
    assert r.status_code == 503 and body["status"] == "not_ready" and "retry-after" in r.headers
    assert body["database"] is True  # readable: the write probe is what fails
    assert (body["database_writable"], body["data_dir_writable"]) == ((False, True) if fault.startswith("db")
                                                                       else (True, False))
    assert [x.split(":")[0] for x in body["reasons"]] == [cause]


@pytest.mark.parametrize("fault", ["data:readonly", "data:full"])
def test_report_on_full_or_read_only_disk_is_rendered_uncached_not_500(client_and_job, tmp_path, fault):
    c, job_id, _ = client_and_job
    c.app.state.files.faults = FaultInjector(tmp_path / "faults")
    (tmp_path / "faults").write_text(fault)
    r = c.get(f"/v1/jobs/{job_id}/report")
    assert r.status_code == 200 and "<html" in r.text.lower()
    assert r.headers["x-report-cache"].startswith("off (data-dir-")
    ready = c.get("/readyz").json()
    assert ready["data_dir_writable"] is False and ready["status"] == "not_ready"
    (tmp_path / "faults").unlink()
    assert "x-report-cache" not in c.get(f"/v1/jobs/{job_id}/report").headers  # cached once the disk is back


def test_real_sqlite_and_os_errors_are_classified(tmp_path):
    db = tmp_path / "x.db"
    sqlite3.connect(db).execute("CREATE TABLE t (a)").connection.close()
    ro = sqlite3.connect(f"file:{db}?mode=ro", uri=True)
    with pytest.raises(sqlite3.OperationalError) as exc:
        ro.execute("INSERT INTO t VALUES (1)")
    f = classify(exc.value)
    assert f is not None
    assert (f.where, f.kind, f.status, f.cause) == ("database", "read-only", 503, "database-read-only")
    full = classify(OSError(28, "No space left on device", "/d/agent.zip"))
    assert (full.cause, full.status) == ("data-dir-full", 507) and "ENOSPC" in full.detail
    assert classify(ValueError("x")) is None and classify(OSError(2, "No such file")) is None


# ---------------------------------------------------- database outage (defect 5)


def test_db_outage_recomputed_finished_work_and_stopped_restarts(tmp_path, caplog):
    """A result finished while the database is read-only is kept and written afterwards (attempt 1, not
    recomputed); the outage does not count against the lease; a failing tick still restarts workers."""
    faults = tmp_path / "faults"
    s = settings_for(tmp_path, test_storage_fault_file=faults, heartbeat_timeout=1.0, poll_interval=0.02)
    store = JobStore(s.db_path, FaultInjector(faults))
    store.init()
    row, _ = store.create("anonymous", _spec_json(), "h", "lag3", idem_key=None, max_queue=9)
    job = store.claim(__import__("os").getpid())
    inner = make_fake_tune()

    def tune_then_outage(spec, **kw):
        res = inner(spec, **kw)
        faults.write_text("db:readonly")  # the disk goes read-only just as the search ends
        return res

    out: dict = {}
    caplog.set_level(logging.WARNING, logger="gaintune.worker")
    th = threading.Thread(target=lambda: out.setdefault("s", run_job(store, job, s, tune_then_outage, hard_exit=False)))
    th.start()
    wait_until(lambda: any("result kept" in r.getMessage() for r in caplog.records), what="the result to be kept")
    sup = Supervisor(s, store)

    class Dead:  # a worker process that died during the outage
        pid, exitcode = 999999, -9

        def is_alive(self):
            return False

        def join(self, t=None):
            pass

    spawned = []
    sup.procs, sup.pulses = [Dead()], [None]
    sup._spawn = spawned.append
    asyncio.run(sup.tick())  # the job checks fail (read-only database) ...
    assert spawned == [0]  # ... and the dead worker is restarted all the same
    with sqlite3.connect(s.db_path) as db:  # the heartbeat is older than the lease ...
        db.execute("UPDATE jobs SET heartbeat_at=? WHERE id=?", (time.time() - 60, row.id))
    faults.unlink()
    sup.check_jobs()  # ... but the outage just ended: the lease restarts now, the job is not recovered
    th.join(30)
    assert out["s"] == "succeeded"
    done = store.get(row.id)
    assert done.status == "succeeded" and done.attempts == 1 and loads(done.result)["gains"] == GOOD


def _spec_json() -> str:
    from gaintune.spec import TuningSpec

    return TuningSpec.model_validate(SPEC).model_dump_json()


def test_expired_lease_is_recovered_once_the_database_is_back(tmp_path):
    s = settings_for(tmp_path, heartbeat_timeout=1.0)
    store = JobStore(s.db_path)
    store.init()
    row, _ = store.create("anonymous", _spec_json(), "h", "x", idem_key=None, max_queue=9)
    store.claim(__import__("os").getpid())  # a live pid: only the lease can expire
    with sqlite3.connect(s.db_path) as db:
        db.execute("UPDATE jobs SET heartbeat_at=? WHERE id=?", (time.time() - 60, row.id))
    sup = Supervisor(s, store)
    sup.db_ok_since = time.time()
    sup.check_jobs()
    assert store.get(row.id).status == "running"  # the database just became writable: lease counted from now
    sup.db_ok_since = time.time() - 5
    sup.check_jobs()
    got = store.get(row.id)
    assert got.status == "queued" and "lease expired" in got.error


# ----------------------------------------------------------------- lower severity (7)


def test_misspelt_setting_is_warned_with_the_likely_name(monkeypatch, tmp_path, caplog):
    msgs = unknown_settings({"GAINTUNE_DB": "x.db", "GAINTUNE_WORKERS": "2", "GAINTUNE_CHROMIUM": "/x",
                             "GAINTUNE_HEARTBEAT_TIMOUT": "3"}, None)
    assert msgs == ["unknown setting GAINTUNE_DB is ignored; did you mean GAINTUNE_DB_PATH?",
                    "unknown setting GAINTUNE_HEARTBEAT_TIMOUT is ignored; did you mean GAINTUNE_HEARTBEAT_TIMEOUT?"]
    env = tmp_path / ".env"
    env.write_text("# comment\nGAINTUNE_WORKER=2\nOTHER=1\n")
    assert unknown_settings({}, env) == [f"unknown setting GAINTUNE_WORKER (in {env}) is ignored; "
                                         "did you mean GAINTUNE_WORKERS?"]
    monkeypatch.setenv("GAINTUNE_DB", "x.db")
    caplog.set_level(logging.WARNING)
    with TestClient(create_app(settings_for(tmp_path))):
        pass
    assert any("GAINTUNE_DB is ignored; did you mean GAINTUNE_DB_PATH?" in r.getMessage() for r in caplog.records)


@pytest.mark.parametrize("public", [False, True])
def test_openapi_and_docs_need_a_key_when_api_keys_set_unless_docs_public(tmp_path, public):
    app = create_app(settings_for(tmp_path, api_keys=["k1"], docs_public=public))
    with TestClient(app) as c:
        for path in ("/openapi.json", "/docs", "/redoc", "/docs/oauth2-redirect"):
            r = c.get(path)
            assert r.status_code == (200 if public else 401), path
            assert c.get(path, headers={"X-API-Key": "k1"}).status_code == 200, path
        if not public:
            assert c.get("/openapi.json", headers={"X-API-Key": "nope"}).status_code == 401
        assert c.get("/healthz").status_code == 200 and c.get("/readyz").status_code == 200
    with TestClient(create_app(settings_for(tmp_path / "open"))) as c:  # no keys: docs always open
        assert c.get("/openapi.json").status_code == 200


def test_recovery_log_says_failed_not_requeue_after_the_last_attempt(tmp_path, caplog):
    s = settings_for(tmp_path, recover="requeue", max_attempts=1)
    store = JobStore(s.db_path)
    store.init()
    row, _ = store.create("anonymous", _spec_json(), "h", "x", idem_key=None, max_queue=9)
    store.claim(2**22 + 12345)  # no such process
    caplog.set_level(logging.WARNING, logger="gaintune.supervisor")
    assert Supervisor(s, store).recover("its worker process died") == [row.id]
    msgs = [r.getMessage() for r in caplog.records]
    assert any(f"recovered job {row.id}: failed" in m and "gave up after 1 attempt" in m for m in msgs), msgs
    assert not any("re-queue" in m or "requeue" in m for m in msgs), msgs


def test_injected_faults_leave_reads_alone(tmp_path):
    faults = tmp_path / "f"
    store = JobStore(tmp_path / "j.db", FaultInjector(faults))
    store.init()
    faults.write_text("db:readonly, data:full")
    with pytest.raises(StorageFault) as exc:
        store.create("a", _spec_json(), "h", "x", idem_key=None, max_queue=9)
    assert exc.value.cause == "database-read-only"
    assert store.counts()["queued"] == 0
    files = JobFiles(tmp_path / "jobs", FaultInjector(faults))
    with pytest.raises(StorageFault) as exc:
        files.probe()
    assert exc.value.cause == "data-dir-full"
