"""``gaintune bench ...`` with bad arguments: one ``error: --option: ...`` line and exit 2, never a traceback or a hang.

Regressions of the fuzz findings F11 (tracebacks), F12 (hangs, an orphaned API server) and F13
(clear messages but exit 1). Every check fails fast: the arguments are refused at parse time,
before any benchmark, subprocess or server starts.
"""

from __future__ import annotations

import importlib
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

GAINTUNE = str(Path(sys.executable).with_name("gaintune"))


def _exit_code(fn, *args) -> int:
    try:
        return int(fn(*args) or 0)
    except SystemExit as exc:
        return exc.code if isinstance(exc.code, int) else 1


def _assert_bad_input(capsys, module: str, argv: list[str], option: str) -> str:
    """``gaintune.bench.<module>.main(argv)`` exits 2 with one ``error: <option>: ...`` line on stderr."""
    main = importlib.import_module(f"gaintune.bench.{module}").main
    code = _exit_code(main, argv)
    err = capsys.readouterr().err
    assert code == 2, f"exit {code}, stderr: {err}"
    lines = [line for line in err.splitlines() if line.strip()]
    assert len(lines) == 1 and lines[0].startswith(f"error: {option}: "), err
    assert "Traceback" not in err
    return lines[0]


def _run_cli(args: list[str], timeout: float = 30) -> subprocess.CompletedProcess:
    """The real ``gaintune`` command in its own session; the whole group is killed on timeout (no orphans)."""
    p = subprocess.Popen([GAINTUNE, *args], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                         start_new_session=True)
    try:
        out, err = p.communicate(timeout=timeout)
    except subprocess.TimeoutExpired:
        os.killpg(p.pid, signal.SIGKILL)
        p.communicate()
        pytest.fail(f"gaintune {' '.join(args)} still running after {timeout} s")
    return subprocess.CompletedProcess(p.args, p.returncode, out, err)


# ------------------------------------------------------------------ F11: tracebacks


@pytest.mark.parametrize("module, argv, option", [
    ("sim", ["--case", "lag3_pid", "--batch", "0", "--repeat", "1", "--no-memory", "--no-numpy"], "--batch"),
    ("sim", ["--case", "lag3_pid", "--batch", "-1", "--repeat", "1", "--no-memory", "--no-numpy"], "--batch"),
    ("sim", ["--case", "lag3_pid", "--batch", "100000000000", "--repeat", "1", "--no-memory", "--no-numpy"], "--batch"),
    ("sim", ["--case", "lag3_pid", "--batch", "1", "--repeat", "0", "--no-memory", "--no-numpy"], "--repeat"),
    ("verify", ["--repeat", "0"], "--repeat"),
    ("verify", ["--repeat", "-1"], "--repeat"),
    ("startup", ["--repeat", "0"], "--repeat"),
    ("constraints", ["--n", "-1"], "--n"),
    ("constraints", ["--n", "2", "--spread", "-1"], "--spread"),
    ("constraints", ["--n", "2", "--spread", "nan"], "--spread"),
    ("ablation", ["--configs", "nope", "--budget", "10"], "--configs"),
    ("chaos", ["--jobs", "1", "--worker-kills", "0", "--server-kills", "0", "--rounds", "0", "--budget", "-1"], "--budget"),
    ("kernel", ["--rev", "HEAD", "--batch", "0"], "--batch"),
    ("search", ["--suite", "quick", "--seeds", "-1"], "--seeds"),
])
def test_f11_bad_bench_number_exits_2_naming_the_option(capsys, tmp_path, monkeypatch, module, argv, option):
    monkeypatch.chdir(tmp_path)  # nothing may be written to the working directory
    _assert_bad_input(capsys, module, argv, option)
    assert not (tmp_path / "bench").exists()


def test_f11_ablation_help_lists_the_config_names(capsys):
    from gaintune.bench import ablation

    with pytest.raises(SystemExit):
        ablation.main(["--help"])
    out = capsys.readouterr().out
    assert all(name in " ".join(out.split()) for name in ablation.CONFIGS)
    line = _assert_bad_input(capsys, "ablation", ["--configs", "nope"], "--configs")
    assert "'ppo (default)'" in line and "'sac'" in line


def _not_a_folder(tmp_path: Path) -> list[Path]:
    f = tmp_path / "a-file"
    f.write_text("x")
    bad = [f, f / "sub"]  # a file, and a folder that cannot be made under a file
    if Path("/proc/self").is_dir():
        bad.append(Path("/proc/x"))  # mkdir fails there even for root
    return bad


@pytest.mark.parametrize("module, argv", [
    ("verify", ["--repeat", "1"]),
    ("search", ["--suite", "quick", "--problems", "q_lag2_pi", "--seeds", "0", "--budget", "10", "--quiet"]),
    ("compare", ["--suite", "quick", "--problems", "q_lag2_pi", "--methods", "simc", "--quiet"]),
    ("constraints", ["--suite", "quick", "--problems", "q_lag2_pi", "--n", "2"]),
    ("startup", ["--repeat", "1"]),
])
def test_f11_out_that_is_not_a_writable_folder_exits_2_naming_out(capsys, tmp_path, module, argv):
    for bad in _not_a_folder(tmp_path):
        line = _assert_bad_input(capsys, module, [*argv, "--out", str(bad)], "--out")
        assert str(bad) in line


