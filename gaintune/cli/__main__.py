"""``python -m gaintune.cli``: the command-line interface (as ``python -m gaintune``)."""

from gaintune.cli import app

__all__: list[str] = []

app()
