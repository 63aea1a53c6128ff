"""The compute pool inside a real uvicorn server on uvloop (what ``gaintune serve`` and uvicorn[standard] run).

uvloop's ``add_reader`` (libuv's ``uv_poll_init``) makes a watched descriptor non-blocking, so a pool
that read a large answer with blocking-style calls on it got ``BlockingIOError`` mid-message and
respawned the worker. These tests push large messages through the real server and read the pool's
counters from ``/metrics``.
"""

from __future__ import annotations

import os
import re
import signal
import socket
import subprocess
import sys
import time
from collections.abc import Iterator
from pathlib import Path

import httpx
import pytest

pytest.importorskip("uvloop")

REPO = Path(__file__).resolve().parents[2]
GAINS = {"loop0": {"Kp": 1.0, "Ki": 0.5}}


def _spec(n_scenarios: int, sequence_points: int = 0) -> dict:
    """1/(s+1)^3 with a PI; ``n_scenarios`` of 2,000 steps (a trace answer of about 100 KB each), each with a
    ``sequence_points``-point reference profile when given (a large request)."""
    scenarios = []
    for i in range(n_scenarios):
        sc: dict = {"name": f"s{i}", "dt": 0.01, "horizon": 20.0, "reference": {"kind": "step", "time": 0.1 * i}}
        if sequence_points:
            sc["reference"] = {"kind": "sequence",
                               "points": [[k * 0.004, 1.0 + 0.01 * i] for k in range(sequence_points)]}
        scenarios.append(sc)
    return {"plant": {"tf": {"num": [1], "den": "(s+1)^3"}}, "loops": [{"type": "pi"}], "scenarios": scenarios}


@pytest.fixture()
def uvloop_server(tmp_path: Path) -> Iterator[httpx.Client]:
    """``uvicorn gaintune_api.main:app --loop uvloop`` with one compute worker and no job workers."""
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    env = dict(os.environ, GAINTUNE_DB_PATH=str(tmp_path / "jobs.db"), GAINTUNE_DATA_DIR=str(tmp_path / "data"),
               GAINTUNE_WORKERS="0", GAINTUNE_COMPUTE_PROCESSES="1", GAINTUNE_WARMUP="false", PYTHONPATH=str(REPO))
    cmd = [sys.executable, "-m", "uvicorn", "gaintune_api.main:app", "--loop", "uvloop", "--host", "127.0.0.1",
           "--port", str(port), "--log-level", "warning"]
    log = open(tmp_path / "server.log", "w")
    proc = subprocess.Popen(cmd, cwd=tmp_path, env=env, stdout=log, stderr=subprocess.STDOUT)
    client = httpx.Client(base_url=f"http://127.0.0.1:{port}", timeout=300)
    try:
        deadline = time.monotonic() + 120  # a start-up guard only: nothing is asserted on time
        while True:
            assert proc.poll() is None, (tmp_path / "server.log").read_text()[-4000:]
            try:
                if client.get("/readyz").status_code == 200:
                    break
            except httpx.TransportError:
                pass
            assert time.monotonic() < deadline, "server not ready:\n" + (tmp_path / "server.log").read_text()[-4000:]
            time.sleep(0.2)
        yield client
    finally:
        client.close()
        proc.send_signal(signal.SIGTERM)
        try:
            proc.wait(30)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait()
        log.close()


def _counter(client: httpx.Client, name: str) -> float:
    text = client.get("/metrics").text
    m = re.search(rf"^{name} (\S+)$", text, re.M)
    assert m, f"{name} missing from /metrics"
    return float(m.group(1))


def test_large_simulate_answer_needs_no_pool_respawn(uvloop_server: httpx.Client):
    c = uvloop_server
    body = {"spec": _spec(16), "gains": GAINS}
    for _ in range(3):  # about 1.5 MB of traces per answer: far beyond a socket buffer
        r = c.post("/v1/simulate", json=body)
        assert r.status_code == 200, r.text
        assert len(r.json()["scenarios"]) == 16 and len(r.json()["scenarios"][15]["t"]) == 2000
    # a large request: 5,000-point reference profiles in 4 scenarios (the spec is sent once, then by hash)
    for kp in (1.0, 1.1):
        r = c.post("/v1/verify", json={"spec": _spec(4, sequence_points=5000),
                                       "gains": {"loop0": {"Kp": kp, "Ki": 0.5}}})
        assert r.status_code == 200, r.text
    assert _counter(c, "gaintune_compute_restarts_total") == 0
    assert _counter(c, "gaintune_compute_fallbacks_total") == 0
