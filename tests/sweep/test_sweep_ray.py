"""Sweeps on Ray (a local cluster of 2 CPUs, or the one at $RAY_ADDRESS): the same results as the local backend,
and a Ray worker killed while it runs an item loses nothing and finishes nothing twice."""

from __future__ import annotations

import os
import signal
import threading
import time
from pathlib import Path

import pytest
from sweep_fleets import grid_fleet

from gaintune.sweep import SweepOptions, run_sweep
from gaintune.sweep.store import SqliteStore
from gaintune.sweep.worker import Hook, ledger_lines

# the Ray tests run one at a time across the xdist workers: they share one 2-CPU cluster
pytestmark = pytest.mark.usefixtures("one_ray_test_at_a_time")


def _answers(out: Path) -> dict[str, tuple]:
    store = SqliteStore(out / "sweep.db")
    try:
        return {r["key"]: (r["status"], r["verdict"], r["cost"], r["gains"], r["sims"], r["seed"])
                for r in store.records()}
    finally:
        store.close()


def test_local_and_ray_backends_give_identical_results_on_a_seeded_sweep(tmp_path, ray_cluster):
    fleet = grid_fleet(tmp_path, [0.5, 1.0, 2.0])
    local = run_sweep(fleet, tmp_path / "local", SweepOptions(backend="local", workers=2))
    ray = run_sweep(fleet, tmp_path / "ray", SweepOptions(backend="ray"))
    assert local.counts == ray.counts == {"pass": 3}
    a, b = _answers(tmp_path / "local"), _answers(tmp_path / "ray")
    assert a == b and len(a) == 3  # bit-identical costs and gains


def _kill_first_started(ledger: Path, gate: Path, killed: list[int]) -> None:
    """Wait until an item is held at the gate, SIGKILL the Ray worker running it, then open the gate."""
    try:
        for _ in range(60_000):
            lines = ledger_lines(ledger)
            if lines:
                killed.append(lines[0][2])
                os.kill(lines[0][2], signal.SIGKILL)
                return
            time.sleep(0.01)
    finally:
        gate.touch()


def test_a_killed_ray_worker_loses_nothing_and_finishes_nothing_twice(tmp_path, ray_cluster):
    fleet, ledger, gate = grid_fleet(tmp_path, [0.5, 1.0, 1.5, 2.0]), tmp_path / "ledger", tmp_path / "gate"
    killed: list[int] = []
    t = threading.Thread(target=_kill_first_started, args=(ledger, gate, killed))
    t.start()
    report = run_sweep(fleet, tmp_path / "out", SweepOptions(backend="ray", hook=Hook(str(ledger), str(gate))))
    t.join()
    lines = ledger_lines(ledger)
    victim = next(key for what, key, pid in lines if what == "start" and pid == killed[0])
    starts = [key for what, key, _ in lines if what == "start"]
    done = [key for what, key, _ in lines if what == "done"]
    assert starts.count(victim) == 2  # Ray ran the killed item again
    assert sorted(done) == sorted(set(done)) and len(done) == 4  # each item ran to completion once
    assert report.ran == 4 and report.refused == 0 and report.counts == {"pass": 4}
    assert {s for s, *_ in _answers(tmp_path / "out").values()} == {"done"}


def test_cpus_per_task_reaches_ray_so_tasks_that_ask_for_every_cpu_never_overlap(tmp_path, ray_cluster):
    """``--cpus-per-task`` is Ray's ``num_cpus``: tasks asking for all the cluster's CPUs run one at a time."""
    cpus = int(ray_cluster.cluster_resources()["CPU"])
    fleet = grid_fleet(tmp_path, [0.5, 1.0, 2.0])
    report = run_sweep(fleet, tmp_path / "ray", SweepOptions(backend="ray", cpus_per_task=cpus))
    assert report.counts == {"pass": 3}
    store = SqliteStore(tmp_path / "ray" / "sweep.db")
    try:
        spans = sorted((r["started"], r["finished"]) for r in store.records())
    finally:
        store.close()
    assert all(a[1] <= b[0] for a, b in zip(spans, spans[1:], strict=False))
