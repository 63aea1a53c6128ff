"""The MIMO verdict's robust set: the frozen gains judged on every plant of the single-loop robust set.

:func:`mimo_robust` draws the set :func:`gaintune.verification.robust.robust_samples` draws (the
box corners of ``randomize.params`` and ``verify.robust_samples`` Monte-Carlo draws, seeded by
``search.seed``), builds each drawn plant and its MIMO report by the nominal path's own function
(:func:`~gaintune.verification.mimo_sampled_report.sampled_margins` by default,
:func:`~gaintune.verification.mimo_spec.spec_margins` with ``verify.sampled: false``), and keeps,
per requirement line of :func:`gaintune.verification.mimo.judge`, the least margin over the stable
drawn loops and the draw attaining it; per break point and per side, the worst figures.

Per-plant work is cached as the nominal path caches it: a drawn plant shares the nominal plant's
memo of its MIMO form per parameter set, so its sampled core (keyed by that form) is reused by the
next verification of the same plant object.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np

from gaintune.controllers.layout import GainLayout
from gaintune.errors import SpecError
from gaintune.plants.mimo import MimoPlant, as_mimo
from gaintune.spec import TuningSpec
from gaintune.verification.figures import delay_samples
from gaintune.verification.margins import BreakFigures
from gaintune.verification.mimo import MimoLine, MimoMargins
from gaintune.verification.mimo_sampled_report import sampled_margins
from gaintune.verification.mimo_spec import loop_frame, spec_margins
from gaintune.verification.report import RobustReport, WorstCase, WorstSide
from gaintune.verification.robust import WORSE, public_sample, robust_samples

__all__ = ["MimoRobust", "mimo_robust", "drawn_plant", "check_randomize"]

#: A sample as :func:`robust_samples` gives it.
_Sample = dict[str, float]
#: figure -> (worst value, the sample attaining it)
_Tracked = dict[str, tuple[float, _Sample]]
#: The MIMO-wide figures tracked per side, and which way is worse.
_SIDE_WORSE: dict[str, Callable[[float, float], float]] = {"ms": max, "mt": max, "disk_alpha": min}


@dataclass
class MimoRobust:
    """What :func:`mimo_robust` found: the report section, the worst requirement lines (as
    :func:`gaintune.verification.mimo.judge` gives them, one per nominal line, in its order) with
    the draw attaining each, and the unstable draws."""

    report: RobustReport
    worst_lines: list[MimoLine]
    worst_draws: list[_Sample]
    n_unstable: int


def check_randomize(spec: TuningSpec, plant: Any) -> MimoPlant:
    """The plant as a :class:`MimoPlant`, after checking that every randomised entry is one the MIMO
    robust set draws.

    Raises
    ------
    SpecError
        For ``randomize.delay`` (a MIMO plant's delays are per path) or a ``randomize.params`` key
        that is not a parameter of the plant.
    """
    if spec.randomize.delay is not None:
        raise SpecError("randomize.delay", "a plant with several inputs or a loop graph has a delay per path; "
                        "randomise a parameter the delays are written in (randomize.params) instead")
    mp = as_mimo(plant)
    for name in spec.randomize.params:
        if name not in mp.params:
            raise SpecError(f"randomize.params.{name}", f"the plant has no parameter {name!r}; parameters: "
                            f"{', '.join(mp.params) or 'none (give plant.params and write them into the entries)'}")
    return mp


def drawn_plant(plant: Any, sample: _Sample) -> MimoPlant:
    """``plant`` with the parameters of one robust sample (its memo of MIMO forms shared)."""
    mp = as_mimo(plant)
    return replace(mp, params=mp.with_params(sample))


def _margin(q: MimoLine) -> float:
    return -np.inf if np.isnan(q.margin) else q.margin


@dataclass
class _Worst:
    """The running worst over the drawn plants (stable ones only: an unstable loop's figures mean nothing)."""

    lines: list[tuple[MimoLine, _Sample]] = field(default_factory=list)
    breaks: list[_Tracked] = field(default_factory=list)
    sides: dict[str, _Tracked] = field(default_factory=dict)
    names: list[tuple[str, str]] = field(default_factory=list)  # (loop, break point) of each break

    def add(self, rep: MimoMargins, lines: list[MimoLine], smp: _Sample) -> None:
        if not self.lines:
            self.lines = [(q, smp) for q in lines]
        else:
            self.lines = [(q, smp) if _margin(q) < _margin(w) else (w, s)
                          for q, (w, s) in zip(lines, self.lines, strict=True)]
        figs: list[BreakFigures] = rep.input_breaks + rep.output_breaks
        if not self.breaks:
            self.names = [(f.loop, f.break_point) for f in figs]
            self.breaks = [{k: (getattr(f, k), smp) for k in WORSE} for f in figs]
        for f, tr in zip(figs, self.breaks, strict=True):
            _keep(tr, {k: getattr(f, k) for k in WORSE}, WORSE, smp)
        for side, (ms, mt, disk) in {"input": (rep.ms_input, rep.mt_input, rep.disk_input),
                                     "output": (rep.ms_output, rep.mt_output, rep.disk_output)}.items():
            vals = {"ms": ms.value, "mt": mt.value, "disk_alpha": disk.alpha}
            tr = self.sides.setdefault(side, {k: (v, smp) for k, v in vals.items()})
            _keep(tr, vals, _SIDE_WORSE, smp)


def _keep(tr: _Tracked, values: dict[str, float], worse: dict[str, Callable[[float, float], float]],
          smp: _Sample) -> None:
    """Keep, per figure, the worse of the tracked value and ``values`` (the first among ties)."""
    for k, v in values.items():
        cur = tr[k][0]
        if worse[k](v, cur) != cur and v != cur:
            tr[k] = (v, smp)


def _worst_cases(w: _Worst, dt: float) -> list[WorstCase]:
    out = []
    for (loop, brk), tr in zip(w.names, w.breaks, strict=True):
        where = {k: public_sample(tr[k][1]) for k in WORSE}
        out.append(WorstCase(loop=loop, break_point=brk, gm_db=tr["gm_db"][0], pm_deg=tr["pm_deg"][0],
                             delay_margin=tr["delay_margin"][0],
                             delay_margin_samples=delay_samples(tr["delay_margin"][0], dt), ms=tr["ms"][0],
                             mt=tr["mt"][0], disk_alpha=tr["disk_alpha"][0], where=where))
    return out


def _worst_sides(w: _Worst) -> list[WorstSide]:
    return [WorstSide(side=side, ms=tr["ms"][0], mt=tr["mt"][0], disk_alpha=tr["disk_alpha"][0],
                      where={k: public_sample(tr[k][1]) for k in _SIDE_WORSE})
            for side, tr in w.sides.items()]


def mimo_robust(spec: TuningSpec, plant: Any, layout: GainLayout, full: np.ndarray, sampled: bool,
                dt: float) -> MimoRobust:
    """The frozen gains ``full`` judged on every plant of the robust set (see the module docstring).

    Parameters
    ----------
    spec, plant, layout
        The MIMO problem (scenario dt resolved), its nominal plant and gain layout.
    full
        One gain vector, layout order.
    sampled
        Judge the exact sampled loop (``verify.sampled``), else the continuous one.
    dt
        The analysis sample time (delay margins in samples).

    Raises
    ------
    SpecError
        As :func:`check_randomize`, or for a requirement target that is not a loop, input, output or side.
    """
    check_randomize(spec, plant)
    samples, n_corners, n_mc = robust_samples(spec)
    margins = sampled_margins if sampled else spec_margins
    w, unstable = _Worst(), []
    first: list[tuple[MimoLine, _Sample]] = []
    for smp in samples:
        drawn = drawn_plant(plant, smp)
        _, rep, lines = margins(spec, drawn, layout, full, frame=loop_frame(spec, drawn, cache=False))
        first = first or [(q, smp) for q in lines]
        if rep.stability.stable:
            w.add(rep, lines, smp)
        else:
            unstable.append(smp)
    picked = w.lines or first  # no stable draw: the first draw's lines, not applicable (the loop is unstable)
    rob = RobustReport(n_samples=len(samples), n_corners=n_corners, n_monte_carlo=n_mc, seed=spec.search.seed,
                       n_unstable=len(unstable), unstable_samples=[public_sample(u) for u in unstable[:20]],
                       worst=_worst_cases(w, dt), sides=_worst_sides(w))
    return MimoRobust(rob, [q for q, _ in picked], [public_sample(s) for _, s in picked], len(unstable))
