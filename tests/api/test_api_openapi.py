"""The OpenAPI document serves typed clients: request schemas mark defaulted fields optional (issue 13).

Design tools generate clients from ``/openapi.json`` (e.g. openapi-typescript). A field with a
default listed as ``required``, or carrying a ``default`` that openapi-typescript reads as "always
present", makes the README's two-line minimal spec fail to type-check. The last tests generate the
TypeScript client with the pinned toolchain in ``.ci/openapi-client`` (``npm ci --prefix
.ci/openapi-client``; ``.ci/run`` does it) and type-check the README's request bodies with ``tsc``.
"""

from __future__ import annotations

import json
import re
import shutil
import subprocess
from pathlib import Path

import jsonschema_rs
import pytest
import yaml
from fastapi.testclient import TestClient

from gaintune_api.main import app

MINIMAL = {"plant": {"tf": {"num": [1], "den": "(s+1)^3"}}, "loops": [{"type": "pid"}]}
REPO = Path(__file__).resolve().parents[2]
NODE_BIN = REPO / ".ci" / "openapi-client" / "node_modules" / ".bin"


@pytest.fixture(scope="module")
def doc() -> dict:
    with TestClient(app) as c:
        return c.get("/openapi.json").json()


def _reachable(doc: dict, todo: list) -> set[str]:
    """Every component schema reachable from the schemas in ``todo``."""
    comps = doc["components"]["schemas"]
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


def _request_schemas(doc: dict) -> set[str]:
    """Every component schema reachable from a request body."""
    return _reachable(doc, [media.get("schema", {}) for path in doc["paths"].values() for op in path.values()
                            if isinstance(op, dict) for media in op.get("requestBody", {}).get("content", {}).values()])


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


def _object_schemas(node):
    """Every schema with ``properties`` inside ``node`` (nested objects, anyOf branches, items...)."""
    if isinstance(node, dict):
        if isinstance(node.get("properties"), dict):
            yield node
        for key, value in node.items():
            if key not in ("default", "examples", "enum", "const"):
                yield from _object_schemas(value)
    elif isinstance(node, list):
        for value in node:
            yield from _object_schemas(value)


def test_request_schemas_carry_no_default_that_generators_read_as_always_present(doc):
    """openapi-typescript (default flags) types a property with a ``default`` as required.

    The default goes in the description instead (the server still applies it).
    """
    comps = doc["components"]["schemas"]
    wrong = [f"{n}.{f}" for n in _request_schemas(doc) for obj in _object_schemas(comps[n])
             for f, p in obj["properties"].items() if isinstance(p, dict) and "default" in p]
    assert not wrong, f"request schema properties with a default: {wrong}"
    assert comps["LoopSpec"]["properties"]["form"]["description"].endswith('Default: `"parallel"`.')


def test_readme_and_plant_example_specs_validate_against_the_published_schema(doc):
    """What the README shows and GET /v1/plants serves as ``example_spec`` (``[low, high]`` ranges included)."""
    from gaintune_api.routes.plants import list_plants

    validator = jsonschema_rs.validator_for({**doc, "$ref": "#/components/schemas/TuningSpec"})
    for spec in _readme_specs() + [p.example_spec for p in list_plants().items]:
        errors = [f"{e.instance_path}: {e.message}" for e in validator.iter_errors(spec)]
        assert not errors, (spec.get("name"), errors)


# ------------------------------------------------- a generated TypeScript client type-checks the README

#: Gains of the README's ``verify(spec, {"loop0": {"Kp": 1.14, "Ki": 0.454}})``.
GAINS = {"loop0": {"Kp": 1.14, "Ki": 0.454}}
#: Request bodies per POST route that takes a spec, as docs/api.md gives them: the bare form and every optional field.
BODIES = {
    "/v1/tune": lambda spec: [spec],
    "/v1/verify": lambda spec: [{"spec": spec, "gains": GAINS},
                                {"spec": spec, "gains": GAINS, "robust": None, "nonlinear": False}],
    "/v1/simulate": lambda spec: [{"spec": spec, "gains": GAINS},
                                  {"spec": spec, "gains": GAINS, "max_points": 500, "scenarios": ["step"]}],
    "/v1/tuners": lambda spec: [{"spec": spec}, {"spec": spec, "episodes": 20000, "seed": 1}],
}
#: Bodies the generated types must reject: each line must be a TypeScript error (``@ts-expect-error``).
REJECTED = {
    "TuningSpec": [{"loops": [{"type": "pid"}]},                     # no plant
                   {**MINIMAL, "loops": [{"type": 42}]},             # controller type is a string
                   {**MINIMAL, "loops": [{"type": "pidd"}]},         # unknown controller type
                   {**MINIMAL, "plnt": {}},                          # unknown key (extra="forbid")
                   {**MINIMAL, "loops": [{"type": "pi", "b": "1"}]},  # setpoint weight is a number
                   {**MINIMAL, "randomize": {"params": {"K": [1, 2, 3]}}}],  # a range has two ends
    "/v1/tune": [{"loops": [{"type": "pid"}]}],
    "/v1/verify": [{"spec": MINIMAL}, {"spec": MINIMAL, "gains": {"loop0": {"Kp": "1"}}}],
    "/v1/simulate": [{"spec": MINIMAL}, {"spec": MINIMAL, "gains": GAINS, "max_points": "2000"}],
    "/v1/tuners": [{"spec": MINIMAL, "episodes": "2000"}, {"family": "pid"}],
}


