"""GET /v1/jobs/{id} reads its answer through the result model (gaintune.search.result.TuneResult): one rule
decides the accepted gains, for the API as for the report and the exports."""

from __future__ import annotations

import pytest
from fastapi.testclient import TestClient
from test_api_routes import BAD, GOOD, make_client, make_fake_tune, run_next, submit  # noqa: F401 (make_client: fixture)


@pytest.fixture
def client(make_client) -> TestClient:  # noqa: F811 (pytest passes the fixture imported above)
    return make_client()


def test_job_answer_does_not_accept_gains_whose_stored_verification_is_for_other_gains(client):
    """A stored result whose gains differ from the ones its verification passed: the API answered verdict pass
    and handed out the unverified gains as accepted, while the report and the exports set that verdict aside."""
    fake = make_fake_tune(GOOD)

    def edited_tune(spec, **kw):
        result = fake(spec, **kw)
        result.gains = BAD  # after verification: the stored verification is for GOOD
        return result

    job = submit(client)
    assert run_next(client, edited_tune) == "succeeded"
    res = client.get(f"/v1/jobs/{job['id']}").json()["result"]
    assert res["accepted_gains"] is None
    assert res["verdict"] is None and res["verification"] is None
