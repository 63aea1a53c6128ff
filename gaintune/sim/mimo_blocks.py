"""The static blocks of a MIMO architecture per candidate: the decoupler ``W`` and the feedforward ``F``.

Per step the kernel applies ``u = sat(W v + F r)``: ``v`` the loops' outputs, ``r`` the references
(nonzero columns of ``F`` only at the chains' outer loops, whose setpoint is the reference). ``W``
(m x L, loops in evaluation order) is the identity wiring or the decoupler
(:func:`gaintune.sim.mimo.architecture`); tuned decoupler entries and feedforward gains are slots of
the :class:`~gaintune.controllers.layout.GainLayout`, so each candidate's full gain vector gives its own
``W`` and ``F``. Without tuned entries ``W`` is one matrix for the whole batch (``(1, m, L)``), as before.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from gaintune.controllers.layout import GainLayout
from gaintune.errors import SpecError
from gaintune.spec import TuningSpec
from gaintune.spec.blocks import DECOUPLER, FEEDFORWARD, decoupler_gain_name, entry_value, feedforward_gain_name

__all__ = ["BlockMatrices", "check_block_inputs", "with_candidate_W"]


def check_block_inputs(spec: TuningSpec, inputs: list[str]) -> None:
    """SpecError naming the decoupler or feedforward field whose input the plant does not have (a model's
    inputs are known only once it is built)."""
    for k, name in enumerate(spec.decoupler.inputs if spec.decoupler is not None else []):
        if name not in inputs:
            raise SpecError(f"decoupler.inputs[{k}]", f"the plant has no input {name!r}; inputs: {', '.join(inputs)}")
    for k, ff in enumerate(spec.feedforward or []):
        if ff.input not in inputs:
            raise SpecError(f"feedforward[{k}].input", f"the plant has no input {ff.input!r}; inputs: "
                            f"{', '.join(inputs)}")


@dataclass(frozen=True)
class _Entry:
    """One entry of W or F: at (row, col), the full gain vector's slot ``slot`` (-1: fixed at ``value``)."""

    row: int
    col: int
    slot: int
    value: float


class BlockMatrices:
    """``W`` and ``F`` of every candidate, from their full gain vectors.

    Parameters
    ----------
    spec, layout
        The problem and its gain layout (tuned entries are its ``decoupler`` / ``feedforward`` slots).
    W, drives, order
        The architecture's wiring (m, L), the input each loop position drives (-1: a setpoint) and the
        spec loop index at each position.
    inputs
        The plant's input names.
    """

    def __init__(self, spec: TuningSpec, layout: GainLayout, W: np.ndarray, drives: np.ndarray,
                 order: tuple[int, ...], inputs: list[str]) -> None:
        index = {(s.loop_name, s.name): k for k, s in enumerate(layout.slots) if s.loop >= len(spec.loops)}
        self.W = np.ascontiguousarray(W, dtype=float)
        self.m, self.L = W.shape
        self.w_tuned: list[_Entry] = []
        dec = spec.decoupler
        if dec is not None:
            for a, row in enumerate(dec.matrix):
                for b, e in enumerate(row):
                    k = index.get((DECOUPLER, decoupler_gain_name(dec.inputs[a], dec.inputs[b])), -1)
                    cols = np.flatnonzero(drives == inputs.index(dec.inputs[b]))
                    if k >= 0 and cols.size:  # a column no loop drives multiplies nothing
                        self.w_tuned.append(_Entry(inputs.index(dec.inputs[a]), int(cols[0]), k, entry_value(e)))
        pos = {i: p for p, i in enumerate(order)}
        names = spec.loop_names
        self.f_entries = [
            _Entry(inputs.index(ff.input), pos[names.index(ff.loop)],
                   index.get((FEEDFORWARD, feedforward_gain_name(ff.loop, ff.input)), -1), entry_value(ff.gain))
            for ff in spec.feedforward or []
        ]

    @property
    def has_feedforward(self) -> bool:
        """Whether any feedforward gain is given (fixed or tuned)."""
        return bool(self.f_entries)

    def matrices(self, full: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """``(W, F)`` for the (B, n_gains) gain vectors ``full``: ``W`` (B or 1, m, L), ``F`` (B or 1, m, L), or
        (0, m, L) without feedforward; one matrix serves the batch when no entry of it is tuned."""
        full = np.atleast_2d(full)
        B = full.shape[0]
        if self.w_tuned:
            W = np.repeat(self.W[None], B, axis=0)
            for e in self.w_tuned:
                W[:, e.row, e.col] = full[:, e.slot]
        else:
            W = self.W[None]
        tuned_f = any(e.slot >= 0 for e in self.f_entries)
        F = np.zeros((B if tuned_f else (1 if self.f_entries else 0), self.m, self.L))
        for e in self.f_entries:
            F[:, e.row, e.col] = full[:, e.slot] if e.slot >= 0 else e.value
        return np.ascontiguousarray(W), F

    def one(self, full: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """``(W, F)`` (m, L) of one full gain vector (F all 0 without feedforward)."""
        W, F = self.matrices(np.asarray(full, dtype=float)[None])
        return W[0], (F[0] if F.shape[0] else np.zeros((self.m, self.L)))


def with_candidate_W(spec: TuningSpec, layout: GainLayout, arch, inputs: list[str], full: np.ndarray):
    """``arch`` (an :class:`~gaintune.sim.mimo.Architecture`) with the decoupler of the gain vector ``full``
    (``arch`` itself when no decoupler entry is tuned)."""
    from dataclasses import replace

    if spec.decoupler is None:
        return arch
    bm = BlockMatrices(spec, layout, arch.W, arch.drives, arch.order, inputs)
    return replace(arch, W=bm.one(full)[0]) if bm.w_tuned else arch
