"""The MIMO verification of a spec's gains: the loop it describes, its requirements, its graded violation.

A spec needs it when its plant has several inputs or its loops say what they drive
(:func:`gaintune.sim.simulator.needs_mimo`). :func:`spec_loop` turns the spec and one gain set into the
:func:`gaintune.verification.mimo.mimo_report` arguments:

* the plant's :mod:`gaintune.lti.mimo` form, with ``dt/2`` (sample-and-hold, largest scenario dt),
  ``verify.compute_delay`` samples and the actuator's own delay added to every driven input;
* the controller matrix ``K`` (m x p) of the loop graph: a loop's PID law from its measured output to
  its input, a cascade's product of laws along the chain, the decoupler ``W`` in front (the gain set's own
  when its entries are tuned; a reference feedforward is outside the loop and changes no figure here);
* the pairing: per loop its measured output and the plant input its chain ends at.

:func:`spec_requirements` maps the spec's limits to :data:`gaintune.verification.mimo.REQUIREMENTS`
(``requirements.targets`` names a loop, a plant input or output, or a side); :func:`graded` is the
search's violation built from the same lines: 0 exactly when every line passes with
:data:`~gaintune.verification.quick.FEASIBILITY_MARGIN` to spare.
"""

from __future__ import annotations

import threading
from collections import OrderedDict
from dataclasses import dataclass, replace
from typing import Any

import numpy as np

from gaintune.controllers.layout import GainLayout
from gaintune.controllers.pid import pid_params
from gaintune.errors import SpecError
from gaintune.lti.mimo import DelayedSS, MimoLti, TfEntry, TfMatrix
from gaintune.plants.mimo import as_mimo
from gaintune.sim.mimo import architecture
from gaintune.sim.mimo_blocks import with_candidate_W
from gaintune.spec import TuningSpec
from gaintune.verification.analysis import analysis_dt
from gaintune.verification.margins import PEAK_FIGURES, BreakFigures
from gaintune.verification.mimo import REQUIREMENTS, MimoLine, MimoMargins, analysis_grid, judge, mimo_report
from gaintune.verification.mimo_loop import LoopPair, MimoLoop, pid_entry
from gaintune.verification.mimo_margins import loop_at_a_time, multiloop_disk, sigma_peak
from gaintune.verification.mimo_stability import mimo_stability
from gaintune.verification.quick import FEASIBILITY_MARGIN, MAX_TERM, UNSTABLE_VIOLATION

__all__ = ["SpecLoop", "LoopFrame", "loop_frame", "spec_loop", "spec_requirements", "aimed_requirements",
           "spec_margins", "graded", "requirement_needs", "break_peaks", "MIMO_NOT_CHECKED"]

#: Single-loop requirement fields the MIMO verdict does not judge (a note says so when they are set).
MIMO_NOT_CHECKED = ("wc_min", "wc_max", "mks_max")
#: spec requirement field -> MIMO requirement (verification.mimo.REQUIREMENTS)
_FIELDS = {"gm_min_db": "gm_min_db", "pm_min_deg": "pm_min_deg", "dm_min": "dm_min", "ms_max": "ms_max",
           "mt_max": "mt_max", "mimo_ms_max": "mimo_ms_max", "mimo_mt_max": "mimo_mt_max",
           "disk_margin_min": "disk_alpha_min"}
_SIDE = {"all": "all", "inputs": "input", "outputs": "output"}


@dataclass
class SpecLoop:
    """The MIMO loop of one gain set: plant (sampling and actuator delays included), controller, pairing."""

    plant: MimoLti
    controller: TfMatrix
    pairing: list[LoopPair]
    extra_delay: float  # dt/2 + compute delay added at every driven input (s)
    dt: float


def _with_input_delays(lti: MimoLti, extra: np.ndarray) -> MimoLti:
    """``lti`` with ``extra[j]`` seconds more delay on input j."""
    if isinstance(lti, DelayedSS):
        return replace(lti, input_delays=np.asarray(lti.input_delays, float) + extra)
    rows = tuple(tuple(e if e.is_zero else replace(e, delay=e.delay + float(extra[j])) for j, e in enumerate(row))
                 for row in lti.entries)
    return replace(lti, entries=rows)


def _trim(a: np.ndarray) -> np.ndarray:
    """``a`` without leading zeros ([0.] when all are zero), as ``np.poly1d`` keeps coefficients."""
    nz = np.flatnonzero(a)
    return a[nz[0]:] if nz.size else np.zeros(1, dtype=a.dtype)


