"""The MIMO report of a verified result: the margin tables read the verification report itself (its
stability and loop-at-a-time figures), and a robust set adds a worst-case row, with its draw, after each."""

from __future__ import annotations

import sys
from pathlib import Path

from gaintune.fmt import fmt
from gaintune.report import render_html
from gaintune.report.mimo import mimo_margin_tables, verified_margins
from gaintune.search.result import Provenance, TuneResult
from gaintune.spec import load_spec
from gaintune.verification import verify

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "verification"))
from test_mimo_robust import GAINS, RANDOM_K11, wood_berry_k11  # noqa: E402


def _verified(data: dict):
    spec = load_spec(data)
    rep = verify(spec, GAINS, nonlinear=False)
    res = TuneResult(spec=spec.model_dump(mode="json"), algo="manual", gains=GAINS, cost=1.0, verification=rep,
                     provenance=Provenance(spec_hash=spec.content_hash(), seed=0, versions={}))
    return rep, res


def test_mimo_report_of_a_verified_result_shows_its_breaks_stability_and_peaks() -> None:
    """The tables read ``verification.mimo`` (MimoFigures: peaks as numbers, no stability, no breaks)
    together with the report's own stability and loop figures: not '-' peaks, no breaks and 'UNSTABLE'."""
    rep, res = _verified(wood_berry_k11(mimo_ms_max=2.0))
    t = mimo_margin_tables(verified_margins(rep))
    assert t is not None and t["stable"] is True and t["stability"].startswith("stable (")
    assert rep.mimo is not None and t["sides"][0]["ms"] == fmt(rep.mimo.ms_input, 3) != "-"
    assert [(r["loop"], r["break"]) for r in t["breaks"]] == [
        ("xD", "plant input R"), ("xB", "plant input S"), ("xD", "plant output xD"), ("xB", "plant output xB")]
    assert t["breaks"][0]["gm"] == fmt(rep.loops[0].gm_db, 3) and t["robust"] is None
    assert verified_margins(rep.model_dump(mode="json")) is not None
    html = render_html(res)
    sec = html[html.index('<section id="mimo-margins">'):]
    assert "UNSTABLE" not in sec and "plant input R" in sec and "worst case" not in sec


def test_mimo_report_margin_tables_show_the_worst_case_and_its_draw() -> None:
    rep, res = _verified(wood_berry_k11(randomize=RANDOM_K11, mimo_ms_max=2.0))
    assert rep.robust is not None
    t = mimo_margin_tables(verified_margins(rep), rep.robust)
    assert t is not None and t["robust"].startswith("robust set: 18 drawn plants (2 box corners + 16 Monte-Carlo")
    assert [r["side"] for r in t["sides"]] == ["plant inputs", "plant inputs (worst case)", "plant outputs",
                                               "plant outputs (worst case)"]
    assert t["sides"][1]["ms"] == fmt(rep.robust.sides[0].ms, 3) and "Ms, Mt, alpha at K11=10" in t["sides"][1]["draw"]
    assert [r["break"] for r in t["breaks"][:2]] == ["plant input R", "plant input R (worst case)"]
    html = render_html(res)
    sec = html[html.index('<section id="mimo-margins">'):]
    assert 'id="mimo-robust"' in sec and "plant inputs (worst case)" in sec and "at K11=10" in sec
    assert "input / worst (draw K11=10)" in sec and "FAILED" in html
