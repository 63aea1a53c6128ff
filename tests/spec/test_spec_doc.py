"""docs/spec.md is generated from the schema and must be current."""

from pathlib import Path

from gaintune.spec.doc import render_markdown


def test_spec_reference_is_current(repo_root: Path):
    path = repo_root / "docs" / "spec.md"
    assert path.read_text().strip() == render_markdown().strip(), "run: python -m gaintune.spec.doc > docs/spec.md"
