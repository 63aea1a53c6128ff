"""Tuner-training jobs (``POST /v1/tuners``): a worker trains a tuner into the attempt's staging folder.

A job of kind ``tuner`` stores its request (:class:`gaintune_api.schemas.TunerTrainRequest`) in the
``spec`` column. :func:`run_tuner_job` runs it like a tuning job (:func:`gaintune_api.worker.run_job`):
the attempt's monitor (:class:`gaintune_api.attempt.Attempt`) heartbeats the progress (episodes done,
the training curve's median cost / optimum) and stops the training on a cancel request, the wall-time
limit or a lost claim; the final state is written fenced by the claim, and the tuner's files
(``tuner.json``, ``policy.npz``, ``agent.zip``) are renamed into the job folder by the owning
attempt only. The job folder is then a tuner folder (``POST /v1/tuners/job:{id}/query``).

A worker killed mid-training leaves its checkpoint in its staging folder; the next attempt of the
job (after recovery) copies the most advanced one into its own and resumes from it
(:func:`gaintune.tuners.train.train` continues a checkpoint of the same problem and settings).
"""

from __future__ import annotations

import json
import logging
import shutil
import threading
import traceback
from pathlib import Path
from typing import Any

from gaintune_api.attempt import Attempt
from gaintune_api.job_commit import commit, error_text, outcome
from gaintune_api.job_store import JobRow
from gaintune_api.jobfiles import STAGING, JobFiles
from gaintune_api.schemas import TunerTrainRequest
from gaintune_api.settings import Settings
from gaintune_api.storage_faults import StorageFault, classify
from gaintune_api.stores import Store

__all__ = ["run_tuner_job", "train_settings", "problem_of", "TRAIN_DEFAULTS", "TUNER_DIR"]

log = logging.getLogger("gaintune.worker")

#: The folder inside the staging folder that training writes (its checkpoint: ``.tuner.training`` beside it).
TUNER_DIR = "tuner"
#: TrainSettings fields a request does not choose (the library's defaults; tests shrink the network's batches).
TRAIN_DEFAULTS: dict[str, Any] = {}


class _Stopped(Exception):
    """The monitor asked the training to stop (cancel, wall time, lost claim)."""


def problem_of(req: TunerTrainRequest) -> Any:
    """The training problem of a request: its spec's family, or a ready-made family."""
    from gaintune.tuners.problems import FamilyProblem, SpecProblem

    if req.spec is not None:
        return SpecProblem(req.spec)
    return FamilyProblem(str(req.family), req.ctype or "pi", req.ms_max or 1.4)


def train_settings(req: TunerTrainRequest) -> Any:
    """The request's TrainSettings: its episodes and seed over :data:`TRAIN_DEFAULTS`."""
    from gaintune.tuners.train import TrainSettings

    chosen: dict[str, Any] = {"seed": req.seed}
    if req.episodes is not None:
        chosen["episodes"] = req.episodes
    return TrainSettings(**{**TRAIN_DEFAULTS, **chosen})


def _checkpoint_of(staging: Path) -> Path:
    return staging / f".{TUNER_DIR}.training"


def _seed_checkpoint(files: JobFiles, job: JobRow, staging: Path) -> None:
    """Copy the most advanced checkpoint an earlier (killed) attempt of the job left into this attempt's folder."""
    best, best_episodes = None, 0
    for d in (files.job_dir(job.id) / STAGING).glob(f"*/{_checkpoint_of(Path()).name}"):
        if d.parent == staging:
            continue
        try:
            episodes = int(json.loads((d / "state.json").read_text())["episodes"])
        except (OSError, ValueError, KeyError, TypeError):
            continue
        if episodes > best_episodes:
            best, best_episodes = d, episodes
    if best is not None:
        shutil.copytree(best, _checkpoint_of(staging), dirs_exist_ok=True)
        log.info("job %s: resuming the training from attempt folder %s (%d episodes)", job.id, best.parent.name,
                 best_episodes)


def _flatten(folder: Path, staging: Path) -> None:
    """Move the tuner's files up into the staging folder (the promoter renames the staging folder's files)."""
    for f in folder.iterdir():
        f.replace(staging / f.name)
    folder.rmdir()


def _train(req: TunerTrainRequest, staging: Path, attempt: Attempt) -> tuple[dict[str, Any] | None, str | None]:
    """Train with ``attempt``'s monitor beside it: (the tuner's summary or None, the error text or None)."""
    from gaintune.tuners.listing import summary
    from gaintune.tuners.train import train

    threading.Thread(target=attempt.watch, name=f"monitor-{attempt.job.id[:8]}", daemon=True).start()
    last: dict[str, Any] = {}

    def on_progress(done: int, total: int, info: dict[str, Any]) -> None:
        if info.get("ratio") is not None:
            last["median_ratio"] = float(info["ratio"])
        p = {"phase": "validate" if done >= total else "train", "episodes": done, "episodes_total": total,
             "sims": int(info.get("sims") or 0), "budget": 0, "elapsed": float(info.get("elapsed_s") or 0.0), **last}
        if not attempt.on_progress(p):
            raise _Stopped

    try:
        folder = train(problem_of(req), staging / TUNER_DIR, train_settings(req), name=req.label(),
                       on_progress=on_progress)
        _flatten(folder, staging)
        return summary(staging, req.label()), None
    except _Stopped:
        return None, None
    except BaseException as exc:  # noqa: BLE001 - a job failure must never kill the worker loop
        if isinstance(exc, (KeyboardInterrupt, SystemExit)):
            raise
        from gaintune.errors import GaintuneError

        if not isinstance(exc, GaintuneError) and classify(exc, "data") is None:
            log.error("tuner job %s crashed:\n%s", attempt.job.id, traceback.format_exc())
        return None, error_text(exc)
    finally:
        attempt.done.set()


def run_tuner_job(store: Store, job: JobRow, settings: Settings, files: JobFiles, *, hard_exit: bool) -> str:
    """Run one claimed tuner-training job to a terminal state (the status written, or "lost")."""
    claim = job.claim
    assert claim is not None
    req = TunerTrainRequest.model_validate_json(job.spec)
    try:
        staging = files.stage(job.id, job.attempts, claim)
        _seed_checkpoint(files, job, staging)
    except (StorageFault, OSError) as exc:
        fault = exc if isinstance(exc, StorageFault) else classify(exc, "data")
        detail = fault.detail if fault is not None else str(exc)
        log.error("job %s cannot write its folder: %s", job.id, detail)
        return commit(store, files, job, None, "failed", result=None, progress=None, settings=settings,
                       error=f"storage fault: {detail} The job was not started.")
    attempt = Attempt(store, job, claim, settings, hard_exit)
    tuner, error = _train(req, staging, attempt)
    if attempt.reason == "lost":
        files.discard(staging)
        log.warning("job %s: attempt %d lost its claim: stopped, and discarded its files", job.id, job.attempts)
        return "lost"
    payload = None
    if tuner is not None:
        payload = {"kind": "tuner", "tuner": tuner, "tuner_path": str(files.job_dir(job.id)),
                   "agent_path": files.final_path(job.id, staging / "agent.zip", staging)}
    status, error = outcome(attempt.reason, error, settings)
    progress = {**(attempt.progress or {}), "phase": "done"} if tuner is not None else attempt.progress
    return commit(store, files, job, staging, status, result=payload, error=error, progress=progress,
                   settings=settings)
