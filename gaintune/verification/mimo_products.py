"""Products of sparse transfer matrices over many frequencies: the MIMO loop gains ``Ks Gs`` and ``Gs Ks``.

A decentralised or cascaded controller has one entry per loop, and a large plant (a train of units)
couples only neighbours: a dense ``Ks @ Gs`` at every frequency spends nearly all its work on zeros.
:func:`product_plan` pairs the nonzero entries once (per loop and side); :func:`sparse_product`
then multiplies and sums only those pairs, each target's terms in one fixed order, so a point's
value does not depend on the other points evaluated with it.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = ["ProductPlan", "product_plan", "sparse_product"]


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
