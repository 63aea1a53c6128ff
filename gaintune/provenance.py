"""Versions of Python, gaintune and the packages that shape its numbers (provenance of every result), and the
CPUs this process may use."""

from __future__ import annotations

import os
import platform
from importlib.metadata import PackageNotFoundError, version

__all__ = ["PACKAGES", "versions", "cpus_here"]

#: Packages whose versions can change a result.
PACKAGES = ("gaintune", "numpy", "scipy", "numba", "control", "casadi", "torch", "stable-baselines3", "gymnasium",
            "pydantic")


def versions() -> dict[str, str]:
    """``{"python": ..., package: version}``; a package that is not installed reads "not installed".

    Examples
    --------
    >>> v = versions()
    >>> {"python", "gaintune", "numpy"} <= set(v)
    True
    """
    out = {"python": platform.python_version()}
    for pkg in PACKAGES:
        try:
            out[pkg] = version(pkg)
        except PackageNotFoundError:
            out[pkg] = "not installed"
    return out


def cpus_here() -> int:
    """The CPUs this process may run on (its affinity mask, where the OS has one)."""
    try:
        return len(os.sched_getaffinity(0))
    except AttributeError:  # pragma: no cover - not Linux
        return os.cpu_count() or 1
