"""``gaintune bench mimo`` with a tiny budget: every published Wood-Berry row and the tuned rows print."""

from __future__ import annotations

from gaintune.bench import mimo


def test_bench_mimo_smoke_prints_every_row(capsys, tmp_path) -> None:
    assert mimo.main(["--cmaes-budget", "30", "--rl-budget", "0", "--plants", "wood_berry", "--ref-restarts", "1",
                      "--ref-sims", "100", "--out", str(tmp_path)]) == 0
    out = capsys.readouterr().out
    assert out.startswith("command: gaintune bench mimo --cmaes-budget 30") and "load average" in out
    for row in ("BLT (published)", "BLT (gaintune.classical.blt) (published)", "Chen-Seborg (published)",
                "Boyd-Hast-Astrom (published)", "Garrido (published)"):
        assert row in out
    tuned = [ln for ln in out.splitlines() if "gaintune cmaes @30" in ln]
    assert len(tuned) == 2 and all(ln.count("|") == 9 for ln in tuned)  # one per tuned-for row, with its ratios
    optima = [ln for ln in out.splitlines() if ln.startswith("|   optimum, ")]
    assert len(optima) == 2 and all(ln.split("|")[-2].strip() == "1.000" for ln in optima)
    assert (tmp_path / "reference_mimo.json").is_file()  # cached: the next run re-scores instead of searching
