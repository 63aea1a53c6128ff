"""The first run on a cold numba cache (issue 25): the variants a tune needs compile side by side,
behind "compiling the simulator (first run only)"; a warm cache costs a lookup and says nothing."""

from __future__ import annotations

import io
import json
import os
import subprocess
import sys
from pathlib import Path

import numba
import numpy as np
from numba.core import ir_utils
from numba.core.compiler import CompilerBase, DefaultPassBuilder
from numba.core.compiler_machinery import FunctionPass, register_pass
from numba.core.typed_passes import NopythonRewrites
from rich.console import Console

from gaintune.cli import compiling
from gaintune.sim import kernel_aot, precompile
from gaintune.sim.kernel import COMPILED, pipeline

_SEEN: list[tuple[dict, dict]] = []


@register_pass(mutates_CFG=False, analysis_only=True)
class _BothCopyPropagations(FunctionPass):
    _name = "gaintune_test_both_copy_propagations"

    def __init__(self) -> None:
        FunctionPass.__init__(self)

    def run_pass(self, state) -> bool:
        numbas, _ = ir_utils.copy_propagate(state.func_ir.blocks, state.typemap)
        _SEEN.append((pipeline._copy_propagate(state.func_ir.blocks, state.typemap), numbas))
        return False


class _Compare(CompilerBase):
    def define_pipelines(self):
        pm = DefaultPassBuilder.define_nopython_pipeline(self.state)
        pm.add_pass_after(_BothCopyPropagations, NopythonRewrites)
        pm.finalize()
        return [pm]


@numba.njit(inline="always")
def _stage(a, b, n):
    for i in range(n):
        a[i] = b[i] + a[i]


def _loops(x, y, n):
    z = x
    for k in range(n):
        w = y
        if k % 2:
            w = z
        _stage(z, w, n)
    return z


def test_shallow_copy_propagation_reaches_numbas_fixed_point() -> None:
    """The kernel's copy propagation snapshots shallowly; it must find numba's copies, block for block."""
    _SEEN.clear()
    numba.njit(pipeline_class=_Compare)(_loops)(np.ones(4), np.ones(4), 4)
    ours, numbas = _SEEN[-1]
    assert ours == numbas
    assert any(ours.values())  # the inlined stage's parameter copies are there to propagate


def test_the_sample_signature_is_every_calls_signature(monkeypatch) -> None:
    """What is compiled ahead is what real calls need: nonlinear, randomised, traced, any batch (a batch of one
    on the JIT variant here: the ahead-of-time module is compiled for this same signature)."""
    import gaintune.sim.kernel as kernel

    monkeypatch.setattr(kernel, "load_single", lambda: None)
    from gaintune.plants.library import load_model
    from gaintune.sim import Simulator
    from gaintune.sim import draws as draws_mod
    from gaintune.spec import load_spec

    sample = precompile._sample_args()
    # other tests in the same process may have compiled other signatures on purpose: only the ones these
    # calls add count
    before = {name: list(fn.signatures) for name, fn in COMPILED.items()}
    for model in ("water_tank", "dc_motor"):
        sim = Simulator(load_spec(load_model(model).example_spec()))
        for B in (1, 3, 70):
            d = draws_mod.sample(sim.spec, sim.plant, np.random.default_rng(0), B) if sim.spec.randomize.active else None
            sim.run(np.tile(sim.layout.full(sim.layout.initial_tuned()), (B, 1)), d, traces=B == 3)
    for name, fn in COMPILED.items():
        want = tuple(fn.typeof_pyval(a) for a in sample)
        added = [sig for sig in fn.signatures if sig not in before[name]]
        assert want in fn.signatures and all(sig == want for sig in added), (name, added)


def test_a_cold_cache_lacks_every_variant_and_the_check_compiles_nothing(fresh_python, tmp_path: Path) -> None:
    code = ("import json; from gaintune.sim.precompile import missing; from gaintune.sim.kernel import COMPILED; "
            "print(json.dumps([missing(), [len(f.signatures) for f in COMPILED.values()]]))")
    todo, loaded = fresh_python(code, env={**os.environ, "NUMBA_CACHE_DIR": str(tmp_path)})
    assert sorted(todo) == sorted(COMPILED) and loaded == [0, 0]


def test_variants_this_process_has_are_not_missing() -> None:
    for fn in COMPILED.values():
        fn(*precompile._sample_args())
    assert precompile.missing() == []


