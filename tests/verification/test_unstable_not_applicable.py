"""An unstable closed loop: its margins and peaks are shown as not applicable, never as PASS (CLI, API, report)."""

from __future__ import annotations

import pytest

from gaintune.plants.library import load_model
from gaintune.spec import load_spec
from gaintune.verification import verify
from gaintune.verification.report import NOT_APPLICABLE, format_table

#: On the demo plant 1/(s+1)^3: both are unstable; the first printed PASS gm_min_db and PASS ms_max,
#: the second "nonlinear check: ok".
UNSTABLE = [{"main": {"Kp": 100.0, "Ki": 50.0, "Kd": 1.0}}, {"main": {"Kp": 10.0, "Ki": 5.0, "Kd": 1.0}}]


@pytest.fixture(scope="module")
def demo():
    return load_spec(load_model("lag_n").example_spec())


@pytest.mark.parametrize("gains", UNSTABLE)
def test_unstable_loop_report_shows_no_pass_lines(demo, gains):
    rep = verify(demo, gains)
    assert not rep.stability.stable and rep.verdict == "fail"
    assert rep.requirements and all(q.status == "n/a" and not q.passed for q in rep.requirements)
    table = format_table(rep)
    assert "PASS" not in table.replace("verification of", "")
    assert NOT_APPLICABLE in table
    assert "nonlinear check: ok" not in table
    # the reasons give the instability, not a margin line per requirement
    assert rep.reasons and not any(r.startswith(("gm_min_db", "ms_max", "pm_min_deg")) for r in rep.reasons)


def test_unstable_loop_nonlinear_check_is_not_applicable(demo):
    rep = verify(demo, UNSTABLE[1])
    assert rep.nonlinear is not None and rep.nonlinear.ran and rep.nonlinear.passed is None
    assert "not applicable" in rep.nonlinear.note


def test_stable_loop_requirement_lines_still_pass_or_fail(demo):
    rep = verify(demo, {"main": {"Kp": 1.0, "Ki": 0.4, "Kd": 0.5}})
    assert rep.stability.stable
    assert all(q.applicable and q.status in ("pass", "fail") for q in rep.requirements)


def test_unstable_loop_html_report_shows_not_applicable(demo):
    from gaintune.report import render_html
    from gaintune.search.result import Provenance, TuneResult

    gains = UNSTABLE[0]
    rep = verify(demo, gains)
    result = TuneResult(spec=demo.model_dump(mode="json"), algo="ppo", gains=gains, cost=1.0, metrics={}, curve=[],
                        sims=0, wall_time=0.0, stopped="budget", verification=rep.model_dump(mode="json"),
                        provenance=Provenance(spec_hash=demo.content_hash(), seed=0, versions={}))
    html = render_html(result)
    req = html.split('id="requirements"', 1)[1].split("</table>", 1)[0]
    assert "not applicable (closed loop unstable)" in req and ">pass<" not in req
