"""TuneResult.verification is a VerificationReport: stored as the report's own JSON, old result files still load."""

from __future__ import annotations

import json
import math

import pytest
from pydantic import ValidationError

from gaintune.search.result import Provenance, TuneResult
from gaintune.spec import load_spec
from gaintune.verification import VerificationReport, verify
from gaintune.verification.report import load_report

GAINS = {"loop0": {"Kp": 1.14, "Ki": 0.454}}


def _spec(**requirements):
    return load_spec({"plant": {"tf": {"num": [1], "den": "(s+1)^3"}}, "loops": [{"type": "pi"}],
                      "requirements": requirements or {"gm_min_db": 6, "pm_min_deg": 45}})


def _result(report: VerificationReport | None, spec=None) -> TuneResult:
    spec = spec or _spec()
    return TuneResult(spec=spec.model_dump(mode="json"), algo="manual", gains=GAINS, cost=1.0, verification=report,
                      provenance=Provenance(spec_hash=spec.content_hash(), seed=0, versions={"gaintune": "test"}))


@pytest.fixture(scope="module")
def passed() -> TuneResult:
    r = _result(verify(_spec(), GAINS))
    assert r.verdict == "pass"
    return r


@pytest.fixture(scope="module")
def failed() -> TuneResult:
    spec = _spec(gm_min_db=6, pm_min_deg=89)
    r = _result(verify(spec, GAINS), spec)
    assert r.verdict == "fail"
    return r


def test_round_trip_dump_load_equal(passed: TuneResult, failed: TuneResult) -> None:
    for r in (passed, failed):
        text = r.model_dump_json()
        back = TuneResult.model_validate_json(text)
        assert isinstance(back.verification, VerificationReport)
        assert back == r and back.verification == r.verification
        assert back.model_dump_json() == text
        assert back.verdict == r.verdict and back.accepted_gains == r.accepted_gains


def test_verification_is_stored_as_the_reports_own_json(passed: TuneResult) -> None:
    """result.json and model_dump() (the API stores it) keep the form they had as a dict: infinities as "Infinity"."""
    own = json.loads(passed.verification.model_dump_json())
    assert json.loads(passed.model_dump_json())["verification"] == own
    assert passed.model_dump()["verification"] == own and passed.model_dump(mode="json")["verification"] == own
    assert passed.verification.loops[0].gm_lower_db == math.inf and own["loops"][0]["gm_lower_db"] == "Infinity"
    assert _result(None).model_dump()["verification"] is None and _result(None).verdict is None


def test_old_result_json_with_null_infinities_loads_as_a_report(failed: TuneResult) -> None:
    """Regression: older result.json files hold infinite figures as null and lack fields added since."""
    doc = json.loads(failed.model_dump_json())
    ver = doc["verification"]
    for loop in ver["loops"]:  # no crossover -> infinite figures, written as null by old files
        loop.update(gm_db=None, gm_upper_db=None, gm_lower_db=None, pm_deg=None, delay_margin=None)
        for key in ("gm_binding", "delay_margin_samples", "crossings_omitted"):  # fields added since
            loop.pop(key, None)
    for key in ("sampled", "dt", "compute_delay", "analysis_band"):
        ver.pop(key, None)
    lines = ver["requirements"]
    ok = next(q for q in lines if q["passed"])
    bad = next(q for q in lines if not q["passed"])
    ok["margin"] = bad["margin"] = None
    text = json.dumps(doc)
    assert '"gm_db": null' in text and '"margin": null' in text

    back = TuneResult.model_validate_json(text)
    rep = back.verification
    assert isinstance(rep, VerificationReport) and back.verdict == "fail" and back.accepted_gains is None
    for f in rep.loops:
        assert f.gm_db == f.gm_upper_db == f.gm_lower_db == f.pm_deg == f.delay_margin == math.inf
        assert f.gm_binding == "none"  # derived from the two (infinite) gain margins
    by_name = {q.requirement: q for q in rep.requirements}
    assert by_name[ok["requirement"]].margin == math.inf and by_name[bad["requirement"]].margin == -math.inf
    assert rep.sampled is False and rep.dt is None and rep.reasons == failed.verification.reasons
    # the same from a dict (TuneResult.model_validate), and through the one loader
    assert TuneResult.model_validate(json.loads(text)).verification == rep
    assert load_report(json.loads(text)["verification"]) == rep
    # written back in today's form: infinities as "Infinity"/"-Infinity" strings
    again = json.loads(back.model_dump_json())["verification"]
    assert again["loops"][0]["gm_db"] == "Infinity"
    assert {q["requirement"]: q["margin"] for q in again["requirements"]}[bad["requirement"]] == "-Infinity"


def test_invalid_stored_verification_is_still_an_error(passed: TuneResult) -> None:
    doc = json.loads(passed.model_dump_json())
    doc["verification"]["verdict"] = "maybe"
    with pytest.raises(ValidationError, match="verdict"):
        TuneResult.model_validate(doc)
    doc = json.loads(passed.model_dump_json())
    doc["verification"]["loops"][0]["ms"] = "high"  # not a number (and not a null infinity)
    with pytest.raises(ValidationError, match="ms"):
        TuneResult.model_validate(doc)


def test_result_edited_after_verification_loses_its_verdict_instead_of_showing_pass(passed: TuneResult) -> None:
    """Bug (fuzzing): gains edited in result.json kept the stored PASS, so `gaintune export -f c` wrote
    GT_VERIFIED 1 for unstable gains and the report said PASS. Same for a tightened requirement."""
    doc = json.loads(passed.model_dump_json())
    doc["gains"]["loop0"] = {"Kp": 50.0, "Ki": 5000.0}
    doc["diagnosis"] = {"status": "pass", "summary": "the gains pass verification"}
    edited = TuneResult.model_validate(doc)
    assert edited.verification is None and edited.verdict is None and edited.accepted_gains is None
    assert edited.diagnosis is None and "other gains" in edited.verification_set_aside
    doc = json.loads(passed.model_dump_json())
    doc["spec"]["requirements"]["pm_min_deg"] = 89.0
    edited = TuneResult.model_validate(doc)
    assert edited.verification is None and "another spec" in edited.verification_set_aside
    doc["spec"]["scenarios"][0]["dt"] = -1.0
    assert "does not validate" in TuneResult.model_validate(doc).verification_set_aside
    # untouched, and the dict form the API stores: kept
    same = TuneResult.model_validate(json.loads(passed.model_dump_json()))
    assert same.verdict == "pass" and same.verification_set_aside is None
