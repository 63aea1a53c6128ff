"""The MIMO report: the loop map, every loop's section, per-chain time responses, the MIMO margin tables
(filled from the verification when it carries MIMO figures, 'not computed' otherwise); `gaintune tune --out`,
`gaintune report` and `gaintune export` on a MIMO result."""

from __future__ import annotations

import json
import re
from pathlib import Path

import pytest
import yaml
from typer.testing import CliRunner

from gaintune import cli
from gaintune.plants.library import load_model
from gaintune.report import render_html
from gaintune.report.loopmap import chains_of
from gaintune.search.result import Provenance, TuneResult
from gaintune.spec import load_spec

BLT = {"xD": {"Kp": 0.375, "Ki": 0.375 / 8.29}, "xB": {"Kp": -0.075, "Ki": -0.075 / 23.6}}


def _result(data: dict, gains=BLT, verification=None) -> TuneResult:
    spec = load_spec(data)
    return TuneResult(spec=spec.model_dump(mode="json"), algo="manual", gains=gains, cost=1.0,
                      verification=verification,
                      provenance=Provenance(spec_hash=spec.content_hash(), seed=0, versions={}))


def _section(html: str, sid: str) -> str:
    start = html.index(f'<section id="{sid}">')
    return html[start:html.index("</section>", start)]


@pytest.fixture(scope="module")
def wood_berry_html() -> str:
    return render_html(_result(load_model("wood_berry").example_spec()))


def test_mimo_report_shows_the_loop_map_every_loop_and_the_actuators(wood_berry_html) -> None:
    html = wood_berry_html
    lm = _section(html, "loop-map")
    assert lm.count('class="loop"') == 2 and 'data-loop="xD"' in lm and 'data-loop="xB"' in lm
    assert "measures xD" in lm and "F (no loop)" in lm and "decoupler" not in lm.split("</p>", 1)[1]
    loops = _section(html, "loops-section")
    assert loops.count('class="loop-row"') == 2 and "input R" in loops and "input S" in loops
    assert re.search(r"<td>F</td><td>lb/min</td><td>-</td>", loops)  # the feed is driven by no loop
    assert "(lb/min)/(mol%)/s" in loops  # Ki's unit from the signals' units


def test_mimo_report_time_responses_per_scenario_with_every_chain_and_actuator(wood_berry_html) -> None:
    time = _section(wood_berry_html, "time")
    assert time.count("<figure>") == 2  # one per scenario
    for label in ("reference xD", "reference xB", "input R", "input S"):
        assert time.count(label) == 2, label
    assert "input F" not in time  # an input no loop drives has no trace to show
    summary = _section(wood_berry_html, "summary")
    assert "IAE xD" in summary and "IAE xB" in summary and "step_xB" in summary


def test_mimo_report_without_mimo_figures_says_not_computed_and_not_verified(wood_berry_html) -> None:
    assert 'id="margins-not-computed"' in _section(wood_berry_html, "mimo-margins")
    assert "NOT VERIFIED" in _section(wood_berry_html, "summary") and 'id="unverified-banner"' in wood_berry_html


def test_mimo_margin_tables_are_filled_from_the_verification() -> None:
    """The hook for the MIMO verification: figures named as gaintune.verification.mimo.MimoMargins."""
    from gaintune.report.mimo import build_mimo_context, mimo_margin_tables

    def brk(loop, bp, gm):
        return {"loop": loop, "break_point": bp, "gm_db": gm, "pm_deg": 61.0, "delay_margin": 4.5, "ms": 1.4,
                "mt": 1.1, "disk_alpha": 0.62}

    margins = {
        "loops": ["xD", "xB"], "inputs": ["R", "S"], "outputs": ["xD", "xB"],
        "stability": {"stable": True, "method": "nyquist", "max_real_pole": -0.02},
        "input_breaks": [brk("xD", "plant_input", 11.5), brk("xB", "plant_input", 9.25)],
        "output_breaks": [brk("xD", "plant_output", 12.5), brk("xB", "plant_output", 8.75)],
        "ms_input": {"value": 2.05, "freq": 0.3}, "mt_input": {"value": 1.6, "freq": 0.2},
        "ms_output": {"value": 2.08, "freq": 0.31}, "mt_output": {"value": 1.7, "freq": 0.2},
        "disk_input": {"alpha": 0.41, "gm_db": 3.9, "pm_deg": 22.9, "freq": 0.25},
        "disk_output": {"alpha": 0.39, "gm_db": 3.7, "pm_deg": 21.9, "freq": 0.26}, "notes": [],
    }
    t = mimo_margin_tables(margins)
    assert t is not None and [r["side"] for r in t["sides"]] == ["plant inputs", "plant outputs"]
    assert t["sides"][0]["ms"] == "2.05" and t["sides"][1]["alpha"] == "0.39"
    assert [(r["loop"], r["break"]) for r in t["breaks"]] == [
        ("xD", "plant input R"), ("xB", "plant input S"), ("xD", "plant output xD"), ("xB", "plant output xB")]
    res = _result(load_model("wood_berry").example_spec())
    ctx = build_mimo_context(res, margins=margins)
    assert ctx["margins"]["breaks"][3]["gm"] == "8.75"


