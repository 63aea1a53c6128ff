"""Service settings: one ``Settings`` object, read from ``GAINTUNE_*`` environment variables and ``.env``.

Every limit the service enforces lives here with its default; ``docs/api.md``
lists them. Lists (``GAINTUNE_API_KEYS``, ``GAINTUNE_CORS_ORIGINS``) accept a
JSON array or a comma-separated string. A ``GAINTUNE_*`` variable that names no
setting is not silently ignored: :func:`warn_unknown_settings` logs a warning at
start naming the closest valid one.
"""

from __future__ import annotations

import difflib
import logging
import os
from functools import lru_cache
from pathlib import Path
from typing import Annotated, Any, Literal

from pydantic import Field, field_validator
from pydantic_settings import BaseSettings, NoDecode, SettingsConfigDict

from gaintune.errors import SpecError
from gaintune.files import read_text_bounded
from gaintune.spec import MAX_ORDER, MAX_STEPS

__all__ = ["Settings", "get_settings", "unknown_settings", "warn_unknown_settings", "LIBRARY_ENV"]

PREFIX = "GAINTUNE_"
#: ``GAINTUNE_*`` variables read by the gaintune library itself, not by this service: never reported as unknown.
LIBRARY_ENV = frozenset({"GAINTUNE_CHROMIUM", "GAINTUNE_TORCH_THREADS", "GAINTUNE_MODELS"})


