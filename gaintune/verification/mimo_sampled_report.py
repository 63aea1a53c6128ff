"""The MIMO report of the exact sampled loop (:mod:`.mimo_sampled`) and its requirement lines.

:func:`sampled_margins` is :func:`gaintune.verification.mimo_spec.spec_margins` for the loop the
MIMO simulator and the exports run at the analysis dt (the largest scenario dt): the same spec
loop (:func:`~gaintune.verification.mimo_spec.spec_loop`: controller, cascades, decoupler,
pairing), the plant and the controller sampled exactly, the figures of :mod:`.mimo_margins` on
``z = e^{j w dt}`` for ``0 < w <= pi/dt`` and stability from the discrete closed-loop eigenvalues.
"""

from __future__ import annotations

import math
from dataclasses import replace
from typing import Any

import numpy as np

from gaintune.cache import LRU
from gaintune.controllers.layout import GainLayout
from gaintune.errors import SpecError
from gaintune.plants.mimo import as_mimo
from gaintune.spec import TuningSpec
from gaintune.verification.mimo import MimoLine, MimoMargins, judge
from gaintune.verification.mimo_loop import MimoLoop, char_freqs
from gaintune.verification.mimo_margins import lat_rows, loop_at_a_time, multiloop_disk, sigma_peak
from gaintune.verification.mimo_sampled import SampledCore, SampledLoop, sampled_core, sampled_stability_mimo
from gaintune.verification.mimo_spec import (
    LoopFrame,
    SpecLoop,
    aimed_requirements,
    break_peaks,
    requirement_needs,
    spec_loop,
    spec_requirements,
)
from gaintune.verification.mimo_stability import MimoStability

__all__ = ["sampled_grid", "sampled_loop", "sampled_report", "sampled_margins"]

#: The sampled plant of each (plant form, channels, dt, delays): the plant form is kept with it, so an
#: id reused by another object never matches.
_CORES: LRU[tuple, tuple[Any, SampledCore]] = LRU(32)

#: Log-grid points per decade (at least; 200/n for n loops), as the continuous analysis grid.
_PER_DECADE = 40
#: Most points of the uniform grid that follows the delays' phase spin.
_SPIN_MAX = 20000



def _unchecked() -> MimoStability:
    """The stability of a loop whose check skipped it (:func:`sampled_report` with ``stability=False``): a fresh
    object each time, so no report shares its notes list."""
    return MimoStability(True, "unchecked", 0, None, True, np.zeros(0, dtype=complex), 0, -math.inf,
                         notes=["closed-loop stability not checked (a root find's trial point)"])

