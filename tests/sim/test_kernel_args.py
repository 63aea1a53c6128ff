"""The kernel's argument record: its fields are the kernel's parameters, and a record from
``Simulator.kernel_args`` run through ``run_kernel`` gives ``Simulator.run``'s numbers bit for bit."""

from __future__ import annotations

import inspect
import shutil
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from gaintune.sim import KernelArgs, Simulator
from gaintune.sim import draws as draws_mod
from gaintune.sim.kernel import METRICS, VARIANTS, drivers, run_kernel, simulate_kernel
from gaintune.spec import load_spec

LAG3 = {"tf": {"num": [1], "den": "(s+1)^3"}}
NOISY_DELAYED: dict[str, Any] = {
    "plant": {"tf": {"num": ["K"], "den": "(T*s + 1)^3"}, "params": {"K": 1.0, "T": 1.0}, "delay": 0.1},
    "loops": [{"type": "pid", "anti_windup": "back_calculation"}],
    "actuator": {"limits": [-3, 3], "rate_limit": 20.0},
    "scenario": {"dt": 0.02, "horizon": 6.0, "noise_std": 0.01,
                 "disturbance": {"kind": "step", "entry": "input", "amplitude": 0.3, "time": 3.0}},
    "randomize": {"params": {"K": [0.7, 1.3], "T": [0.8, 1.2]}, "delay": [0.0, 0.33],
                  "reference_kinds": ["step", "ramp"], "actuator_scale": [0.8, 1.2]},
}


def _spec(name: str) -> dict[str, Any]:
    from gaintune.plants.library import load_model

    if name == "noisy_delayed":
        return NOISY_DELAYED
    if name == "lag3_pid_sat":
        return {"plant": LAG3, "loops": [{"type": "pid", "anti_windup": "clamping"}],
                "actuator": {"limits": [-1.5, 1.5]}, "scenario": {"dt": 0.01, "horizon": 5.0},
                "safety": {"max_abs_output": 1.3}}
    return load_model(name).example_spec()


def test_record_fields_are_the_kernel_parameters_in_order() -> None:
    """The record, then the range of chunks to run (what the threads over a batch split)."""
    assert KernelArgs._fields + ("chunk0", "chunk1") == tuple(inspect.signature(drivers._kernel).parameters)
    assert len(KernelArgs._fields) == len(set(KernelArgs._fields))


@pytest.mark.parametrize("name, B", [("lag3_pid_sat", 1), ("noisy_delayed", 70), ("dc_motor", 9), ("water_tank", 3)])
def test_record_of_a_real_batch_runs_like_simulator_run_bit_for_bit(name: str, B: int) -> None:
    sim = Simulator(load_spec(_spec(name)))
    rng = np.random.default_rng(5)
    tuned = sim.layout.initial_tuned()[None, :] * np.exp(rng.uniform(-0.5, 0.5, (B, sim.layout.log_lo.size)))
    full = sim.layout.full(tuned)
    d = draws_mod.sample(sim.spec, sim.plant, rng, B) if sim.spec.randomize.active else None
    args = sim.kernel_args(full, d, traces=True)
    assert isinstance(args, KernelArgs) and args.batch == B and args.n_loops == len(sim.spec.loops)
    out = run_kernel(args)
    res = sim.run(full, d, traces=True)
    for i, m in enumerate(METRICS):
        np.testing.assert_array_equal(out[i], res.metrics[m].astype(float), err_msg=m)
    for i, lp in enumerate(sim.spec.loops):
        np.testing.assert_array_equal(args.tr_y[i].T, res.traces[f"y.{lp.name}"])
        np.testing.assert_array_equal(args.tr_sp[i].T, res.traces[f"sp.{lp.name}"])
    np.testing.assert_array_equal(args.tr_u.T, res.traces["u"])
    # the record splats into the kernel positionally, as before the record existed
    np.testing.assert_array_equal(simulate_kernel(*args), out)


def test_a_field_replaced_by_name_reaches_the_kernel_parameter_of_that_name() -> None:
    sim = Simulator(load_spec({"plant": LAG3, "loops": [{"type": "pi"}], "scenario": {"dt": 0.01, "horizon": 5.0}}))
    g = sim.layout.from_dict({"loop0": {"Kp": 1.0, "Ki": 0.4}})
    doubled = sim.layout.from_dict({"loop0": {"Kp": 2.0, "Ki": 0.4}})
    args = sim.kernel_args(g[None, :])
    out = run_kernel(args._replace(kp=args.kp * 2.0))
    ref = sim.run(doubled[None, :])
    for i, m in enumerate(METRICS):
        np.testing.assert_array_equal(out[i], ref.metrics[m].astype(float), err_msg=m)
    assert not np.array_equal(run_kernel(args)[0], out[0])


def test_variants_and_traces() -> None:
    sim = Simulator(load_spec({"plant": LAG3, "loops": [{"type": "pid"}], "scenario": {"dt": 0.01, "horizon": 2.0}}))
    full = np.tile(sim.layout.from_dict({"loop0": {"Kp": 2.0, "Ki": 1.0, "Kd": 0.5}}), (3, 1))
    args = sim.kernel_args(full)
    assert not args.want_traces and args.tr_u.size == 0
    tr = args.with_traces()
    assert tr.want_traces and tr.tr_y.shape == (1, args.n_steps, 3) and tr.tr_u.shape == (args.n_steps, 3)
    outs = {v: run_kernel(tr if v == "serial" else args, v) for v in VARIANTS}
    for o in outs.values():
        np.testing.assert_array_equal(o, outs["serial"])
    assert np.all(tr.tr_u[0] != 0.0)
    with pytest.raises(ValueError, match="variant"):
        run_kernel(args, "gpu")


def test_cache_tag_covers_every_kernel_module(tmp_path: Path) -> None:
    """numba's cache checks only the compiled function's file: the variants' names carry a hash of all of them."""
    here = Path(drivers.__file__).parent
    copy = tmp_path / "kernel"
    shutil.copytree(here, copy, ignore=shutil.ignore_patterns("__pycache__"))
    assert drivers._source_tag(copy) == drivers._TAG
    assert all(drivers._TAG in fn.py_func.__qualname__ for fn in drivers.COMPILED.values())
    law = copy / "law.py"
    law.write_text(law.read_text() + "\n# edited\n")
    assert drivers._source_tag(copy) != drivers._TAG


def test_the_record_does_not_load_numba(fresh_python) -> None:
    assert fresh_python("import sys, json, gaintune.sim.kernel_args; print(json.dumps('numba' in sys.modules))") is False


def test_from_fields_takes_every_field_by_name_and_nothing_else() -> None:
    values = {name: i for i, name in enumerate(KernelArgs._fields)}
    head = dict(list(values.items())[:10])
    assert tuple(KernelArgs.from_fields(head, values)) == tuple(range(len(values)))
    with pytest.raises(TypeError, match=r"missing \['dt'\], unknown \[\]"):
        KernelArgs.from_fields({k: v for k, v in values.items() if k != "dt"})
    with pytest.raises(TypeError, match=r"missing \[\], unknown \['zz'\]"):
        KernelArgs.from_fields(values, {"zz": 0})
    with pytest.raises(TypeError, match=r"missing \['dt'\], unknown \['zz'\]"):
        KernelArgs.from_fields({k: v for k, v in values.items() if k != "dt"}, {"zz": 0})
