"""One list of RL algorithms: the spec, the agents and the CLI read the same names."""

from __future__ import annotations

import typing

from gaintune.search.algos import ALGO_NAMES
from gaintune.spec import SearchSpec


def test_the_spec_accepts_exactly_the_search_algorithms() -> None:
    """``search.algo`` is validated in the spec layer, below ``gaintune.search``: its choices must be ALGO_NAMES."""
    assert typing.get_args(SearchSpec.model_fields["algo"].annotation) == ALGO_NAMES


def test_every_algorithm_name_is_an_agent_class() -> None:
    from gaintune.search.agents import ALGOS

    assert tuple(ALGOS) == ALGO_NAMES and all(cls.__name__ == name.upper() for name, cls in ALGOS.items())
