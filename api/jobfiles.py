"""Job artefacts on disk, fenced like the database rows: only the attempt that owns a job puts files in place.

Layout under ``data_dir/jobs/<id>/``::

    .attempts/<n>-<claim>/   staging folder of attempt n (the search saves agent.zip here)
    agent.zip                renamed into place by the owning attempt, inside the store's finish transaction
    report.html              rendered on first request and cached

An attempt writes only into its own staging folder. :meth:`JobFiles.promoter`
gives :meth:`gaintune_api.job_store.JobStore.finish` the function that renames the staged
files into the job folder; the store calls it inside its write transaction,
after checking the attempt's claim token, so a stale attempt (a frozen worker
that resumes after its job was recovered and finished elsewhere) can never
replace a finished job's files. The manifest it returns (SHA-256 and size per
file) is stored with the result and checked whenever a file is served.

Every write here goes through the storage-fault layer (:mod:`gaintune_api.storage_faults`):
an ``OSError`` of a full or read-only disk leaves as a named ``StorageFault``.
"""

from __future__ import annotations

import hashlib
import os
import shutil
import threading
import uuid
from collections.abc import Callable
from pathlib import Path
from typing import Any

from gaintune.files import write_atomic
from gaintune_api.storage_faults import FaultInjector, classify

__all__ = ["JobFiles", "ArtifactMissing", "ArtifactMismatch"]

STAGING = ".attempts"


class ArtifactMissing(Exception):
    """A file the job's result refers to is gone from the data directory."""


class ArtifactMismatch(Exception):
    """A job file differs from the manifest written when the job finished."""


def _sha256(path: Path) -> tuple[str, int]:
    h = hashlib.sha256()
    n = 0
    with open(path, "rb") as f:
        for block in iter(lambda: f.read(1 << 20), b""):
            h.update(block)
            n += len(block)
    return h.hexdigest(), n


def _fsync_dir(path: Path) -> None:
    try:
        fd = os.open(path, os.O_RDONLY)
    except OSError:
        return
    try:
        os.fsync(fd)
    except OSError:
        pass
    finally:
        os.close(fd)


