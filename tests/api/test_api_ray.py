"""API jobs on Ray (``GAINTUNE_BACKEND=ray``): real servers whose job workers are Ray tasks on a local cluster.

The cluster is ``RAY_ADDRESS``'s when set, else one this module starts (``ray.init(address="local", num_cpus=2)``)
and the servers join. Jobs pause after their first progress report while the hold file exists
(``GAINTUNE_TEST_HOLD_FILE``), so each kill lands mid-job, provably.
"""

from __future__ import annotations

import os
import signal

import pytest
from test_api_server import TINY, Server, pid_gone

# the Ray tests run one at a time across the xdist workers: they share one 2-CPU cluster
pytestmark = pytest.mark.usefixtures("one_ray_test_at_a_time")

HOLD_JOB = {**TINY, "name": "on-ray", "search": {**TINY["search"], "budget": 300}}


@pytest.fixture(scope="module")
def ray_address():
    """The address of a Ray cluster for the servers to join. In CI its absence fails, never skips."""
    try:
        import ray
    except ImportError:
        if os.environ.get("CI"):
            pytest.fail("CI must run the Ray tests, but ray is not installed (pip install gaintune[ray])",
                        pytrace=False)
        pytest.skip("ray is not installed (pip install gaintune[ray])")
    if os.environ.get("RAY_ADDRESS"):
        yield os.environ["RAY_ADDRESS"]
        return
    ray.init(address="local", num_cpus=2, include_dashboard=False, log_to_driver=False)  # a new cluster of our own
    try:
        yield ray.get_runtime_context().gcs_address
    finally:
        ray.shutdown()


def _server(tmp_path, ray_address, hold) -> Server:
    srv = Server(tmp_path, GAINTUNE_BACKEND="ray", RAY_ADDRESS=ray_address, GAINTUNE_WORKERS="1",
                 GAINTUNE_RECOVER="requeue", GAINTUNE_TEST_HOLD_FILE=str(hold), GAINTUNE_COMPUTE_PROCESSES="0",
                 GAINTUNE_POLL_INTERVAL="0.1")
    srv.wait_ready(180)
    return srv


def test_killed_ray_worker_requeues_its_job_which_then_completes_once(tmp_path, ray_address):
    hold = tmp_path / "hold"
    hold.touch()
    srv = _server(tmp_path, ray_address, hold)
    try:
        job = srv.client.post("/v1/tune", json=HOLD_JOB).json()["id"]
        srv.wait_job(job, {"running"}, timeout=300, cond=lambda j: j["progress"] is not None)
        pid = srv.worker_pid(job)
        assert pid not in srv.worker_pids(), "the job ran in a local worker process, not in a Ray task"
        os.kill(pid, signal.SIGKILL)  # the Ray worker process running the job
        second = srv.wait_job(job, {"running"}, timeout=300,
                              cond=lambda j: j["attempts"] == 2 and j["progress"] is not None)
        assert "re-queued" not in (second["error"] or "")  # a running attempt has no error
        assert srv.worker_pid(job) != pid
        hold.unlink()
        done = srv.wait_job(job, {"succeeded", "failed"}, timeout=300)
        assert done["status"] == "succeeded" and done["attempts"] == 2, done
        assert srv.client.get(f"/v1/jobs/{job}/agent").status_code == 200
        assert srv.metric("gaintune_worker_restarts_total") >= 1  # the lost task was replaced
        # once: the killed attempt wrote nothing (its staging folder gone, no second final write)
        assert srv.sql("SELECT COUNT(*) FROM jobs")[0] == 1
    finally:
        srv.stop()


def test_ray_job_survives_a_server_kill_and_finishes_after_restart(tmp_path, ray_address):
    hold = tmp_path / "hold"
    hold.touch()
    srv = _server(tmp_path, ray_address, hold)
    try:
        job = srv.client.post("/v1/tune", json=HOLD_JOB).json()["id"]
        srv.wait_job(job, {"running"}, timeout=300, cond=lambda j: j["progress"] is not None)
        pid = srv.worker_pid(job)
    finally:
        srv.stop(signal.SIGKILL)
    assert pid_gone(pid, timeout=60), "the Ray worker outlived its server"  # Ray ends a dead driver's tasks
    hold.unlink()
    srv2 = _server(tmp_path, ray_address, hold)
    try:
        done = srv2.wait_job(job, {"succeeded", "failed"}, timeout=300)
        assert done["status"] == "succeeded" and done["attempts"] == 2, done
    finally:
        srv2.stop()
