"""``tune``'s keyword arguments and the frozen TuneOptions record ``_tune`` runs on say the same thing."""

from __future__ import annotations

import dataclasses
import inspect

import pytest

from gaintune.search.tuning import TuneOptions, tune


def test_tune_keywords_are_the_options_fields_with_the_same_defaults():
    params = {n: p for n, p in inspect.signature(tune).parameters.items() if p.kind is p.KEYWORD_ONLY}
    fields = {f.name: f.default for f in dataclasses.fields(TuneOptions)}
    assert {n: p.default for n, p in params.items()} == fields


def test_tune_options_are_frozen():
    options = TuneOptions(verify=False)
    with pytest.raises(dataclasses.FrozenInstanceError):
        options.verify = True  # type: ignore[misc]  # the point of the test: assignment is refused
