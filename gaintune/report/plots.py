"""Report plots: matplotlib (Agg) figures rendered to inline SVG strings.

Every function takes plain arrays and returns an ``<svg>`` element whose ids
are prefixed uniquely, so several figures can live in one HTML page.
"""

from __future__ import annotations

import io
import itertools
import math
import re
from typing import Any

import numpy as np

__all__ = ["to_svg", "time_figure", "bode_figure", "nyquist_figure", "sensitivity_figure",
           "envelope_figure", "curve_figure", "overlay_figure"]

_counter = itertools.count()
COLORS = ["#1f77b4", "#d62728", "#2ca02c", "#9467bd", "#ff7f0e", "#8c564b", "#e377c2", "#17becf"]


def _plt():
    import matplotlib

    matplotlib.use("Agg", force=False)
    import matplotlib.pyplot as plt

    plt.rcParams.update({
        "svg.fonttype": "none",
        "svg.hashsalt": "gaintune",
        "font.size": 9,
        "axes.grid": True,
        "grid.alpha": 0.3,
        "axes.spines.top": False,
        "axes.spines.right": False,
        "figure.dpi": 100,
        # A fixed title height. The automatic one measures every tick label at each draw to keep the
        # title clear of labels on top, which no figure here has (same output, ~0.1 s per report).
        "axes.titley": 1.0,
    })
    return plt


def to_svg(fig: Any) -> str:
    """Render a figure to an ``<svg>`` string (no XML prolog) with unique ids, then close it."""
    plt = _plt()
    buf = io.StringIO()
    # data near the float limit (gains of 1e308, a diverged run) overflows matplotlib's tick
    # arithmetic: the figure is still drawn, so its numpy warnings are only noise on stderr
    with np.errstate(over="ignore", invalid="ignore"):
        fig.savefig(buf, format="svg")
    plt.close(fig)
    text = buf.getvalue()
    text = text[text.index("<svg"):]
    text = re.sub(r"<metadata>.*?</metadata>", "", text, flags=re.S)
    pre = f"f{next(_counter)}_"
    text = re.sub(r'\bid="([^"]+)"', lambda m: f'id="{pre}{m.group(1)}"', text)
    text = re.sub(r"url\(#([^)]+)\)", lambda m: f"url(#{pre}{m.group(1)})", text)
    text = re.sub(r'href="#([^"]+)"', lambda m: f'href="#{pre}{m.group(1)}"', text)
    # scale with the page: keep the viewBox, drop the fixed size
    text = re.sub(r'<svg([^>]*?)\swidth="[^"]+"\sheight="[^"]+"', r'<svg\1 class="plot"', text, count=1)
    return text


#: Time-domain data is drawn clipped to +-this: values near the float limit (a diverged run, gains of
#: 1e308) overflow matplotlib's tick arithmetic ("arange: cannot compute length"), and beyond it a
#: plot shows nothing more.
PLOT_LIMIT = 1e100


def _plottable(v: Any) -> np.ndarray:
    """``v`` as floats clipped to +-PLOT_LIMIT (NaN stays a gap in the line)."""
    return np.clip(np.asarray(v, dtype=float), -PLOT_LIMIT, PLOT_LIMIT)


def _layout(fig: Any, hspace: float = 0.25, wspace: float = 0.2) -> None:
    """Fixed margins in inches (room for 7-character tick labels, an axis label and a title).

    matplotlib's ``tight_layout`` measures every text to place the axes; it took 0.37 s of a
    0.84 s report. ``hspace``/``wspace`` are the gaps between subplots in inches."""
    w, h = fig.get_size_inches()
    rows, cols = fig.axes[0].get_subplotspec().get_gridspec().get_geometry() if fig.axes else (1, 1)
    left, right, bottom, top = 0.85, 0.2, 0.55, 0.35
    ax_h = (h - bottom - top - hspace * (rows - 1)) / rows
    ax_w = (w - left - right - wspace * (cols - 1)) / cols
    fig.subplots_adjust(left=left / w, right=1 - right / w, bottom=bottom / h, top=1 - top / h,
                        hspace=hspace / ax_h if rows > 1 else 0.2, wspace=wspace / ax_w if cols > 1 else 0.2)


