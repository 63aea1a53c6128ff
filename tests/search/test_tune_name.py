"""``from gaintune.search import tune`` is the search function whatever was imported before it."""

from __future__ import annotations

import subprocess
import sys


def test_search_tune_is_the_function_even_after_its_module_was_imported() -> None:
    """Before, the module gaintune/search/tune.py became the package's ``tune`` once anything imported it,
    and an API worker then called a module ("'module' object is not callable")."""
    code = ("import gaintune.search.tuning, gaintune.search as s, gaintune\n"
            "from gaintune.search import tune\n"
            "assert callable(tune) and tune is s.tune is gaintune.tune, tune\n"
            "assert tune.__module__ == 'gaintune.search.tuning'\n")
    res = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=300)
    assert res.returncode == 0, res.stderr