def sampled_grid(base: MimoLoop, loop: SampledLoop) -> np.ndarray:
    """Frequencies (rad/s) up to the Nyquist frequency pi/dt (included): a log grid from 1/100 of the
    slowest characteristic frequency of the continuous loop (at most Nyquist/1e4), and a uniform grid
    fine enough for the phase spin of the sampled delays; none on a pole of the unit circle."""
    nyq = math.pi / loop.dt
    lo = min(float(char_freqs(base).min()) / 100.0, nyq * 1e-4)
    per_decade = max(_PER_DECADE, 200 // max(loop.n_in, loop.n_out))
    w = np.logspace(math.log10(lo), math.log10(nyq), int(per_decade * math.log10(nyq / lo)) + 1)
    T = 2.0 * loop.max_delay()
    n = min(int(nyq * T / 0.5) + 2, _SPIN_MAX)
    w = np.unique(np.concatenate([w, np.linspace(lo, nyq, n), [nyq]]))
    assert loop.core is not None
    ev = np.linalg.eigvals(loop.core.Ad) if loop.core.Ad.size else np.zeros(0, dtype=complex)
    on = np.abs(np.angle(ev[np.abs(np.abs(ev) - 1.0) <= 1e-9])) / loop.dt
    if on.size:  # the loop gain is infinite there
        w = w[np.all(np.abs(w[:, None] - on[None, :]) > 1e-9 * np.maximum(on[None, :], 1e-300), axis=1)]
    return w


def sampled_loop(spec: TuningSpec, plant: Any, sl: SpecLoop) -> tuple[MimoLoop, SampledLoop]:
    """(continuous loop without sampling delays, sampled loop) of the spec loop ``sl`` at ``sl.dt``."""
    lti = as_mimo(plant).lti()
    base = MimoLoop.build(lti, sl.controller, sl.pairing)
    acts = spec.actuators or {}
    act = np.array([float(getattr(acts.get(name), "delay", 0.0) or 0.0) for name in lti.inputs])
    key = (id(lti), tuple(base.ins), tuple(base.outs), float(sl.dt), act.tobytes(), int(spec.verify.compute_delay))

    def build() -> tuple[Any, SampledCore]:
        return lti, sampled_core(lti, base.ins, base.outs, sl.dt, act, spec.verify.compute_delay)

    # plant-only work: once per plant, not once per candidate (nor once per thread checking a batch's rows)
    hit = _CORES.get_or_build(key, build)
    if hit[0] is not lti:  # the id of a plant form since freed: not this plant
        hit = build()
        _CORES.put(key, hit)
    return base, SampledLoop.of(base, hit[1])


def sampled_report(base: MimoLoop, loop: SampledLoop, sigma: float = 0.0,
                   needs: set[str] | None = None, stability: bool = True) -> MimoMargins:
    """:func:`gaintune.verification.mimo.mimo_report` of the sampled loop: the same figures by the
    same functions, on :func:`sampled_grid`, with the discrete closed-loop stability.

    ``needs`` (the search's check, as :func:`~gaintune.verification.mimo_spec.lean_report`): compute
    only the figures it names (``break``, ``ms``, ``mt``, ``disk``), each equal to the full report's;
    the others are placeholders no requirement reads, and an unstable loop stops after its stability.
    ``stability=False`` (a root find's trial points, whose answer is checked in full afterwards) skips the
    closed-loop eigenvalues, over half of a 110-gain check, and reports the loop as stable, unchecked."""
    # the search's check (lean) may call a clearly diverging loop unstable without its eigenvalues
    stab = sampled_stability_mimo(loop, base, screen=needs is not None) if stability else _unchecked()
    P = loop.plant
    rep = MimoMargins.unmeasured(loop.names, stab, sigma, inputs=[P.inputs[j] for j in loop.loop_ins],
                                 outputs=[P.outputs[i] for i in loop.loop_outs], notes=list(stab.notes),
                                 break_inputs=[P.inputs[j] for j in loop.ins])
    lean = needs is not None
    if lean and not stab.stable:
        return rep
    want = needs if needs is not None else {"break", "ms", "mt", "disk"}
    grid = sampled_grid(base, loop)
    rep.band, rep.grid_points = (float(grid[0]), float(grid[-1])), int(grid.size)
    Si = loop.sensitivity(1j * grid, "input")
    # a cascade's output rows come from the input side (lat_rows): the larger output-side inverse only for peaks
    peaks = bool(want & {"ms", "mt", "disk"})
    So = loop.sensitivity(1j * grid, "output") if peaks or not loop.outputs_by_inputs() else None
    if "break" in want:
        breaks = loop_at_a_time(loop, grid, lat_rows(loop, 1j * grid, True, (Si, So)), break_peaks(needs))
        rep.input_breaks, rep.output_breaks = breaks[: loop.n_in], breaks[loop.n_in:]
    _sampled_peaks_and_disks(rep, loop, grid, Si, So, want, sigma)
    return rep


def _sampled_peaks_and_disks(rep: MimoMargins, loop: SampledLoop, grid: np.ndarray, Si: np.ndarray,
                             So: np.ndarray | None, want: set[str], sigma: float) -> None:
    """The sigma peaks of S and T and the multiloop disk margins ``want`` names, into ``rep`` (``So`` is
    there when ``want`` names any)."""
    if not want & {"ms", "mt", "disk"}:
        return
    assert So is not None
    nyq = math.pi / loop.dt
    eye_i, eye_o = np.eye(loop.n_in), np.eye(loop.n_out)

    def S_in(ww: np.ndarray) -> np.ndarray:
        return loop.sensitivity(1j * np.minimum(ww, nyq), "input")

    def S_out(ww: np.ndarray) -> np.ndarray:
        return loop.sensitivity(1j * np.minimum(ww, nyq), "output")

    g0 = np.concatenate([[0.0], grid])
    Si0, So0 = np.concatenate([S_in(np.zeros(1)), Si]), np.concatenate([S_out(np.zeros(1)), So])
    if "disk" in want:
        if rep.stability.stable:
            rep.disk_input = multiloop_disk(S_in, g0, Si0, sigma)
            rep.disk_output = replace(rep.disk_input) if loop.diagonal_controller() else \
                multiloop_disk(S_out, g0, So0, sigma)
        else:
            rep.notes.append("the closed loop is unstable: multiloop disk margins are 0")
    if "ms" in want:
        rep.ms_input, rep.ms_output = sigma_peak(S_in, g0, Si0), sigma_peak(S_out, g0, So0)
    if "mt" in want:
        rep.mt_input = sigma_peak(lambda ww: eye_i - S_in(ww), g0, eye_i - Si0)
        rep.mt_output = sigma_peak(lambda ww: eye_o - S_out(ww), g0, eye_o - So0)


def sampled_margins(spec: TuningSpec, plant: Any, layout: GainLayout, full: np.ndarray, aimed: bool = False,
                    frame: LoopFrame | None = None, stability: bool = True
                    ) -> tuple[SpecLoop, MimoMargins, list[MimoLine]]:
    """The sampled loop's MIMO report and requirement lines of one gain set (as
    :func:`~gaintune.verification.mimo_spec.spec_margins` gives the continuous ones; ``aimed``: the
    search's check, at the search's aim and with only the figures its requirements read; ``stability``:
    False skips the closed-loop stability, see :func:`sampled_report`).

    Raises
    ------
    SpecError
        For a requirement target that is not a loop, plant input, output or side.
    """
    sl = spec_loop(spec, plant, layout, full, frame)
    base, loop = sampled_loop(spec, plant, sl)
    reqs = aimed_requirements(spec) if aimed else spec_requirements(spec)
    rep = sampled_report(base, loop, needs=requirement_needs(reqs) if aimed else None, stability=stability)
    if aimed and not rep.stability.stable:
        return sl, rep, []  # graded() scores the instability; the lean report has no figures to judge
    if as_mimo(plant).nonlinear:  # the simulator steps the ODE itself by RK4, actuator delays in whole samples
        rep.notes.append("nonlinear plant: the sampled loop uses its linearisation, ZOH-sampled with exact delays")
    try:
        lines = judge(rep, reqs)
    except ValueError as exc:
        raise SpecError("requirements.targets", str(exc)) from None
    return sl, rep, lines
