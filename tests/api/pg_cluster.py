"""A throwaway PostgreSQL cluster for the tests: the Debian binaries, a temporary folder, a free port.

``GAINTUNE_TEST_PG_URL`` set: that server is used instead (each test still gets its own database).
Run as root, the cluster runs as the ``postgres`` user (``runuser``): PostgreSQL refuses to run as root.
In CI (``CI`` set) a missing PostgreSQL is an error, never a skip: the store's tests must run there.
"""

from __future__ import annotations

import glob
import os
import shutil
import socket
import subprocess
import tempfile
import uuid
from pathlib import Path

__all__ = ["PgCluster", "start_cluster", "no_postgres_reason"]


def _bindir() -> Path | None:
    dirs = sorted(glob.glob("/usr/lib/postgresql/*/bin"), key=lambda d: int(Path(d).parent.name))
    return Path(dirs[-1]) if dirs and Path(dirs[-1], "initdb").exists() else None


def no_postgres_reason() -> str | None:
    """Why no PostgreSQL can be used here (None: one can)."""
    if os.environ.get("GAINTUNE_TEST_PG_URL"):
        return None
    try:
        import psycopg  # noqa: F401 - only whether it is there
    except ImportError:
        return "psycopg is not installed (pip install gaintune[postgres])"
    if _bindir() is None:
        return "no /usr/lib/postgresql/*/bin/initdb (apt-get install postgresql) and GAINTUNE_TEST_PG_URL unset"
    if os.geteuid() == 0 and shutil.which("runuser") is None:
        return "running as root without runuser to start PostgreSQL as the postgres user"
    return None


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


class PgCluster:
    """A PostgreSQL server: started here (``folder`` set) or given by ``GAINTUNE_TEST_PG_URL``."""

    def __init__(self, url: str, folder: Path | None = None, bindir: Path | None = None) -> None:
        self.url, self.folder, self.bindir = url, folder, bindir

    def _run(self, *cmd: str) -> None:
        prefix = ["runuser", "-u", "postgres", "--"] if os.geteuid() == 0 else []
        subprocess.run([*prefix, *cmd], check=True, capture_output=True, text=True, timeout=120)

    def start(self, port: int) -> None:
        """initdb and start the server on 127.0.0.1:``port`` (fsync off: a throwaway test server)."""
        assert self.folder is not None and self.bindir is not None
        data = self.folder / "data"
        self._run(str(self.bindir / "initdb"), "-D", str(data), "-U", "postgres", "--auth=trust", "-E", "UTF8",
                  "--no-sync")
        opts = (f"-p {port} -k {self.folder} -c listen_addresses=127.0.0.1 -c fsync=off -c max_connections=200"
                " -c synchronous_commit=off")
        self._run(str(self.bindir / "pg_ctl"), "-D", str(data), "-o", opts, "-l", str(self.folder / "log"), "-w",
                  "start")

    def stop(self) -> None:
        """Stop a server started here and remove its folder."""
        if self.folder is None or self.bindir is None:
            return
        try:
            self._run(str(self.bindir / "pg_ctl"), "-D", str(self.folder / "data"), "-m", "immediate", "-w", "stop")
        finally:
            shutil.rmtree(self.folder, ignore_errors=True)

    def new_database(self) -> str:
        """A fresh empty database on the server; its URL."""
        import psycopg

        name = f"t_{uuid.uuid4().hex[:16]}"
        with psycopg.connect(self.url, autocommit=True) as conn:
            conn.execute(f"CREATE DATABASE {name}")
        return self.url.rsplit("/", 1)[0] + f"/{name}"

    def drop_database(self, url: str) -> None:
        """Drop a database made by :meth:`new_database` (closing its connections)."""
        import psycopg

        with psycopg.connect(self.url, autocommit=True) as conn:
            conn.execute(f"DROP DATABASE IF EXISTS {url.rsplit('/', 1)[1]} WITH (FORCE)")


def start_cluster() -> PgCluster:
    """``GAINTUNE_TEST_PG_URL``'s server, else a new cluster in a temporary folder (call :meth:`PgCluster.stop`)."""
    url = os.environ.get("GAINTUNE_TEST_PG_URL")
    if url:
        return PgCluster(url)
    bindir = _bindir()
    assert bindir is not None
    folder = Path(tempfile.mkdtemp(prefix="gaintune-pg-"))
    if os.geteuid() == 0:
        shutil.chown(folder, "postgres", "postgres")
    port = _free_port()
    cluster = PgCluster(f"postgresql://postgres@127.0.0.1:{port}/postgres", folder, bindir)
    try:
        cluster.start(port)
    except BaseException:
        shutil.rmtree(folder, ignore_errors=True)
        raise
    return cluster
