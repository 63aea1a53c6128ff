"""Report plots: log axes carry plain-number tick labels, and no plot needs matplotlib's mathtext
parser (it cost ~0.3 s of every ``gaintune tune --out``; see docs/benchmarks.md, "Start-up")."""

from __future__ import annotations

import re

import pytest

from gaintune.plants.library import load_model
from gaintune.report import plots, render_html, result_from_gains
from gaintune.search.result import CurvePoint
from gaintune.spec import load_spec

AMIGO = {"main": {"Kp": 0.6485, "Ki": 0.3957, "Kd": 0.3751}}


@pytest.fixture
def no_mathtext(monkeypatch):
    from matplotlib import mathtext

    def refuse(self, s, *args, **kwargs):
        raise AssertionError(f"mathtext parsed {s!r}")

    monkeypatch.setattr(mathtext.MathTextParser, "parse", refuse)


def _labels(svg: str) -> list[str]:
    return [t.strip() for t in re.findall(r"<text[^>]*>([^<]*)</text>", svg)]


@pytest.mark.parametrize(("costs", "expected"), [
    ([2.737, 2.718, 2.7075, 2.699, 2.698], {"2.7", "2.73"}),  # inside one decade: minor ticks labelled
    ([50.0, 3.0, 0.2, 0.03], {"0.1", "1", "10"}),  # several decades: the decades
])
def test_curve_on_a_log_axis_has_plain_labels(costs, expected, no_mathtext) -> None:
    svg = plots.curve_figure([("ppo", [32 * (i + 1) for i in range(len(costs))], costs)])
    labels = _labels(svg)
    assert expected <= set(labels), labels
    assert not any("10^" in t or "\u00d7" in t for t in labels)


def test_whole_report_renders_without_mathtext(no_mathtext) -> None:
    spec = load_spec(load_model("lag_n").example_spec())
    r = result_from_gains(spec, AMIGO, algo="ppo")
    r.curve = [CurvePoint(sims=s, best_cost=c, wall_time=0.1 * i) for i, (s, c) in enumerate([(32, 5.0), (320, 3.0), (1000, 2.5)])]
    assert render_html(r).count("<svg") >= 6


def test_plot_of_values_near_the_float_limit_prints_no_overflow_warning() -> None:
    # a report of gains of 1e308 printed matplotlib's "overflow encountered in multiply" on stderr
    import warnings

    import numpy as np

    from gaintune.report.plots import time_figure

    t = np.linspace(0, 1, 50)
    big = np.full(50, 1e308)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        svg = time_figure(t, [{"name": "loop0", "sp": np.ones(50), "y": big, "measure": "y"}], -big, None, "huge")
    assert svg.startswith("<svg")
