"""Sweeps on the local backend: a bad spec fails alone, a killed driver resumes without rerunning what finished,
a worker process that dies is replaced, and the summary exports."""

from __future__ import annotations

import csv
import importlib
import json
import os
import signal
import subprocess
import sys
import textwrap
from pathlib import Path

import pytest
from sweep_fleets import TINY_SPEC, grid_fleet, write_fleet
from typer.testing import CliRunner

from gaintune import cli
from gaintune.sweep import SweepOptions, run_sweep
from gaintune.sweep.store import SqliteStore
from gaintune.sweep.worker import Hook, ledger_lines

runner = CliRunner()


def test_a_bad_spec_fails_only_its_item_with_its_error_in_the_summary(tmp_path):
    bad = {**TINY_SPEC, "name": "bad", "plant": {**TINY_SPEC["plant"], "delay": "-L"}}
    fleet = write_fleet(tmp_path, {"name": "mixed", "specs": [TINY_SPEC, bad, "missing.yaml"]})
    out = tmp_path / "out"
    res = runner.invoke(cli.app, ["sweep", str(fleet), "--out", str(out), "--workers", "1"])
    assert res.exit_code == 3, res.output  # not every item passed
    assert "Traceback" not in res.output and "pass 1, fail 0, error 2" in res.output
    res = runner.invoke(cli.app, ["sweep", "summary", str(out), "--csv", str(tmp_path / "s.csv"),
                                  "--parquet", str(tmp_path / "s.parquet")])
    assert res.exit_code == 0, res.output
    rows = list(csv.DictReader((tmp_path / "s.csv").open()))
    assert [r["status"] for r in rows] == ["done", "error", "error"]
    assert rows[0]["verdict"] == "pass" and float(rows[0]["flow.Kp"]) > 0 and json.loads(rows[0]["gains"])
    assert "plant.delay" in rows[1]["error"] and "file not found" in rows[2]["error"]
    pq = importlib.import_module("pyarrow.parquet") if os.environ.get("CI") else pytest.importorskip("pyarrow.parquet")
    table = pq.read_table(tmp_path / "s.parquet").to_pylist()
    assert [r["status"] for r in table] == ["done", "error", "error"]
    assert table[0]["flow.Kp"] == float(rows[0]["flow.Kp"])


DRIVER = textwrap.dedent("""
    import os, signal, sys
    from gaintune.sweep import SweepOptions, run_sweep
    from gaintune.sweep.worker import Hook

    fleet, out, ledger, after = sys.argv[1], sys.argv[2], sys.argv[3], int(sys.argv[4])

    def on_record(rec, report):
        if report.ran >= after:  # the record is committed: die now, as a kill -9 of the driver would
            os.kill(os.getpid(), signal.SIGKILL)

    run_sweep(fleet, out, SweepOptions(workers=1, hook=Hook(ledger=ledger)), on_record=on_record)
""")


def test_a_killed_driver_resumes_and_reruns_nothing_that_finished(tmp_path):
    fleet, out = grid_fleet(tmp_path, [0.5, 1.0, 1.5, 2.0]), tmp_path / "out"
    log = open(tmp_path / "driver.log", "w")  # a file, not a pipe: an orphaned worker may hold it a moment
    proc = subprocess.run([sys.executable, "-c", DRIVER, str(fleet), str(out), str(tmp_path / "run1"), "2"],
                          stdout=log, stderr=subprocess.STDOUT, timeout=900)
    assert proc.returncode == -signal.SIGKILL, (tmp_path / "driver.log").read_text()
    store = SqliteStore(out / "sweep.db")
    finished = store.finished_keys()
    store.close()
    assert len(finished) == 2
    report = run_sweep(fleet, out, SweepOptions(workers=1, hook=Hook(ledger=str(tmp_path / "run2"))))
    assert report.skipped == 2 and report.ran == 2 and report.refused == 0
    started = [key for what, key, _ in ledger_lines(tmp_path / "run2") if what == "start"]
    assert sorted(started) == sorted(set(started)) and not set(started) & finished  # nothing finished ran again
    store = SqliteStore(out / "sweep.db")
    assert len(store.finished_keys()) == 4 and all(r["verdict"] == "pass" for r in store.records())
    store.close()
    # the killed driver's worker died with it: at most the item it was running got done, never the ones queued
    # to it (without that it ran on through them, unrecorded, while the restart ran them again)
    orphaned = {key for what, key, _ in ledger_lines(tmp_path / "run1") if what == "done"} - finished
    assert len(orphaned) <= 1


def test_a_local_worker_process_that_dies_is_replaced_and_its_item_run_again(tmp_path):
    fleet, out, ledger, gate = grid_fleet(tmp_path, [0.5, 1.0, 2.0]), tmp_path / "out", tmp_path / "ledger", \
        tmp_path / "gate"
    import threading

    def kill_first_worker() -> None:  # wait for an item to be held at the gate, kill its worker, open the gate
        import time

        for _ in range(60_000):
            lines = ledger_lines(ledger)
            if lines:
                os.kill(lines[0][2], signal.SIGKILL)
                break
            time.sleep(0.01)
        Path(gate).touch()

    t = threading.Thread(target=kill_first_worker)
    t.start()
    report = run_sweep(fleet, out, SweepOptions(workers=1, hook=Hook(ledger=str(ledger), gate=str(gate))))
    t.join()
    lines = ledger_lines(ledger)
    done = [key for what, key, _ in lines if what == "done"]
    assert len({pid for _, _, pid in lines}) == 2  # the killed worker and its replacement
    assert len(done) == len(set(done)) == 3 and report.ran == 3 and report.counts == {"pass": 3}
