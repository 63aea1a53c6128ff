"""Driving a real API server for ``gaintune bench api``: its process, and HTTP load with latency per request.

:func:`start_server` runs ``python -m gaintune_api`` on 127.0.0.1 in a temporary folder (and the kernel
stops it if the benchmark dies); :func:`run_load` fires requests at a fixed concurrency through
:class:`RawClient` (or an ``httpx.AsyncClient``) and summarises their latencies. The phases and
the report are in :mod:`gaintune.bench.api`.
"""

from __future__ import annotations

import asyncio
import json
import os
import signal
import socket
import subprocess
import sys
import time
from collections.abc import Callable
from pathlib import Path
from typing import TYPE_CHECKING, Any, Protocol

import numpy as np

if TYPE_CHECKING:  # pragma: no cover
    import httpx

__all__ = [
    "LoadClient", "LoadResponse", "RawClient", "Request", "free_port", "run_load", "start_server", "stop_server",
    "term_with_parent", "wait_ready",
]

#: One request of a load phase: ``(method, url, JSON body or None)``.
Request = tuple[str, str, Any]


class LoadResponse(Protocol):
    """What :func:`run_load` reads of an answer (an ``httpx.Response`` or :class:`RawClient`'s)."""

    @property
    def status_code(self) -> int:
        """The HTTP status."""

    @property
    def content(self) -> bytes:
        """The body."""


class LoadClient(Protocol):
    """A client :func:`run_load` can drive: ``httpx.AsyncClient`` or :class:`RawClient`."""

    async def request(self, method: str, url: str, *, json: Any = None) -> LoadResponse:
        """Send one request with an optional JSON body; return the answer."""


def free_port() -> int:
    """A TCP port on 127.0.0.1 that is free now (the OS picks it)."""
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def _pct(x: list[float], q: float) -> float:
    return float(np.percentile(np.asarray(x) * 1e3, q)) if x else float("nan")


class _Response:
    """An answer read by :class:`RawClient`."""

    __slots__ = ("status_code", "content")

    def __init__(self, status_code: int, content: bytes) -> None:
        self.status_code, self.content = status_code, content

    def json(self) -> Any:
        """The body parsed as JSON."""
        return json.loads(self.content)


class RawClient:
    """A minimal HTTP/1.1 keep-alive client for the load phases (``--client raw``, the default).

    The load generator shares the 2 CPUs with the server it measures; httpx spends about
    2.5 ms of CPU per request here, which the server then does not get. This client writes
    the request bytes and reads the status line, headers and ``Content-Length`` (or chunked)
    body on a pool of persistent connections: a fraction of that cost. Same interface as
    ``httpx.AsyncClient.request`` for what :func:`run_load` uses.
    """

    def __init__(self, host: str, port: int) -> None:
        self.host, self.port = host, port
        self._idle: list[tuple[asyncio.StreamReader, asyncio.StreamWriter]] = []

    async def request(self, method: str, url: str, *, json: Any = None) -> _Response:
        """Send ``method url`` with body ``json`` (as httpx's ``json=``) on a kept-alive connection.

        Raises
        ------
        ConnectionError
            When a fresh connection closes without an answer.
        """
        import json as _json  # the parameter takes httpx's name

        body = b"" if json is None else _json.dumps(json).encode()
        head = (f"{method} {url} HTTP/1.1\r\nHost: {self.host}:{self.port}\r\n"
                + ("Content-Type: application/json\r\n" if json is not None else "")
                + f"Content-Length: {len(body)}\r\n\r\n").encode()
        while True:
            reused = bool(self._idle)
            conn = self._idle.pop() if reused else await asyncio.open_connection(self.host, self.port)
            reader, writer = conn
            try:
                writer.write(head + body)
                line = await reader.readline()
            except (ConnectionError, OSError):
                line = b""
            if line:
                break
            writer.close()
            if not reused:  # a fresh connection closed at once: a real error
                raise ConnectionError("server closed the connection without a response")
            # the server closed an idle keep-alive connection (uvicorn: after 5 s): retry on a new one
        status = int(line.split(b" ", 2)[1])
        length, chunked, close = None, False, False
        while True:
            line = await reader.readline()
            if line in (b"\r\n", b"\n", b""):
                break
            k, _, v = line.partition(b":")
            k = k.strip().lower()
            if k == b"content-length":
                length = int(v)
            elif k == b"transfer-encoding" and b"chunked" in v.lower():
                chunked = True
            elif k == b"connection" and b"close" in v.lower():
                close = True
        if chunked:
            parts = []
            while True:
                size = int((await reader.readline()).split(b";")[0], 16)
                if size == 0:
                    await reader.readline()
                    break
                parts.append(await reader.readexactly(size))
                await reader.readline()
            content = b"".join(parts)
        else:
            content = await reader.readexactly(length or 0)
        if close:
            writer.close()
        else:
            self._idle.append(conn)
        return _Response(status, content)

    async def aclose(self) -> None:
        """Close every idle connection."""
        for _, w in self._idle:
            w.close()
        self._idle.clear()


