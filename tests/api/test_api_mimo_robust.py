"""POST /v1/verify on a MIMO spec that randomises plant parameters: the worst case with its draw in the
report; a randomised parameter the plant lacks is a 422 naming the field."""

from __future__ import annotations

import sys
from pathlib import Path

from fastapi.testclient import TestClient

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "verification"))
from test_mimo_robust import GAINS, RANDOM_K11, wood_berry_k11  # noqa: E402


def test_api_verify_of_a_randomised_mimo_spec_reports_the_worst_case_and_its_draw(client: TestClient) -> None:
    r = client.post("/v1/verify", json={"spec": wood_berry_k11(randomize=RANDOM_K11, mimo_ms_max=2.0),
                                        "gains": GAINS})
    assert r.status_code == 200, r.text
    rep = r.json()
    assert rep["verdict"] == "fail" and rep["reasons"][0].endswith("(worst case, draw K11=10)")
    assert rep["robust"]["sides"][0]["where"]["ms"] == {"K11": 10.0}


def test_api_verify_of_a_mimo_spec_randomising_an_unknown_parameter_is_a_422_naming_it(client: TestClient) -> None:
    spec = wood_berry_k11(randomize={"params": {"K21": {"low": 1.0, "high": 2.0}}})
    r = client.post("/v1/verify", json={"spec": spec, "gains": GAINS})
    assert r.status_code == 422 and "randomize.params.K21" in r.text and "Traceback" not in r.text
