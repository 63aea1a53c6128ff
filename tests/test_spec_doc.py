"""docs/spec.md is generated from the schema and must be current."""

from pathlib import Path

from gaintune.spec_doc import render_markdown


def test_spec_reference_is_current():
    path = Path(__file__).resolve().parents[1] / "docs" / "spec.md"
    assert path.read_text().strip() == render_markdown().strip(), "run: python -m gaintune.spec_doc > docs/spec.md"
