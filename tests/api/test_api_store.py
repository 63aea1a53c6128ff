"""The job store's contract, on SQLite and on PostgreSQL (a real server: see conftest.pg_server).

Every test taking ``store`` (or ``db_settings``) runs once per backend: the same leases, fencing tokens,
idempotency, cancel and recovery rules on both. The PostgreSQL-only tests pin what row locks change:
concurrent claims from several stores (servers) and a frozen transaction that holds a job's row.
"""

from __future__ import annotations

import threading
import time

import pytest
from fastapi.testclient import TestClient
from test_api_routes import SPEC, make_fake_tune, settings_for, submit

from gaintune_api.job_rows import HOST
from gaintune_api.main import create_app
from gaintune_api.settings import Settings
from gaintune_api.storage_faults import StorageFault
from gaintune_api.stores import open_store
from gaintune_api.supervisor import Supervisor
from gaintune_api.worker import process_next

DEAD_PID = 2**22 + 12345  # no such process


@pytest.fixture
def settings(tmp_path, db_settings) -> Settings:
    return settings_for(tmp_path, **db_settings)


@pytest.fixture
def store(settings):
    s = open_store(settings)
    s.init()
    yield s
    if hasattr(s, "close"):
        s.close()


def _queue(store, n: int = 1, **kw) -> list[str]:
    return [store.create("alice", '{"x": 1}', "h", f"job{i}", idem_key=None, max_queue=100, **kw)[0].id
            for i in range(n)]


def test_create_is_idempotent_per_key_and_bounded_by_max_queue(store):
    a, created = store.create("alice", "{}", "h1", "a", idem_key="k", max_queue=2)
    again, created2 = store.create("alice", "{}", "h1", "a", idem_key="k", max_queue=2)
    assert created and not created2 and again.id == a.id
    with pytest.raises(Exception) as conflict:
        store.create("alice", "{}", "other-hash", "a", idem_key="k", max_queue=2)
    assert type(conflict.value).__name__ == "IdempotencyConflict"
    store.create("bob", "{}", "h1", "b", idem_key="k", max_queue=2)  # keys are per owner
    with pytest.raises(Exception) as full:
        store.create("alice", "{}", "h1", "c", idem_key=None, max_queue=2)
    assert type(full.value).__name__ == "QueueFull"


def test_claim_takes_the_oldest_job_and_records_pid_and_host(store):
    first, second = _queue(store, 2)
    job = store.claim(4242, host="node-7")
    assert job.id == first and job.status == "running" and job.attempts == 1
    assert job.worker_pid == 4242 and job.worker_host == "node-7" and job.claim
    assert store.claim(4243).id == second
    assert store.claim(4244) is None


def test_recovered_job_refuses_every_write_of_the_old_claim(store):
    (job_id,) = _queue(store)
    old = store.claim(DEAD_PID).claim
    assert store.recover([job_id], "requeue", "test", 3) == [(job_id, "queued", "re-queued: test")]
    assert store.heartbeat(job_id, old, {"sims": 1}) == (False, True)
    assert not store.owns(job_id, old)
    promoted = []
    assert store.finish(job_id, old, "succeeded", result={"x": 1}, promote=lambda: promoted.append(1)) is None
    assert not promoted and store.get(job_id).status == "queued"
    new = store.claim(DEAD_PID)
    assert new.attempts == 2 and new.claim != old
    assert store.finish(job_id, new.claim, "succeeded", result={"x": 2}, promote=lambda: {"agent": "a"}) == "succeeded"
    row = store.get(job_id)
    assert row.status == "succeeded" and row.result == '{"x":2}' and row.artifacts == '{"agent":"a"}'


def test_cancel_accepted_while_running_ends_cancelled_whatever_the_attempt_writes(store):
    (job_id,) = _queue(store)
    job = store.claim(DEAD_PID)
    row, accepted = store.request_cancel(job_id, "alice")
    assert accepted and row.status == "running" and row.cancel_requested_at is not None
    assert store.heartbeat(job_id, job.claim, None) == (True, True)
    assert store.finish(job_id, job.claim, "succeeded", result={"x": 1}) == "cancelled"
    assert store.request_cancel(job_id, "alice")[1] is False  # already finished
    assert store.request_cancel(job_id, "mallory") == (None, False)


