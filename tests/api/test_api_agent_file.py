"""POST /v1/jobs/{id}/policy reads the job's agent.zip as weights only (issue 24): nothing in the file runs."""

from __future__ import annotations

import base64
import json
import os
import shlex
import zipfile
from pathlib import Path

import cloudpickle
from test_api_routes import make_fake_tune, run_next, submit


class _RunsCode:
    def __init__(self, marker: Path) -> None:
        self.marker = marker

    def __reduce__(self):
        return (os.system, (f"touch {shlex.quote(str(self.marker))}",))


def test_job_agent_with_pickled_code_is_422_and_runs_nothing(client, tmp_path):
    """A job whose agent.zip holds pickled code in its data entry (as SB3's loader would unpickle it)."""
    marker = tmp_path / "ran"
    fake = make_fake_tune()

    def forging_tune(spec, **kw):
        result = fake(spec, **kw)
        payload = base64.b64encode(cloudpickle.dumps(_RunsCode(marker))).decode()
        with zipfile.ZipFile(result.agent_path, "w") as z:
            z.writestr("data", json.dumps({"policy_class": {":type:": "<class 'abc.ABCMeta'>",
                                                            ":serialized:": payload}}))
        return result

    job = submit(client)
    assert run_next(client, forging_tune) == "succeeded"
    r = client.post(f"/v1/jobs/{job['id']}/policy", json={})
    assert not marker.exists()  # code run from a loaded file: 0
    assert r.status_code == 422 and r.json()["errors"][0]["loc"] == "agent", r.text
    assert "holds no policy weights" in r.text
