"""``gaintune bench mimo`` with a tiny budget: every published Wood-Berry row and the tuned rows print."""

from __future__ import annotations

from gaintune.bench import mimo


def test_bench_mimo_smoke_prints_every_row(capsys) -> None:
    assert mimo.main(["--cmaes-budget", "30", "--rl-budget", "0", "--plants", "wood_berry"]) == 0
    out = capsys.readouterr().out
    assert out.startswith("command: gaintune bench mimo --cmaes-budget 30") and "load average" in out
    for row in ("BLT (published)", "BLT (gaintune.classical.blt) (published)", "Chen-Seborg (published)",
                "Boyd-Hast-Astrom (published)", "Garrido (published)"):
        assert row in out
    tuned = [ln for ln in out.splitlines() if "gaintune cmaes @30" in ln]
    assert len(tuned) == 2 and all(ln.count("|") == 8 for ln in tuned)  # one per tuned-for row, with its ratio
