"""The API's job folder: a symlink planted there is replaced, never written through; its .env is read bounded."""

from __future__ import annotations

import os
import threading
from pathlib import Path

from gaintune.plants.library import load_model
from gaintune.report import render_report, result_from_gains
from gaintune.spec import load_spec
from gaintune_api.jobfiles import JobFiles
from gaintune_api.settings import unknown_settings

PRECIOUS = "precious: must not be overwritten"


def test_api_job_folder_symlink_not_followed(tmp_path: Path) -> None:
    outside = tmp_path / "elsewhere"
    outside.mkdir()
    files = JobFiles(tmp_path / "jobs")
    files.ensure_root()
    # the readiness probe's file
    probe_target = outside / "probe"
    probe_target.write_text(PRECIOUS)
    probe = files.root / f".probe-{os.getpid()}-{threading.get_ident()}"
    probe.symlink_to(probe_target)
    files.probe()
    assert probe_target.read_text() == PRECIOUS and not probe.exists() and not probe.is_symlink()
    # the cached report of a job
    report_target = outside / "report.html"
    report_target.write_text(PRECIOUS)
    files.job_dir("j1").mkdir()
    (files.job_dir("j1") / "report.html").symlink_to(report_target)
    result = result_from_gains(load_spec(load_model("lag_n").example_spec()),
                               {"main": {"Kp": 0.6485, "Ki": 0.3957, "Kd": 0.3751}})
    path = files.write_report("j1", lambda tmp: render_report(result, tmp))
    assert report_target.read_text() == PRECIOUS
    assert not path.is_symlink() and "<html" in path.read_text()
    assert sorted(p.name for p in outside.iterdir()) == ["probe", "report.html"]


def test_env_file_fifo_not_read_by_the_unknown_settings_check(tmp_path: Path) -> None:
    """A FIFO .env with no writer: reading it would block the server's start; it is skipped at once."""
    fifo = tmp_path / ".env"
    os.mkfifo(fifo)
    assert unknown_settings({}, fifo) == []
