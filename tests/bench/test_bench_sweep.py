"""``gaintune bench sweep``: its fleet, its projection model and its argument checks (the run is the benchmark)."""

from __future__ import annotations

import pytest
import yaml

from gaintune.bench import sweep as bench_sweep
from gaintune.sweep.fleet import expand, load_fleet


def test_the_benchmark_fleet_has_the_asked_number_of_distinct_valid_items(tmp_path):
    path = tmp_path / "fleet.yaml"
    path.write_text(yaml.safe_dump(bench_sweep.fleet_doc(40, 100)))
    items = expand(*load_fleet(path))
    assert len(items) == len({i.key for i in items}) == 40
    assert all(i.error is None and i.doc["search"]["budget"] == 100 for i in items)


def test_projection_counts_waves_of_items_on_the_cluster_cpus():
    p = bench_sweep.projection(item_s=2.0, overhead_s=0.1, loops=10_000, nodes=32, cores=16, start_s=5.0)
    assert p["waves"] == 20  # 10,000 items on 512 CPUs
    assert p["wall_s"] == pytest.approx(5.0 + 20 * 2.1)
    assert p["serial_s"] == pytest.approx(20_000.0)


@pytest.mark.parametrize("argv, option", [(["--problems", "2"], "--problems"), (["--budget", "5"], "--budget"),
                                          (["--kill-problems", "0"], "--kill-problems")])
def test_bad_arguments_exit_2_naming_the_option(capsys, argv, option):
    with pytest.raises(SystemExit) as info:
        bench_sweep.main(argv)
    assert info.value.code == 2 and f"error: {option}:" in capsys.readouterr().err