class JobFiles:
    """The artefact folders of all jobs under ``jobs_dir``.

    Parameters
    ----------
    jobs_dir
        ``Settings.jobs_dir``.
    faults
        Tests only: injected storage faults (see :class:`gaintune_api.storage_faults.FaultInjector`).
    """

    def __init__(self, jobs_dir: Path, faults: FaultInjector | None = None) -> None:
        self.root = Path(jobs_dir)
        self.faults = faults or FaultInjector(None)

    # ------------------------------------------------------------ plumbing
    def _guard(self, target: Path, fn: Callable[[], Any]) -> Any:
        """Run a write with injected faults applied and OSErrors of the disk named."""
        try:
            self.faults.check("data", target)
            return fn()
        except OSError as exc:
            fault = classify(exc, "data")
            if fault is None:
                raise
            raise fault from exc

    def job_dir(self, job_id: str) -> Path:
        """The folder of a job's artefacts."""
        return self.root / job_id

    def ensure_root(self) -> None:
        """Create ``jobs_dir``; raises StorageFault when the disk does not allow it."""
        self._guard(self.root, lambda: self.root.mkdir(parents=True, exist_ok=True))

    def probe(self) -> None:
        """Raise StorageFault unless one byte can be written, synced and removed in ``jobs_dir`` (readiness check)."""
        path = self.root / f".probe-{os.getpid()}-{threading.get_ident()}"

        def write() -> None:
            self.root.mkdir(parents=True, exist_ok=True)
            write_atomic(path, b"x")  # synced; a symlink planted at the probe's name is replaced, not followed
            path.unlink()

        try:
            self._guard(path, write)
        finally:
            try:
                path.unlink()
            except OSError:
                pass

    # ------------------------------------------------------------ attempts
    def stage(self, job_id: str, attempt: int, claim: str) -> Path:
        """Create and return the staging folder of one attempt (StorageFault when the disk refuses)."""
        path = self.job_dir(job_id) / STAGING / f"{attempt}-{claim[:16]}"
        self._guard(path, lambda: path.mkdir(parents=True, exist_ok=True))
        return path

    def discard(self, staging: Path) -> None:
        """Remove an attempt's staging folder (best effort: a stale attempt's leftovers are never served)."""
        shutil.rmtree(staging, ignore_errors=True)

    def final_path(self, job_id: str, staged: str | Path | None, staging: Path) -> str | None:
        """Where a file the attempt staged will be after promotion (None: not one of the attempt's files)."""
        if not staged:
            return None
        p = Path(staged)
        try:
            p.resolve().relative_to(staging.resolve())
        except ValueError:
            return None
        return str(self.job_dir(job_id) / p.name)

    def promoter(self, job_id: str, staging: Path, attempt: int, claim: str) -> Callable[[], dict[str, Any]]:
        """The function :meth:`gaintune_api.job_store.JobStore.finish` calls under its write lock, the claim verified.

        Digests are computed now, outside the lock; the returned function only renames
        (``os.replace``, atomic per file) the staged files into the job folder and returns
        the manifest ``{"attempt", "claim", "files": {name: {"sha256", "bytes"}}}``.
        Raises StorageFault when the rename fails (read-only or full disk).
        """
        dest = self.job_dir(job_id)
        files: dict[str, dict[str, Any]] = {}

        def scan() -> None:
            for f in sorted(staging.iterdir()) if staging.is_dir() else []:
                if f.is_file():
                    digest, size = _sha256(f)
                    files[f.name] = {"sha256": digest, "bytes": size}

        self._guard(staging, scan)

        def promote() -> dict[str, Any]:
            def move() -> None:
                for name in files:
                    os.replace(staging / name, dest / name)
                _fsync_dir(dest)

            self._guard(dest, move)
            return {"attempt": attempt, "claim": claim[:16], "files": files}

        return promote

    # ------------------------------------------------------------ serving
    def artifact(self, job_id: str, name: str, manifest: dict[str, Any] | None) -> tuple[Path, str | None]:
        """A finished job's file, checked against its manifest.

        Returns
        -------
        (path, sha256)
            ``sha256`` is None for jobs finished before manifests were written.

        Raises
        ------
        ArtifactMissing
            The file is gone (deleted, or the disk was swapped).
        ArtifactMismatch
            The file's size or SHA-256 differs from the manifest.
        """
        path = self.job_dir(job_id) / name
        if not path.is_file():
            raise ArtifactMissing(f"{name} of job {job_id} is missing from the data directory")
        entry = ((manifest or {}).get("files") or {}).get(name)
        if not entry:
            return path, None
        digest, size = _sha256(path)
        if size != entry.get("bytes") or digest != entry.get("sha256"):
            raise ArtifactMismatch(f"{name} of job {job_id} does not match the file its attempt "
                                   f"{(manifest or {}).get('attempt')} saved (sha256 {digest[:12]}…, "
                                   f"expected {str(entry.get('sha256'))[:12]}…)")
        return path, digest

    def write_report(self, job_id: str, render: Callable[[Path], Path | str]) -> Path:
        """Render the job's HTML report into a unique temporary file, then rename it to ``report.html``.

        ``render(tmp)`` writes the file and returns its path. Raises StorageFault when the disk refuses.
        """
        path = self.job_dir(job_id) / "report.html"
        tmp = path.with_name(f".report-{uuid.uuid4().hex}.tmp.html")

        def write() -> Path:
            path.parent.mkdir(parents=True, exist_ok=True)
            out = Path(render(tmp))
            os.replace(out, path)
            return path

        try:
            return self._guard(path, write)
        finally:
            try:
                tmp.unlink()
            except OSError:
                pass
