"""``gaintune bench policy``: trains a small family, times the tuner's answers, writes the figures."""

from __future__ import annotations

import json

import pytest

from gaintune.bench import policy as P


def test_bench_policy_prints_search_load_and_answer_times(tmp_path, capsys) -> None:
    assert P.main(["--budget", "200", "--points", "4", "--out", str(tmp_path)]) == 0
    text = capsys.readouterr().out
    for row in ("search that trained the policy", "load the tuner", "answer one plant, median of 4",
                "answers that passed verification", "search time / median answer time"):
        assert row in text, text
    raw = json.loads((tmp_path / "policy.json").read_text())
    assert raw["answers"] == 4 and 0 <= raw["passed"] <= 4
    assert 0 < raw["median_ms"] <= raw["p95_ms"] <= raw["max_ms"] and raw["search_s"] > 0


@pytest.mark.parametrize("args, option", [(["--points", "0"], "--points"), (["--budget", "5"], "--budget"),
                                          (["--seed", "-1"], "--seed")])
def test_bench_policy_bad_argument_exits_2_naming_it(args, option, capsys) -> None:
    with pytest.raises(SystemExit) as info:
        P.main(args)
    assert info.value.code == 2 and f"error: {option}:" in capsys.readouterr().err