@pytest.mark.parametrize("policy,attempts,expected", [("requeue", 3, "queued"), ("fail", 3, "failed"),
                                                      ("requeue", 1, "failed")])
def test_recovery_policy_and_attempt_limit(store, policy, attempts, expected):
    (job_id,) = _queue(store)
    store.claim(DEAD_PID)
    [(got_id, status, error)] = store.recover([job_id], policy, "worker died", attempts)
    assert got_id == job_id and status == expected and store.get(job_id).status == expected
    assert store.recover([job_id], policy, "again", attempts) == []  # no longer running: untouched


def test_concurrent_claims_from_several_stores_never_take_a_job_twice(settings):
    """Several servers (one store object each) and threads claim at once: every job exactly once."""
    stores = [open_store(settings) for _ in range(3)]
    stores[0].init()
    ids = set(_queue(stores[0], 30))
    got: list[str] = []
    mu = threading.Lock()
    errors: list[BaseException] = []

    def claimer(st) -> None:
        while True:
            try:
                job = st.claim(DEAD_PID)
            except StorageFault:  # SQLite: the write lock was busy past its write timeout; try again
                continue
            except BaseException as exc:  # noqa: BLE001 - reported below
                errors.append(exc)
                return
            if job is None:
                return
            with mu:
                got.append(job.id)

    threads = [threading.Thread(target=claimer, args=(stores[i % 3],)) for i in range(6)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    assert not errors
    assert sorted(got) == sorted(ids)


def test_supervisor_checks_a_worker_pid_only_on_its_own_host(store, settings):
    """A pid recorded by another machine says nothing here: only the lease recovers that job."""
    here, there = _queue(store, 2)
    store.claim(DEAD_PID, host=HOST)
    store.claim(DEAD_PID, host="another-host")
    assert Supervisor(settings, store).recover("its worker process died") == [here]
    assert store.get(there).status == "running"


def test_job_lifecycle_through_the_api_on_each_store(tmp_path, db_settings):
    with TestClient(create_app(settings_for(tmp_path, **db_settings))) as client:
        job = submit(client, SPEC, **{"Idempotency-Key": "once"})
        assert submit(client, SPEC, **{"Idempotency-Key": "once"})["id"] == job["id"]
        app = client.app
        assert process_next(app.state.store, app.state.settings, make_fake_tune()) == "succeeded"
        got = client.get(f"/v1/jobs/{job['id']}").json()
        assert got["status"] == "succeeded" and got["result"]["cost"] == 1.5
        assert client.get(f"/v1/jobs/{job['id']}/agent").status_code == 200
        assert client.get("/readyz").status_code == 200


# ------------------------------------------------------------------ PostgreSQL only


def test_db_url_that_is_not_postgresql_is_refused_naming_the_setting():
    with pytest.raises(ValueError, match="db_url must be a PostgreSQL URL"):
        Settings(_env_file=None, db_url="mysql://x@h/db")


def test_unreachable_postgresql_is_a_named_storage_fault_not_a_crash(tmp_path):
    pytest.importorskip("psycopg")
    from gaintune_api.job_store_pg import PgJobStore

    store = PgJobStore("postgresql://nobody:secret@127.0.0.1:1/none", write_timeout=0.2)
    with pytest.raises(StorageFault) as fault:
        store.ping()
    assert fault.value.cause == "database-unavailable"
    assert "secret" not in repr(store)
    store.close()


def _session_gone(pg_url: str, pid: int) -> bool:
    import psycopg

    with psycopg.connect(pg_url, autocommit=True) as c:
        return c.execute("SELECT COUNT(*) FROM pg_stat_activity WHERE pid=%s", (pid,)).fetchone()[0] == 0


def test_frozen_transaction_holding_a_job_row_blocks_no_other_job_and_is_closed_by_the_server(pg_url, tmp_path):
    """A worker frozen mid-write holds one job's row lock: the rest of the store goes on, writes to that row
    are refused at once (not queued), and the server closes the frozen session after db_idle_timeout, which
    frees the row. On SQLite the same freeze holds the whole file's write lock until the holder is killed."""
    import psycopg

    from gaintune_api.job_store_pg import PgJobStore

    store = PgJobStore(pg_url, write_timeout=0.3, idle_timeout=1.0)
    store.init()
    held, other = _queue(store, 2)
    job = store.claim(DEAD_PID)
    assert job.id == held
    frozen = psycopg.connect(pg_url, autocommit=True)
    store._configure(frozen)  # the same session limits every store connection has
    frozen_pid = frozen.info.backend_pid
    frozen.execute("BEGIN")
    frozen.execute("SELECT 1 FROM jobs WHERE id=%s FOR UPDATE", (held,))  # ...and the process freezes here
    try:
        more = _queue(store, 1)
        other_job = store.claim(DEAD_PID)
        assert other_job.id == other  # SKIP LOCKED: the claim does not wait for the held row
        assert store.heartbeat(other, other_job.claim, {"sims": 3}) == (True, False)
        assert store.finish(other, other_job.claim, "succeeded", result={"x": 1}) == "succeeded"
        assert store.counts()["queued"] == len(more) and store.get(held).status == "running"  # reads never wait
        assert store.recover([held], "requeue", "lease", 3) == []  # skipped while held; the next pass retries
        with pytest.raises(StorageFault) as refused:
            store.heartbeat(held, job.claim, None)
        assert refused.value.cause == "database-locked"
        deadline = time.monotonic() + 120  # a generous bound on an observable condition, not a timing claim
        while not _session_gone(pg_url, frozen_pid):
            assert time.monotonic() < deadline, "the server never closed the frozen session"
            time.sleep(0.1)
        assert store.heartbeat(held, job.claim, None) == (True, False)
        assert store.recover([held], "requeue", "lease", 3)[0][1] == "queued"
    finally:
        frozen.close()
        store.close()


@pytest.mark.parametrize("setting,module,extra", [({"db_url": "postgresql://h/db"}, "psycopg_pool", "postgres"),
                                                  ({"backend": "ray"}, "ray", "ray")])
def test_backend_without_its_extra_is_refused_naming_the_extra(monkeypatch, setting, module, extra):
    import importlib.util

    from gaintune_api.stores import missing_extra

    real = importlib.util.find_spec
    monkeypatch.setattr(importlib.util, "find_spec", lambda name, *a: None if name == module else real(name, *a))
    msg = missing_extra(Settings(_env_file=None, **setting))
    assert msg is not None and f"gaintune[{extra}]" in msg
    assert missing_extra(Settings(_env_file=None)) is None


def test_sqlite_database_written_before_hosts_gains_the_worker_host_column(tmp_path):
    import sqlite3

    from gaintune_api.job_store import JobStore

    old = sqlite3.connect(tmp_path / "old.db")
    old.executescript("CREATE TABLE jobs (seq INTEGER PRIMARY KEY AUTOINCREMENT, id TEXT NOT NULL UNIQUE, owner TEXT "
                      "NOT NULL, idem_key TEXT, status TEXT NOT NULL, spec TEXT NOT NULL, spec_hash TEXT NOT NULL, "
                      "spec_name TEXT NOT NULL, created_at REAL NOT NULL, updated_at REAL NOT NULL, started_at REAL, "
                      "finished_at REAL, progress TEXT, result TEXT, error TEXT, cancel_requested_at REAL, claim TEXT,"
                      " worker_pid INTEGER, heartbeat_at REAL, attempts INTEGER NOT NULL DEFAULT 0, artifacts TEXT,"
                      " kind TEXT NOT NULL DEFAULT 'tune');")
    old.close()
    store = JobStore(tmp_path / "old.db")
    store.init()
    (job_id,) = _queue(store)
    assert store.claim(DEAD_PID).worker_host == HOST

