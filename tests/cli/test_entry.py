"""The process entry (gaintune.cli.entry): a command run as the program exits without interpreter
teardown, with the exit code, output and atexit handlers of an ordinary exit."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

from gaintune.cli import app, entry

SPEC = {"plant": {"tf": {"num": [1], "den": "(s+1)^3"}}, "loops": [{"type": "pi"}],
        "scenario": {"dt": 0.05, "horizon": 20}}
GOOD = {"loop0": {"Kp": 1.14, "Ki": 0.454}}
UNSTABLE = {"loop0": {"Kp": 20.0, "Ki": 10.0}}


def run_main(code: str, *, full_exit: bool = False, cwd: Path | None = None) -> subprocess.CompletedProcess:
    """Run ``code`` as ``__main__`` of a fresh interpreter (as the console script runs the app)."""
    env = dict(os.environ)
    env.pop("GAINTUNE_FULL_EXIT", None)
    if full_exit:
        env["GAINTUNE_FULL_EXIT"] = "1"
    return subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=300, env=env, cwd=cwd)


@pytest.fixture(scope="module")
def spec_file(tmp_path_factory) -> Path:
    p = tmp_path_factory.mktemp("entry") / "pi.json"
    p.write_text(json.dumps(SPEC))
    return p


@pytest.mark.parametrize(("gains", "code"), [(GOOD, 0), (UNSTABLE, 3), ({"loop0": {"Kp": -1}}, 2)])
def test_verify_as_the_program_exits_as_the_ordinary_exit_does(spec_file: Path, gains, code: int) -> None:
    """Exit code, stdout and stderr are those of the ordinary interpreter exit (GAINTUNE_FULL_EXIT=1)."""
    prog = f"from gaintune.cli import app\napp(['verify', {str(spec_file)!r}, '--gains', {json.dumps(gains)!r}])"
    fast, full = run_main(prog), run_main(prog, full_exit=True)
    assert fast.returncode == full.returncode == code, (fast.stderr, full.stderr)
    assert fast.stdout == full.stdout and fast.stderr == full.stderr
    assert (fast.stdout if code != 2 else fast.stderr).strip()


def test_atexit_handlers_run_and_output_is_flushed() -> None:
    prog = ("import atexit, sys\natexit.register(lambda: print('atexit ran', flush=False))\n"
            "sys.stdout.write('partial line without newline')\nfrom gaintune.cli import app\napp(['--help'])")
    res = run_main(prog)
    assert res.returncode == 0, res.stderr
    assert res.stdout.startswith("partial line without newline")
    assert "Usage:" in res.stdout and res.stdout.rstrip().endswith("atexit ran")


def test_a_live_non_daemon_thread_gets_the_ordinary_exit() -> None:
    """The interpreter joins non-daemon threads before exiting; the fast exit must not cut them off."""
    prog = ("import threading, time\n"
            "def late():\n    time.sleep(0.5)\n    print('thread finished', flush=True)\n"
            "threading.Thread(target=late).start()\nfrom gaintune.cli import app\napp(['--help'])")
    res = run_main(prog)
    assert res.returncode == 0 and "thread finished" in res.stdout


def test_python_m_gaintune_exit_codes(spec_file: Path) -> None:
    env = {k: v for k, v in os.environ.items() if k != "GAINTUNE_FULL_EXIT"}
    ok = subprocess.run([sys.executable, "-m", "gaintune", "verify", str(spec_file), "--gains", json.dumps(GOOD)],
                        capture_output=True, text=True, timeout=300, env=env)
    bad = subprocess.run([sys.executable, "-m", "gaintune.cli", "verify", str(spec_file), "--gains", json.dumps(UNSTABLE)],
                         capture_output=True, text=True, timeout=300, env=env)
    assert ok.returncode == 0 and "PASS" in ok.stdout
    assert bad.returncode == 3 and "FAIL" in bad.stdout


def test_called_in_process_the_app_raises_system_exit_as_before() -> None:
    """Tests and programs embedding the app (not ``__main__``) keep the ordinary SystemExit."""
    with pytest.raises(SystemExit) as exc:
        app(["--help"])
    assert exc.value.code == 0


@pytest.mark.parametrize(("code", "status"), [(None, 0), (0, 0), (3, 3), ("message", 1)])
def test_exit_code_as_the_interpreter_derives_it(code, status: int, capsys) -> None:
    assert entry._exit_code(code) == status
    if isinstance(code, str):
        assert capsys.readouterr().err == "message\n"


def test_serve_turns_the_fast_exit_off(monkeypatch) -> None:
    import types

    calls = []
    fake = types.ModuleType("gaintune_api.main")
    fake.serve = lambda host, port, workers: calls.append((host, port, workers))
    monkeypatch.setitem(sys.modules, "gaintune_api.main", fake)
    monkeypatch.setattr(entry, "FAST_EXIT", True)
    from typer.testing import CliRunner

    res = CliRunner().invoke(app, ["serve", "--port", "8123"])
    assert res.exit_code == 0 and calls == [("127.0.0.1", 8123, 1)]
    assert entry.FAST_EXIT is False


def test_under_a_profiler_the_ordinary_exit_lets_it_report() -> None:
    """``python -m cProfile -m gaintune ...`` prints its statistics after the program returns."""
    env = {k: v for k, v in os.environ.items() if k != "GAINTUNE_FULL_EXIT"}
    res = subprocess.run([sys.executable, "-m", "cProfile", "-m", "gaintune", "--help"], capture_output=True, text=True,
                         timeout=300, env=env)
    assert res.returncode == 0 and "Usage:" in res.stdout and "ncalls" in res.stdout


def test_the_program_runs_with_the_raised_gc_threshold_and_an_embedding_caller_keeps_its_own() -> None:
    """Start-up imports trigger full collections at CPython's default threshold (700): a command run
    as the program raises it to GC_THRESHOLD0; a caller that embeds the app keeps its setting."""
    report = "import atexit, gc\natexit.register(lambda: print('threshold', gc.get_threshold()[0]))\n"
    res = run_main(report + "from gaintune.cli import app\napp(['--help'])")
    assert res.returncode == 0, res.stderr
    assert res.stdout.rstrip().endswith(f"threshold {entry.GC_THRESHOLD0}")
    embedded = ("import gc\nfrom gaintune.cli import app\n"  # called from a module other than __main__
                "try:\n    exec(\"app(['--help'])\", {'__name__': 'embedder', 'app': app})\nexcept SystemExit:\n    pass\n"
                "print('threshold', gc.get_threshold()[0])\n")
    res = subprocess.run([sys.executable, "-c", embedded], capture_output=True, text=True, timeout=300)
    assert res.returncode == 0, res.stderr
    assert res.stdout.rstrip().endswith("threshold 700")


def test_a_fresh_tuner_query_runs_no_cyclic_collection_at_the_raised_threshold() -> None:
    """A fresh ``gaintune tuner query`` allocates ~155,000 objects once the threshold is raised (numba's
    and scipy's imports among them): at GC_THRESHOLD0 it runs no collection (at 50,000 it ran three,
    each walking those start-up objects)."""
    code = ("import atexit, gc\nn = [0]\n"
            "gc.callbacks.append(lambda phase, info: n.__setitem__(0, n[0] + (phase == 'start' "
            "and gc.get_threshold()[0] > 700)))\n"
            "atexit.register(lambda: print('collections', n[0]))\n"
            "from gaintune.cli import app\n"
            "app(['tuner', 'query', 'fotd_pi_ms1.4', '-p', 'K=2', '-p', 'T=60', '-p', 'L=10', '--json'])")
    res = run_main(code)
    assert res.returncode == 0, res.stderr
    assert res.stdout.rstrip().endswith("collections 0"), res.stdout[-200:]


def test_the_program_keeps_freed_memory_in_the_heap_and_an_embedding_caller_keeps_its_allocator() -> None:
    """A command run as the program sets glibc's mmap and trim thresholds (keep_heap): an answer's temporaries
    were otherwise mapped and handed back time and again (~160 page faults per tuner answer, 14 with them)."""
    spy = ("import atexit\nimport gaintune.cli.entry as e\ncalls = []\nreal = e.keep_heap\n"
           "e.keep_heap = lambda: calls.append(real()) or calls[-1]\n"
           "atexit.register(lambda: print('keep_heap', calls))\n")
    res = run_main(spy + "from gaintune.cli import app\napp(['--help'])")
    assert res.returncode == 0, res.stderr
    assert res.stdout.rstrip().endswith("keep_heap [True]" if sys.platform.startswith("linux") else "keep_heap [False]")
    embedded = (spy + "from gaintune.cli import app\n"
                "try:\n    exec(\"app(['--help'])\", {'__name__': 'embedder', 'app': app})\nexcept SystemExit:\n    pass\n")
    res = subprocess.run([sys.executable, "-c", embedded], capture_output=True, text=True, timeout=300)
    assert res.returncode == 0, res.stderr
    assert res.stdout.rstrip().endswith("keep_heap []")


def test_keep_heap_sets_both_thresholds_and_leaves_a_users_setting(monkeypatch) -> None:
    import ctypes

    calls = []

    class FakeLibc:
        def __init__(self, _name) -> None:
            self.mallopt = self

        def __call__(self, param, value):
            calls.append((param, value))
            return 1

    monkeypatch.setattr(ctypes, "CDLL", FakeLibc)
    monkeypatch.setattr(sys, "platform", "linux")
    monkeypatch.delenv("MALLOC_MMAP_THRESHOLD_", raising=False)
    monkeypatch.delenv("MALLOC_TRIM_THRESHOLD_", raising=False)
    assert entry.keep_heap() is True
    assert calls == [(-3, entry.MMAP_THRESHOLD), (-1, entry.TRIM_THRESHOLD)]
    calls.clear()
    monkeypatch.setenv("MALLOC_TRIM_THRESHOLD_", "131072")
    assert entry.keep_heap() is False and calls == []
    monkeypatch.delenv("MALLOC_TRIM_THRESHOLD_")
    monkeypatch.setattr(sys, "platform", "darwin")
    assert entry.keep_heap() is False and calls == []
