"""MIMO verification: one entry point, :func:`mimo_report`, and the requirement check :func:`judge`.

``mimo_report(plant, controller, pairing)`` analyses the negative-feedback loop ``u = K (r - y)``
(:mod:`.mimo_loop`): closed-loop stability by Padé eigenvalues and the generalised Nyquist count
(:mod:`.mimo_stability`), loop-at-a-time margins at every plant input and output, multiloop disk
margins at the plant inputs and outputs, and the MIMO Ms and Mt (:mod:`.mimo_margins`).

Requirements name a loop, a plant input, a plant output, a side (``input``/``output``) or ``all``
(see :data:`REQUIREMENTS`).
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np

from gaintune.lti.mimo import MimoLti
from gaintune.verification.margins import MAG_FLOOR, BreakFigures, judged_pm
from gaintune.verification.mimo_loop import LoopPair, MimoLoop, char_freqs
from gaintune.verification.mimo_margins import MultiloopDisk, Peak, lat_rows, loop_at_a_time, multiloop_disk, sigma_peak
from gaintune.verification.mimo_plant import plant_eigvals
from gaintune.verification.mimo_stability import MimoStability, mimo_stability

__all__ = ["MimoMargins", "MimoLine", "REQUIREMENTS", "mimo_report", "analysis_grid", "judge"]

#: Log-grid points per decade: 200/n (n loops), at least 40: each point costs an n x n inverse.
_PER_DECADE = 40
#: Phase crossings are resolved (the grid follows the delays' phase spin) while some loop-at-a-time
#: |L| is above this level (a crossing below it has GM > 26 dB and binds no practical requirement).
_SPIN_LEVEL = 0.05
#: Most points of the delay-spin grid.
_SPIN_MAX = 20000


@dataclass
class MimoMargins:
    """Everything :func:`mimo_report` computes; break figures are those of the SISO analysis."""

    loops: list[str]
    inputs: list[str]  # plant input each loop names (loops of one cascade share it)
    outputs: list[str]  # plant output each loop measures
    stability: MimoStability
    input_breaks: list[BreakFigures]  # one per driven input (``break_inputs``), the others closed
    output_breaks: list[BreakFigures]  # loop k broken at its measured output
    ms_input: Peak  # peak sigma_max(S_i)
    mt_input: Peak
    ms_output: Peak  # peak sigma_max(S_o)
    mt_output: Peak
    disk_input: MultiloopDisk  # all plant inputs perturbed at once
    disk_output: MultiloopDisk
    band: tuple[float, float]
    grid_points: int
    notes: list[str] = field(default_factory=list)
    break_inputs: list[str] = field(default_factory=list)  # the input of each input break

    @classmethod
    def unmeasured(cls, loops: list[str], stability: MimoStability, sigma: float = 0.0, **names: Any) -> MimoMargins:
        """A report with only ``stability`` (and the ``names`` fields: inputs, outputs, break_inputs,
        notes) filled: the placeholders a lean check leaves for the figures no requirement reads."""
        none, disk0 = Peak(1.0, None), MultiloopDisk(0.0, 0.0, None, 1.0, 1.0, 0.0, 0.0, sigma)
        base: dict[str, Any] = dict(inputs=[], outputs=[], input_breaks=[], output_breaks=[], ms_input=none,
                                    mt_input=none, ms_output=none, mt_output=none, disk_input=disk0,
                                    disk_output=replace(disk0), band=(0.0, 0.0), grid_points=0)
        return cls(loops=loops, stability=stability, **{**base, **names})

    @property
    def ms(self) -> float:
        """MIMO Ms: the larger of the input- and output-side peaks."""
        return max(self.ms_input.value, self.ms_output.value)

    @property
    def mt(self) -> float:
        """MIMO Mt: the larger of the input- and output-side peaks."""
        return max(self.mt_input.value, self.mt_output.value)

    @property
    def disk_alpha(self) -> float:
        """The smaller multiloop disk margin of the two sides."""
        return min(self.disk_input.alpha, self.disk_output.alpha)


def analysis_grid(loop: MimoLoop) -> np.ndarray:
    """Frequencies (rad/s): a log grid from 1/100 of the slowest characteristic frequency to 100x the
    fastest (raised x10, up to 3 times, until every loop-at-a-time |L| < 1e-4 at its end), and a
    uniform grid fine enough for the delays' phase spin while some |L| > :data:`_SPIN_LEVEL`."""
    cf = char_freqs(loop)
    lo, hi = float(cf.min()) / 100.0, float(cf.max()) * 100.0
    for _ in range(3):
        with np.errstate(all="ignore"):
            top = np.nanmax(np.abs(lat_rows(loop, np.array([1j * hi]), not loop.diagonal_controller())))
        if not top > MAG_FLOOR:
            break
        hi *= 10.0
    per_decade = max(_PER_DECADE, 200 // max(loop.n_in, loop.n_out))
    w = np.logspace(math.log10(lo), math.log10(hi), int(per_decade * math.log10(hi / lo)) + 1)
    T = 2.0 * loop.max_delay()
    if T > 0:
        with np.errstate(all="ignore"):
            big = np.nanmax(np.abs(lat_rows(loop, 1j * w, not loop.diagonal_controller())), axis=0) > _SPIN_LEVEL
        w_spin = float(w[np.nonzero(big)[0][-1]]) if big.any() else 0.0
        n = min(int(w_spin * T / 0.5) + 2, _SPIN_MAX)
        w = np.unique(np.concatenate([w, np.linspace(lo, w_spin, n)])) if w_spin > lo else w
    # not on an open-loop pole of the imaginary axis (L is infinite there: a NaN would poison the peaks)
    poles = np.concatenate([plant_eigvals(A) for A in (r[0] for r in loop.realisations(0)) if A.size]
                           or [np.zeros(0, dtype=complex)])
    axis = np.abs(poles.imag[np.abs(poles.real) <= 1e-12 * np.maximum(1.0, np.abs(poles))])
    if axis.size:
        w = w[np.all(np.abs(w[:, None] - axis[None, :]) > 1e-9 * np.maximum(axis[None, :], 1e-300), axis=1)]
    return w


def _user_grid(w: np.ndarray) -> np.ndarray:
    """A given grid: its finite positive frequencies, sorted (w = 0 is added where it matters)."""
    g = np.unique(np.asarray(w, dtype=float).ravel())
    g = g[np.isfinite(g) & (g > 0)]
    if g.size < 2:
        raise ValueError("w: give at least two finite positive frequencies (rad/s), or None for the default grid")
    return g


def mimo_report(plant: MimoLti, controller: MimoLti, pairing: Sequence[LoopPair], w: np.ndarray | None = None,
                sigma: float = 0.0, pade_order: int | None = None) -> MimoMargins:
    """Verify the MIMO loop ``u = K (r - y)``.

    Parameters
    ----------
    plant
        The plant (:class:`~gaintune.lti.mimo.TfMatrix` or :class:`~gaintune.lti.mimo.DelayedSS`).
    controller
        The controller, m x p (plant outputs in, plant inputs out), e.g.
        :func:`~gaintune.verification.mimo_loop.decentralised_pid`.
    pairing
        Per loop its name, measured output and driven input (``LoopPair`` or ``PidLoop``).
    w
        Analysis frequencies (rad/s); default :func:`analysis_grid`.
    sigma
        Skew of the multiloop disk margins (0: balanced, as MATLAB's default).
    pade_order
        Padé order of the eigenvalue check (default 6).
    """
    loop = MimoLoop.build(plant, controller, pairing)
    stab = mimo_stability(loop, pade_order)
    grid = analysis_grid(loop) if w is None else _user_grid(w)
    s = 1j * grid
    Si, So = loop.sensitivities(s)
    eye_i, eye_o = np.eye(loop.n_in), np.eye(loop.n_out)

    def S_in(ww: np.ndarray) -> np.ndarray:
        return loop.sensitivity(1j * ww, "input")

    def S_out(ww: np.ndarray) -> np.ndarray:
        return loop.sensitivity(1j * ww, "output")

    L = lat_rows(loop, s, True, (Si, So))  # as the lean check takes them
    breaks = loop_at_a_time(loop, grid, L)
    notes = list(stab.notes)
    # w = 0 too: a static loop's disk margin can peak there (the satellite example)
    g0 = np.concatenate([[0.0], grid])
    Si0, So0 = np.concatenate([S_in(np.zeros(1)), Si]), np.concatenate([S_out(np.zeros(1)), So])
    disks = [multiloop_disk(S_in, g0, Si0, sigma)]
    # a diagonal K makes S_i = K^-1 S_o K, a diagonal similarity that leaves mu unchanged: one side serves both
    disks.append(replace(disks[0]) if loop.diagonal_controller() else multiloop_disk(S_out, g0, So0, sigma))
    if not stab.stable:
        disks = [MultiloopDisk(0.0, 0.0, None, 1.0, 1.0, 0.0, 0.0, sigma) for _ in disks]
        notes.append("the closed loop is unstable: multiloop disk margins are 0")
    peaks = [sigma_peak(fn, g0, X) for fn, X in (
        (S_in, Si0), (lambda ww: eye_i - S_in(ww), eye_i - Si0), (S_out, So0),
        (lambda ww: eye_o - S_out(ww), eye_o - So0))]
    return MimoMargins(loop.names, [plant.inputs[j] for j in loop.loop_ins], [plant.outputs[i] for i in loop.loop_outs],
                       stab, breaks[: loop.n_in], breaks[loop.n_in:], peaks[0], peaks[1], peaks[2], peaks[3],
                       disks[0], disks[1], (float(grid[0]), float(grid[-1])), int(grid.size), notes,
                       [plant.inputs[j] for j in loop.ins])


# ------------------------------------------------------------------ requirements


#: requirement -> (figure, kind, scope): kind "min" (value >= limit) or "max"; scope "side" (targets
#: ``all``, ``input``, ``output``) or "break" (targets ``all``, a loop, a plant input or output).
REQUIREMENTS: dict[str, tuple[str, str, str]] = {
    "mimo_ms_max": ("ms", "max", "side"),
    "mimo_mt_max": ("mt", "max", "side"),
    "disk_alpha_min": ("alpha", "min", "side"),
    "disk_gm_min_db": ("gm_db", "min", "side"),
    "disk_pm_min_deg": ("pm_deg", "min", "side"),
    "gm_min_db": ("gm_db", "min", "break"),
    "pm_min_deg": ("pm_deg", "min", "break"),
    "dm_min": ("delay_margin", "min", "break"),
    "ms_max": ("ms", "max", "break"),
    "mt_max": ("mt", "max", "break"),
    "loop_disk_gm_min_db": ("disk_gm_db", "min", "break"),
}


@dataclass
class MimoLine:
    """One requirement at its binding place."""

    requirement: str
    target: str
    limit: float
    value: float
    margin: float
    passed: bool
    where: str  # "input"/"output" side, or "loop/break point"


def _side_values(rep: MimoMargins, figure: str, target: str) -> list[tuple[float, str]]:
    sides = {"input": (rep.ms_input, rep.mt_input, rep.disk_input),
             "output": (rep.ms_output, rep.mt_output, rep.disk_output)}
    if target not in ("all", "input", "output"):
        raise ValueError(f"requirement target {target!r}: a MIMO-wide figure takes 'all', 'input' or 'output'")
    out = []
    for side in (("input", "output") if target == "all" else (target,)):
        ms, mt, disk = sides[side]
        v = {"ms": ms.value, "mt": mt.value}.get(figure)
        out.append((float(getattr(disk, figure)) if v is None else v, side))
    return out


def _break_values(rep: MimoMargins, figure: str, target: str) -> list[tuple[float, str]]:
    picked: list[BreakFigures] = []
    for k, name in enumerate(rep.loops):
        if target in ("all", name, rep.outputs[k]):
            picked.append(rep.output_breaks[k])
    for k, chan in enumerate(rep.break_inputs):
        users = [nm for nm, inp in zip(rep.loops, rep.inputs, strict=True) if inp == chan]
        if target in ("all", chan) or target in users:
            picked.append(rep.input_breaks[k])
    if not picked:
        raise ValueError(f"requirement target {target!r} is not a loop, plant input or output of the pairing; "
                         f"choose 'all' or one of {rep.loops + rep.break_inputs + rep.outputs}")
    order = {id(f): i for i, f in enumerate(rep.input_breaks + rep.output_breaks)}
    picked.sort(key=lambda f: order[id(f)])  # inputs first, as the report lists them
    read = (lambda f: judged_pm(f.pm_deg)) if figure == "pm_deg" else (lambda f: getattr(f, figure))
    return [(float(read(f)), f"{f.loop}/{f.break_point}") for f in picked]


def judge(rep: MimoMargins, requirements: Mapping[str, float | Mapping[str, float]]) -> list[MimoLine]:
    """Check requirements, e.g. ``{"mimo_ms_max": 2.1, "gm_min_db": {"all": 6, "top": 8}}``: a number
    applies to ``all``; a mapping gives a limit per target. One line per (requirement, target), at
    its binding place; on an unstable closed loop every line fails."""
    lines = []
    for req, spec in requirements.items():
        if req not in REQUIREMENTS:
            raise ValueError(f"requirement {req!r} is unknown; choose one of {sorted(REQUIREMENTS)}")
        figure, kind, scope = REQUIREMENTS[req]
        for target, limit in (spec.items() if isinstance(spec, Mapping) else [("all", spec)]):
            if not isinstance(limit, int | float) or not math.isfinite(limit):
                raise ValueError(f"requirement {req}[{target}]: limit {limit!r} must be a finite number")
            vals = (_side_values if scope == "side" else _break_values)(rep, figure, str(target))
            margins = [((v - limit) if kind == "min" else (limit - v), v, where) for v, where in vals]
            m, v, where = min(margins, key=lambda t: -math.inf if math.isnan(t[0]) else t[0])
            ok = bool(m >= 0) and rep.stability.stable
            lines.append(MimoLine(req, str(target), float(limit), v, float(m), ok, where))
    return lines
