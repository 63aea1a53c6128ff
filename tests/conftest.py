"""Shared test set-up. The tree mirrors the package: tests/<package>/test_<module>.py.

Test files are plain modules (no ``__init__.py``) with unique names; pytest puts each file's
folder on ``sys.path``, so a folder's helpers (``tests/verify/plant_fixtures.py``) import by name.
"""

from __future__ import annotations

import os
from pathlib import Path

import pytest

#: The repository root (docs/, models/, pyproject.toml).
REPO_ROOT = Path(__file__).resolve().parents[1]

# Headless plotting everywhere (the report and `simulate --plot` render with matplotlib).
os.environ.setdefault("MPLBACKEND", "Agg")


@pytest.fixture(scope="session")
def repo_root() -> Path:
    """The repository root."""
    return REPO_ROOT
