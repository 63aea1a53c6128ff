"""The kill campaign, small and deterministic, on PostgreSQL: two real API servers on one store.

Two servers (one worker each) share a PostgreSQL database and a data folder. Jobs pause after their
first progress report while the hold file exists (``GAINTUNE_TEST_HOLD_FILE``), so every kill lands
mid-job, provably. A worker of one server and then the whole other server are SIGKILLed; the surviving
server re-queues the dead server's job without waiting for its restart; every Idempotency-Key is replayed
through the restarted server; every job then succeeds exactly once, its agent matching its digest.
(The full campaign, 40 jobs with 10 worker and 2 server kills: ``gaintune bench chaos --db-url URL``.)
"""

from __future__ import annotations

import hashlib
import os
import signal
from base64 import b64encode

import pytest
from test_api_server import TINY, Server, pid_gone

KEYS = [f"pg-{i}" for i in range(4)]


def _spec(i: int) -> dict:
    return {**TINY, "name": f"pg-{i}", "search": {**TINY["search"], "seed": i + 1}}


def _worker_pid(pg_url: str, job_id: str) -> int:
    import psycopg

    with psycopg.connect(pg_url) as c:
        return c.execute("SELECT worker_pid FROM jobs WHERE id=%s", (job_id,)).fetchone()[0]


def _running(srv: Server, ids: list[str]) -> list[dict]:
    jobs = [srv.client.get(f"/v1/jobs/{i}").json() for i in ids]
    return [j for j in jobs if j["status"] == "running" and j["progress"] is not None]


@pytest.fixture
def two_servers(tmp_path, pg_url):
    hold = tmp_path / "hold"
    hold.touch()
    env = dict(GAINTUNE_DB_URL=pg_url, GAINTUNE_DATA_DIR=str(tmp_path / "data"), GAINTUNE_WORKERS="1",
               GAINTUNE_MAX_ATTEMPTS="5", GAINTUNE_RECOVER="requeue", GAINTUNE_TEST_HOLD_FILE=str(hold),
               GAINTUNE_COMPUTE_PROCESSES="0", GAINTUNE_POLL_INTERVAL="0.1")
    made: list[Server] = []

    def start(i: int) -> Server:
        folder = tmp_path / f"server-{i}"
        folder.mkdir(exist_ok=True)
        srv = Server(folder, **env)
        made.append(srv)
        srv.wait_ready(180)
        return srv

    yield start, hold
    for srv in made:
        srv.stop(signal.SIGKILL)


def test_two_servers_on_one_postgresql_store_lose_and_duplicate_nothing_under_kills(two_servers, pg_url):
    start, hold = two_servers
    a, b = start(0), start(1)
    ids = [(a if i % 2 else b).client.post("/v1/tune", json=_spec(i), headers={"Idempotency-Key": k}).json()["id"]
           for i, k in enumerate(KEYS)]
    busy = a.wait(lambda: (lambda r: r if len(r) == 2 else None)(_running(a, ids)), 300, "both workers mid-job")
    by_server = {_worker_pid(pg_url, j["id"]): j["id"] for j in busy}
    a_job = next(job for pid, job in by_server.items() if pid in a.worker_pids())
    b_job = next(job for pid, job in by_server.items() if pid in b.worker_pids())

    os.kill(_worker_pid(pg_url, a_job), signal.SIGKILL)  # a worker of server A, mid-job
    a.wait(lambda: a.metric("gaintune_worker_restarts_total") == 1, 60, "server A to restart its worker")

    b_worker = _worker_pid(pg_url, b_job)
    b.stop(signal.SIGKILL)  # the whole of server B, mid-job: its worker dies with it
    assert pid_gone(b_worker), "server B's worker outlived it"
    # Server A re-queues B's job at once (the dead pid is on its host) and its worker runs it again.
    a.wait_job(b_job, {"running", "queued"}, timeout=60,
               cond=lambda j: "re-queued" in (j["error"] or "") or j["attempts"] == 2)

    b = start(1)
    for i, k in enumerate(KEYS):  # clients replay through the restarted server: the same jobs, none new
        r = b.client.post("/v1/tune", json=_spec(i), headers={"Idempotency-Key": k})
        assert r.json()["id"] == ids[i]
    hold.unlink()
    for srv, job_id in zip([a, b] * 2, ids, strict=True):
        j = srv.wait_job(job_id, {"succeeded", "failed", "cancelled"}, timeout=300)
        assert j["status"] == "succeeded", j
        assert j["result"]["provenance"]["spec_hash"] == j["spec_hash"]
        other = b if srv is a else a  # the files are on the shared data folder: either server serves them
        r = other.client.get(f"/v1/jobs/{job_id}/agent")
        digest = b64encode(hashlib.sha256(r.content).digest()).decode()
        assert r.status_code == 200 and r.headers["repr-digest"] == f"sha-256=:{digest}:"
    assert a.client.get("/v1/jobs").json()["total"] == len(KEYS)
    attempts = {i: a.client.get(f"/v1/jobs/{i}").json()["attempts"] for i in ids}
    assert attempts[a_job] == 2 and attempts[b_job] == 2, attempts  # each killed attempt ran again, once
