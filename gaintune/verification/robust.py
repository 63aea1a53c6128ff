"""The robust check: the sample set (box corners of the randomised parameters and delay, plus
Monte-Carlo draws) and the worst figures of the frozen gains over it (:func:`robust_check`)."""

from __future__ import annotations

import itertools
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from gaintune.plants.plant import Plant
from gaintune.sim.draws import draw_dist as _draw
from gaintune.spec import DistSpec, TuningSpec
from gaintune.verification.analysis import Analysis, analyse
from gaintune.verification.cascade import Cascade
from gaintune.verification.figures import delay_samples
from gaintune.verification.freqresp import DelayModel
from gaintune.verification.margins import judged_pm
from gaintune.verification.noise import noise_peaks
from gaintune.verification.report import RobustReport, WorstCase
from gaintune.verification.sampled import SampledPlant, sample_plant

__all__ = ["robust_samples", "robust_check", "RobustResult", "MAX_CORNERS", "DELAY_KEY", "WORSE", "public_sample"]

#: Most box corners used (a random subset when 2^d is larger).
MAX_CORNERS = 256
#: Key of the delay in a sample dict.
DELAY_KEY = "__delay__"


def robust_samples(spec: TuningSpec) -> tuple[list[dict[str, float]], int, int]:
    """Samples as dicts {param: value} (delay under :data:`DELAY_KEY`), n_corners, n_monte_carlo.

    Seeded from ``spec.search.seed``; the same spec always gives the same set.
    """
    dims: list[tuple[str, DistSpec]] = list(spec.randomize.params.items())
    if spec.randomize.delay is not None:
        dims.append((DELAY_KEY, spec.randomize.delay))
    if not dims:
        return [], 0, 0
    rng = np.random.default_rng(spec.search.seed)
    boxes = [d.box for _, d in dims]
    n_all = 2 ** len(dims)
    if n_all <= MAX_CORNERS:
        corners = list(itertools.product(*boxes))
    else:
        bits = rng.integers(0, 2, size=(MAX_CORNERS, len(dims)))
        corners = [tuple(boxes[j][b] for j, b in enumerate(row)) for row in bits]
    samples = [dict(zip([k for k, _ in dims], map(float, c), strict=True)) for c in corners]
    n_mc = spec.verify.robust_samples
    if n_mc:
        cols = {k: _draw(d, rng, n_mc) for k, d in dims}
        samples += [{k: float(cols[k][i]) for k in cols} for i in range(n_mc)]
    for s in samples:
        if DELAY_KEY in s:
            s[DELAY_KEY] = max(0.0, s[DELAY_KEY])
    return samples, len(corners), n_mc


#: The figures tracked over the robust set, and which way is worse.
_WORSE: dict[str, Callable[[float, float], float]] = {
    "gm_db": min, "pm_deg": lambda a, b: min(a, b, key=judged_pm), "delay_margin": min, "ms": max, "mt": max,
    "disk_alpha": min}
#: The figures tracked over the robust set per break point, and which way is worse (the MIMO robust set's too).
WORSE = _WORSE
#: (value, the sample attaining it), per figure, for one break point.
_Tracked = dict[str, tuple[float, dict[str, float]]]
#: (Mks or None, frequency or None) per loop, as :func:`gaintune.verification.noise.noise_peaks` gives.
_Peaks = list[tuple[float | None, float | None]]


@dataclass
class RobustResult:
    """What :func:`robust_check` found: the report section, its worst cases, and how many samples
    could not be analysed (their loop response overflowed: figures not trustworthy)."""

    report: RobustReport
    worst: list[WorstCase]
    n_bad: int


def _sample_analysis(spec: TuningSpec, plant: Plant, cas: Cascade, smp: dict[str, float], t_s: float,
                     sampled: SampledPlant | None, band: float) -> tuple[Analysis, _Peaks]:
    """Analysis and Mks peaks of the frozen gains on one robust sample."""
    params = {k: v for k, v in smp.items() if k != DELAY_KEY}
    lin = plant.linearize(params)
    tau = smp[DELAY_KEY] if DELAY_KEY in smp else lin.delay
    if sampled is not None:
        sp = sample_plant(lin, sampled.dt, sampled.compute_delay, sampled.method == "rk4", tau)
        a = analyse(cas, lin, None, spec.verify.n_freq, sampled=sp)
        return a, noise_peaks(cas, lin, a.omega_range, None, sp)
    a = analyse(cas, lin, DelayModel(tau + t_s, spec.verify.pade_order), spec.verify.n_freq, band)
    return a, noise_peaks(cas, lin, a.omega_range, DelayModel(tau + t_s), None)


