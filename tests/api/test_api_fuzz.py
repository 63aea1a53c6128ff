"""Property-based fuzzing of the REST API: no generated input may cause a 5xx.

Two layers: schemathesis over the whole OpenAPI schema (bounded examples per
operation), and hypothesis over the verify/simulate gains and spec numbers.
"""

from __future__ import annotations

import tempfile
from pathlib import Path

import pytest
from hypothesis import HealthCheck, Phase, given, settings
from hypothesis import strategies as st

from gaintune_api.main import create_app
from gaintune_api.settings import Settings

schemathesis = pytest.importorskip("schemathesis")

_DIR = Path(tempfile.mkdtemp(prefix="gaintune-fuzz-"))
APP = create_app(Settings(_env_file=None, db_path=_DIR / "jobs.db", data_dir=_DIR, workers=0, warmup=False,
                          compute_processes=0, max_budget=2000, max_steps=20_000, sync_max_n_freq=2000,
                          sync_max_robust_samples=4))
SCHEMA = schemathesis.openapi.from_asgi("/openapi.json", APP)

SPEC = {
    "plant": {"tf": {"num": [1], "den": "(s+1)^3"}},
    "loops": [{"type": "pi"}],
    "scenario": {"dt": 0.05, "horizon": 10.0},
}


@SCHEMA.parametrize()
# Phase.generate only: the explicit phase adds schemathesis' exhaustive 'coverage' cases (~2,000 per operation).
@settings(max_examples=15, deadline=None, suppress_health_check=list(HealthCheck), derandomize=True,
          phases=[Phase.generate])
def test_openapi_fuzz_no_server_errors(case):
    response = case.call()
    assert response.status_code < 500, (case.method, case.path, response.status_code, response.text[:500])


@pytest.fixture(scope="module")
def client():
    from fastapi.testclient import TestClient

    with TestClient(APP, raise_server_exceptions=False) as c:
        yield c


numbers = st.one_of(
    st.floats(allow_nan=False, allow_infinity=False, width=64),
    st.integers(min_value=-(10**6), max_value=10**6),
    st.sampled_from(["nan", "inf", "-inf", "1e999", "", "1"]),
    st.none(),
)


@given(kp=numbers, ki=numbers, extra=st.dictionaries(st.text(max_size=5), numbers, max_size=2))
@settings(max_examples=25, deadline=None, suppress_health_check=list(HealthCheck))
def test_fuzz_gains_never_5xx(client, kp, ki, extra):
    gains = {"loop0": {"Kp": kp, "Ki": ki, **extra}}
    for path in ("/v1/verify", "/v1/simulate"):
        r = client.post(path, json={"spec": SPEC, "gains": gains})
        assert r.status_code in (200, 422), (path, gains, r.status_code, r.text[:300])


@given(
    dt=numbers, horizon=numbers, amp=numbers, delay=numbers, den=st.lists(numbers, min_size=0, max_size=4),
    budget=numbers, loop=st.sampled_from(["p", "pi", "pd", "pid", "lqr", "lqi", "x"]),
)
@settings(max_examples=25, deadline=None, suppress_health_check=list(HealthCheck))
def test_fuzz_spec_numbers_never_5xx(client, dt, horizon, amp, delay, den, budget, loop):
    spec = {
        "plant": {"tf": {"num": [1], "den": den}, "delay": delay},
        "loops": [{"type": loop}],
        "scenario": {"dt": dt, "horizon": horizon, "reference": {"amplitude": amp}},
        "search": {"budget": budget},
    }
    r = client.post("/v1/tune", json=spec)
    assert r.status_code in (202, 422), (spec, r.status_code, r.text[:300])
    r = client.post("/v1/simulate", json={"spec": spec, "gains": {"loop0": {"Kp": 1.0, "Ki": 1.0, "Kd": 0.1}}})
    assert r.status_code in (200, 422), (spec, r.status_code, r.text[:300])
