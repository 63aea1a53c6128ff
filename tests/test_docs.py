"""README.md and docs/*.md describe the project as it is, and their links resolve.

Figures are dated by the commit and command that measured them (docs/benchmarks.md, "How the
figures are dated"), never by an ordinal history of the work ("re-run in the sixth session").
Links and result paths into docs/ and bench/results/ must name files that exist.
"""

from __future__ import annotations

import re
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
DOCS = [ROOT / "README.md", *sorted((ROOT / "docs").glob("*.md"))]

ORDINALS = "first|second|third|fourth|fifth|sixth|seventh|eighth|ninth|tenth|eleventh|twelfth"
LATE = "fourth|fifth|sixth|seventh|eighth|ninth|tenth|eleventh|twelfth"
#: Phrases that date a figure or a change by the history of the work.
HISTORY = [
    re.compile(rf"\b({ORDINALS})\s+sessions?\b", re.I),
    re.compile(rf"\b(since|before|after|until|in) the ({LATE})\b", re.I),  # "since the tenth"
    re.compile(rf"\bthe ({LATE})'s\b", re.I),  # "the ninth's tree"
]
SESSION = re.compile(r"\bsessions?\b", re.I)
#: "session" in a technical sense is fine; every other use is history of the work.
SESSION_ALLOWED = re.compile(
    r"\b(HTTP|TLS|SSH|database|SQLAlchemy|requests|httpx|aiohttp|client)\s+sessions?\b", re.I)

LINK = re.compile(r"!?\[[^\]]*\]\(([^)\s]+)\)")
RESULT_PATH = re.compile(r"`(bench/results/[^`\s]+)`")
FENCE = re.compile(r"^\s*(```|~~~)")


def prose_lines(path: Path) -> list[tuple[int, str]]:
    """Numbered lines of a Markdown file outside fenced code blocks."""
    lines, fenced = [], False
    for n, line in enumerate(path.read_text(encoding="utf-8").splitlines(), 1):
        if FENCE.match(line):
            fenced = not fenced
        elif not fenced:
            lines.append((n, line))
    return lines


def history_phrases(text: str) -> list[str]:
    """The phrases of one line that date something by the history of the work."""
    found = [m.group(0) for rx in HISTORY for m in rx.finditer(text)]
    allowed = [m.span() for m in SESSION_ALLOWED.finditer(text)]
    for m in SESSION.finditer(text):
        if not any(start <= m.start() < end for start, end in allowed):
            found.append(m.group(0))
    return found


def slug(heading: str) -> str:
    """GitHub's anchor for a heading: lower case, punctuation dropped, spaces as hyphens."""
    text = re.sub(r"[^\w\- ]", "", heading.strip().lower())
    return text.replace(" ", "-")


def anchors(path: Path) -> set[str]:
    """Every heading anchor of a Markdown file, with GitHub's -1, -2 suffixes for repeats."""
    seen: dict[str, int] = {}
    out = set()
    for _, line in prose_lines(path):
        m = re.match(r"#{1,6}\s+(.*?)\s*#*\s*$", line)
        if m:
            base = slug(m.group(1))
            k = seen.get(base, 0)
            seen[base] = k + 1
            out.add(base if k == 0 else f"{base}-{k}")
    return out


def broken_links(path: Path) -> list[str]:
    """Relative links (and anchors) of one Markdown file that name no file or heading."""
    bad = []
    for n, line in prose_lines(path):
        for m in LINK.finditer(line):
            target = m.group(1)
            if re.match(r"[a-z][a-z0-9+.-]*:", target, re.I):  # http:, mailto: ...
                continue
            file_part, _, anchor = target.partition("#")
            dest = (path.parent / file_part).resolve() if file_part else path
            if not dest.exists():
                bad.append(f"{path.name}:{n}: {target} (no such file)")
            elif anchor and dest.suffix == ".md" and anchor not in anchors(dest):
                bad.append(f"{path.name}:{n}: {target} (no such heading)")
    return bad


def missing_results(path: Path) -> list[str]:
    """`bench/results/...` paths quoted in one Markdown file that do not exist."""
    bad = []
    for n, line in prose_lines(path):
        for m in RESULT_PATH.finditer(line):
            name = m.group(1)
            if "<" in name:  # a pattern such as reference_<suite>.json
                continue
            stem, _, rest = name.partition("{")  # compare_standard.{md,json}
            options, _, tail = rest.partition("}")
            names = [stem + ext + tail for ext in options.split(",")] if rest else [name]
            bad += [f"{path.name}:{n}: {x}" for x in names if not (ROOT / x).exists()]
    return bad


def history_hits(path: Path) -> list[str]:
    """One ``file:line: phrases`` entry per line with history phrases, a phrase broken across lines included."""
    lines = prose_lines(path)
    hits = []
    for i, (n, line) in enumerate(lines):
        nxt = lines[i + 1][1].lstrip() if i + 1 < len(lines) else ""
        joined = f"{line} {nxt}"
        spanning = [m.group(0) for rx in HISTORY for m in rx.finditer(joined) if m.start() < len(line) < m.end()]
        phrases = history_phrases(line) + spanning
        if phrases:
            hits.append(f"{path.name}:{n}: {', '.join(map(repr, phrases))} in {line.strip()[:100]}")
    return hits


@pytest.mark.parametrize("path", DOCS, ids=lambda p: p.name)
def test_docs_date_figures_by_commit_not_by_session(path: Path) -> None:
    hits = history_hits(path)
    assert not hits, "date figures by commit and command, not by session:\n" + "\n".join(hits)


@pytest.mark.parametrize("path", DOCS, ids=lambda p: p.name)
def test_doc_links_into_docs_and_bench_results_resolve(path: Path) -> None:
    bad = broken_links(path) + missing_results(path)
    assert not bad, "\n".join(bad)


@pytest.mark.parametrize("line", [
    "Command: `gaintune bench compare` (seed 0; re-run in the sixth session)",
    "**Eleventh session: figures unchanged.**",
    "the brentq below is gone since the tenth",
    "before = f444edb, the ninth's final tree",
    "Measured (an earlier session) with the script",
])
def test_history_check_flags_ordinal_history(line: str) -> None:
    assert history_phrases(line)


@pytest.mark.parametrize("line", [
    "The first run of the simulator compiles numba kernels.",
    "Loops are listed outer first; the second one is inner.",
    "Measured at commit a144b17 with `gaintune bench startup --repeat 5`.",
    "each request reuses one httpx session",
])
def test_history_check_passes_ordinary_ordinals(line: str) -> None:
    assert not history_phrases(line)


def test_link_check_finds_a_missing_result_file(tmp_path: Path) -> None:
    doc = tmp_path / "docs" / "x.md"
    doc.parent.mkdir()
    doc.write_text("[old](../bench/results/startup_vs_fe6d29f.md) and [here](#nowhere)\n# Title\n")
    assert len(broken_links(doc)) == 2


def test_history_check_flags_a_phrase_broken_across_lines(tmp_path: Path) -> None:
    doc = tmp_path / "x.md"
    doc.write_text("before = c2406d6, the seventh\nsession's final tree\n")
    assert [h.split(":")[1] for h in history_hits(doc)] == ["1", "2"]