def test_a_failed_child_compile_is_reported_not_raised() -> None:
    seen = []
    failed = precompile.precompile(["single", "no_such_variant"], on_progress=lambda d, t: seen.append((d, t)),
                                   processes=2)
    assert list(failed) == ["no_such_variant"] and "KeyError" in failed["no_such_variant"]
    assert seen[0] == (0, 2) and sorted(seen[1:]) == [(1, 2), (2, 2)]


def _console() -> tuple[Console, io.StringIO]:
    buf = io.StringIO()
    return Console(file=buf, width=120, force_terminal=False), buf


def test_a_warm_cache_compiles_nothing_and_says_nothing() -> None:
    for fn in COMPILED.values():
        fn(*precompile._sample_args())
    console, buf = _console()
    assert compiling.compile_simulator(console) == []
    assert buf.getvalue() == ""


def test_missing_variants_show_compiling_the_simulator_with_their_count(monkeypatch) -> None:
    """The message logic: the progress line names the first run and counts the variants as they finish."""
    def fake_precompile(todo, on_progress=None, processes=None):
        for done in range(len(todo) + 1):
            on_progress(done, len(todo))
        return {}

    monkeypatch.setattr(precompile, "missing", lambda: ["single", "serial"])
    monkeypatch.setattr(precompile, "precompile", fake_precompile)
    console, buf = _console()
    assert compiling.compile_simulator(console) == ["single", "serial"]
    assert "compiling the simulator (first run only)" in buf.getvalue() and "2/2" in buf.getvalue()


def test_first_demo_on_a_cold_cache_says_compiling_the_simulator(tmp_path: Path) -> None:
    """A real first run: empty numba cache, both variants compiled (side by side), the message on stderr; the
    ahead-of-time single-lane module is a tuner query's to build, not a tune's."""
    cache = tmp_path / "numba"
    env = {**os.environ, "NUMBA_CACHE_DIR": str(cache)}
    run = subprocess.run([sys.executable, "-m", "gaintune", "demo", "--budget", "10", "--out", str(tmp_path / "out")],
                         capture_output=True, text=True, env=env, cwd=tmp_path, timeout=900)
    assert run.returncode in (0, 3), run.stderr[-2000:]  # 3: a 10-simulation search may fail verification
    assert "compiling the simulator (first run only)" in run.stderr and "2/2" in run.stderr
    for name in COMPILED:
        assert list(cache.rglob(f"*simulate_kernel_{name}_*.nbi")), name
    assert not list(cache.rglob(f"{kernel_aot.module_name()}*"))
    again = subprocess.run([sys.executable, "-c", "import json; from gaintune.sim.precompile import missing; "
                            "print(json.dumps(missing()))"], capture_output=True, text=True, env=env, check=True)
    assert json.loads(again.stdout) == []


def test_a_failed_compile_in_this_process_is_reported_not_raised() -> None:
    failed = precompile.precompile(["no_such_variant"], processes=1)
    assert list(failed) == ["no_such_variant"] and "KeyError" in failed["no_such_variant"]


def test_a_tuner_querys_first_run_builds_the_ahead_of_time_kernel_behind_the_compile_line(monkeypatch) -> None:
    built = []

    def fake_precompile(todo, on_progress=None, processes=None):
        built.extend(todo)
        for done in range(len(todo) + 1):
            on_progress(done, len(todo))
        return {}

    monkeypatch.setattr(precompile, "precompile", fake_precompile)
    monkeypatch.setattr(kernel_aot, "aot_missing", lambda: True)
    console, buf = _console()
    assert compiling.compile_single_kernel(console) == [kernel_aot.AOT] == built
    assert "compiling the simulator (first run only)" in buf.getvalue() and "1/1" in buf.getvalue()
    monkeypatch.setattr(kernel_aot, "aot_missing", lambda: False)  # built, or a build failed before: nothing
    console, buf = _console()
    assert compiling.compile_single_kernel(console) == [] and buf.getvalue() == ""


def test_a_built_ahead_of_time_kernel_costs_a_query_no_numba_import(fresh_python) -> None:
    precompile.build_single()
    code = ("import sys, json; from gaintune.cli.compiling import compile_single_kernel; "
            "print(json.dumps([compile_single_kernel(None), 'numba' in sys.modules]))")
    assert fresh_python(code) == [[], False]