def _node_tool(name: str) -> str:
    tool = NODE_BIN / name
    if not tool.exists() or shutil.which("node") is None:
        pytest.skip(f"{name} is not installed (needs node): run `npm ci --prefix .ci/openapi-client` "
                    "(.ci/run does, so CI runs this test)")
    return str(tool)


def _run(args: list[str], cwd: Path) -> subprocess.CompletedProcess:
    return subprocess.run(args, cwd=cwd, capture_output=True, text=True, timeout=300)


def _readme_specs() -> list[dict]:
    """The specs README.md shows (its YAML blocks with a plant and loops)."""
    blocks = re.findall(r"```yaml\n(.*?)```", (REPO / "README.md").read_text(), re.S)
    specs = [s for s in map(yaml.safe_load, blocks) if isinstance(s, dict) and {"plant", "loops"} <= s.keys()]
    assert MINIMAL in specs and len(specs) >= 2, "README.md lost its minimal or its fuller spec"
    return specs


def _spec_routes(doc: dict) -> list[str]:
    """POST routes whose JSON body reaches the TuningSpec schema."""
    return [path for path, item in doc["paths"].items()
            if "TuningSpec" in _reachable(doc, [item.get("post", {}).get("requestBody", {}).get("content", {})])]


@pytest.fixture(scope="module")
def ts_client(doc, tmp_path_factory) -> Path:
    """A folder holding openapi.json and the TypeScript client openapi-typescript generates from it (default flags)."""
    generate = _node_tool("openapi-typescript")
    out = tmp_path_factory.mktemp("openapi-client")
    (out / "openapi.json").write_text(json.dumps(doc))
    r = _run([generate, "openapi.json", "-o", "schema.d.ts"], out)
    assert r.returncode == 0 and (out / "schema.d.ts").is_file(), f"openapi-typescript failed:\n{r.stdout}\n{r.stderr}"
    return out


def _tsc(folder: Path, source: str, name: str) -> subprocess.CompletedProcess:
    (folder / name).write_text(source)
    return _run([_node_tool("tsc"), "--noEmit", "--strict", "--target", "es2022", "--lib", "es2022",
                 "--module", "esnext", "--moduleResolution", "bundler", name, "schema.d.ts"], folder)


_PRELUDE = """import type { components, paths } from "./schema";

type TuningSpec = components["schemas"]["TuningSpec"];
type PostBody<P extends keyof paths> =
    paths[P]["post"] extends { requestBody: { content: { "application/json": infer B } } } ? B : never;
"""


def _const(name: str, type_: str, value) -> str:
    return f"export const {name}: {type_} = {json.dumps(value)};"


def test_generated_typescript_client_types_the_readme_request_bodies(doc, ts_client):
    routes = _spec_routes(doc)
    assert sorted(routes) == sorted(BODIES), f"give example bodies for every POST route taking a spec: {routes}"
    from gaintune_api.routes.plants import list_plants  # what GET /v1/plants serves: an example spec per built-in model

    specs = _readme_specs() + [p.example_spec for p in list_plants().items]
    lines = [_PRELUDE]
    lines += [_const(f"spec{i}", "TuningSpec", s) for i, s in enumerate(specs)]
    for route, bodies in BODIES.items():
        type_ = f'PostBody<"{route}">'
        lines += [_const(f"{route.split('/')[-1]}{i}_{j}", type_, b)
                  for i, s in enumerate(specs) for j, b in enumerate(bodies(s))]
    for target, bad in REJECTED.items():
        type_ = target if target == "TuningSpec" else f'PostBody<"{target}">'
        for i, b in enumerate(bad):
            lines += ["// @ts-expect-error", _const(f"rejected_{target.split('/')[-1]}{i}", type_, b)]
    r = _tsc(ts_client, "\n".join(lines) + "\n", "client.ts")
    assert r.returncode == 0, f"tsc --strict rejects the README's request bodies:\n{r.stdout}{r.stderr}"


def test_generated_typescript_client_rejects_a_wrongly_typed_spec(ts_client):
    """The type check can fail: a number as controller type and a verify body without gains are tsc errors."""
    source = "\n".join([_PRELUDE, _const("bad", "TuningSpec", {**MINIMAL, "loops": [{"type": 42}]}),
                         _const("no_gains", 'PostBody<"/v1/verify">', {"spec": MINIMAL})]) + "\n"
    r = _tsc(ts_client, source, "bad.ts")
    out = r.stdout + r.stderr
    assert r.returncode != 0, out
    bad, no_gains = (source.splitlines().index(line) + 1 for line in source.splitlines() if "export const" in line)
    errors = re.findall(r"^bad\.ts\((\d+),\d+\): error (TS\d+: .*)$", out, re.M)
    assert [int(n) for n, _ in errors] == [bad, no_gains], out
    assert errors[0][1].startswith("TS2322: Type 'number' is not assignable to type '\"p\" | \"pi\""), out
    assert errors[1][1].startswith("TS2741: Property 'gains' is missing"), out
