"""HTML report: content of every section, failed gains never shown as the answer, PDF, and a real headless browser."""

from __future__ import annotations

import json
import re
from pathlib import Path

import pytest

from gaintune.plants.library import load_model
from gaintune.report import SECTIONS, ReportError, render_html, render_pdf, render_report, result_from_gains
from gaintune.search.result import CurvePoint, TuneResult
from gaintune.spec import load_spec

CHROMIUM = Path("/usr/bin/chromium")
BROWSER_ARGS = ["--no-sandbox", "--disable-gpu", "--disable-background-networking", "--disable-component-update",
                "--disable-sync", "--no-first-run"]
AMIGO = {"main": {"Kp": 0.6485, "Ki": 0.3957, "Kd": 0.3751}}
DC_BAD = {"position": {"Kp": 20.0}, "speed": {"Kp": 0.5, "Ki": 20.0}, "current": {"Kp": 5.0, "Ki": 500.0}}


@pytest.fixture(scope="module")
def passed_result() -> TuneResult:
    spec = load_spec(load_model("lag_n").example_spec())
    r = result_from_gains(spec, AMIGO, algo="ppo", command="gaintune tune lag.yaml --seed 0")
    r.curve = [CurvePoint(sims=s, best_cost=c, wall_time=0.1 * i) for i, (s, c) in enumerate([(32, 5.0), (320, 3.0), (1000, 2.5)])]
    return r


@pytest.fixture(scope="module")
def failed_result() -> TuneResult:
    spec = load_spec(load_model("dc_motor").example_spec())
    return result_from_gains(spec, DC_BAD)


@pytest.fixture(scope="module")
def passed_html(passed_result, tmp_path_factory) -> Path:
    return render_report(passed_result, tmp_path_factory.mktemp("report") / "report.html")


def _section(html: str, sid: str) -> str:
    m = re.search(rf'<section id="{sid}">(.*?)</section>', html, re.S)
    assert m, f"section {sid} missing"
    return m.group(1)


def test_every_section_present_with_its_content(passed_html: Path) -> None:
    html = passed_html.read_text()
    for sid in SECTIONS:
        _section(html, sid)
    summary = _section(html, "summary")
    assert "Accepted gains" in summary and "PASS" in summary
    assert "gm_min_db" not in summary or "gain margin" in summary
    assert summary.count("<td class=\"pass\">pass</td>") >= 3  # GM, PM, Ms requirements and stability
    assert html.count("<svg") >= 6  # time (2), Bode, Nyquist, |S||T|, envelope, curve, baselines
    assert "Load disturbance" in _section(html, "time")
    freq = _section(html, "frequency")
    assert "GM " in freq and "PM " in freq and "Ms = 2 limit" in freq
    rob = _section(html, "robustness")
    assert "Worst-case margins" in rob and "envelope" in rob
    assert "ppo" in _section(html, "search")
    base = _section(html, "baselines")
    assert "simc" in base and "amigo" in base
    repro = _section(html, "reproducibility")
    assert "gaintune tune lag.yaml --seed 0" in repro and "numpy" in repro and "lag_n" in repro
    # self-contained: nothing loaded from elsewhere
    assert not re.search(r'(src|href)="(https?:)?//', html) and "<script src" not in html and "<link" not in html


def test_failed_gains_are_marked_failed_never_the_answer(failed_result: TuneResult, tmp_path: Path) -> None:
    assert failed_result.verdict == "fail"
    html = render_html(failed_result)
    summary = _section(html, "summary")
    assert "Accepted gains" not in summary
    assert "FAILED" in summary and 'id="failed-banner"' in summary
    assert 'class="failed"' in summary
    assert "ms_max" in summary  # the reasons are listed


def test_unverified_result_with_its_own_baselines(passed_result: TuneResult) -> None:
    base = [{"method": "cmaes", "gains": {"main": {"Kp": 3.0, "Ki": 0.8, "Kd": 2.0}}, "cost": 1.7, "n_sims": 300,
             "history": [[32, 4.0], [300, 1.7]]}]
    html = render_html(passed_result.model_copy(update={"verification": None, "curve": [], "baselines": base}))
    assert "verified when this report was rendered" in html  # verification is run, never skipped
    b = _section(html, "baselines")
    assert "cmaes" in b and "simc" not in b  # the result's own baselines are used
    assert "cmaes" in _section(html, "search")  # and their history is the curve