def _logx(*axes, numticks: int = 12) -> None:
    """Plain decade labels and no minor ticks: mathtext labels and minor tick artists make log axes slow.

    ``numticks``: at most this many decade labels (fewer on narrow axes, so that they do not overlap)."""
    from matplotlib.ticker import FuncFormatter, LogLocator, NullLocator

    for ax in axes:
        ax.set_xscale("log")
        ax.xaxis.set_major_locator(LogLocator(base=10.0, numticks=numticks))
        ax.xaxis.set_major_formatter(FuncFormatter(lambda v, _p: f"{v:g}"))
        ax.xaxis.set_minor_locator(NullLocator())


def _plain_log_labels(axis) -> None:
    """Label a log axis with plain numbers ("0.3", "2.705", "1e+05"): the ticks matplotlib's own log
    formatters label, without their mathtext ("2.7x10^0"), whose parsing cost ~0.3 s per report."""
    from matplotlib.ticker import LogFormatter

    class Plain(LogFormatter):
        def _num_to_string(self, x, vmin, vmax):
            return f"{x:g}"

    axis.set_major_formatter(Plain(10.0))
    axis.set_minor_formatter(Plain(10.0, labelOnlyBase=False))


def time_figure(t: np.ndarray, loops: list[dict], u: np.ndarray, u_limits: tuple[float, float] | None,
                title: str, extra_u: list[tuple[str, np.ndarray]] | None = None, u_unit: str = "") -> str:
    """One subplot per loop (output vs setpoint) and one for the control effort with saturation limits."""
    plt = _plt()
    n = len(loops) + 1
    fig, axes = plt.subplots(n, 1, figsize=(8, 1.9 * n + 0.4), sharex=True)
    for ax, lp in zip(axes, loops, strict=False):  # the last axes hold the actuator
        ax.plot(t, _plottable(lp["sp"]), color="0.4", ls="--", lw=1.0, label=f"setpoint {lp['name']}")
        ax.plot(t, _plottable(lp["y"]), color=COLORS[0], lw=1.4, label=f"{lp['name']} ({lp['measure']})")
        ax.set_ylabel(lp["measure"] + (f" [{lp['unit']}]" if lp.get("unit") and lp["unit"] != "-" else ""))
        ax.legend(loc="lower right", fontsize=8, framealpha=0.8)
    ax = axes[-1]
    ax.plot(t, _plottable(u), color=COLORS[1], lw=1.2, label="u (actuator)")
    if u_limits is not None:
        for v in u_limits:
            if math.isfinite(v):
                ax.axhline(v, color="k", ls=":", lw=1.0)
        lab = [f"{v:g}" for v in u_limits if math.isfinite(v)]
        if lab:
            ax.plot([], [], "k:", label="saturation " + " / ".join(lab))
    ax.set_ylabel("u" + (f" [{u_unit}]" if u_unit else ""))
    ax.set_xlabel("time [s]")
    ax.legend(loc="lower right", fontsize=8, framealpha=0.8)
    axes[0].set_title(title)
    _layout(fig)
    return to_svg(fig)


def bode_figure(w: np.ndarray, L: np.ndarray, title: str, gm: dict | None, pm: dict | None) -> str:
    """Magnitude (dB) and unwrapped phase (deg) with the binding GM and PM marked."""
    plt = _plt()
    fig, (a1, a2) = plt.subplots(2, 1, figsize=(8, 4.4), sharex=True)
    with np.errstate(divide="ignore"):
        mag = 20 * np.log10(np.abs(L))
    ph = np.degrees(np.unwrap(np.angle(L)))
    # shift the phase so that it starts within (-360, 0] like textbook Bode plots
    if ph.size and np.isfinite(ph[0]):
        ph = ph - 360.0 * math.ceil(ph[0] / 360.0) if ph[0] > 0 else ph
    a1.plot(w, mag, color=COLORS[0], lw=1.4)
    a1.axhline(0, color="k", lw=0.8)
    a1.set_ylabel("|L| [dB]")
    a2.plot(w, ph, color=COLORS[0], lw=1.4)
    _logx(a1, a2)
    a2.axhline(-180, color="k", lw=0.8)
    a2.set_ylabel("phase [deg]")
    a2.set_xlabel("frequency [rad/s]")
    if gm and gm.get("freq") and math.isfinite(gm["db"]):
        wg = gm["freq"]
        m = float(np.interp(np.log(wg), np.log(w), mag))
        a1.vlines(wg, m, 0, color=COLORS[1], lw=2)
        a1.annotate(f"GM {gm['db']:.1f} dB", (wg, m / 2), xytext=(6, 0), textcoords="offset points", color=COLORS[1])
    if pm and pm.get("freq") and math.isfinite(pm["deg"]):
        wc = pm["freq"]
        p = float(np.interp(np.log(wc), np.log(w), ph))
        base = p - pm["deg"]
        a2.vlines(wc, base, p, color=COLORS[2], lw=2)
        a2.annotate(f"PM {pm['deg']:.1f} deg", (wc, (p + base) / 2), xytext=(6, 0), textcoords="offset points",
                    color=COLORS[2])
    lo = np.nanpercentile(mag[np.isfinite(mag)], 1) if np.any(np.isfinite(mag)) else -60
    hi = np.nanmax(mag[np.isfinite(mag)]) if np.any(np.isfinite(mag)) else 20
    a1.set_ylim(max(lo, -120) - 5, min(hi, 120) + 5)
    fin = ph[np.isfinite(ph)]
    if fin.size:
        a2.set_ylim(max(fin.min(), -900) - 10, min(fin.max(), 180) + 10)
    a1.set_title(title)
    _layout(fig)
    return to_svg(fig)


