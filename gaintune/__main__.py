"""``python -m gaintune``: the command-line interface."""

from gaintune.cli import app

app(prog_name="gaintune")
