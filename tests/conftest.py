"""Shared test set-up. The tree mirrors the package: tests/<package>/test_<module>.py.

Test files are plain modules (no ``__init__.py``) with unique names; pytest puts each file's
folder on ``sys.path``, so a folder's helpers (``tests/verification/plant_fixtures.py``) import by name.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
from collections.abc import Callable
from pathlib import Path
from typing import Any

import pytest

#: The repository root (docs/, models/, pyproject.toml).
REPO_ROOT = Path(__file__).resolve().parents[1]

# Headless plotting everywhere (the report and `simulate --plot` render with matplotlib).
os.environ.setdefault("MPLBACKEND", "Agg")


@pytest.fixture(scope="session")
def repo_root() -> Path:
    """The repository root."""
    return REPO_ROOT


def run_fresh_python(code: str, env: dict[str, str] | None = None, timeout: float = 300) -> Any:
    """Run ``code`` in a fresh interpreter; return the JSON value its last stdout line holds.

    For what only a new process shows: which modules an import path loads, a first import.
    """
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=env, check=True,
                         timeout=timeout).stdout
    return json.loads(out.strip().splitlines()[-1])


@pytest.fixture(scope="session")
def fresh_python() -> Callable[..., Any]:
    """:func:`run_fresh_python`: ``fresh_python(code, env=None, timeout=300)``."""
    return run_fresh_python


# ------------------------------------------------------------------------------------- tiny trained tuners

#: Sizes of the tiny tuners the tests train: the figures mean nothing, every code path is the real one.
TINY_TRAINING: dict[str, Any] = dict(n_envs=32, contexts_per_step=4, n_steps=4, batch_size=64, validation=2,
                                     curve_contexts=1)


def tiny_training_settings() -> dict[str, Any]:
    """:data:`TINY_TRAINING`, with a checkpoint every 512 episodes where the settings name the interval (``chunk``)."""
    from gaintune.tuners.train import TrainSettings

    fields = getattr(TrainSettings, "__dataclass_fields__", {})
    return {**TINY_TRAINING, **({"chunk": 512} if "chunk" in fields else {})}


def tank_family_spec() -> dict[str, Any]:
    """The water tank's example spec as a family over the operating level H0 (2 .. 20 m)."""
    from gaintune.plants.library import load_model

    spec = load_model("water_tank").example_spec()
    spec["randomize"] = {"params": {"H0": [2.0, 20.0]}}
    return spec


@pytest.fixture(scope="session")
def tiny_training() -> dict[str, Any]:
    """:func:`tiny_training_settings`, for tests that train a tuner themselves."""
    return tiny_training_settings()


@pytest.fixture
def tank_spec() -> dict[str, Any]:
    """:func:`tank_family_spec`: a fresh copy per test."""
    return tank_family_spec()


def _run_root(tmp_path_factory) -> Path:
    """A folder shared by every xdist worker of this test run (the worker's own basetemp without xdist)."""
    root = tmp_path_factory.getbasetemp()
    if os.environ.get("PYTEST_XDIST_WORKER"):
        root = root.parent  # the folder every worker's basetemp sits in
    (root / "shared").mkdir(exist_ok=True)
    return root / "shared"


@pytest.fixture
def one_ray_test_at_a_time(tmp_path_factory):
    """Hold a run-wide lock for the test: the Ray tests share one 2-CPU cluster and kill its workers, so two
    xdist workers never run them side by side (``make test`` runs two)."""
    from filelock import FileLock

    with FileLock(str(_run_root(tmp_path_factory) / "ray.lock")):
        yield


def _once_per_run(tmp_path_factory, name: str, build: Callable[[Path], Path]) -> Path:
    """``build(folder)`` once per test run: the xdist workers (``make test`` runs two) share the first one's.

    Each worker has its own session, so a session fixture alone trained every tiny tuner once per worker
    (~25 s each). A file lock in the run's shared temporary folder makes the others wait and reuse it.
    """
    from filelock import FileLock

    root = _run_root(tmp_path_factory)
    folder, done = root / name, root / f"{name}.done"
    with FileLock(str(root / f"{name}.lock")):
        if not done.exists():
            folder = build(folder)
            done.write_text(str(folder))
    return Path(done.read_text())


@pytest.fixture(scope="session")
def tiny_fotd_tuner(tmp_path_factory) -> Path:
    """A FOTD PI tuner (Ms <= 1.4) trained for 512 episodes (about 25 s on the 2-core machine)."""
    from gaintune.tuners.problems import FamilyProblem
    from gaintune.tuners.train import TrainSettings, train

    return _once_per_run(tmp_path_factory, "fotd_pi", lambda out: train(
        FamilyProblem("fotd", "pi", 1.4), out, TrainSettings(episodes=512, **tiny_training_settings())))


@pytest.fixture(scope="session")
def tiny_tank_tuner(tmp_path_factory) -> Path:
    """A spec tuner of the water tank over H0, trained for 512 episodes."""
    from gaintune.spec import load_spec
    from gaintune.tuners.problems import SpecProblem
    from gaintune.tuners.train import TrainSettings, train

    return _once_per_run(tmp_path_factory, "tank_h0", lambda out: train(
        SpecProblem(load_spec(tank_family_spec())), out, TrainSettings(episodes=512, **tiny_training_settings())))
