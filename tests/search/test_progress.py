"""The progress a tune reports: its simulation count is the result's, and no ETA outside the search or below 0."""

from __future__ import annotations

import pytest

from gaintune.search import tune
from gaintune.spec import load_spec

SPEC = {"name": "lag3", "plant": {"tf": {"num": [1], "den": "(s+1)^3"}}, "loops": [{"type": "pi"}],
        "scenario": {"dt": 0.05, "horizon": 20.0}, "search": {"budget": 400, "n_envs": 16, "seed": 1}}


@pytest.fixture(scope="module")
def run():
    reports = []
    result = tune(load_spec(SPEC), progress=lambda p: reports.append(p) or True)
    return result, reports


def test_progress_counts_the_simulations_the_result_reports(run):
    """The bar counted 2,609 search simulations where the summary said 2,983 (set-up, settle and refine left out)."""
    result, reports = run
    assert reports[-1].sims == result.sims
    assert all(p.budget >= p.sims for p in reports)
    assert [p.sims for p in reports] == sorted(p.sims for p in reports)


def test_progress_eta_is_never_negative_and_only_while_searching(run):
    """'ETA -2s' was shown once the search had used its share and settle/verify ran."""
    _, reports = run
    assert all(p.eta is None or p.eta >= 0 for p in reports)
    assert all(p.eta is None for p in reports if p.phase != "search")


def test_progress_phases_run_in_order_and_end_with_verify(run):
    _, reports = run
    phases = [p.phase for p in reports]
    assert phases[0] == "search" and phases[-1] == "verify"
    order = ["search", "settle", "refine", "verify"]
    seen = [order.index(p) for p in phases]
    assert seen == sorted(seen)
