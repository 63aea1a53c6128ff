"""The sweep tests' local Ray cluster (the fleets themselves are in sweep_fleets.py)."""

from __future__ import annotations

import importlib.util
import os

import pytest


@pytest.fixture(scope="session")
def ray_cluster():
    """A Ray cluster for the session: the one at $RAY_ADDRESS (CI starts it), else a local one of 2 CPUs."""
    from gaintune.sweep.backends import connect, import_ray

    if importlib.util.find_spec("ray") is None and not os.environ.get("CI"):  # CI installs it: never skipped there
        pytest.skip("ray is not installed (pip install 'gaintune[ray]')")
    ray = import_ray()
    connect(ray, None, 2)  # as the sweep connects: $RAY_ADDRESS, else a local cluster
    yield ray
    ray.shutdown()