def test_f11_out_folder_is_created_when_missing(tmp_path):
    from gaintune.bench.arguments import output_dir

    assert output_dir(str(tmp_path / "new" / "deeper")).is_dir()


def test_f11_kernel_without_a_usable_rev_exits_2_and_says_how_to_pick_one(capsys):
    for argv in ([], ["--rev", "nope-not-a-revision"]):
        line = _assert_bad_input(capsys, "kernel", [*argv, "--repeat", "1", "--min-time", "0.01"], "--rev")
        assert "e.g. --rev " in line or "git" in line  # an example revision, or what is missing to find one


def test_f11_chaos_refused_job_names_the_status_not_keyerror_id():
    from gaintune.bench.chaos_procs import Server

    class Refusing:
        def post(self, *a, **k):
            return type("R", (), {"status_code": 422, "text": '{"detail": "search.budget: must be >= 10"}'})()

    srv = Server.__new__(Server)
    srv.client = Refusing()
    with pytest.raises(RuntimeError, match="422.*search.budget"):
        srv.submit({"search": {"budget": -1}})


# ------------------------------------------------------------------ F12: hangs, orphaned server


def test_f12_sim_min_time_nan_exits_2_instead_of_hanging():
    r = _run_cli(["bench", "sim", "--case", "lag3_pid", "--batch", "4", "--repeat", "1", "--min-time", "nan",
                  "--no-memory", "--no-numpy"])
    assert r.returncode == 2 and r.stderr.startswith("error: --min-time: ") and "Traceback" not in r.stderr


def test_f12_sim_timer_ends_on_a_nan_limit():
    from gaintune.bench.sim import _per_call

    ticks = iter(range(1000))

    def clock() -> float:  # a loop that never ends runs out of ticks instead of hanging the test run
        return float(next(ticks))

    calls = []
    assert _per_call(lambda: calls.append(1), float("nan"), clock=clock) >= 0 and len(calls) == 1


def test_f12_api_concurrency_0_exits_2_before_starting_a_server(capsys, monkeypatch):
    from gaintune.bench import api

    def no_server(*a, **k):
        raise AssertionError("the API server was started before the arguments were checked")

    monkeypatch.setattr(api, "start_server", no_server)
    monkeypatch.setattr(api, "_in_process_verify_ms", lambda *a, **k: 0.0)
    for argv in (["--concurrency", "0"], ["--concurrency", "-1"], ["--sweep", "1,0"], ["--seconds", "nan"]):
        _assert_bad_input(capsys, "api", ["--requests", "1", *argv], argv[0])


def test_f12_api_server_is_stopped_when_the_run_fails(monkeypatch):
    import httpx

    from gaintune.bench import api

    started = []

    def fake_server(tmp, port, workers, compute_processes=None):
        started.append(subprocess.Popen([sys.executable, "-c", "import time; time.sleep(60)"]))
        return started[0]

    def broken_client(*a, **k):
        raise RuntimeError("client failed")

    monkeypatch.setattr(api, "start_server", fake_server)
    monkeypatch.setattr(api, "_in_process_verify_ms", lambda *a, **k: 0.0)
    monkeypatch.setattr(httpx, "AsyncClient", broken_client)
    with pytest.raises(RuntimeError, match="client failed"):
        api.main(["--requests", "1", "--seconds", "1"])
    assert started and started[0].poll() is not None, "the server outlived the failed benchmark"


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="PR_SET_PDEATHSIG is Linux-only")
def test_f12_api_server_dies_when_the_benchmark_is_killed():
    """SIGKILL skips every finally: the server must still get SIGTERM from the kernel (it was orphaned)."""
    code = ("import subprocess, sys, time\n"
            "from gaintune.bench.api_load import term_with_parent\n"
            "p = subprocess.Popen([sys.executable, '-c', 'import time; time.sleep(60)'], preexec_fn=term_with_parent())\n"
            "print(p.pid, flush=True)\n"
            "time.sleep(60)\n")
    parent = subprocess.Popen([sys.executable, "-c", code], stdout=subprocess.PIPE, text=True)
    child = int(parent.stdout.readline())
    parent.kill()
    parent.wait()

    def alive() -> bool:
        try:
            state = Path(f"/proc/{child}/stat").read_text().rsplit(")", 1)[1].split()[0]
        except OSError:
            return False
        return state != "Z"

    t0 = time.monotonic()
    while alive() and time.monotonic() - t0 < 10:
        time.sleep(0.05)
    if alive():
        os.kill(child, signal.SIGKILL)
        pytest.fail("the server started by the benchmark outlived it")


# ------------------------------------------------------------------ F13: exit 2, not 1


@pytest.mark.parametrize("argv, option", [
    (["bench", "search", "--problems", "nope", "--quiet"], "--problems"),
    (["bench", "search", "--suite", "quick", "--budget", "0", "--quiet"], "--budget"),
    (["bench", "compare", "--methods", "nope", "--quiet"], "--methods"),
])
def test_f13_invalid_bench_input_exits_2_not_1(tmp_path, argv, option):
    r = _run_cli([*argv, "--out", str(tmp_path)])
    assert r.returncode == 2, r.stderr
    assert r.stderr.startswith(f"error: {option}: ") and len(r.stderr.strip().splitlines()) == 1
    assert "Traceback" not in r.stderr
