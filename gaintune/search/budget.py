"""How a tune splits ``search.budget``: set-up, RL, final checks and the refinement reserve.

One place for the arithmetic, so that the search (:mod:`gaintune.search.tuning`) and what the
result says about it (:mod:`gaintune.search.diagnosis`) cannot drift apart.
"""

from __future__ import annotations

__all__ = ["FINAL_CHECKS", "refine_reserve", "rollout_sims", "rl_budget", "min_budget_for_rl"]

#: Gain sets scored after the search (policy, best seen, start point, and room for the settle step).
FINAL_CHECKS = 5
#: Share of the budget kept for the local refinement, and its cap (simulations).
REFINE_SHARE, REFINE_CAP = 0.1, 1000


def refine_reserve(budget: int, refine: bool) -> int:
    """Simulations kept for the local refinement (0 without it)."""
    return min(int(REFINE_SHARE * budget), REFINE_CAP) if refine else 0


def rollout_sims(n_envs: int, per_candidate: int, env: str) -> int:
    """Simulations of one batched step of every env (the iterative env may also reset, scoring its start gains)."""
    return (2 if env == "iterative" else 1) * n_envs * per_candidate


def rl_budget(budget: int, setup: int, per_candidate: int, refine: bool) -> int:
    """Simulations left for the RL search after the set-up's ``setup``, the final checks and the reserve."""
    return max(budget - setup - refine_reserve(budget, refine) - FINAL_CHECKS * per_candidate, 0)


def min_budget_for_rl(setup: int, per_candidate: int, rollout: int, refine: bool) -> int:
    """The smallest budget whose RL share holds one rollout of ``rollout`` simulations."""
    b = setup + FINAL_CHECKS * per_candidate + rollout  # enough without a reserve
    while rl_budget(b, setup, per_candidate, refine) < rollout:  # the reserve takes a share (capped) of each step
        b += 1
    return b