def test_mimo_report_draws_a_cascade_chain_and_the_decoupler() -> None:
    d = load_model("wood_berry").example_spec()
    d["loops"] = [
        {"name": "outer", "measure": "xD", "drives": "loop:inner", "type": "pi"},
        {"name": "inner", "measure": "xB", "drives": "R", "type": "pi"},
        {"name": "side", "measure": "xB", "drives": "S", "type": "pi"},
    ]
    d["scenarios"] = [{"name": "step", "dt": 0.5, "horizon": 60.0,
                       "reference": {"loop": "outer", "kind": "step", "amplitude": 1.0}}]
    d["decoupler"] = {"inputs": ["R", "S"], "matrix": [[1.0, 0.5], [0.3, 1.0]]}
    gains = {"outer": {"Kp": 0.2, "Ki": 0.01}, "inner": {"Kp": 0.1, "Ki": 0.01}, "side": {"Kp": -0.05, "Ki": -0.002}}
    html = render_html(_result(d, gains))
    lm = _section(html, "loop-map")
    assert lm.count('class="loop"') == 3 and ">sp<" in lm and ">decoupler<" in lm and "measured by side, inner" in lm
    assert 'id="decoupler"' in _section(html, "loops-section")
    assert "setpoint of inner" in html


def test_chains_follow_the_graph_outer_first() -> None:
    loops = [{"name": "a", "parent": -1, "chain": 0}, {"name": "b", "parent": -1, "chain": 1},
             {"name": "c", "parent": 0, "chain": -1}, {"name": "d", "parent": 2, "chain": -1}]
    assert chains_of(loops) == [[0, 2, 3], [1]]


def test_siso_report_keeps_its_page(tmp_path) -> None:
    """A single-input spec still gets the SISO page (frequency section, no loop map)."""
    from gaintune.report import result_from_gains

    spec = load_spec({"plant": {"tf": {"num": [1], "den": "(s+1)^3"}}, "loops": [{"type": "pi"}],
                      "scenario": {"dt": 0.05, "horizon": 20.0}})
    html = render_html(result_from_gains(spec, {"loop0": {"Kp": 1.14, "Ki": 0.454}}))
    assert '<section id="frequency">' in html and "loop-map" not in html and "<style>" in html


def test_tune_out_writes_the_mimo_report_and_exports_and_report_export_read_it(tmp_path: Path) -> None:
    run = CliRunner()
    spec_path = tmp_path / "wb.yaml"
    data = load_model("wood_berry").example_spec()
    data["scenarios"] = [dict(sc, horizon=60.0, dt=0.5) for sc in data["scenarios"]]
    spec_path.write_text(yaml.safe_dump(data, sort_keys=False))
    out = tmp_path / "out"
    res = run.invoke(cli.app, ["tune", str(spec_path), "--budget", "300", "--seed", "0", "-o", str(out)])
    assert res.exit_code == 0, res.output
    names = {p.name for p in out.iterdir()}
    verdict = json.loads((out / "result.json").read_text())["verification"]["verdict"]
    # the MIMO verdict decides the firmware files, as for single loops: written on a pass, withheld otherwise
    assert {"gains.json", "gains.yaml", "report.html", "result.json"} <= names, names
    assert ("gains.h" in names) == (verdict == "pass") and ("not written: gains.h, gains.m" in res.output) == (
        verdict != "pass"), (verdict, names)
    html = (out / "report.html").read_text()
    assert 'id="loop-map"' in html and html.count('class="loop-row"') == 2
    assert json.loads((out / "gains.json").read_text())["evaluation_order"] == ["xD", "xB"]
    rep = run.invoke(cli.app, ["report", str(out / "result.json"), "-o", str(tmp_path / "again.html")])
    assert rep.exit_code == 0, rep.output
    assert 'id="loop-map"' in (tmp_path / "again.html").read_text()
    exp = run.invoke(cli.app, ["export", str(out / "result.json"), "-f", "matlab", "--allow-unverified"])
    assert exp.exit_code == 0 and "loop_names = {'xD', 'xB'};" in exp.output and "Traceback" not in exp.output
    assert ("accepted = true;" if verdict == "pass" else "accepted = false;") in exp.output


def test_mimo_report_shows_the_verdict_and_requirement_lines_the_verification_carries() -> None:
    from gaintune.verification.report import RequirementLine, VerificationReport

    line = RequirementLine(requirement="mimo_ms_max", figure="ms", limit=2.1, value=1.93, margin=0.17, passed=True,
                           loop="all")
    rep = VerificationReport.model_construct(verdict="pass", reasons=[], requirements=[line])
    res = _result(load_model("wood_berry").example_spec())
    res.verification = rep
    html = render_html(res)
    summary, margins = _section(html, "summary"), _section(html, "mimo-margins")
    assert ">PASS<" in summary and "NOT VERIFIED" not in summary and 'class="failed"' not in html
    assert 'id="requirements"' in margins and "mimo_ms_max" in margins and "1.93" in margins
