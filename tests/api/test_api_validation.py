"""REST API input handling: every invalid input is a 4xx RFC 7807 problem with field paths, never a 5xx."""

from __future__ import annotations

import json

import pytest
import yaml
from fastapi.testclient import TestClient

from gaintune_api.main import create_app
from gaintune_api.settings import Settings

SPEC = {
    "plant": {"tf": {"num": [1], "den": "(s+1)^3"}},
    "loops": [{"type": "pi"}],
    "scenario": {"dt": 0.05, "horizon": 20.0},
    "search": {"budget": 200},
}


@pytest.fixture(scope="module")
def client(tmp_path_factory):
    d = tmp_path_factory.mktemp("api")
    s = Settings(_env_file=None, db_path=d / "jobs.db", data_dir=d, workers=0, warmup=False, compute_processes=0,
                 max_budget=5000, max_body_bytes=64_000, max_order=8)
    with TestClient(create_app(s), raise_server_exceptions=False) as c:
        yield c


def _with(path: str, value):
    """SPEC with one nested key set (path 'a.b.0.c')."""
    spec = json.loads(json.dumps(SPEC))
    node = spec
    keys = path.split(".")
    for k in keys[:-1]:
        node = node[int(k)] if isinstance(node, list) else node.setdefault(k, {})
    last = keys[-1]
    if isinstance(node, list):
        node[int(last)] = value
    else:
        node[last] = value
    return spec


def assert_problem(r, status: int, loc: str | None = None):
    assert r.status_code == status, r.text
    assert r.headers["content-type"] == "application/problem+json"
    body = r.json()
    assert body["status"] == status and body["title"] and body["type"].startswith("https://")
    assert "Traceback" not in r.text
    if loc is not None:
        locs = [e["loc"] for e in body["errors"]]
        assert any(x == loc or x.startswith(loc) for x in locs), locs
    return body


SCHEMA_ERRORS = [
    (_with("loops", []), "loops"),
    (_with("loops.0.type", "pidd"), "loops.0.type"),
    (_with("plant.tf", None) | {"plant": {}}, "plant"),
    (_with("scenario.dt", -1), "scenarios.0"),
    (_with("scenario.horizon", 1e9), "scenarios.0"),
    (_with("search.budget", 5), "search.budget"),
    (_with("search.algo", "dqn"), "search.algo"),
    (_with("bogus", 1), "bogus"),
    (_with("loops.0.gains", {"Kp": {"bounds": [5, 1]}}), "loops.0.gains.Kp"),
    (_with("plant.tf.num", []), "plant.tf.num"),
    ({"loops": [{"type": "pi"}]}, "plant"),
]


@pytest.mark.parametrize("spec,loc", SCHEMA_ERRORS)
def test_schema_errors_are_422_with_paths(client, spec, loc):
    assert_problem(client.post("/v1/tune", json=spec), 422, loc)


SEMANTIC_ERRORS = [
    (_with("loops.0.measure", "nope"), "loops[0].measure"),
    (_with("plant.tf.den", "(s+1)^30"), "plant"),  # order limit (spec MAX_ORDER=20; server max_order=8 here)
    (_with("plant.tf.den", "(s+1)^10"), "plant"),  # server limit max_order=8
    (_with("plant.tf.den", [1]), "plant.tf.den"),  # static gain
    (_with("plant.tf.num", "K*s"), "plant"),  # unknown parameter in an expression
    (_with("plant.model", "nope") | {"plant": {"model": "nope"}}, "plant.model.name"),
    (_with("loops.0.gains", {"Kd": {"bounds": [1, 2]}}), "loops[0].gains"),
    (_with("randomize.params", {"J": [1, 2]}), "randomize.params.J"),
    (_with("safety.state_bounds", {"zz": 1.0}), "safety.state_bounds.zz"),
    (_with("actuator.limits", [1, 2]) | {"plant": {"tf": {"num": [1], "den": "(s+1)^3"}, "params": {}}}, None),
    (_with("search.budget", 50000), "search.budget"),  # server max_budget=5000
    ({**SPEC, "plant": {"ss": {"A": [[0, 1], [2]], "B": [[0], [1]], "C": [[1, 0]]}}}, "plant.ss.A"),
    ({**SPEC, "plant": {"ss": {"A": [[0, 1], [-1, -1]], "B": [[0], [1], [2]], "C": [[1, 0]]}}}, "plant.ss.B"),
    ({**SPEC, "plant": {"ode": {"states": ["x"], "rhs": {"x": "-x + u + import_os"}, "outputs": {"y": "x"}}}}, "plant"),
    ({**SPEC, "plant": {"ode": {"states": ["x"], "rhs": {"x": "__import__('os').system('true')"},
                                "outputs": {"y": "x"}}}}, "plant"),
]


