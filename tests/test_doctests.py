"""The docstring examples of the public API (what ``gaintune`` exports, plus gaintune.controllers.forms) and of
the other modules that carry ``>>>`` examples run as doctests: an example that no longer runs fails here."""

from __future__ import annotations

import doctest
import importlib

import pytest

import gaintune

#: Every module whose docstrings hold ``>>>`` examples, and the modules that define the public API.
MODULES = (
    "gaintune",
    "gaintune.spec",
    "gaintune.search.tuning",
    "gaintune.search.result",
    "gaintune.verification",
    "gaintune.verification.report",
    "gaintune.provenance",
    "gaintune.controllers.forms",
    "gaintune.export",
    "gaintune.report",
)


@pytest.mark.parametrize("name", MODULES)
def test_docstring_examples_run(name: str) -> None:
    module = importlib.import_module(name)
    result = doctest.testmod(module, optionflags=doctest.ELLIPSIS | doctest.NORMALIZE_WHITESPACE, verbose=False)
    assert result.failed == 0, f"{result.failed} of {result.attempted} examples of {name} failed (output above)"


@pytest.mark.parametrize("name", [n for n in gaintune.__all__ if n != "__version__"])
def test_public_name_has_an_example(name: str) -> None:
    """Each public name is shown at work: in its own docstring, or in the package's examples."""
    obj = getattr(gaintune, name)
    examples = [ex.source for ex in doctest.DocTestParser().get_examples(gaintune.__doc__ or "")]
    assert ">>>" in (obj.__doc__ or "") or any(name in src for src in examples), name