class Settings(BaseSettings):
    """Configuration of the API server and its job workers."""

    model_config = SettingsConfigDict(env_prefix="GAINTUNE_", env_file=".env", extra="ignore")

    # ------------------------------------------------------------ storage
    db_path: Path = Field(Path("gaintune-data/jobs.sqlite3"), description="SQLite job database (WAL mode).")
    data_dir: Path = Field(Path("gaintune-data"), description="Job artifacts: agents, reports (one folder per job).")
    db_url: str | None = Field(
        None, description="PostgreSQL job store, e.g. postgresql://user:pass@host:5432/gaintune (needs "
        "gaintune[postgres]): several API servers and workers on several machines share it. Unset: SQLite at db_path.")
    db_idle_timeout: float = Field(
        5.0, gt=0, le=3600, description="PostgreSQL only: a store connection idle inside a transaction this long "
        "(its process frozen mid-write) is closed by the server, which frees the row locks it held.")
    backend: Literal["local", "ray"] = Field(
        "local", description="Where job workers run: local worker processes, or Ray tasks (needs gaintune[ray]; "
        "the cluster is RAY_ADDRESS; unset: Ray's default, a cluster already running on this machine, else a new "
        "local one).")

    # ---------------------------------------------------------- workers
    workers: int = Field(1, ge=0, le=64,
                         description="Job worker processes = max concurrent jobs (0: none in this server).")
    max_queue: int = Field(64, ge=0,
                           description="Most queued (not yet running) jobs; beyond this POST /v1/tune is 503.")
    retry_after: int = Field(30, ge=1, description="Seconds advertised in Retry-After when the queue is full.")
    recover: Literal["requeue", "fail"] = Field(
        "requeue", description="What happens to jobs that were running when their server or worker died."
    )
    max_attempts: int = Field(3, ge=1, description="A job interrupted this many times is failed instead of re-queued.")
    job_wall_time: float = Field(3600.0, gt=0, description="Per-job wall-time limit in seconds (job fails beyond it).")
    cancel_grace: float = Field(
        5.0, gt=0, description="Seconds a cancelled/over-time job may take to stop before its worker is killed.")
    heartbeat_interval: float = Field(0.5, gt=0, description="Worker progress/heartbeat write period (s).")
    heartbeat_timeout: float = Field(
        30.0, gt=0, description="Lease of a running job: without a heartbeat this long (counted while the database "
        "accepts writes) it is recovered, and a worker process frozen this long is killed and restarted.")
    worker_liveness_timeout: float = Field(
        10.0, gt=0, description="A worker process whose pulse (a shared-memory heartbeat beaten every "
        "heartbeat_interval) is older than this does not count as alive in /readyz.")
    poll_interval: float = Field(0.25, gt=0, description="Idle worker queue-poll period (s).")
    warmup: bool = Field(True, description="Compile the simulator once at start-up so the first request is fast.")

    # ----------------------------------------------------------- limits
    max_budget: int = Field(100_000, ge=10, description="Largest search.budget (simulations) a job may ask for.")
    max_steps: int = Field(MAX_STEPS, ge=2, le=MAX_STEPS, description="Largest horizon/dt of one scenario.")
    max_order: int = Field(MAX_ORDER, ge=1, le=MAX_ORDER, description="Largest plant state dimension.")
    max_scenarios: int = Field(16, ge=1, description="Most scenarios in one spec.")
    max_body_bytes: int = Field(1_048_576, ge=1024, description="Largest request body (413 beyond).")
    max_json_depth: int = Field(32, ge=4, description="Deepest JSON nesting accepted.")
    max_array_items: int = Field(10_000, ge=10, description="Longest JSON array accepted.")
    sync_max_n_freq: int = Field(20_000, ge=100, description="verify.n_freq cap for synchronous /v1/verify.")
    sync_max_robust_samples: int = Field(64, ge=0, description="verify.robust_samples cap for synchronous /v1/verify.")
    simulate_max_points: int = Field(2000, ge=2, description="Most points per returned trace of /v1/simulate.")
    compute_processes: int = Field(
        default_factory=lambda: min(os.cpu_count() or 1, 4), ge=0, le=64,
        description="Warm worker processes for /v1/verify and /v1/simulate (default: CPUs, at most 4); "
        "0: compute in the server process with compute_threads threads.",
    )
    compute_threads: int = Field(
        1, ge=1, le=64, description="Concurrent /v1/verify and /v1/simulate computations in the server process "
        "when compute_processes is 0 (GIL-bound: more threads add contention, not throughput)."
    )
    verify_cache_size: int = Field(256, ge=0, description="LRU entries of identical /v1/verify requests (0: off).")
    tuner_cache_size: int = Field(16, ge=1, le=1024,
                                  description="Trained tuners kept loaded per process (/v1/tuners/{name}/query).")
    max_tuner_refine: int = Field(2000, ge=0, le=1_000_000,
                                  description="Most refining simulations one /v1/tuners/{name}/query may ask for.")
    max_tuner_episodes: int = Field(200_000, ge=1,
                                    description="Most training episodes a POST /v1/tuners job may ask for.")

    # ------------------------------------------------------- security
    api_keys: Annotated[list[str], NoDecode] = Field(
        default_factory=list, description="Accepted X-API-Key values; empty: no authentication."
    )
    metrics_public: bool = Field(False, description="Serve /metrics without an API key.")
    docs_public: bool = Field(False, description="Serve /openapi.json, /docs and /redoc without an API key "
                              "(when api_keys is empty they are always open).")
    cors_origins: Annotated[list[str], NoDecode] = Field(default_factory=list, description="Allowed CORS origins.")

    log_level: str = "info"

    # ------------------------------------------------------ tests only
    test_hold_file: Path | None = Field(
        None, description="FOR TESTS ONLY (unset in production: no effect). While this file exists, a worker "
        "whose job has reported progress pauses the search (heartbeats continue), so integration tests can "
        "kill a worker or server while a job is provably mid-run, however fast the machine.",
    )

    test_storage_fault_file: Path | None = Field(
        None, description="FOR TESTS ONLY (unset in production: no effect). While this file exists, the words in it "
        "(db:readonly, db:full, data:readonly, data:full) make the job store and the artefact layer fail writes as a "
        "read-only or full disk would (see gaintune_api.storage_faults.FaultInjector): deterministic storage-fault "
        "tests, even as root.",
    )

    @field_validator("db_url")
    @classmethod
    def _postgres_url(cls, v: str | None) -> str | None:
        if v is not None and not v.strip():
            return None
        if v is not None and not v.startswith(("postgresql://", "postgres://")):
            raise ValueError("db_url must be a PostgreSQL URL (postgresql://user:password@host:port/dbname); "
                             "unset it to use the SQLite file db_path")
        return v

    @field_validator("api_keys", "cors_origins", mode="before")
    @classmethod
    def _split(cls, v: Any) -> Any:
        if isinstance(v, str):
            s = v.strip()
            if s.startswith("["):
                import json

                return json.loads(s)
            return [p.strip() for p in s.split(",") if p.strip()]
        return v

    @property
    def jobs_dir(self) -> Path:
        """The folder of the jobs' files (``data_dir/jobs``)."""
        return self.data_dir / "jobs"


