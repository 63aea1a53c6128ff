"""Self-contained HTML report of a tuning result (PDF on request via headless Chromium).

Sections: 1 Summary, 2 Time responses, 3 Frequency, 4 Robustness, 5 Search,
6 Baselines, 7 Reproducibility. A MIMO spec has its own page (:mod:`gaintune.report.mimo`): Summary,
Loop map, Loops, Time responses, MIMO margins, Search, Reproducibility. Plots are inline SVG (matplotlib, Agg), so the
page is one file that works offline.

Examples
--------
>>> import pathlib, tempfile
>>> from gaintune.spec import load_spec
>>> spec = load_spec({"plant": {"tf": {"num": [1], "den": "(s+1)^3"}}, "loops": [{"type": "pi"}],
...                   "scenario": {"dt": 0.05, "horizon": 20.0}})
>>> result = result_from_gains(spec, {"loop0": {"Kp": 1.14, "Ki": 0.454}})
>>> result.verdict
'pass'
>>> with tempfile.TemporaryDirectory() as d:
...     path = render_report(result, pathlib.Path(d) / "report.html")
...     print(path.name, path.read_text().startswith("<!DOCTYPE html>"))
report.html True
"""

from __future__ import annotations

import json
import math
import os
import subprocess
import tempfile
import time
from datetime import UTC, datetime
from pathlib import Path
from typing import TYPE_CHECKING, Any

from gaintune.errors import GaintuneError
from gaintune.files import write_atomic

if TYPE_CHECKING:  # pragma: no cover
    from gaintune.spec import Gains

__all__ = ["SECTIONS", "ReportError", "load_verification", "render_html", "render_report", "render_pdf",
           "find_chromium", "result_from_gains"]

#: Section ids in page order (the HTML element ids).
SECTIONS: tuple[str, ...] = ("summary", "time", "frequency", "robustness", "search", "baselines", "reproducibility")

#: Where the PDF renderer looks for a browser ($GAINTUNE_CHROMIUM first).
CHROMIUM_PATHS = ("/usr/bin/chromium", "/usr/bin/chromium-browser", "/usr/bin/google-chrome")


class ReportError(GaintuneError):
    """The report cannot be produced (e.g. no browser for the PDF)."""


def _version() -> str:
    try:
        from importlib.metadata import version

        return version("gaintune")
    except Exception:  # pragma: no cover
        return "unknown"


def load_verification(data: Any):
    """A stored verification report (dict) -> VerificationReport; a report is returned as it is.

    Kept for callers holding a raw report dict: :attr:`TuneResult.verification
    <gaintune.search.result.TuneResult.verification>` is already a report. Delegates to
    :func:`gaintune.verification.report.load_report` (tolerant of infinities stored as JSON ``null``).
    """
    from gaintune.verification.report import load_report

    return load_report(data)


def render_html(result: Any, *, command: str | None = None) -> str:
    """The report of ``result`` (a :class:`~gaintune.search.result.TuneResult`) as one HTML string.

    A MIMO spec (several plant inputs or a loop graph) gets the MIMO report
    (:mod:`gaintune.report.mimo`: loop map, every loop, per-chain responses, MIMO margins).
    """
    import jinja2

    from gaintune.export.mimo import is_mimo
    from gaintune.spec import TuningSpec

    template = "report.html.j2"
    if is_mimo(TuningSpec.model_validate(result.spec)):
        from gaintune.report.mimo import build_mimo_context

        ctx = build_mimo_context(result, command=command)
        template = "report_mimo.html.j2"
    else:
        from gaintune.report.context import build_context

        ctx = build_context(result, command=command)
        if result.verification is not None and getattr(result, "verification_set_aside", None):
            ctx["verified_now"] = True  # verified again after the stored verdict was set aside (gaintune report)
    env = jinja2.Environment(
        loader=jinja2.FileSystemLoader(str(Path(__file__).parent / "templates")),
        autoescape=jinja2.select_autoescape(["html", "j2"]),
    )
    ctx.update(generated=datetime.now(UTC).strftime("%Y-%m-%d %H:%M UTC"), version=_version())
    return env.get_template(template).render(**ctx)


