"""The results store: a finished record is written once and never replaced; a crashed one is."""

from __future__ import annotations

import pytest

from gaintune.sweep.store import DirStore, SqliteStore
from gaintune.sweep.worker import error_record


def _done(key: str, cost: float) -> dict:
    rec = error_record({"key": key, "kind": "tune", "label": key}, "done", "")
    rec.update(error=None, verdict="pass", cost=cost, gains={"loop0": {"Kp": cost}}, sims=10, seed=0)
    return rec


@pytest.fixture(params=["sqlite", "dir"])
def store(request, tmp_path):
    s = SqliteStore(tmp_path / "sweep.db") if request.param == "sqlite" else DirStore(tmp_path / "results")
    yield s
    s.close()


def test_a_finished_record_is_never_written_twice(store):
    assert store.put(_done("a", 1.0))
    assert not store.put(_done("a", 2.0))  # a second answer for a finished item is refused
    assert not store.put(error_record({"key": "a", "kind": "tune"}, "crashed", "lost"))
    [rec] = store.records()
    assert rec["cost"] == 1.0 and rec["gains"] == {"loop0": {"Kp": 1.0}}
    assert store.finished_keys() == {"a"}


def test_a_crashed_record_is_replaced_by_the_finished_one(store):
    assert store.put(error_record({"key": "b", "kind": "tune"}, "crashed", "lost"))
    assert store.finished_keys() == set()  # a resumed sweep runs it again
    assert store.put(_done("b", 3.0))
    assert store.finished_keys() == {"b"} and store.records()[0]["status"] == "done"


def test_records_survive_reopening(tmp_path):
    s = SqliteStore(tmp_path / "sweep.db")
    s.put(_done("c", 1.5))
    s.close()
    again = SqliteStore(tmp_path / "sweep.db")
    assert again.finished_keys() == {"c"}
    again.close()


def test_a_sweep_item_keeps_the_simulator_to_the_cpus_it_asked_for() -> None:
    """Before, a 1-CPU worker's simulator ran on every core, so two workers fought over the same two."""
    from gaintune.sim.threads import set_sim_threads, sim_threads
    from gaintune.sweep.worker import run_item

    try:
        rec = run_item(dict(key="k", label="bad", kind="tune", doc={"plant": "nope"}, cpus=1))
        assert rec["status"] == "error"
        assert sim_threads() == 1
    finally:
        set_sim_threads(None)
