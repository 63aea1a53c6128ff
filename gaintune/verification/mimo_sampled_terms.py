"""The sampled plant's channels as a sum of first-order terms, by independent blocks of states.

A plant realised entry by entry (a transfer matrix: a train of units, each entry its own states) has a
block-diagonal ``Ad``: the states split into blocks no entry of ``Ad`` couples. Each block's channels
(:class:`~gaintune.verification.mimo_sampled.SampledCore`) reach only the outputs its ``C`` columns
reach, through its own modes only, so

    Gs(z)[i, j] = sum over blocks, channels c of input j, modes m of the block:
                  z^-d(c) (R0[i, c, m] + R1[i, c, m] z^-1) / (z - lambda_m)

with the residues ``R0 = (C V)[i, m] (V^-1 G0)[m, c]`` (R1 of G1) of the block's eigendecomposition
``A_b = V diag(lambda) V^-1``. That is :meth:`SampledCore.response_dense`'s modal form with the
products of zeros left out: a 44 x 22 channel matrix of 94 nonzero entries costs ~200 terms per
frequency instead of ~550,000 products. A block whose eigenvectors are ill conditioned (a repeated
pole) is solved per point instead, as the dense form does for the whole ``Ad``.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Protocol

import numpy as np

from gaintune.lti.arrays import int_power

__all__ = ["SampledTerms", "state_blocks"]

class _Core(Protocol):
    """What the terms read of a :class:`~gaintune.verification.mimo_sampled.SampledCore`."""

    Ad: np.ndarray
    C: np.ndarray
    G0: np.ndarray
    G1: np.ndarray
    src: np.ndarray
    d: np.ndarray


#: Eigenvectors of a block conditioned worse than this: the block is solved per point.
_COND_MAX = 1e8


def state_blocks(A: np.ndarray) -> list[np.ndarray]:
    """The states of ``A`` in blocks no nonzero entry couples (connected components of its pattern)."""
    from scipy.sparse import csr_matrix
    from scipy.sparse.csgraph import connected_components

    if A.shape[0] == 0:
        return []
    n, label = connected_components(csr_matrix(A != 0), directed=False)
    order = np.argsort(label, kind="stable")
    return np.split(order, np.flatnonzero(np.diff(label[order])) + 1)


@dataclass(frozen=True)
class _SolvedBlock:
    """A block evaluated by a solve per point: its state matrix, its outputs' rows of C, its channels' columns
    of G0 and G1 and their whole-sample delays, and the entry index of each (row, channel)."""

    A: np.ndarray
    C: np.ndarray
    G0: np.ndarray
    G1: np.ndarray
    d: np.ndarray
    targets: np.ndarray  # (rows, channels)

    def response(self, z: np.ndarray) -> np.ndarray:
        """(len(z), rows, channels): C_b (zI - A_b)^-1 (G0 + G1 z^-1) z^-d per channel."""
        from gaintune.verification.mimo_loop import solve_points

        inv = 1.0 / z
        f = int_power(inv[:, None], self.d[None, :])
        Bz = (self.G0[None] + self.G1[None] * inv[:, None, None]) * f[:, None, :]
        X = solve_points(z[:, None, None] * np.eye(self.A.shape[0]) - self.A[None], Bz)
        return self.C[None] @ X


@dataclass(frozen=True)
class SampledTerms:
    """Gs(z) of a :class:`~gaintune.verification.mimo_sampled.SampledCore` as first-order terms.

    The core's channels: ``x[k+1] = Ad x[k] + sum_c (G0[:, c] u_src(c)[k - d(c)] + G1[:, c] u_src(c)[k - d(c) - 1])``,
    ``y = C x``.

    Term k adds ``coef[k] z^-shift[k] / (z - lam[mode[k]])`` to entry ``entry[k]``; the terms are
    sorted by entry (each entry's from ``starts``); ``rows``, ``cols``: the channel matrix position of
    each entry (every entry the structure lets be nonzero)."""

    n_in: int
    rows: np.ndarray
    cols: np.ndarray
    lam: np.ndarray
    mode: np.ndarray
    coef: np.ndarray
    shifts: np.ndarray  # distinct shifts
    shift_of: np.ndarray  # term -> index into shifts
    entry: np.ndarray
    starts: np.ndarray
    solved: tuple[_SolvedBlock, ...]

    @classmethod
    def of(cls, core: _Core, n_in: int) -> SampledTerms:
        """The terms of ``core``'s channels (Ad, C, G0, G1, src, d: a SampledCore's) to its ``n_in`` driven inputs."""
        lam: list[np.ndarray] = []
        parts: list[tuple[np.ndarray, ...]] = []  # (mode, coef, shift, flat target) per block
        solved: list[tuple[np.ndarray, np.ndarray, np.ndarray]] = []
        n_modes = 0
        for idx in state_blocks(core.Ad):
            rows = np.flatnonzero(np.any(core.C[:, idx] != 0, axis=1))
            c0 = np.flatnonzero(np.any(core.G0[idx] != 0, axis=0))
            c1 = np.flatnonzero(np.any(core.G1[idx] != 0, axis=0))
            if rows.size == 0 or c0.size + c1.size == 0:
                continue  # no channel reaches an output through these states
            lb, V = np.linalg.eig(core.Ad[np.ix_(idx, idx)])
            if np.linalg.cond(V) >= _COND_MAX:
                solved.append((idx, rows, np.union1d(c0, c1)))
                continue
            Vi = np.linalg.inv(V)
            CV = core.C[np.ix_(rows, idx)] @ V
            modes = n_modes + np.arange(lb.size)
            for G, cols, extra in ((core.G0, c0, 0), (core.G1, c1, 1)):
                if cols.size:
                    R = CV[:, None, :] * (Vi @ G[np.ix_(idx, cols)]).T[None, :, :]  # (rows, chans, modes)
                    r, c, m = (a.ravel() for a in np.meshgrid(rows, cols, np.arange(lb.size), indexing="ij"))
                    parts.append((modes[m], R.ravel(), core.d[c] + extra, r * n_in + core.src[c]))
            lam.append(lb)
            n_modes += lb.size
        return cls._assemble(core, n_in, lam, parts, solved)

    @classmethod
    def _assemble(cls, core: _Core, n_in: int, lam: list[np.ndarray], parts: list[tuple[np.ndarray, ...]],
                  solved: list[tuple[np.ndarray, np.ndarray, np.ndarray]]) -> SampledTerms:
        """Sort the blocks' terms by entry and number the entries (those of solved blocks too)."""
        mode, coef, shift, target = (np.concatenate([p[k] for p in parts]) if parts else np.zeros(0)
                                     for k in range(4))
        flat = [target.astype(int)] + [(r[:, None] * n_in + core.src[c][None, :]).ravel() for _, r, c in solved]
        ents = np.unique(np.concatenate(flat))
        order = np.argsort(target, kind="stable")
        entry = np.searchsorted(ents, target[order].astype(int))
        starts = np.flatnonzero(np.concatenate([[True], np.diff(entry) != 0])) if entry.size else entry
        shifts, shift_of = np.unique(shift[order].astype(int), return_inverse=True)
        blocks = tuple(_SolvedBlock(core.Ad[np.ix_(idx, idx)], core.C[np.ix_(r, idx)], core.G0[np.ix_(idx, c)],
                                    core.G1[np.ix_(idx, c)], core.d[c],
                                    np.searchsorted(ents, r[:, None] * n_in + core.src[c][None, :]))
                       for idx, r, c in solved)
        return cls(n_in, ents // n_in, ents % n_in, np.concatenate(lam) if lam else np.zeros(0, dtype=complex),
                   mode[order].astype(int), coef[order].astype(complex), shifts, shift_of.ravel(), entry, starts,
                   blocks)

    def values(self, z: np.ndarray) -> np.ndarray:
        """The entries at the points ``z``: (len(z), entries); inf or NaN on a pole, as the dense form."""
        out = np.zeros((z.size, self.rows.size), dtype=complex)
        with np.errstate(all="ignore"):
            if self.mode.size:
                inv = 1.0 / z
                f = inv[:, None] ** self.shifts[None, :]
                r = 1.0 / (z[:, None] - self.lam[None, :])
                v = (r[:, self.mode] * f[:, self.shift_of]) * self.coef[None, :]
                out[:, self.entry[self.starts]] = np.add.reduceat(v, self.starts, axis=1)
            for b in self.solved:  # (two channels of one input may meet in one entry: add.at sums both)
                np.add.at(out.T, b.targets.ravel(), b.response(z).reshape(z.size, -1).T)
        return out