@pytest.mark.parametrize("spec,loc", SEMANTIC_ERRORS)
def test_semantic_errors_are_422_before_accepting(client, spec, loc):
    r = client.post("/v1/tune", json=spec)
    if loc is None:  # the spec may or may not be valid; either way never 5xx
        assert r.status_code in (202, 422), r.text
        return
    assert_problem(r, 422, loc)


def test_non_finite_via_strings_rejected(client):
    spec = _with("scenario.reference", {"kind": "sequence", "points": [[0, 1], [1, "nan"]]})
    assert_problem(client.post("/v1/tune", json=spec), 422, "scenarios.0.reference.points")
    spec = _with("actuator.safe_value", "inf")
    assert_problem(client.post("/v1/tune", json=spec), 422, "actuator.safe_value")


@pytest.mark.parametrize(
    "body",
    [
        b"{",
        b"not json",
        b'{"plant": NaN, "loops": []}',
        b'{"plant": {"tf": {"num": [Infinity], "den": [1, 1]}}, "loops": [{"type": "p"}]}',
        b'{"plant": {"tf": {"num": [-Infinity], "den": [1, 1]}}, "loops": [{"type": "p"}]}',
        b'{"plant": {"tf": {"num": [1e999], "den": [1, 1]}}, "loops": [{"type": "p"}]}',
        b'{"search": {"budget": ' + b"9" * 5000 + b"}}",
        b"[" * 50_000 + b"]" * 50_000,
        b"\xff\xfe\x00",
        b'{"a": "\\ud800"}',
    ],
)
def test_malformed_json_is_400(client, body):
    for path in ("/v1/tune", "/v1/verify", "/v1/simulate"):
        r = client.post(path, content=body, headers={"content-type": "application/json"})
        assert 400 <= r.status_code < 500, (path, r.status_code, r.text)
        assert r.headers["content-type"] == "application/problem+json"


def test_deep_nesting_is_4xx(client):
    deep = {"x": 1}
    for _ in range(40):
        deep = {"a": deep}
    r = client.post("/v1/tune", json={**SPEC, "description": "x", "plant": deep})
    assert_problem(r, 422)


def test_huge_array_is_4xx(client):
    r = client.post("/v1/tune", json=_with("plant.tf.num", [1.0] * 20_000))
    assert r.status_code in (413, 422)
    r = client.post("/v1/tune", json=_with("plant.tf.num", [0.0] * 12_000))
    assert r.status_code in (413, 422)


def test_body_too_large_is_413(client):
    r = client.post("/v1/tune", json={**SPEC, "description": "x" * 100_000})
    assert_problem(r, 413)

    def chunks():  # streamed, no Content-Length
        for _ in range(100):
            yield b" " * 1000

    r = client.post("/v1/tune", content=chunks(), headers={"content-type": "application/json"})
    assert_problem(r, 413)


def test_wrong_types_and_methods(client):
    assert_problem(client.post("/v1/tune", json=[1, 2]), 422)
    assert_problem(client.post("/v1/tune", json="spec"), 422)
    assert_problem(client.post("/v1/tune", content=b"plant: 1", headers={"content-type": "text/yaml"}), 422)
    assert_problem(client.put("/v1/tune", json=SPEC), 405)
    assert_problem(client.get("/v1/nothing"), 404)
    assert_problem(client.post("/v1/verify", json={"spec": SPEC}), 422, "gains")
    assert_problem(client.post("/v1/verify", json={"spec": SPEC, "gains": {"loop0": {"Kp": 1, "Ki": 1}}, "x": 1}),
                   422, "x")
    assert_problem(client.post("/v1/simulate", json={"spec": SPEC, "gains": {}, "max_points": 1}), 422, "max_points")
    assert_problem(client.get("/v1/jobs", params={"offset": -1}), 422, "query.offset")
    assert_problem(client.post("/v1/tune", json=SPEC, headers={"Idempotency-Key": "k" * 500}), 422)
    assert_problem(client.post("/v1/tune", json=SPEC, headers={"Content-Length": "abc"}), 400)


