"""The budget's split (gaintune.search.budget) and what a result says when the budget bought no RL search."""

from __future__ import annotations

import re

import pytest

from gaintune.search import tune
from gaintune.search.budget import min_budget_for_rl, rl_budget
from gaintune.spec import load_spec


@pytest.mark.parametrize("setup, per, rollout, refine", [(86, 1, 8, True), (86, 1, 8, False), (522, 1, 4096, True),
                                                         (50_000, 256, 8192, True), (0, 3, 96, True)])
def test_min_budget_for_rl_is_the_exact_smallest_budget_with_one_rollout(setup, per, rollout, refine) -> None:
    b = min_budget_for_rl(setup, per, rollout, refine)
    assert rl_budget(b, setup, per, refine) >= rollout > rl_budget(b - 1, setup, per, refine)


def test_budget_too_small_for_one_rollout_says_no_rl_ran_and_the_budget_that_would() -> None:
    """Fuzzing: budget 10 (or n_envs 4096) ran no RL at all, and nothing said so."""
    data = {"plant": {"tf": {"num": [1], "den": [1, 1]}}, "loops": [{"type": "pi"}],
            "scenario": {"dt": 0.05, "horizon": 5}, "search": {"budget": 10, "n_envs": 8}}
    small = tune(load_spec(data), verify=False)
    assert small.rl_sims == 0 and small.setup_sims > 0
    hint = small.diagnosis.hints[0]
    assert hint.startswith("no RL search ran"), small.diagnosis.hints
    need = int(re.search(r"at least (\d+)", hint).group(1))
    enough = tune(load_spec({**data, "search": {**data["search"], "budget": need}}), verify=False)
    assert enough.rl_sims > 0 and not any("no RL search ran" in h for h in enough.diagnosis.hints)
    short = tune(load_spec({**data, "search": {**data["search"], "budget": need - 1}}), verify=False)
    assert short.rl_sims == 0
