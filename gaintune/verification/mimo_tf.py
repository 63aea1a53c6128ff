"""Transfer-matrix entries of the MIMO loop, evaluated and realised from their nonzero entries only.

A decentralised or cascaded controller and a large plant are mostly zeros: the nonzero entries of a
:class:`~gaintune.lti.mimo.TfMatrix` (restricted to some rows and columns) are stacked once per matrix
object and evaluated together (Horner over padded coefficients) at any points. Helpers of
:mod:`.mimo_loop` (private to the MIMO verification).
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from gaintune.lti.mimo import TfEntry, TfMatrix, block_diag

_NZ_CACHE: dict[tuple, tuple[TfMatrix, list[tuple[int, int, TfEntry]], tuple]] = {}


def _nonzero(sys: TfMatrix, rows: tuple[int, ...], cols: tuple[int, ...]) -> list[tuple[int, int, TfEntry]]:
    """(row, column, entry) of the nonzero entries of ``sys[rows, cols]``, remembered per matrix object."""
    return _nz_data(sys, rows, cols)[0]


def _nz_data(sys: TfMatrix, rows: tuple[int, ...], cols: tuple[int, ...]) -> tuple[list, tuple]:
    """The nonzero entries and their coefficients stacked for a vectorised evaluation: (row indices,
    column indices, numerators and denominators padded to one length, delays)."""
    key = (id(sys), rows, cols)
    hit = _NZ_CACHE.get(key)
    if hit is not None and hit[0] is sys:
        return hit[1], hit[2]
    nz = [(a, b, sys.entries[i][j]) for a, i in enumerate(rows) for b, j in enumerate(cols)
          if not sys.entries[i][j].is_zero]
    k = max([max(e.num.size, e.den.size) for _, _, e in nz], default=1)
    num = np.array([np.pad(np.asarray(e.num, float), (k - e.num.size, 0)) for _, _, e in nz]).reshape(len(nz), k)
    den = np.array([np.pad(np.asarray(e.den, float), (k - e.den.size, 0)) for _, _, e in nz]).reshape(len(nz), k)
    stacked = (np.array([a for a, _, _ in nz], dtype=int), np.array([b for _, b, _ in nz], dtype=int), num, den,
               np.array([e.delay for _, _, e in nz]))
    if len(_NZ_CACHE) > 256:
        _NZ_CACHE.clear()
    _NZ_CACHE[key] = (sys, nz, stacked)
    return nz, stacked


def _tf_values(sys: TfMatrix, s: np.ndarray, rows: tuple[int, ...], cols: tuple[int, ...]
               ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(row indices, column indices, values (len(s), entries)) of the nonzero entries of
    ``sys[rows, cols]`` at ``s``, all at once (Horner over the stacked coefficients)."""
    _, (ra, cb, num, den, delay) = _nz_data(sys, rows, cols)
    n = np.zeros((s.size, ra.size), dtype=complex)
    d = np.zeros((s.size, ra.size), dtype=complex)
    for c in range(num.shape[1]):
        n = n * s[:, None] + num[:, c]
        d = d * s[:, None] + den[:, c]
    with np.errstate(all="ignore"):  # an integrator at s = 0: inf, as meant
        v = n / d
        if np.any(delay):
            v = v * np.exp(-s[:, None] * delay[None, :])
    return ra, cb, v


def _tf_response(sys: TfMatrix, s: np.ndarray, rows: tuple[int, ...], cols: tuple[int, ...]) -> np.ndarray:
    """``sys[rows, cols]`` at ``s`` (len(s), len(rows), len(cols))."""
    out = np.zeros((s.size, len(rows), len(cols)), dtype=complex)
    ra, cb, v = _tf_values(sys, s, rows, cols)
    if ra.size:
        out[:, ra, cb] = v
    return out


def _tf_realisation(sys: TfMatrix, rows: Sequence[int], cols: Sequence[int]) -> tuple:
    """(A, B, C, D) of the delay-free ``sys[rows, cols]``, entry by entry (zero entries add nothing)."""
    As, Bs, Cs = [], [], []
    D = np.zeros((len(rows), len(cols)))
    for a, b, e in _nonzero(sys, tuple(rows), tuple(cols)):
        A, B, C, Dij = e.realisation()
        if e.den.size > 1:  # a static entry's realisation has a dummy state
            As.append(A)
            Bc = np.zeros((A.shape[0], len(cols)))
            Bc[:, b] = B[:, 0]
            Cr = np.zeros((len(rows), A.shape[0]))
            Cr[a, :] = C[0, :]
            Bs.append(Bc)
            Cs.append(Cr)
        D[a, b] = Dij[0, 0]
    if not As:
        return np.zeros((0, 0)), np.zeros((0, len(cols))), np.zeros((len(rows), 0)), D
    return block_diag(*As), np.vstack(Bs), np.hstack(Cs), D