@pytest.mark.parametrize("path", ["/v1/verify", "/v1/simulate"])
def test_sync_endpoints_validate_spec_semantics(client, path):
    spec = _with("loops.0.measure", "nope")
    body = assert_problem(client.post(path, json={"spec": spec, "gains": {"loop0": {"Kp": 1, "Ki": 1}}}), 422)
    assert body["errors"][0]["loc"] == "spec.loops[0].measure"


@pytest.mark.parametrize("kp", [1e-300, 1e300, 1e-12, 1e12])
def test_extreme_gains_never_5xx(client, kp):
    for path in ("/v1/verify", "/v1/simulate"):
        r = client.post(path, json={"spec": SPEC, "gains": {"loop0": {"Kp": kp, "Ki": kp}}})
        assert r.status_code in (200, 422), (path, kp, r.text)


# Found by a fuzzer (tenth session): each of these was an HTTP 500 on all three POST routes.
FUZZ_500S = {
    "design_with_list_requirements": ({**SPEC, "design": {"phase_margin": 60}, "requirements": [1, 2]}, "requirements"),
    "design_with_list_pm_min_deg": ({**SPEC, "design": {"phase_margin": 60}, "requirements": {"pm_min_deg": [1]}},
                                    "requirements.pm_min_deg"),
    "design_crossover_with_int_loops": ({**SPEC, "design": {"crossover": 1.0}, "loops": 5}, "loops"),
    "design_crossover_with_list_wc_min": ({**SPEC, "design": {"crossover": 1.0}, "requirements": {"wc_min": [1]}},
                                          "requirements.wc_min"),
    "seed_beyond_numpys_range": ({**SPEC, "search": {"seed": 2**70}}, "search.seed"),
    "negative_seed": ({**SPEC, "search": {"seed": -5, "budget": 200}}, "search.seed"),
    "delay_of_1e300_seconds": ({**SPEC, "plant": {**SPEC["plant"], "delay": 1e300}}, "plant.delay"),
}


@pytest.mark.parametrize("path", ["/v1/verify", "/v1/simulate", "/v1/tune"])
@pytest.mark.parametrize("case", sorted(FUZZ_500S))
def test_fuzzer_found_500s_are_422_naming_the_field(client, path: str, case: str) -> None:
    spec, field = FUZZ_500S[case]
    body = spec if path == "/v1/tune" else {"spec": spec, "gains": {"loop0": {"Kp": 1, "Ki": 0.5}}}
    problem = assert_problem(client.post(path, json=body), 422)
    assert field in json.dumps(problem["errors"]), problem


@pytest.mark.parametrize("path", ["/v1/verify", "/v1/simulate", "/v1/tune"])
def test_lone_surrogate_in_spec_is_422_not_500(client, path: str) -> None:
    """JSON may carry "\\ud800": a valid Python str that no UTF-8 encoder takes (the spec hash raised)."""
    spec = {**SPEC, "name": "SURROGATE"}
    body = spec if path == "/v1/tune" else {"spec": spec, "gains": {"loop0": {"Kp": 1, "Ki": 0.5}}}
    raw = json.dumps(body).replace('"SURROGATE"', '"\\ud800"').encode()
    problem = assert_problem(client.post(path, content=raw, headers={"content-type": "application/json"}), 422)
    assert "not valid Unicode" in json.dumps(problem["errors"]), problem


@pytest.mark.parametrize("path", ["/v1/verify", "/v1/tune"])
def test_a_plant_model_file_sent_as_the_spec_is_one_422_saying_what_it_is(client, path: str, repo_root) -> None:
    model = yaml.safe_load((repo_root / "models" / "dc_motor.yaml").read_text())
    body = model if path == "/v1/tune" else {"spec": model, "gains": {}}
    problem = assert_problem(client.post(path, json=body), 422)
    assert len(problem["errors"]) == 1 and "this is a plant model file" in problem["errors"][0]["msg"], problem
    assert "gaintune plants show dc_motor --spec" in problem["errors"][0]["msg"]


