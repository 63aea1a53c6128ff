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
