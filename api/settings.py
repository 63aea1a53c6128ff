"""Service settings: one ``Settings`` object, read from ``GAINTUNE_*`` environment variables and ``.env``.

Every limit the service enforces lives here with its default; ``docs/api.md``
lists them. Lists (``GAINTUNE_API_KEYS``, ``GAINTUNE_CORS_ORIGINS``) accept a
JSON array or a comma-separated string.
"""

from __future__ import annotations

import os
from functools import lru_cache
from pathlib import Path
from typing import Annotated, Any, Literal

from pydantic import Field, field_validator
from pydantic_settings import BaseSettings, NoDecode, SettingsConfigDict

from gaintune.spec import MAX_ORDER, MAX_STEPS

__all__ = ["Settings", "get_settings"]


class Settings(BaseSettings):
    """Configuration of the API server and its job workers."""

    model_config = SettingsConfigDict(env_prefix="GAINTUNE_", env_file=".env", extra="ignore")

    # ------------------------------------------------------------ storage
    db_path: Path = Field(Path("gaintune-data/jobs.sqlite3"), description="SQLite job database (WAL mode).")
    data_dir: Path = Field(Path("gaintune-data"), description="Job artifacts: agents, reports (one folder per job).")

    # ---------------------------------------------------------- workers
    workers: int = Field(1, ge=0, le=64, description="Job worker processes = max concurrent jobs (0: none in this server).")
    max_queue: int = Field(64, ge=0, description="Most queued (not yet running) jobs; beyond this POST /v1/tune is 503.")
    retry_after: int = Field(30, ge=1, description="Seconds advertised in Retry-After when the queue is full.")
    recover: Literal["requeue", "fail"] = Field(
        "requeue", description="What happens to jobs that were running when their server or worker died."
    )
    max_attempts: int = Field(3, ge=1, description="A job interrupted this many times is failed instead of re-queued.")
    job_wall_time: float = Field(3600.0, gt=0, description="Per-job wall-time limit in seconds (job fails beyond it).")
    cancel_grace: float = Field(5.0, gt=0, description="Seconds a cancelled/over-time job may take to stop before its worker is killed.")
    heartbeat_interval: float = Field(0.5, gt=0, description="Worker progress/heartbeat write period (s).")
    heartbeat_timeout: float = Field(30.0, gt=0, description="A running job without a heartbeat this long is recovered.")
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

    # ------------------------------------------------------- security
    api_keys: Annotated[list[str], NoDecode] = Field(
        default_factory=list, description="Accepted X-API-Key values; empty: no authentication."
    )
    metrics_public: bool = Field(False, description="Serve /metrics without an API key.")
    cors_origins: Annotated[list[str], NoDecode] = Field(default_factory=list, description="Allowed CORS origins.")

    log_level: str = "info"

    # ------------------------------------------------------ tests only
    test_hold_file: Path | None = Field(
        None, description="FOR TESTS ONLY (unset in production: no effect). While this file exists, a worker "
        "whose job has reported progress pauses the search (heartbeats continue), so integration tests can "
        "kill a worker or server while a job is provably mid-run, however fast the machine.",
    )

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
        return self.data_dir / "jobs"


@lru_cache(maxsize=1)
def get_settings() -> Settings:
    """The process-wide settings singleton (from the environment)."""
    return Settings()
