"""Every benchmark module runs as ``python -m gaintune.bench.<name>``, as the package docstring says."""

from __future__ import annotations

import subprocess
import sys

import pytest


@pytest.mark.parametrize("name", ["constraints", "verify", "ablation"])
def test_bench_module_run_with_python_m_is_not_a_silent_no_op(name):
    """Regression: these modules had no ``__main__`` block, so ``python -m`` exited 0 having done nothing."""
    out = subprocess.run([sys.executable, "-m", f"gaintune.bench.{name}", "--help"], capture_output=True, text=True,
                         timeout=300)
    assert out.returncode == 0, out.stderr
    assert f"usage: gaintune bench {name}" in out.stdout


def test_bench_module_run_with_python_m_checks_its_arguments():
    """The ``-m`` entry is the same ``main`` as ``gaintune bench verify``: a bad option exits 2 naming it."""
    out = subprocess.run([sys.executable, "-m", "gaintune.bench.verify", "--repeat", "0"], capture_output=True,
                         text=True, timeout=300)
    assert out.returncode == 2 and "--repeat" in out.stderr and "Traceback" not in out.stderr