def test_tune_with_every_gain_fixed_is_422_not_accepted_then_failed(client) -> None:
    """Fuzzing: /v1/tune took a spec with nothing to tune (202), then the job failed with an internal error."""
    fixed = {"Kp": {"value": 1, "tune": False}, "Ki": {"value": 0.5, "tune": False}}
    spec = {**SPEC, "loops": [{"type": "pi", "gains": fixed}]}
    problem = assert_problem(client.post("/v1/tune", json=spec), 422)
    errors = json.dumps(problem["errors"])
    assert "every gain is fixed" in errors and '"loops"' in errors, problem
    # verifying those gains is what the spec is for, and stays allowed
    assert client.post("/v1/verify", json={"spec": spec, "gains": {}}).status_code == 200


# ------------------------------------------------- issue 24: bounded spec checks, booleans

NESTED_POWER = "((((s+1)**40)**40)**40)**40"


@pytest.mark.parametrize("path", ["/v1/tune", "/v1/verify", "/v1/simulate"])
def test_nested_power_expression_refused_fast(client, path: str) -> None:
    """This den kept both cores busy for minutes (129 CPU-s in 75 s) after the client had gone. The degree
    bound refuses it from the expression tree (tests/plants/test_expr_limits.py shows nothing is expanded)."""
    spec = _with("plant.tf.den", NESTED_POWER)
    body = spec if path == "/v1/tune" else {"spec": spec, "gains": {"loop0": {"Kp": 1, "Ki": 0.5}}}
    problem = assert_problem(client.post(path, json=body), 422)
    (err,) = problem["errors"]
    assert err["loc"] == ("plant.tf.den" if path == "/v1/tune" else "spec.plant.tf.den")
    assert "can reach degree 40" in err["msg"] and "limit of 20" in err["msg"]


def test_spec_check_runs_under_a_cpu_budget(client, monkeypatch) -> None:
    """The plant build of a request is refused (422 naming the expression) once it has used the budget."""
    import gaintune_api.validation as validation

    monkeypatch.setattr(validation, "SPEC_CPU_SECONDS", 0.0)  # already spent: the first expression node trips it
    problem = assert_problem(client.post("/v1/tune", json={**SPEC, "name": "cpu budget"}), 422, "plant.tf.den")
    assert "s of CPU time" in json.dumps(problem["errors"])


@pytest.mark.parametrize("path", ["/v1/verify", "/v1/simulate"])
@pytest.mark.parametrize("value", [True, False])
def test_verify_refuses_boolean_gain(client, path: str, value: bool) -> None:
    """`"Kp": true` was verified as Kp = 1.0."""
    body = {"spec": SPEC, "gains": {"loop0": {"Kp": value, "Ki": 0.5}}}
    problem = assert_problem(client.post(path, json=body), 422, "gains.loop0.Kp")
    assert "not a boolean" in json.dumps(problem["errors"])


def test_boolean_in_a_spec_number_is_422(client) -> None:
    spec = _with("loops.0.gains", {"Kp": {"bounds": [True, 10]}})
    problem = assert_problem(client.post("/v1/tune", json=spec), 422, "loops.0.gains.Kp.bounds")
    assert "not a boolean" in json.dumps(problem["errors"])


def test_yaml_alias_bomb_body_is_refused_before_expansion(client) -> None:
    """A spec sent as YAML goes through the spec's bounded parser: an alias bomb is a 400, not a hang."""
    lines = ["b0: &b0 [x, x, x, x, x, x, x, x, x]"]
    lines += [f"b{i}: &b{i} [{', '.join([f'*b{i - 1}'] * 9)}]" for i in range(1, 10)]
    laughs = "\n".join(lines) + "\n"
    for ctype in ("application/yaml", "application/x-yaml", "text/yaml"):
        r = client.post("/v1/tune", content=laughs, headers={"content-type": ctype})
        assert r.status_code == 400 and "alias" in r.json()["detail"].lower(), r.text