def _track(worst: list[_Tracked], mks_worst: list[tuple[float | None, dict[str, float]]], a: Analysis,
           mks: _Peaks, smp: dict[str, float]) -> None:
    """Keep, per break point, each figure's worst value so far and the sample attaining it."""
    for r, (v, _) in enumerate(mks):
        cur_mks = mks_worst[r][0]
        if v is not None and (cur_mks is None or v > cur_mks):
            mks_worst[r] = (v, dict(smp))
    for r, f in enumerate(a.figures):
        for k, worse in _WORSE.items():
            v = getattr(f, k)
            cur = worst[r][k][0]
            if worse(v, cur) != cur and v != cur:
                worst[r][k] = (v, dict(smp))


def public_sample(sample: dict[str, float]) -> dict[str, float]:
    """A sample as reported: the delay under ``"delay"``."""
    return {("delay" if k == DELAY_KEY else k): v for k, v in sample.items()}


_public = public_sample


def _worst_cases(nominal: Analysis, worst: list[_Tracked], mks_worst: list[tuple[float | None, dict[str, float]]],
                 dt: float) -> list[WorstCase]:
    """The worst figures per break point as the report's :class:`WorstCase` list."""
    wc = []
    for r, f in enumerate(nominal.figures):
        w = worst[r]
        where = {k: _public(w[k][1]) for k in _WORSE}
        wc.append(WorstCase(loop=f.loop, break_point=f.break_point, gm_db=w["gm_db"][0], pm_deg=w["pm_deg"][0],
                            delay_margin=w["delay_margin"][0],
                            delay_margin_samples=delay_samples(w["delay_margin"][0], dt),
                            ms=w["ms"][0], mt=w["mt"][0], mks=mks_worst[r][0],
                            disk_alpha=w["disk_alpha"][0], where=where))
    return wc


def robust_check(spec: TuningSpec, plant: Plant, cas: Cascade, t_s: float, nominal: Analysis, nominal_mks: _Peaks,
                 sampled: SampledPlant | None, band: float, dt: float) -> RobustResult:
    """Worst figures of the frozen gains ``cas`` over the robust samples of :func:`robust_samples`.

    Parameters
    ----------
    spec, plant, cas
        The problem, its plant (linearised at every sample) and the one-member cascade of the gains.
    t_s
        Extra delay of the continuous analysis (sampling and computation delay); unused when ``sampled``.
    nominal, nominal_mks
        The nominal analysis and Mks peaks (the starting worst case).
    sampled
        The nominal sampled plant (its dt, computation delay and method are applied to every
        sample); None for the continuous analysis.
    band
        Upper end of the continuous analysis band (:func:`gaintune.verification.analysis.analysis_band`).
    dt
        The analysis sample time (delay margins in samples).
    """
    samples, n_corners, n_mc = robust_samples(spec)
    R = len(nominal.figures)
    worst = [{k: (getattr(nominal.figures[r], k), {"nominal": 1.0}) for k in _WORSE} for r in range(R)]
    n_loops = len(cas.loops)
    mks_worst: list[tuple[float | None, dict[str, float]]] = [
        (nominal_mks[r][0] if r < n_loops else None, {"nominal": 1.0}) for r in range(R)]
    unstable: list[dict[str, float]] = []
    n_bad = 0
    for smp in samples:
        a, mks = _sample_analysis(spec, plant, cas, smp, t_s, sampled, band)
        if not a.stability.stable:
            unstable.append(dict(smp))
        n_bad += bool(a.problems or a.stability.uncertain)
        _track(worst, mks_worst, a, mks, smp)
    wc = _worst_cases(nominal, worst, mks_worst, dt)
    rep = RobustReport(
        n_samples=len(samples), n_corners=n_corners, n_monte_carlo=n_mc, seed=spec.search.seed,
        n_unstable=len(unstable), unstable_samples=[_public(u) for u in unstable[:20]], worst=wc,
    )
    return RobustResult(rep, wc, n_bad)