def _pmul(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """``np.polymul(a, b)`` for arrays, without its poly1d objects (a search builds thousands)."""
    return np.convolve(_trim(a), _trim(b))


def _poly_sum(terms: list[TfEntry]) -> TfEntry:
    """The sum of delay-free entries over the product of their denominators."""
    den = np.array([1.0])
    for t in terms:
        den = _pmul(den, t.den)
    num = np.array([0.0])
    for k, t in enumerate(terms):
        part = t.num
        for m, o in enumerate(terms):
            if m != k:
                part = _pmul(part, o.den)
        num = np.polyadd(num, part)
    return TfEntry(np.trim_zeros(num, "f") if np.any(num) else np.array([0.0]), den)


def _controller(spec: TuningSpec, layout: GainLayout, full: np.ndarray, lti: MimoLti, arch) -> TfMatrix:
    """K (m x p): u = W v, v_k = C_k (v_parent - y_meas(k)); entry (j, i) sums the products of the laws
    along each chain from a loop measuring output i down to a loop feeding input j."""
    arch = with_candidate_W(spec, layout, arch, list(lti.inputs), full)  # W with this gain set's tuned entries
    cols: dict[int, dict[str, float]] = {}
    for k, slot in enumerate(layout.slots):
        cols.setdefault(slot.loop, {})[slot.name] = float(full[k])
    laws = []
    for i in arch.order:
        pp = pid_params(spec.loops[i], cols.get(i, {}))
        laws.append(pid_entry(float(pp.Kp), float(pp.Ki), float(pp.Kd), float(pp.Tf)))
    p, m = lti.shape
    terms: dict[tuple[int, int], list[TfEntry]] = {}
    for k in range(len(arch.order)):  # every chain a -> ... -> k, a an ancestor of k or k itself
        a, prod = k, laws[k]
        while True:
            for j in np.flatnonzero(arch.W[:, k]):
                w = float(arch.W[j, k])
                terms.setdefault((int(j), int(arch.meas[a])), []).append(TfEntry(prod.num * w, prod.den))
            if arch.parent[a] < 0:
                break
            a = int(arch.parent[a])
            prod = TfEntry(_pmul(prod.num, laws[a].num), _pmul(prod.den, laws[a].den))
    zero = TfEntry(np.array([0.0]), np.array([1.0]))
    rows = [[_poly_sum(terms[(j, i)]) if (j, i) in terms else zero for i in range(p)] for j in range(m)]
    return TfMatrix(tuple(tuple(r) for r in rows), inputs=lti.outputs, outputs=lti.inputs)


def _chain_input(arch, k: int, parent_of: dict[int, list[int]]) -> int:
    """The plant input loop position ``k``'s chain ends at (its first driving descendant)."""
    todo = [k]
    while todo:
        q = todo.pop(0)
        if arch.drives[q] >= 0:
            return int(arch.drives[q])
        todo += parent_of.get(q, [])
    raise SpecError("loops", f"loop {k} drives no plant input through its chain")


@dataclass(frozen=True)
class LoopFrame:
    """The plant side of :func:`spec_loop`, the same for every gain set of one (spec, plant): built
    once (:func:`loop_frame`), so every loop shares one plant object and its plant-only work
    (:mod:`gaintune.verification.mimo_plant`)."""

    spec: TuningSpec
    source: Any  # the plant it was built from
    arch: Any  # gaintune.sim.mimo.architecture
    lti: MimoLti  # the plant's MIMO form, without the added delays
    plant: MimoLti  # with the sampling, compute and actuator delays on the driven inputs
    pairing: list[LoopPair]
    extra_delay: float
    dt: float


_FRAMES: OrderedDict[tuple[int, int], LoopFrame] = OrderedDict()
_FRAMES_LOCK = threading.Lock()


def loop_frame(spec: TuningSpec, plant: Any, cache: bool = True) -> LoopFrame:
    """The :class:`LoopFrame` of ``spec`` on ``plant`` (the same object for the same spec and plant objects;
    ``cache=False``: built afresh and not kept, for a plant object used once, e.g. a robust draw)."""
    if not cache:
        return _build_frame(spec, plant)
    key = (id(spec), id(plant))
    with _FRAMES_LOCK:
        hit = _FRAMES.get(key)
        if hit is not None and hit.spec is spec and hit.source is plant:
            _FRAMES.move_to_end(key)
            return hit
    frame = _build_frame(spec, plant)
    with _FRAMES_LOCK:
        _FRAMES[key] = frame
        while len(_FRAMES) > 8:
            _FRAMES.popitem(last=False)
    return frame


def _build_frame(spec: TuningSpec, plant: Any) -> LoopFrame:
    mp = as_mimo(plant)
    arch = architecture(spec, mp)
    lti = mp.lti()
    dt = analysis_dt(spec)
    extra = 0.5 * dt + spec.verify.compute_delay * dt
    delays = np.zeros(lti.shape[1])
    driven = sorted({int(j) for j in np.flatnonzero(np.any(arch.W != 0, axis=1))})
    for j in driven:
        act = spec.actuators.get(lti.inputs[j]) if spec.actuators else None
        delays[j] = extra + (act.delay if act is not None else 0.0)
    children: dict[int, list[int]] = {}
    for k, par in enumerate(arch.parent):
        if par >= 0:
            children.setdefault(int(par), []).append(k)
    pairing = [LoopPair(spec.loop_names[i], int(arch.meas[k]), _chain_input(arch, k, children))
               for k, i in enumerate(arch.order)]
    return LoopFrame(spec, plant, arch, lti, _with_input_delays(lti, delays), pairing, extra, dt)


def spec_loop(spec: TuningSpec, plant: Any, layout: GainLayout, full: np.ndarray,
              frame: LoopFrame | None = None) -> SpecLoop:
    """The MIMO loop ``spec`` describes with the gains ``full`` (one vector, layout order);
    ``frame``: its :func:`loop_frame` (looked up when None)."""
    fr = frame if frame is not None else loop_frame(spec, plant)
    return SpecLoop(fr.plant, _controller(spec, layout, full, fr.lti, fr.arch), list(fr.pairing), fr.extra_delay,
                    fr.dt)


def spec_requirements(spec: TuningSpec) -> dict[str, float | dict[str, float]]:
    """The spec's limits in :func:`gaintune.verification.mimo.judge` form: each set field applies to
    ``all`` (``disk_margin_min`` to ``disk_margin_at``), and ``requirements.targets`` adds per-target limits."""
    req = spec.requirements
    out: dict[str, Any] = {}
    for fld, name in _FIELDS.items():
        v = getattr(req, fld)
        if v is not None:
            target = _SIDE[req.disk_margin_at] if fld == "disk_margin_min" else "all"
            out[name] = {target: float(v)}
    for fld, per in (getattr(req, "targets", None) or {}).items():
        out.setdefault(_FIELDS[fld], {}).update({str(t): float(v) for t, v in per.items()})
    return out


#: MIMO requirement -> the requirements field whose back-off it takes (the disk margin: the peaks', upwards)
_AIM_AS = {"gm_min_db": "gm_min_db", "pm_min_deg": "pm_min_deg", "dm_min": "dm_min", "ms_max": "ms_max",
           "mt_max": "mt_max", "mimo_ms_max": "ms_max", "mimo_mt_max": "mt_max"}


def aimed_requirements(spec: TuningSpec) -> dict[str, float | dict[str, float]]:
    """:func:`spec_requirements` with every limit moved to the search's aim (``requirements.backoff``);
    the multiloop disk margin aims ``peaks`` higher (relative), as a peak aims lower."""
    b = spec.requirements.backoff
    out: dict[str, Any] = {}
    for name, per in spec_requirements(spec).items():
        assert isinstance(per, dict)
        if name == "disk_alpha_min":
            out[name] = {t: v * (1.0 + b.peaks) if b.active else v for t, v in per.items()}
        else:
            out[name] = {t: b.aim(_AIM_AS[name], v) for t, v in per.items()}
    return out


def lean_report(sl: SpecLoop, needs: set[str], pade_order: int | None = None) -> MimoMargins:
    """:func:`gaintune.verification.mimo.mimo_report` computing only the figures ``needs`` names
    (``break``: loop-at-a-time; ``ms``, ``mt``; ``disk``), with the same functions on the same grid,
    so a figure it computes equals the full report's; the others are placeholders no requirement
    reads. An unstable loop stops after the stability check (its margins mean nothing)."""
    loop = MimoLoop.build(sl.plant, sl.controller, sl.pairing)
    stab = mimo_stability(loop, pade_order)
    rep = MimoMargins.unmeasured(loop.names, stab)
    if not stab.stable:
        return rep
    grid = analysis_grid(loop)
    g0 = np.concatenate([[0.0], grid])
    rep.grid_points, rep.band = int(grid.size), (float(grid[0]), float(grid[-1]))
    sides = {"input": np.eye(loop.n_in), "output": np.eye(loop.n_out)}
    for side, eye in sides.items():
        if not needs & {"ms", "mt", "disk"}:
            break

        def S_at(ww: np.ndarray, side: str = side) -> np.ndarray:
            return loop.sensitivity(1j * ww, side)

        S = S_at(g0)
        if "ms" in needs:
            setattr(rep, f"ms_{side}", sigma_peak(S_at, g0, S))
        if "mt" in needs:
            def T_at(ww: np.ndarray, e: np.ndarray = eye, f: Any = S_at) -> np.ndarray:
                return e - f(ww)

            setattr(rep, f"mt_{side}", sigma_peak(T_at, g0, eye - S))
        if "disk" in needs:  # a diagonal K: one side serves both, as in mimo_report
            same = side == "output" and loop.diagonal_controller()
            setattr(rep, f"disk_{side}", replace(rep.disk_input) if same else multiloop_disk(S_at, g0, S, 0.0))
    if "break" in needs:
        breaks: list[BreakFigures] = loop_at_a_time(loop, grid, peaks=break_peaks(needs))
        rep.input_breaks, rep.output_breaks = breaks[: loop.n_in], breaks[loop.n_in:]
        rep.inputs = [sl.plant.inputs[j] for j in loop.loop_ins]
        rep.outputs = [sl.plant.outputs[i] for i in loop.loop_outs]
        rep.break_inputs = [sl.plant.inputs[j] for j in loop.ins]
    return rep


#: a break point's figure -> the peak it reads (the others are read from crossings)
_BREAK_PEAK = {"ms": "ms", "mt": "mt", "disk_gm_db": "disk"}


def requirement_needs(requirements: dict[str, Any]) -> set[str]:
    """What :func:`lean_report` must compute for these requirements: ``break`` (loop-at-a-time, with
    ``break_ms``, ``break_mt``, ``break_disk`` for the break peaks it reads), ``ms``, ``mt``, ``disk``."""
    out = set()
    for name in requirements:
        figure, _, scope = REQUIREMENTS[name]
        out.add("break" if scope == "break" else figure if figure in ("ms", "mt") else "disk")
        if scope == "break" and figure in _BREAK_PEAK:
            out.add(f"break_{_BREAK_PEAK[figure]}")
    return out


def break_peaks(needs: set[str] | None) -> tuple[str, ...]:
    """The break-point peaks to zoom in on: every one for a full report (``needs`` None), else those
    :func:`requirement_needs` named (the others keep their grid maximum, which no requirement reads)."""
    return PEAK_FIGURES if needs is None else tuple(f for f in PEAK_FIGURES if f"break_{f}" in needs)


def spec_margins(spec: TuningSpec, plant: Any, layout: GainLayout, full: np.ndarray,
                 w: np.ndarray | None = None, aimed: bool = False, frame: LoopFrame | None = None
                 ) -> tuple[SpecLoop, MimoMargins, list[MimoLine]]:
    """The MIMO report and the requirement lines of one gain set (``aimed``: at the search's aim;
    ``frame``: the :func:`loop_frame` of ``spec`` and ``plant``, looked up when None).

    Raises
    ------
    SpecError
        For a requirement target that is not a loop, plant input, output or side.
    """
    sl = spec_loop(spec, plant, layout, full, frame)
    reqs = aimed_requirements(spec) if aimed else spec_requirements(spec)
    if aimed:  # the search's constraint: only the figures its requirements read
        rep = lean_report(sl, requirement_needs(reqs), spec.verify.pade_order)
    else:
        rep = mimo_report(sl.plant, sl.controller, sl.pairing, w=w, pade_order=spec.verify.pade_order)
    if aimed and not rep.stability.stable:
        return sl, rep, []  # graded() scores the instability; the lean report has no figures to judge
    try:
        lines = judge(rep, reqs)
    except ValueError as exc:
        raise SpecError("requirements.targets", str(exc)) from None
    return sl, rep, lines


def graded(rep: MimoMargins, lines: list[MimoLine]) -> tuple[float, float]:
    """(violation, shortfall) of one gain set, as :func:`gaintune.verification.quick.requirement_scores`
    grades the single-loop case: the sum of the relative shortfalls (each at least FEASIBILITY_MARGIN
    inside its limit, capped at MAX_TERM), and the largest one; an unstable loop scores
    UNSTABLE_VIOLATION + log1p(max Re pole), graded towards stability."""
    if not rep.stability.stable:
        grade = float(np.log1p(min(max(rep.stability.max_real_pole, 0.0), 1e300)))
        v = UNSTABLE_VIOLATION + min(grade if np.isfinite(grade) else 100.0, 100.0)
        return v, v
    out, short = 0.0, -np.inf
    for q in lines:
        t = -q.margin / max(abs(q.limit), 1e-9)
        t = MAX_TERM if not np.isfinite(t) and t > 0 or np.isnan(t) else t
        t = min(t + FEASIBILITY_MARGIN, MAX_TERM)
        out += max(t, 0.0)
        short = max(short, t)
    return out, (short if lines else -1.0)
