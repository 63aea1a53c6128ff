"""The OpenAPI document serves typed clients: request schemas mark defaulted fields optional (issue 13).

Design tools generate clients from ``/openapi.json`` (e.g. openapi-typescript). A field with a
default listed as ``required`` makes the README's two-line minimal spec fail to type-check.
"""

from __future__ import annotations

import jsonschema_rs
import pytest
from fastapi.testclient import TestClient

from api.main import app

MINIMAL = {"plant": {"tf": {"num": [1], "den": "(s+1)^3"}}, "loops": [{"type": "pid"}]}


@pytest.fixture(scope="module")
def doc() -> dict:
    with TestClient(app) as c:
        return c.get("/openapi.json").json()


def _request_schemas(doc: dict) -> set[str]:
    """Every component schema reachable from a request body."""
    comps = doc["components"]["schemas"]
    todo = []
    for path in doc["paths"].values():
        for op in path.values():
            body = op.get("requestBody", {}) if isinstance(op, dict) else {}
            for media in body.get("content", {}).values():
                todo.append(media.get("schema", {}))
    seen: set[str] = set()
    while todo:
        node = todo.pop()
        if isinstance(node, dict):
            ref = node.get("$ref")
            if ref and ref.startswith("#/components/schemas/"):
                name = ref.rsplit("/", 1)[1]
                if name not in seen:
                    seen.add(name)
                    todo.append(comps[name])
            todo.extend(node.values())
        elif isinstance(node, list):
            todo.extend(node)
    return seen


def test_request_schemas_never_require_a_defaulted_field(doc):
    comps = doc["components"]["schemas"]
    names = _request_schemas(doc)
    assert "TuningSpec" in names and "LoopSpec" in names
    wrong = [f"{n}.{f}" for n in names for f in comps[n].get("required", [])
             if "default" in comps[n].get("properties", {}).get(f, {})]
    assert not wrong, f"defaulted fields marked required in request schemas: {wrong}"


def test_readme_minimal_spec_validates_against_the_published_schema(doc):
    validator = jsonschema_rs.validator_for({**doc, "$ref": "#/components/schemas/TuningSpec"})
    assert validator.is_valid(MINIMAL)
    assert not validator.is_valid({"loops": [{"type": "pid"}]})  # no plant
    assert not validator.is_valid({**MINIMAL, "loops": [{"type": "pidd"}]})  # unknown controller type