def render_report(result: Any, path: str | os.PathLike, *, pdf: bool = False, command: str | None = None) -> Path:
    """Write the HTML report of ``result`` to ``path`` (and ``path`` with ``.pdf`` when ``pdf``). Returns the HTML path.

    The file is written atomically (:func:`gaintune.files.write_atomic`): a symlink at ``path``
    is replaced, never written through. The report shows the verification ``result`` carries;
    for a result read from a file, re-verify first (``gaintune report`` does).
    """
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    write_atomic(path, render_html(result, command=command))
    if pdf:
        render_pdf(path, path.with_suffix(".pdf"))
    return path


def find_chromium() -> str | None:
    """The Chromium that prints PDFs: ``$GAINTUNE_CHROMIUM``, else the first of ``CHROMIUM_PATHS``; None if none."""
    env = os.environ.get("GAINTUNE_CHROMIUM")
    if env:
        return env if Path(env).exists() else None
    for p in CHROMIUM_PATHS:
        if Path(p).exists():
            return p
    return None


def render_pdf(html_path: str | os.PathLike, pdf_path: str | os.PathLike, *, timeout: float = 120.0) -> Path:
    """Print an HTML file to PDF with headless Chromium (``--print-to-pdf``).

    Raises
    ------
    ReportError
        When no Chromium is installed (install the ``chromium`` package or set
        ``$GAINTUNE_CHROMIUM``) or printing fails.
    """
    exe = find_chromium()
    if exe is None:
        raise ReportError(
            "pdf",
            f"PDF output needs headless Chromium; none found at {', '.join(CHROMIUM_PATHS)}. "
            "Install it (apt-get install chromium) or set GAINTUNE_CHROMIUM, or open the HTML report and print it.",
        )
    html_path, pdf_path = Path(html_path).resolve(), Path(pdf_path).absolute()  # a link at pdf_path is not followed
    pdf_path.parent.mkdir(parents=True, exist_ok=True)
    with tempfile.TemporaryDirectory(prefix="gaintune-chromium-") as profile:
        printed = Path(profile) / "print.pdf"  # Chromium writes here; the PDF is then put in place atomically
        cmd = [
            exe, "--headless", "--no-sandbox", "--disable-gpu", "--disable-background-networking",
            "--disable-component-update", "--disable-sync", "--no-first-run", "--no-pdf-header-footer",
            f"--user-data-dir={profile}", f"--print-to-pdf={printed}", html_path.as_uri(),
        ]
        try:
            proc = subprocess.run(cmd, capture_output=True, text=True, timeout=timeout)
        except subprocess.TimeoutExpired:
            raise ReportError("pdf", f"Chromium did not finish printing within {timeout:.0f} s") from None
        if proc.returncode != 0 or not printed.is_file() or printed.stat().st_size == 0:
            raise ReportError("pdf", f"Chromium failed to print the PDF (exit {proc.returncode}): "
                                     f"{proc.stderr.strip()[-500:]}")
        write_atomic(pdf_path, printed.read_bytes())
    return pdf_path


def result_from_gains(spec: Any, gains: Gains, *, algo: str = "manual", verify: bool = True,
                      baselines: list[dict[str, Any]] | None = None, command: str = "") -> Any:
    """Wrap hand-picked (or baseline) gains in a :class:`TuneResult`, verified and scored, so they can be reported and
    exported."""
    from gaintune.evaluation.evaluator import Evaluator
    from gaintune.provenance import versions
    from gaintune.search.result import Provenance, TuneResult
    from gaintune.verification import verify as run_verify

    t0 = time.perf_counter()
    ev = Evaluator(spec)
    full = ev.layout.from_dict(gains)
    named = ev.layout.to_dict(full)
    scores = ev.evaluate(full[ev.layout.tuned_idx][None, :])
    metrics = {
        r.scenario: {k: (float(v[0]) if math.isfinite(float(v[0])) else None) for k, v in r.metrics.items()}
        for r in scores.results
    }
    rep = run_verify(spec, named) if verify else None
    return TuneResult(
        spec=json.loads(spec.model_dump_json()), algo=algo, gains=named, gains_source="best_seen",
        cost=float(scores.cost[0]),
        violation=float(scores.violation[0]),
        metrics=metrics, sims=ev.n_sims, wall_time=time.perf_counter() - t0, stopped="budget", verification=rep,
        baselines=baselines or [],
        provenance=Provenance(spec_hash=spec.content_hash(), seed=spec.search.seed, versions=versions(),
                              command=command),
    )


