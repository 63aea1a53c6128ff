"""Sparse structure of the MIMO loop: products of sparse transfer matrices over many frequencies (the loop
gains ``Ks Gs`` and ``Gs Ks``), and eigenvalues by strongly connected blocks (:func:`block_eigvals`).

A decentralised or cascaded controller has one entry per loop, and a large plant (a train of units)
couples only neighbours: a dense ``Ks @ Gs`` at every frequency spends nearly all its work on zeros.
:func:`product_plan` pairs the nonzero entries once (per loop and side); :func:`sparse_product`
then multiplies and sums only those pairs, each target's terms in one fixed order, so a point's
value does not depend on the other points evaluated with it.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

__all__ = ["ProductPlan", "product_plan", "sparse_product", "block_eigvals", "BLOCK_MIN", "divergence_rate",
           "DIVERGE_STEPS", "DIVERGE_FACTOR"]

#: Below this size a matrix's eigenvalues are taken whole (splitting it costs more than it saves).
BLOCK_MIN = 64
#: Steps of x <- A x in :func:`divergence_rate`, and the growth over their second half that proves nothing
#: but that no loop worth keeping does (a stable A would need ||A^512|| >= 1e4): spectral radii above ~1.018.
DIVERGE_STEPS = 1024
DIVERGE_FACTOR = 1e4


@dataclass(frozen=True)
class ProductPlan:
    """Which entry pairs of ``A @ B`` meet: A's entry ``left[k]`` times B's ``right[k]``, summed per
    target (flat index ``targets[g]``, its terms from ``starts[g]``); ``shape``: the product's."""

    left: np.ndarray
    right: np.ndarray
    targets: np.ndarray
    starts: np.ndarray
    shape: tuple[int, int]


def product_plan(a_rows: np.ndarray, a_cols: np.ndarray, b_rows: np.ndarray, b_cols: np.ndarray,
                 shape: tuple[int, int]) -> ProductPlan:
    """The plan of ``A @ B`` for A's nonzero entries at (``a_rows``, ``a_cols``) and B's at (``b_rows``,
    ``b_cols``); ``shape``: (rows of A, columns of B)."""
    left, right = np.nonzero(np.asarray(a_cols)[:, None] == np.asarray(b_rows)[None, :])
    target = np.asarray(a_rows)[left] * shape[1] + np.asarray(b_cols)[right]
    order = np.argsort(target, kind="stable")
    targets, starts = np.unique(target[order], return_index=True)
    return ProductPlan(left[order], right[order], targets, starts, shape)


def sparse_product(plan: ProductPlan, a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """``A @ B`` at every point: ``a`` (W, A's entries) and ``b`` (W, B's entries) hold the entries'
    values in the order the plan was made with; (W, rows, columns)."""
    out = np.zeros((a.shape[0], plan.shape[0] * plan.shape[1]), dtype=complex)
    if plan.left.size:
        with np.errstate(all="ignore"):
            out[:, plan.targets] = np.add.reduceat(a[:, plan.left] * b[:, plan.right], plan.starts, axis=1)
    return out.reshape(a.shape[0], *plan.shape)


def block_eigvals(A: np.ndarray) -> np.ndarray:
    """The eigenvalues of ``A`` from the diagonal blocks of its block-triangular form.

    The strongly connected components of A's nonzero pattern, in topological order, permute A to block
    upper-triangular form, whose eigenvalues are those of its diagonal blocks. A closed loop built entry
    by entry from a plant's Padé realisation splits so (the states of a channel no loop drives, a train's
    one-way couplings), and each block costs the cube of its own size instead of the whole's.
    """
    from scipy.sparse import csr_matrix
    from scipy.sparse.csgraph import connected_components

    if A.shape[0] < BLOCK_MIN:
        return np.linalg.eigvals(A)
    n_blocks, label = connected_components(csr_matrix(A != 0), directed=True, connection="strong")
    if n_blocks == 1:
        return np.linalg.eigvals(A)
    order = np.argsort(label, kind="stable")
    bounds = np.flatnonzero(np.diff(label[order])) + 1
    return np.concatenate([np.linalg.eigvals(A[np.ix_(idx, idx)]) for idx in np.split(order, bounds)])


def divergence_rate(A: np.ndarray, steps: int = DIVERGE_STEPS, factor: float = DIVERGE_FACTOR) -> float | None:
    """The per-step growth of ``x <- A x`` over the second half of ``steps`` iterations from a fixed start,
    when that half grows x at least ``factor``-fold; else None (stable, or not clearly unstable).

    A cheap screen before :func:`block_eigvals` (which costs ~n^3; this ~steps * nnz): the rate tends to the
    spectral radius, and a 10,000-fold growth over 512 steps means a spectral radius above 1, or a transient
    no acceptable loop has. Only a search's check may use it to call a loop unstable without its eigenvalues.
    """
    from scipy.sparse import csr_matrix

    S = csr_matrix(A)
    x = np.random.default_rng(0).standard_normal(A.shape[0])
    every, half, log_growth = 32, steps // 2, 0.0
    for k in range(0, steps, every):
        for _ in range(every):
            x = S @ x
        nrm = float(np.linalg.norm(x))
        if not (np.isfinite(nrm) and nrm > 0):
            return None  # nilpotent (x died) or overflowed within 32 steps: the eigenvalues decide
        x /= nrm
        log_growth += math.log(nrm) if k + every > half else 0.0
    if log_growth < math.log(factor):
        return None
    return math.exp(log_growth / (steps - half))