async def run_load(
    client: LoadClient, make_request: Callable[[int], Request], n: int, seconds: float, concurrency: int
) -> dict[str, Any]:
    """Fire up to ``n`` requests (or for ``seconds``) with ``concurrency`` in flight; latency per request.

    Returns
    -------
    dict
        ``requests``, ``seconds``, ``rps``, ``p50_ms``, ``p95_ms``, ``p99_ms`` and ``errors``
        (``{status: count}`` of the answers >= 300).
    """
    lat: list[float] = []
    errors: dict[int, int] = {}
    counter = iter(range(n))
    t_end = time.perf_counter() + seconds

    async def one_worker() -> None:
        for i in counter:
            if time.perf_counter() > t_end:
                return
            method, url, body = make_request(i)
            t0 = time.perf_counter()
            r = await client.request(method, url, json=body)
            lat.append(time.perf_counter() - t0)
            if r.status_code >= 300:
                errors[r.status_code] = errors.get(r.status_code, 0) + 1

    t0 = time.perf_counter()
    await asyncio.gather(*(one_worker() for _ in range(concurrency)))
    wall = time.perf_counter() - t0
    return {"requests": len(lat), "seconds": round(wall, 2), "rps": round(len(lat) / wall, 1),
            "p50_ms": round(_pct(lat, 50), 2), "p95_ms": round(_pct(lat, 95), 2), "p99_ms": round(_pct(lat, 99), 2),
            "errors": errors}


def term_with_parent() -> Callable[[], None] | None:
    """A ``preexec_fn`` that has Linux send the child SIGTERM when this process dies (None elsewhere).

    The ``finally`` of ``gaintune.bench.api._run`` stops the server on every exception, but not when this
    process is SIGKILLed (``timeout -s KILL``, the OOM killer): the server and its job workers
    were left running. SIGTERM lets the server stop its workers itself. libc is loaded here,
    in the parent: the child between fork and exec only calls it.
    """
    if not sys.platform.startswith("linux"):
        return None
    try:
        import ctypes

        prctl = ctypes.CDLL("libc.so.6", use_errno=True).prctl
    except OSError:  # pragma: no cover - no glibc
        return None
    return lambda: prctl(1, signal.SIGTERM, 0, 0, 0)  # PR_SET_PDEATHSIG


def start_server(
    tmp: Path, port: int, workers: int, compute_processes: int | None = None
) -> subprocess.Popen[bytes]:
    """Start ``python -m gaintune_api`` on 127.0.0.1:``port`` with its database, data and log in ``tmp``.

    Parameters
    ----------
    tmp
        Working folder (``jobs.db``, ``data/``, ``server.log``).
    port, workers
        Listening port and number of job workers.
    compute_processes
        The server's compute pool size (None: the server default).
    """
    env = dict(os.environ, GAINTUNE_DB_PATH=str(tmp / "jobs.db"), GAINTUNE_DATA_DIR=str(tmp / "data"))
    if compute_processes is not None:
        env["GAINTUNE_COMPUTE_PROCESSES"] = str(compute_processes)
    cmd = [sys.executable, "-m", "gaintune_api", "--host", "127.0.0.1", "--port", str(port), "--workers", str(workers),
           "--log-level", "warning"]
    with open(tmp / "server.log", "w") as log:  # the child keeps its own copy of the descriptor
        return subprocess.Popen(cmd, cwd=tmp, env=env, stdout=log, stderr=subprocess.STDOUT,
                                preexec_fn=term_with_parent())


def stop_server(proc: subprocess.Popen[bytes]) -> None:
    """SIGTERM, then SIGKILL after 15 s: the server must never outlive the benchmark."""
    if proc.poll() is not None:
        return
    proc.send_signal(signal.SIGTERM)
    try:
        proc.wait(15)
    except subprocess.TimeoutExpired:
        proc.kill()
        proc.wait()


async def wait_ready(c: httpx.AsyncClient, proc: subprocess.Popen[bytes], tmp: Path) -> float:
    """Seconds until ``/readyz`` says ready (SystemExit when the server exits or takes over 120 s)."""
    import httpx

    t0 = time.perf_counter()
    while True:
        if proc.poll() is not None:
            raise SystemExit("server exited:\n" + (tmp / "server.log").read_text()[-3000:])
        try:
            if (await c.get("/readyz")).status_code == 200:
                return round(time.perf_counter() - t0, 1)
        except httpx.TransportError:
            pass
        if time.perf_counter() - t0 > 120:
            raise SystemExit("server not ready after 120 s")
        await asyncio.sleep(0.2)
