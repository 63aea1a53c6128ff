"""Phases 4 and 5 of the chaos benchmark (:mod:`gaintune.bench.chaos`): storage faults and reused connections.

4. storage: each storage fault (``GAINTUNE_TEST_STORAGE_FAULT_FILE``), every endpoint: every 5xx must name its
   cause; /readyz must be 503.
5. connections: after each error (a genuine 500 from a row corrupted with ``sqlite3``, 503, 507, 404, 409,
   422) the next request goes on the same keep-alive socket and must succeed (or the error carried
   ``Connection: close``).
"""

from __future__ import annotations

import json
import socket
import sqlite3
from collections.abc import Callable
from pathlib import Path
from typing import Any

from gaintune.bench.chaos_procs import Server, _serving, _wait, job_spec

__all__ = ["storage_and_connections", "storage", "connections"]


def storage_and_connections(root: Path, budget: int, log: Callable) -> tuple[dict, dict]:
    """Phases 4 and 5 on one server (with both tests-only hooks)."""
    hold, faults = root / "hold", root / "faults"
    with _serving(root, 1, GAINTUNE_TEST_HOLD_FILE=str(hold), GAINTUNE_TEST_STORAGE_FAULT_FILE=str(faults)) as srv:
        st, jobs = storage(srv, hold, faults, budget, log)
        return st, connections(srv, jobs, log)


def storage(srv: Server, hold: Path, faults: Path, budget: int, log: Callable) -> tuple[dict, dict[str, str]]:
    """Every endpoint under each storage fault: count 5xx without a named cause and /readyz 200s."""
    c = srv.client
    done = srv.submit(job_spec(200, budget))
    _wait(lambda: srv.job(done)["status"] == "succeeded", 300, "a finished job")
    hold.touch()
    held = srv.submit(job_spec(201, budget))
    _wait(lambda: srv.job(held)["progress"], 300, "a running job")
    faults_order = ("data:readonly", "data:full", "db:readonly", "db:full")  # data first: the report is not cached
    queued = {f: srv.submit(job_spec(210 + i, budget)) for i, f in enumerate(faults_order)}
    out: dict[str, Any] = {"responses": 0, "storage_5xx": 0, "unnamed_5xx": 0, "readyz_polls": 0, "readyz_ready": 0,
           "by_fault": {}}
    for fault in faults_order:
        faults.write_text(fault)
        reqs = [("POST", "/v1/tune", job_spec(203, budget)), ("GET", "/v1/jobs", None),
                ("GET", f"/v1/jobs/{done}", None),
                ("DELETE", f"/v1/jobs/{queued[fault]}", None), ("GET", f"/v1/jobs/{done}/report", None),
                ("GET", f"/v1/jobs/{done}/agent", None), ("GET", f"/v1/jobs/{done}/export?format=json", None),
                ("GET", "/metrics", None)]
        codes = []
        for method, path, body in reqs:
            r = c.request(method, path, json=body)
            out["responses"] += 1
            codes.append(r.status_code)
            if r.status_code >= 500:
                named = r.headers.get("content-type") == "application/problem+json" and "cause" in r.json() \
                    and "retry-after" in r.headers
                out["storage_5xx"] += named
                out["unnamed_5xx"] += not named
        for _ in range(3):
            out["readyz_polls"] += 1
            out["readyz_ready"] += c.get("/readyz").status_code == 200
        out["by_fault"][fault] = codes
        log(f"  storage: {fault}: {codes}")
    # a job submitted while the data directory is read-only is refused at once, naming the cause
    faults.write_text("data:readonly")
    hold.unlink()
    r = c.post("/v1/tune", json=job_spec(204, budget))
    out["job_on_read_only_dir"] = {"status": r.status_code, "cause": r.json().get("cause")}
    faults.unlink()
    srv.wait_ready()
    return out, {"done": done, "held": held}


def _raw_request(sock: socket.socket, buf: bytearray, method: str, path: str,
                 body: Any = None) -> tuple[int, dict, bytes]:
    """One HTTP/1.1 request on a kept-alive socket; returns (status, headers, body). Raises on a closed connection."""
    data = b"" if body is None else json.dumps(body).encode()
    head = (f"{method} {path} HTTP/1.1\r\nHost: x\r\nContent-Type: application/json\r\n"
            f"Content-Length: {len(data)}\r\n\r\n")
    sock.sendall(head.encode() + data)

    def fill() -> None:
        chunk = sock.recv(65536)
        if not chunk:
            raise ConnectionError("the server closed the connection")
        buf.extend(chunk)

    while b"\r\n\r\n" not in buf:
        fill()
    end = buf.index(b"\r\n\r\n")
    lines = bytes(buf[:end]).decode("latin-1").split("\r\n")
    del buf[:end + 4]
    headers = {k.strip().lower(): v.strip() for k, v in (ln.split(":", 1) for ln in lines[1:])}
    n = int(headers.get("content-length", "0"))
    while len(buf) < n:
        fill()
    content = bytes(buf[:n])
    del buf[:n]
    return int(lines[0].split()[1]), headers, content


def connections(srv: Server, jobs: dict[str, str], log: Callable) -> dict:
    """After each error, the next request on the same connection: count failures."""
    faults = srv.root / "faults"
    done, victim = jobs["done"], jobs["held"]  # both finished: nothing writes their rows any more
    with sqlite3.connect(srv.db) as db:  # a corrupt row: a genuine unhandled error (500) when read
        db.execute("UPDATE jobs SET result='{corrupt' WHERE id=?", (victim,))
    cases = [("", "GET", f"/v1/jobs/{victim}", None), ("db:readonly", "POST", "/v1/tune", job_spec(301, 50)),
             ("db:full", "POST", "/v1/tune", job_spec(302, 50)), ("", "GET", "/v1/jobs/nope", None),
             ("", "DELETE", f"/v1/jobs/{done}", None), ("", "POST", "/v1/tune", {"plant": 1})] * 3
    errors = failures = closes = 0
    seen: dict[int, int] = {}
    sock, buf = socket.create_connection(("127.0.0.1", srv.port)), bytearray()
    try:
        for fault, method, path, body in cases:
            faults.write_text(fault)
            status, headers, _ = _raw_request(sock, buf, method, path, body)
            faults.write_text("")
            errors += 1
            seen[status] = seen.get(status, 0) + 1
            closed = headers.get("connection", "").lower() == "close"  # allowed: then the client reconnects
            closes += closed
            if not closed:
                try:
                    failures += _raw_request(sock, buf, "GET", "/healthz")[0] != 200
                    continue
                except (ConnectionError, OSError):
                    failures += 1
            sock.close()
            sock, buf = socket.create_connection(("127.0.0.1", srv.port)), bytearray()
    finally:
        sock.close()
    log(f"  connections: {errors} errors {seen}, {failures} next-request failures, {closes} Connection: close")
    return {"errors": errors, "statuses": seen, "next_request_failures": failures, "connection_close": closes}
