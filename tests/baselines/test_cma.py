"""gaintune.baselines.cma: cmaes imported without scipy.stats, the real CMA class, and scipy.stats still importable."""

from __future__ import annotations

import numpy as np


def test_load_cma_in_a_single_thread_skips_scipy_stats_and_leaves_it_importable(fresh_python) -> None:
    code = ("import sys, json\nfrom gaintune.baselines.cma import load_cma\nC = load_cma()\n"
            "skipped = 'scipy.stats' not in sys.modules\nimport cmaes\nsame = C is cmaes.CMA\n"
            "import scipy.stats\nprint(json.dumps(dict(skipped=skipped, same=same, cdf=float(scipy.stats.norm.cdf(0.0)))))")
    assert fresh_python(code) == {"skipped": True, "same": True, "cdf": 0.5}


def test_load_cma_with_another_thread_running_imports_cmaes_as_usual(fresh_python) -> None:
    """Another thread might import scipy.stats in that moment: then nothing is hidden."""
    code = ("import sys, json, threading\nev = threading.Event()\nt = threading.Thread(target=ev.wait)\nt.start()\n"
            "from gaintune.baselines.cma import load_cma\nC = load_cma()\nloaded = 'scipy.stats' in sys.modules\nev.set()\nt.join()\n"
            "print(json.dumps(dict(loaded=loaded)))")
    assert fresh_python(code) == {"loaded": True}


def test_cma_from_load_cma_minimises_a_quadratic_like_cmaes(fresh_python) -> None:
    from gaintune.baselines.cma import load_cma

    CMA = load_cma()
    opt = CMA(mean=np.array([1.0, -1.0]), sigma=0.5, seed=3)
    for _ in range(60):
        xs = [opt.ask() for _ in range(opt.population_size)]
        opt.tell([(x, float(x @ x)) for x in xs])
    assert np.linalg.norm(opt.mean) < 1e-3


def test_the_tune_path_loads_no_scipy_stats(fresh_python) -> None:
    """The polish's optimiser comes with gaintune.search.tune, without scipy.stats (~0.3 s)."""
    code = "import sys, json\nimport gaintune.search.tuning\nprint(json.dumps(dict(stats='scipy.stats' in sys.modules)))"
    assert fresh_python(code) == {"stats": False}


def test_a_cmaes_that_needs_scipy_stats_is_imported_as_usual(fresh_python, tmp_path) -> None:
    """Should a cmaes release import scipy.stats unguarded, the hidden import fails and is retried."""
    (tmp_path / "cmaes").mkdir()
    (tmp_path / "cmaes" / "__init__.py").write_text("from scipy import stats\nclass CMA:\n    norm = stats.norm\n")
    code = (f"import sys, json\nsys.path.insert(0, {str(tmp_path)!r})\nfrom gaintune.baselines.cma import load_cma\n"
            "C = load_cma()\nprint(json.dumps(dict(ok=float(C.norm.cdf(0.0)) == 0.5, mod=C.__module__)))")
    assert fresh_python(code) == {"ok": True, "mod": "cmaes"}


def test_cmaes_history_shows_no_cost_before_a_feasible_candidate() -> None:
    """`bench scaling` read CMA-ES's history as its best feasible cost: on the 110-gain train, where CMA-ES
    found nothing feasible in 500 simulations, its row showed the unstable start's cost (3.10 x RL's answer)
    as if it were an answer. The history now holds feasible costs only: none when nothing is feasible."""
    from types import SimpleNamespace

    from gaintune.baselines.optimizers import cmaes_search

    class Box:
        layout = SimpleNamespace(log_lo=np.zeros(2), log_hi=np.ones(2), n_tuned=2,
                                 initial_tuned=lambda: np.full(2, 1.5))

        def __init__(self, limit: float) -> None:
            self.limit = limit  # feasible where ln x0 <= limit

        def evaluate(self, tuned: np.ndarray) -> SimpleNamespace:
            cost = np.sum(np.log(tuned) ** 2, axis=1)
            violation = np.maximum(np.log(tuned[:, 0]) - self.limit, 0.0)
            return SimpleNamespace(cost=cost, violation=violation, merit=np.where(violation > 0, 1e3 + violation, cost))

    r = cmaes_search(Box(0.3), 200, seed=0)
    assert r.feasible and r.history
    costs = [c for _, c in r.history]
    assert costs == sorted(costs, reverse=True) and costs[-1] == r.cost
    never = cmaes_search(Box(-1.0), 200, seed=0)  # the unit box starts at ln x = 0: nothing is feasible
    assert not never.feasible and never.history == []
