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
