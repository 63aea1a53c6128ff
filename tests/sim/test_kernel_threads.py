"""Batches of more than one chunk run on threads, each a range of chunks of the one compiled variant:
the numbers and traces are those of one serial pass, bit for bit, whatever the thread count."""

from __future__ import annotations

import threading

import numba
import numpy as np
import pytest

from gaintune.sim import Simulator
from gaintune.sim import draws as draws_mod
from gaintune.sim.kernel import CHUNK, drivers, run_kernel
from gaintune.spec import load_spec

NOISY_DELAYED = {
    "plant": {"tf": {"num": ["K"], "den": "(T*s + 1)^3"}, "params": {"K": 1.0, "T": 1.0}, "delay": 0.1},
    "loops": [{"type": "pid", "anti_windup": "back_calculation"}],
    "actuator": {"limits": [-3, 3], "rate_limit": 20.0},
    "scenario": {"dt": 0.02, "horizon": 3.0, "noise_std": 0.01,
                 "disturbance": {"kind": "step", "entry": "input", "amplitude": 0.3, "time": 1.5}},
    "randomize": {"params": {"K": [0.7, 1.3], "T": [0.8, 1.2]}, "delay": [0.0, 0.33],
                  "reference_kinds": ["step", "ramp"], "actuator_scale": [0.8, 1.2]},
}


def _args(B: int):
    sim = Simulator(load_spec(NOISY_DELAYED))
    rng = np.random.default_rng(11)
    d = draws_mod.sample(sim.spec, sim.plant, rng, B)
    tuned = sim.layout.initial_tuned()[None, :] * np.exp(rng.uniform(-0.3, 0.3, (B, sim.layout.log_lo.size)))
    args = sim.kernel_args(sim.layout.full(tuned), d, traces=True)
    noise = np.zeros(B)
    noise[-3:] = 0.01  # noise in the last chunk only: the batch-wide flag must be the whole batch's
    return args._replace(noise_std=noise)


@pytest.mark.parametrize("threads", [2, 3, 5])
def test_threads_over_chunk_ranges_give_the_serial_numbers_and_traces(threads: int, monkeypatch) -> None:
    B = 3 * CHUNK + 5  # four chunks, the last partial
    serial = _args(B)
    out_serial = run_kernel(serial, "serial")
    monkeypatch.setattr(numba.config, "NUMBA_NUM_THREADS", threads)
    par = serial.with_traces()
    out_par = run_kernel(par, "parallel")
    np.testing.assert_array_equal(np.nan_to_num(out_par, nan=-7.0), np.nan_to_num(out_serial, nan=-7.0))
    for name in ("tr_y", "tr_sp", "tr_u"):
        np.testing.assert_array_equal(getattr(par, name), getattr(serial, name), err_msg=name)
    assert np.all(par.tr_u[:, -1] != 0.0)  # the last range's traces were written


def test_auto_runs_a_large_batch_on_threads_like_one_serial_pass(monkeypatch) -> None:
    args = _args(2 * CHUNK + 1)
    calls = []
    real = drivers._serial

    class Spy:  # the compiled variant, recording each call's chunk range and thread
        def __call__(self, *a):
            calls.append((a[-2], a[-1], threading.current_thread().name))
            return real(*a)

    monkeypatch.setattr(numba.config, "NUMBA_NUM_THREADS", 2)
    monkeypatch.setattr(drivers, "_serial", Spy())
    out = run_kernel(args)
    assert sorted(c[:2] for c in calls) == [(0, 1), (1, 3)]
    assert len({c[2] for c in calls}) == 2
    monkeypatch.undo()
    np.testing.assert_array_equal(np.nan_to_num(out, nan=-7.0), np.nan_to_num(run_kernel(args, "serial"), nan=-7.0))


def test_kernel_threads_do_not_keep_a_finished_command_alive(monkeypatch) -> None:
    """Daemon threads: the CLI's fast exit skips interpreter teardown only when no other thread must be joined."""
    monkeypatch.setattr(numba.config, "NUMBA_NUM_THREADS", 2)
    run_kernel(_args(CHUNK + 1), "parallel")
    workers = [t for t in threading.enumerate() if t.name.startswith("gaintune-kernel")]
    assert workers and all(t.daemon for t in workers)


def test_a_forked_process_starts_its_own_kernel_threads(monkeypatch) -> None:
    pool = drivers._workers(1)
    monkeypatch.setattr(pool, "pid", pool.pid + 1)  # as a fork's child sees its parent's (dead) threads
    assert drivers._workers(1) is not pool


def test_a_process_limited_to_one_sim_thread_runs_a_large_batch_on_the_calling_thread(monkeypatch) -> None:
    """A sweep worker given one CPU must not spread its batches over the other workers' cores."""
    from gaintune.sim.threads import set_sim_threads, sim_threads

    args = _args(2 * CHUNK + 1)
    calls = []
    real = drivers._serial

    def spy(*a):
        calls.append(threading.current_thread().name)
        return real(*a)

    monkeypatch.setattr(numba.config, "NUMBA_NUM_THREADS", 2)
    monkeypatch.setattr(drivers, "_serial", spy)
    set_sim_threads(1)
    try:
        assert sim_threads() == 1
        run_kernel(args)
    finally:
        set_sim_threads(None)
    assert calls == [threading.current_thread().name]
    assert sim_threads() == 2