def nyquist_figure(curves: list[tuple[str, np.ndarray]], ms_max: float | None, ms_values: list[float]) -> str:
    """Nyquist curves (w > 0 solid, mirror dashed) around -1 with the Ms circle(s)."""
    plt = _plt()
    fig, ax = plt.subplots(figsize=(6.2, 5.6))
    th = np.linspace(0, 2 * np.pi, 361)
    for i, (name, L) in enumerate(curves):
        c = COLORS[i % len(COLORS)]
        ok = np.isfinite(L)
        ax.plot(L[ok].real, L[ok].imag, color=c, lw=1.4, label=name)
        ax.plot(L[ok].real, -L[ok].imag, color=c, lw=0.8, ls="--", alpha=0.6)
    if ms_max:
        r = 1.0 / ms_max
        ax.plot(-1 + r * np.cos(th), r * np.sin(th), color="k", ls="--", lw=1.2, label=f"Ms = {ms_max:g} limit")
    for ms in ms_values[:1]:
        if math.isfinite(ms) and ms > 0:
            r = 1.0 / ms
            ax.plot(-1 + r * np.cos(th), r * np.sin(th), color="0.5", ls=":", lw=1.0, label=f"Ms = {ms:.2f} (achieved)")
    ax.plot([-1], [0], "k+", ms=10, mew=2)
    ax.set_xlim(-3, 1.5)
    ax.set_ylim(-2.5, 2.5)
    ax.set_aspect("equal")
    ax.set_xlabel("Re L")
    ax.set_ylabel("Im L")
    ax.set_title("Nyquist (zoomed on -1)")
    ax.legend(loc="lower right", fontsize=8)
    _layout(fig)
    return to_svg(fig)


def sensitivity_figure(w: np.ndarray, curves: list[tuple[str, np.ndarray]], ms_max: float | None,
                       mt_max: float | None) -> str:
    """|S| and |T| per break point with the required peaks."""
    plt = _plt()
    fig, (a1, a2) = plt.subplots(1, 2, figsize=(8, 3.2), sharey=True)
    for i, (name, L) in enumerate(curves):
        c = COLORS[i % len(COLORS)]
        with np.errstate(all="ignore"):
            S = 1.0 / (1.0 + L)
            T = L / (1.0 + L)
            a1.plot(w, 20 * np.log10(np.abs(S)), color=c, lw=1.3, label=name)
            a2.plot(w, 20 * np.log10(np.abs(T)), color=c, lw=1.3, label=name)
    _logx(a1, a2, numticks=6)  # half-width axes
    if ms_max:
        a1.axhline(20 * math.log10(ms_max), color="k", ls="--", lw=1, label=f"Ms limit {ms_max:g}")
    if mt_max:
        a2.axhline(20 * math.log10(mt_max), color="k", ls="--", lw=1, label=f"Mt limit {mt_max:g}")
    a1.set_title("|S| = |1/(1+L)|")
    a2.set_title("|T| = |L/(1+L)|")
    a1.set_ylabel("dB")
    for a in (a1, a2):
        a.set_xlabel("frequency [rad/s]")
        a.set_ylim(-60, 20)
        a.legend(loc="lower right", fontsize=7)
    _layout(fig, wspace=0.2)
    return to_svg(fig)