def _env_file_names(path: Path) -> list[str]:
    try:  # a regular file up to 10 MB only: a FIFO .env is left to Settings, which reads it once
        lines = read_text_bounded(path, "env_file").splitlines()
    except SpecError:
        return []
    out = []
    for line in lines:
        line = line.strip()
        if line.startswith("export "):
            line = line[7:].lstrip()
        if line and not line.startswith("#") and "=" in line:
            out.append(line.split("=", 1)[0].strip())
    return out


def _closest(name: str, known: list[str]) -> str | None:
    """The valid name (without the prefix, which matches always) closest to ``name``.

    A near-identical spelling first (WORKER -> WORKERS), then a truncation (DB -> DB_PATH: the first setting
    of that group as Settings declares them), then difflib's best.
    """
    for cutoff in (0.8, None, 0.5):
        if cutoff is None:
            # a truncation: the first of its group as Settings declares them (DB -> DB_PATH, not DB_URL)
            order = {k.upper(): i for i, k in enumerate(Settings.model_fields)}
            longer = sorted((k for k in known if name and k.startswith(name + "_")), key=lambda k: order.get(k, 999))
            close = longer[:1]
        else:
            close = difflib.get_close_matches(name, known, n=1, cutoff=cutoff)
        if close:
            return close[0]
    return None


def unknown_settings(environ: dict[str, str] | None = None, env_file: Path | None = Path(".env")) -> list[str]:
    """Warnings for ``GAINTUNE_*`` names in the environment (and ``.env``) that are no setting.

    Parameters
    ----------
    environ
        The environment (default ``os.environ``).
    env_file
        The ``.env`` file Settings also reads (None: skip).

    Returns
    -------
    list of str
        One message per unknown name, naming the closest valid variable (:func:`difflib.get_close_matches`).
    """
    environ = dict(os.environ) if environ is None else environ
    valid = sorted({PREFIX + name.upper() for name in Settings.model_fields})
    names = [k for k in environ if k.upper().startswith(PREFIX)]
    if env_file is not None:
        names += [f"{k} (in {env_file})" for k in _env_file_names(env_file) if k.upper().startswith(PREFIX)]
    out = []
    for entry in names:
        name = entry.split(" ", 1)[0]
        if name.upper() in valid or name.upper() in LIBRARY_ENV:
            continue
        close = _closest(name.upper()[len(PREFIX):], [v[len(PREFIX):] for v in valid + sorted(LIBRARY_ENV)])
        hint = (f"; did you mean {PREFIX}{close}?" if close
                else "; no setting has a similar name (see the Settings table of docs/api.md)")
        out.append(f"unknown setting {entry} is ignored{hint}")
    return out


def warn_unknown_settings(log: logging.Logger | None = None) -> list[str]:
    """Log :func:`unknown_settings` as warnings (called once at server and standalone-worker start)."""
    log = log or logging.getLogger("gaintune.settings")
    msgs = unknown_settings()
    for m in msgs:
        log.warning(m)
    return msgs


@lru_cache(maxsize=1)
def get_settings() -> Settings:
    """The process-wide settings singleton (from the environment)."""
    return Settings()
