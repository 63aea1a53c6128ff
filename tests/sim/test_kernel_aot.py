"""The single-lane kernel compiled ahead of time (gaintune.sim.kernel_aot): the JIT variant's numbers bit for bit,
a fresh query without numba, and the JIT variant wherever the module is missing, damaged or cannot be built."""

from __future__ import annotations

import os
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from gaintune.sim import kernel_aot, precompile
from gaintune.sim.kernel import drivers
from gaintune.sim.precompile import build_single


@pytest.fixture(scope="module")
def aot_single() -> Any:
    """The built module's kernel (built once per machine and kernel source; a file lock keeps workers apart)."""
    build_single()
    single = kernel_aot.load_single()
    assert single is not None
    return single


def _cases() -> list[tuple[str, Any, np.ndarray]]:
    """(name, simulator, one full gain vector): nonlinear (tape), linear, delay with noise, randomised plant."""
    from gaintune.plants.library import load_model
    from gaintune.sim import Simulator
    from gaintune.spec import load_spec

    out = []
    for model in ("water_tank", "dc_motor"):
        sim = Simulator(load_spec(load_model(model).example_spec()))
        out.append((model, sim, sim.layout.full(sim.layout.initial_tuned())))
    noisy = {"plant": {"tf": {"num": [2.0], "den": [3.0, 1.0]}, "delay": 0.7}, "loops": [{"type": "pid"}],
             "scenario": {"noise_std": 0.05, "dt": 0.05, "horizon": 30.0,
                          "disturbance": {"kind": "step", "amplitude": 0.5, "time": 10.0}}}
    sim = Simulator(load_spec(noisy))
    out.append(("fotd_noise", sim, sim.layout.full([0.4, 0.2, 0.3])))
    return out


def test_the_compiled_module_gives_the_jit_variants_numbers_and_traces_bit_for_bit(aot_single) -> None:
    for name, sim, full in _cases():
        for traced in (False, True):
            a = sim.kernel_args(full[None, :], traces=traced)
            b = sim.kernel_args(full[None, :], traces=traced)
            out_aot, out_jit = aot_single(*a, 0, 1), drivers.COMPILED["single"](*b, 0, 1)
            assert out_aot.tobytes() == out_jit.tobytes(), name
            for field in ("tr_y", "tr_sp", "tr_u"):
                assert getattr(a, field).tobytes() == getattr(b, field).tobytes(), (name, field)
            if traced:
                assert np.any(a.tr_u != 0.0), name


def test_a_tuner_query_in_a_fresh_process_runs_without_numba(aot_single, fresh_python) -> None:
    code = ("import sys, json; from gaintune.tuners.tuner import Tuner; "
            "a = Tuner.load('fotd_pi_ms1.4').query({'K': 2.0, 'T': 60.0, 'L': 10.0}); "
            "print(json.dumps([a.verdict, 'numba' in sys.modules]))")
    assert fresh_python(code) == ["pass", False]


def test_a_damaged_module_is_passed_over_and_the_jit_variant_runs(tmp_path: Path, fresh_python) -> None:
    env = {**os.environ, "NUMBA_CACHE_DIR": str(tmp_path)}
    code = ("import json; from gaintune.sim import kernel_aot as K; p = K.module_file(K.dirs()[0]); "
            "p.parent.mkdir(parents=True); p.write_bytes(b'not a shared object'); "
            "from gaintune.sim import Simulator; from gaintune.spec import load_spec; "
            "s = Simulator(load_spec({'plant': {'tf': {'num': [1], 'den': [1, 1]}}, 'loops': [{'type': 'pi'}], "
            "'scenario': {'dt': 0.1, 'horizon': 2.0}})); "
            "r = s.run(s.layout.full(s.layout.initial_tuned())[None, :]); "
            "print(json.dumps([K.load_single() is None, K.aot_missing(), float(r.metrics['iae'][0]) > 0]))")
    assert fresh_python(code, env=env) == [True, False, True]


def test_a_failed_build_is_noted_and_not_tried_again_on_every_run(tmp_path: Path, monkeypatch) -> None:
    monkeypatch.setenv("NUMBA_CACHE_DIR", str(tmp_path))

    def no_compiler(out_dir: Path) -> Path:
        raise OSError("no C compiler on this machine")

    monkeypatch.setattr(precompile, "_compile", no_compiler)
    assert kernel_aot.aot_missing()
    with pytest.raises(OSError, match="no C compiler"):
        build_single()
    assert not kernel_aot.aot_missing()
    note = kernel_aot.failed_note(kernel_aot.dirs()[0])
    assert "no C compiler" in note.read_text()
    assert [p.name for p in note.parent.iterdir() if p.is_dir()] == []  # the build folder is gone


def test_the_module_name_follows_the_kernel_source_the_numba_release_and_the_cpu() -> None:
    name = kernel_aot.module_name()
    assert name.startswith(f"gaintune_kernel_single_{drivers._TAG}_") and name.isidentifier()
    import numba

    assert numba.__version__.replace(".", "_") in name


def test_the_compiled_module_runs_on_several_threads_at_once_with_each_calls_own_numbers(aot_single) -> None:
    """It releases the GIL as the JIT variant does (the API's compute threads answer queries side by side); each
    call allocates its own arrays, and numba's runtime counts references atomically."""
    from concurrent.futures import ThreadPoolExecutor

    cases = _cases()
    args = [sim.kernel_args(full[None, :] * scale) for _, sim, full in cases for scale in (0.8, 1.0, 1.2)]
    alone = [aot_single(*a, 0, 1).tobytes() for a in args]
    with ThreadPoolExecutor(4) as pool:
        together = list(pool.map(lambda a: aot_single(*a, 0, 1).tobytes(), args * 8))
    assert together == alone * 8


def test_a_module_another_process_built_meanwhile_is_loaded_by_a_process_that_looked_before(tmp_path: Path,
                                                                                            monkeypatch) -> None:
    """Regression (CI, two pytest workers): a process that looked for the module before it existed kept that
    answer (load_single is read once per process), and build_single, finding the module another process had
    built meanwhile, returned without telling it: the process ran on the JIT variant for good."""
    monkeypatch.setattr(precompile, "_writable_dir", lambda: tmp_path)
    kernel_aot.load_single()  # this process looks (and remembers)
    assert kernel_aot.load_single.cache_info().currsize == 1
    precompile.module_file(tmp_path).write_bytes(b"built by another process")
    assert build_single() == precompile.module_file(tmp_path)
    assert kernel_aot.load_single.cache_info().currsize == 0  # the next load looks again
