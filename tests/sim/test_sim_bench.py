"""The simulation benchmark: its NumPy baseline agrees with the kernel, and the CLI entry point runs."""

from __future__ import annotations

import json

import numpy as np
import pytest

from gaintune.bench import sim as bench


@pytest.mark.parametrize("case", bench.CASES)
def test_numpy_baseline_matches_the_kernel(case: str) -> None:
    c = bench.make_case(case, 8)
    res = c.sim.run(c.full, traces=True)
    m, tr = bench.numpy_rollout(c.sim, c.full, traces=True)
    assert not res.metrics["diverged"].any()
    np.testing.assert_allclose(tr["u"], res.traces["u"], rtol=1e-10, atol=1e-10 * np.abs(res.traces["u"]).max())
    for k in ("iae", "ise", "itae", "effort", "tv", "peak_u", "sat_frac", "overshoot", "rise_time", "settling_time", "y_final"):
        np.testing.assert_allclose(m[k], res.metrics[k], rtol=1e-10, atol=1e-12, err_msg=k)


def test_bench_main_prints_a_markdown_table(capsys) -> None:
    assert bench.main(["--case", "lag3_pid", "--batch", "1", "16", "--repeat", "1", "--min-time", "0.01", "--no-memory"]) == 0
    out = capsys.readouterr().out
    assert "| lag3_pid | 16 | 2000 |" in out and "kernel vs NumPy" in out


def test_bench_json(capsys) -> None:
    assert bench.main(["--case", "water_tank", "--batch", "4", "--repeat", "1", "--min-time", "0.01", "--no-numpy", "--no-memory", "--json"]) == 0
    row = json.loads(capsys.readouterr().out)["rows"][0]
    assert row["case"] == "water_tank" and row["batch"] == 4 and row["kernel_sims_per_s"] > 0


@pytest.mark.slow
def test_memory_worker_reports_peak_rss_of_a_batch() -> None:
    small = bench.measure_memory("lag3_pid", "kernel", 1)
    big = bench.measure_memory("lag3_pid", "kernel", 4096)
    assert small["peak_delta_mb"] >= 0 and big["peak_delta_mb"] > small["peak_delta_mb"]
    assert big["peak_delta_mb"] < 200  # O(B) state: a few KB per candidate