def test_report_reads_infinities_stored_as_null(passed_result: TuneResult) -> None:
    """Regression: older result files wrote the report's infinite figures as null (a report kept as model_dump())."""
    from gaintune.report import load_verification

    rep = passed_result.verification
    assert rep.loops[0].gm_lower_db == float("inf")
    doc = json.loads(passed_result.model_dump_json())
    old = json.loads(json.dumps(rep.model_dump(), allow_nan=True).replace("-Infinity", "null").replace("Infinity", "null"))
    assert old["loops"][0]["gm_lower_db"] is None
    doc["verification"] = old
    back = TuneResult.model_validate_json(json.dumps(doc))
    assert back.verification.loops[0].gm_lower_db == float("inf") and back.verification.verdict == "pass"
    again = load_verification(old)  # a raw report dict still reads the same way
    assert again.loops[0].gm_lower_db == float("inf") and load_verification(again) is again
    assert "Accepted gains" in render_html(back)


def test_pdf_without_browser_is_a_clear_error(passed_html: Path, tmp_path: Path, monkeypatch) -> None:
    monkeypatch.setenv("GAINTUNE_CHROMIUM", str(tmp_path / "no-such-browser"))
    with pytest.raises(ReportError, match="Chromium"):
        render_pdf(passed_html, tmp_path / "r.pdf")


# ------------------------------------------------------------ real browser

needs_chromium = pytest.mark.skipif(not CHROMIUM.exists(), reason="/usr/bin/chromium is not installed (apt-get install chromium)")


@pytest.fixture(scope="module")
def browser():
    if not CHROMIUM.exists():
        pytest.skip("/usr/bin/chromium is not installed (apt-get install chromium)")
    from playwright.sync_api import sync_playwright

    with sync_playwright() as p:
        b = p.chromium.launch(executable_path=str(CHROMIUM), args=BROWSER_ARGS)
        yield b
        b.close()


@pytest.mark.browser
@needs_chromium
def test_report_in_headless_chromium(browser, passed_html: Path) -> None:
    page = browser.new_page(viewport={"width": 1200, "height": 900})
    errors: list[str] = []
    page.on("console", lambda m: errors.append(m.text) if m.type == "error" else None)
    page.on("pageerror", lambda e: errors.append(str(e)))
    page.goto(passed_html.as_uri())
    page.wait_for_load_state("load")
    assert errors == []
    for sid in SECTIONS:
        box = page.locator(f"section#{sid}").bounding_box()
        assert box and box["height"] > 20, sid
    svgs = page.locator("svg.plot")
    n = svgs.count()
    assert n >= 6
    for i in range(n):
        box = svgs.nth(i).bounding_box()
        assert box and box["width"] > 100 and box["height"] > 50, f"plot {i} has no size: {box}"
    assert page.locator("#verdict").inner_text() == "PASS"
    page.close()


@pytest.mark.browser
@needs_chromium
def test_report_screenshot_is_not_blank(browser, passed_html: Path, tmp_path: Path) -> None:
    from PIL import Image, ImageStat

    page = browser.new_page(viewport={"width": 1200, "height": 900})
    page.goto(passed_html.as_uri())
    shot = tmp_path / "report.png"
    page.screenshot(path=str(shot), full_page=False)
    page.close()
    im = Image.open(shot).convert("L")
    assert im.size == (1200, 900)
    stat = ImageStat.Stat(im)
    assert stat.stddev[0] > 10  # text, tables and colours, not a blank page
    assert len(set(im.resize((120, 90)).tobytes())) > 20


@pytest.mark.browser
@needs_chromium
def test_pdf_via_chromium(passed_html: Path, tmp_path: Path) -> None:
    pdf = render_pdf(passed_html, tmp_path / "report.pdf")
    data = pdf.read_bytes()
    assert data.startswith(b"%PDF") and len(data) > 20_000
