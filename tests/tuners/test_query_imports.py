"""A tuner query in a fresh process: what it imports and which compiled kernel it runs on (the ahead-of-time
single-lane module, without numba; and, with it turned off, numba's single-lane JIT variant alone).

Asserted on ``sys.modules`` and on the kernel dispatchers' loaded overloads, never on time (the
times are ``gaintune bench tuners``' figures).
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

import gaintune

#: A child that answers one query through the library, then reports its modules and the loaded kernel variants.
PROBE = """
import json, sys
from gaintune.tuners.tuner import Tuner
answer = Tuner.load("fotd_pi_ms1.4").query({"K": 2.0, "T": 60.0, "L": 10.0})
modules = sorted(sys.modules)
from gaintune.sim.kernel import drivers
print(json.dumps({"verdict": answer.verdict, "modules": modules,
                  "single": len(drivers._single.overloads), "serial": len(drivers._serial.overloads)}))
"""


def _probe(tmp: Path, **env: str) -> dict:
    """The probe's report, from one fresh process in an empty folder (importing this tree's gaintune)."""
    env = {**os.environ, "PYTHONPATH": str(Path(gaintune.__file__).resolve().parents[1]), **env}
    proc = subprocess.run([sys.executable, "-c", PROBE], capture_output=True, text=True, env=env,
                          cwd=tmp, timeout=900, check=False)
    assert proc.returncode == 0, proc.stderr[-3000:]
    return json.loads(proc.stdout.strip().splitlines()[-1])


@pytest.fixture(scope="module")
def probed(tmp_path_factory: pytest.TempPathFactory) -> dict:
    """A fresh query with the ahead-of-time kernel module built (as a first tune leaves it)."""
    from gaintune.sim.precompile import build_single

    build_single()
    return _probe(tmp_path_factory.mktemp("probe"))


@pytest.fixture(scope="module")
def probed_jit(tmp_path_factory: pytest.TempPathFactory) -> dict:
    """A fresh query with the module turned off: numba's JIT kernel."""
    return _probe(tmp_path_factory.mktemp("probe_jit"), GAINTUNE_KERNEL_AOT="0")


def test_tuner_query_in_a_fresh_process_imports_no_torch_and_no_cli(probed: dict) -> None:
    """The answer path (NumPy policy, boundary move, verification) loads neither the learner (torch,
    stable-baselines3, gymnasium) nor the command line (typer, gaintune.cli)."""
    got = probed
    assert got["verdict"] == "pass"
    mods = set(got["modules"])
    top = {m.split(".")[0] for m in mods}
    assert "numpy" in top and "gaintune.tuners.tuner" in mods  # the module list is the child's
    assert not top & {"torch", "stable_baselines3", "gymnasium", "typer", "click", "rich"}, sorted(
        top & {"torch", "stable_baselines3", "gymnasium", "typer", "click", "rich"})
    assert not {m for m in mods if m.startswith("gaintune.cli")}
    # an answer that passes never needs the exact move (imported only for an answer that fails)
    assert "gaintune.evaluation.boundary_exact" not in mods


def test_tuner_query_in_a_fresh_process_runs_on_the_compiled_module_without_numba(probed: dict) -> None:
    """Importing numba and loading its cached kernel cost ~0.25 s of a fresh query: the ahead-of-time module
    needs neither (the probe imports the JIT drivers only after its module list was taken)."""
    mods = set(probed["modules"])
    assert probed["verdict"] == "pass" and probed["single"] == probed["serial"] == 0
    assert not {m for m in mods if m.split(".")[0] in ("numba", "llvmlite")}
    mimo = {"gaintune.plants.mimo", "gaintune.sim.mimo", "gaintune.sim.mimo_kernel"}
    assert not mods & mimo, sorted(mods & mimo)


def test_tuner_query_on_the_jit_kernel_loads_one_kernel_variant(probed_jit: dict) -> None:
    """Every simulation of one query runs on the single-lane variant: the CHUNK-lane one is never loaded
    (loading a compiled variant from numba's cache costs ~30 ms of CPU)."""
    got = probed_jit
    assert got["verdict"] == "pass" and got["single"] == 1 and got["serial"] == 0, got


def test_tuner_query_on_the_jit_kernel_skips_numbas_registries_and_the_mimo_modules(probed_jit: dict) -> None:
    """Loading the cached kernel does not refresh numba's target context (every typing and lowering
    registry: ~0.16 s of a fresh query; :class:`gaintune.sim.kernel_cache.KernelCache`), and a
    single-input problem does not import the MIMO plant and simulator modules (their predicates live
    beside the SISO ones)."""
    mods = set(probed_jit["modules"])
    assert "numba" in mods and "gaintune.sim.kernel_cache" in mods
    refresh_only = {"numba.typed.typeddict", "numba.np.random.generator_methods", "numba.np.npyimpl",
                    "numba.cpython.mathimpl", "numba.experimental.function_type"}
    assert not mods & refresh_only, sorted(mods & refresh_only)
    mimo = {"gaintune.plants.mimo", "gaintune.sim.mimo", "gaintune.sim.mimo_kernel"}
    assert not mods & mimo, sorted(mods & mimo)
