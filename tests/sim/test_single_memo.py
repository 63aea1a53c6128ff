"""A single untraced candidate simulated again on the same draw set and scenario returns the first run's output
(a tuner's answer simulates the gains it returns in the move and again in the verification)."""

from __future__ import annotations

import numpy as np

import gaintune.sim.simulator as simulator
from gaintune.sim import Simulator
from gaintune.sim import draws as draws_mod
from gaintune.spec import load_spec

SPEC = {"plant": {"tf": {"num": [2.0], "den": [3.0, 1.0]}, "delay": 0.5}, "loops": [{"type": "pi"}],
        "scenario": {"noise_std": 0.02, "dt": 0.05, "horizon": 20.0},
        "randomize": {"params": {}, "delay": [0.4, 0.6]}}


def test_the_same_candidate_on_the_same_draws_runs_the_kernel_once_and_returns_copies(monkeypatch) -> None:
    sim = Simulator(load_spec(SPEC))
    runs = []
    real = simulator.run_kernel

    def counted(args, *a):
        runs.append(1)
        return real(args, *a)

    monkeypatch.setattr(simulator, "run_kernel", counted)
    full = sim.layout.full(np.array([0.4, 0.3]))[None, :]
    first = sim.run(full)
    first.metrics["iae"][0] = -1.0  # a caller that changes its result changes nobody else's
    again = sim.run(full, sim.nominal_draws(1))  # the same draw set passed explicitly: the same key
    assert len(runs) == 1 and again.metrics["iae"][0] > 0
    fresh = Simulator(load_spec(SPEC)).run(full)
    assert {k: v.tobytes() for k, v in again.metrics.items()} == {k: v.tobytes() for k, v in fresh.metrics.items()}


def test_other_gains_draws_scenarios_or_traces_run_the_kernel_again(monkeypatch) -> None:
    sim = Simulator(load_spec(SPEC))
    runs = []
    real = simulator.run_kernel
    monkeypatch.setattr(simulator, "run_kernel", lambda args, *a: runs.append(1) or real(args, *a))
    full = sim.layout.full(np.array([0.4, 0.3]))[None, :]
    base = sim.run(full)
    other = draws_mod.sample(sim.spec, sim.plant, np.random.default_rng(3), 1)
    moved = sim.run(full * 1.01)
    drawn = sim.run(full, other)
    traced = sim.run(full, traces=True)
    assert len(runs) == 4
    assert moved.metrics["iae"][0] != base.metrics["iae"][0] and drawn.metrics["iae"][0] != base.metrics["iae"][0]
    assert traced.metrics["iae"][0] == base.metrics["iae"][0] and "u" in traced.traces