def noise_figure(w: np.ndarray, curves: list[tuple[str, np.ndarray, float | None]]) -> str:
    """|C S| (each loop's measurement noise to the plant input) with its Mks limit, where one is required."""
    plt = _plt()
    fig, ax = plt.subplots(figsize=(8, 3.0))
    for i, (name, N, limit) in enumerate(curves):
        c = COLORS[i % len(COLORS)]
        with np.errstate(all="ignore"):
            ax.plot(w, 20 * np.log10(np.abs(N)), color=c, lw=1.3, label=name)
        if limit:
            ax.axhline(20 * math.log10(limit), color=c, ls="--", lw=1, label=f"Mks limit {limit:.4g} ({name})")
    _logx(ax)
    ax.set_title("|C S|: measurement noise to plant input")
    ax.set_xlabel("frequency [rad/s]")
    ax.set_ylabel("dB")
    ax.legend(loc="lower right", fontsize=7)
    _layout(fig)
    return to_svg(fig)


def envelope_figure(t: np.ndarray, ys: np.ndarray, y_nom: np.ndarray, sp: np.ndarray, us: np.ndarray,
                    u_nom: np.ndarray, label: str) -> str:
    """Min-max band over the draws, a few draws, and the nominal response."""
    plt = _plt()
    fig, (a1, a2) = plt.subplots(2, 1, figsize=(8, 4.6), sharex=True)
    ys, y_nom, sp, us, u_nom = (_plottable(v) for v in (ys, y_nom, sp, us, u_nom))
    a1.fill_between(t, np.nanmin(ys, 0), np.nanmax(ys, 0), color=COLORS[0], alpha=0.2, lw=0,
                    label=f"envelope ({ys.shape[0]} plants)")
    for row in ys[: min(12, ys.shape[0])]:
        a1.plot(t, row, color=COLORS[0], lw=0.4, alpha=0.5)
    a1.plot(t, sp, color="0.4", ls="--", lw=1, label="setpoint")
    a1.plot(t, y_nom, color="k", lw=1.4, label="nominal")
    a1.set_ylabel(label)
    a1.legend(loc="lower right", fontsize=8, framealpha=0.8)
    a2.fill_between(t, np.nanmin(us, 0), np.nanmax(us, 0), color=COLORS[1], alpha=0.2, lw=0)
    a2.plot(t, u_nom, color=COLORS[1], lw=1.2)
    a2.set_ylabel("u")
    a2.set_xlabel("time [s]")
    a1.set_title("Response envelope over the randomisation set")
    _layout(fig)
    return to_svg(fig)


def curve_figure(series: list[tuple[str, list[float], list[float]]]) -> str:
    """Best cost vs simulations."""
    plt = _plt()
    fig, ax = plt.subplots(figsize=(8, 3.2))
    allpos = True
    for i, (name, x, y) in enumerate(series):
        if not x:
            continue
        ax.step(x, y, where="post", color=COLORS[i % len(COLORS)], lw=1.4, label=name)
        allpos = allpos and min(y) > 0
    if allpos:
        ax.set_yscale("log")
        _plain_log_labels(ax.yaxis)
    ax.set_xlabel("simulations")
    ax.set_ylabel("best cost")
    ax.set_title("Search progress")
    ax.legend(loc="lower right", fontsize=8, framealpha=0.8)
    _layout(fig)
    return to_svg(fig)


def overlay_figure(t: np.ndarray, sp: np.ndarray, runs: list[tuple[str, np.ndarray, np.ndarray]],
                   u_limits: tuple[float, float] | None, ylabel: str, title: str) -> str:
    """Outer-loop output and actuator of several gain sets overlaid."""
    plt = _plt()
    fig, (a1, a2) = plt.subplots(2, 1, figsize=(8, 4.6), sharex=True)
    a1.plot(t, _plottable(sp), color="0.4", ls="--", lw=1, label="setpoint")
    for i, (name, y, u) in enumerate(runs):
        y, u = _plottable(y), _plottable(u)
        c = COLORS[i % len(COLORS)]
        lw = 1.8 if i == 0 else 1.1
        a1.plot(t, y, color=c, lw=lw, label=name)
        a2.plot(t, u, color=c, lw=lw)
    if u_limits is not None:
        for v in u_limits:
            if math.isfinite(v):
                a2.axhline(v, color="k", ls=":", lw=1.0)
    a1.set_ylabel(ylabel)
    a2.set_ylabel("u")
    a2.set_xlabel("time [s]")
    a1.set_title(title)
    a1.legend(loc="lower right", fontsize=8, framealpha=0.8)
    _layout(fig)
    return to_svg(fig)
