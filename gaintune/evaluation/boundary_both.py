"""The move onto the requirement boundary from both sides: what a trained tuner answers.

:func:`gaintune.evaluation.boundary_estimate.onto_boundary_estimate` moves an infeasible
candidate inward onto the boundary. A tuner must not stop there: a feasible answer that sits
inside the boundary (Ms 1.2 under a 1.4 limit, say) is conservative, and its cost is usually
higher than that of the same controller shape on the boundary. :func:`onto_boundary` therefore
also moves every feasible interior candidate **outward** along its loop-gain scale
(``tuned * alpha**d``, alpha > 1, the same move), onto the boundary of the estimate, and keeps
the outward point only where it lowers the plain cost (one batched evaluation of both). A
constrained optimum usually lies on the boundary, so the policy then only has to choose the
controller's shape; the repair chooses its scale, for every context.
"""

from __future__ import annotations

import numpy as np

from gaintune.evaluation.boundary import alpha_floor, loop_gain_exponents
from gaintune.evaluation.boundary_estimate import TOL, EstimateMove, _Bracket, _regula_falsi, onto_boundary_estimate
from gaintune.evaluation.evaluator import Evaluator, Scores
from gaintune.verification.quick import UNSTABLE_VIOLATION

__all__ = ["BothMove", "onto_boundary", "OUTWARD_LADDER"]

#: Loop-gain scales tried at once above 1: they bracket the boundary of a feasible interior candidate.
OUTWARD_LADDER = (1.02, 1.1, 1.3, 1.7, 2.5, 4.0, 7.0)
#: Rounds of the outward ladder, each starting from the last one's top.
OUTWARD_ROUNDS = 4


class BothMove(EstimateMove):
    """:class:`EstimateMove` plus the scores of the returned gains (the cost comparison evaluated them)."""

    scores: Scores


def _alpha_ceiling(ev: Evaluator, tuned: np.ndarray, d: np.ndarray) -> np.ndarray:
    """(B,) largest alpha >= 1 that keeps ``tuned * alpha**d`` inside the search box."""
    hi = np.exp(ev.layout.log_hi)
    with np.errstate(divide="ignore", invalid="ignore"):
        lim = np.where(d > 0, hi / tuned, np.inf).min(axis=1)
    return np.maximum(lim, 1.0)


def _outward(ev: Evaluator, t: np.ndarray, d: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Each feasible interior row of ``t`` moved out onto the boundary; (moved rows, which rows moved)."""
    n = len(t)
    x_top = np.log(_alpha_ceiling(ev, t, d))
    xs = np.minimum(np.log(np.array(OUTWARD_LADDER))[None, :], x_top[:, None])  # (n, L)
    n_ladder = xs.shape[1]
    lv, lg = ev.requirement_scores((t[:, None, :] * np.exp(xs)[..., None] ** d).reshape(n * n_ladder, -1),
                                   stability=False)
    lv, lg = lv.reshape(n, n_ladder), lg.reshape(n, n_ladder)
    bad = lv > 0
    crosses = np.asarray(bad.any(axis=1))
    first = np.argmax(bad, axis=1)  # the smallest infeasible scale on the ladder
    i = np.arange(n)
    prev = first - 1
    xg = np.where(prev >= 0, xs[i, np.maximum(prev, 0)], 0.0)
    gg = np.where(prev >= 0, lg[i, np.maximum(prev, 0)], -1.0)
    br = _Bracket(t=t, xg=xg, gg=gg, xb=xs[i, first], gb=lg[i, first], found=crosses)
    _regula_falsi(ev, br, d)
    # no crossing below the box ceiling: the top of the ladder (still feasible) is the outward point
    x = np.where(crosses, br.xg, xs[:, -1])
    return t * np.exp(x)[:, None] ** d, x > 0


#: Loop-gain scales tried at once on an unstable candidate, to find a stable start for the inward move.
STABILISE_LADDER = (0.5, 0.25, 0.1, 0.03, 0.01, 0.003)


def _stabilised(ev: Evaluator, tuned: np.ndarray, d: np.ndarray) -> np.ndarray:
    """Unstable rows scaled down to the largest stable scale of :data:`STABILISE_LADDER` (within the box).

    :func:`onto_boundary_estimate` leaves an unstable candidate as it is; from a stable point the inward
    move can bring it onto the boundary. Rows that no scale stabilises are left unchanged.
    """
    if not d.any():
        return tuned
    v = ev.requirement_scores(tuned)[0]
    rows = np.nonzero(v >= UNSTABLE_VIOLATION)[0]
    if not rows.size:
        return tuned
    t = tuned[rows]
    floor = alpha_floor(ev.layout, t, d)
    alphas = np.maximum(np.array(STABILISE_LADDER)[None, :], floor[:, None])  # (n, L)
    n, n_l = alphas.shape
    lv = ev.requirement_scores((t[:, None, :] * alphas[..., None] ** d).reshape(n * n_l, -1))[0].reshape(n, n_l)
    stable = lv < UNSTABLE_VIOLATION
    first = np.argmax(stable, axis=1)
    ok = stable.any(axis=1)
    out = tuned.copy()
    out[rows[ok]] = t[ok] * alphas[np.nonzero(ok)[0], first[ok]][:, None] ** d
    return out


def _outward_all(ev: Evaluator, t: np.ndarray, d: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """:func:`_outward`, repeated from the ladder's top for rows it did not bring onto the boundary (at most
    :data:`OUTWARD_ROUNDS` times: a scale of up to 7**4 = 2401)."""
    moved, did = _outward(ev, t, d)
    for _ in range(OUTWARD_ROUNDS - 1):
        g = ev.requirement_scores(moved, stability=False)[1]
        more = np.nonzero(did & (g < -TOL) & (np.log(_alpha_ceiling(ev, moved, d)) > 1e-9))[0]
        if not more.size:
            break
        moved[more] = _outward(ev, moved[more], d)[0]
    return moved, did


def onto_boundary(ev: Evaluator, tuned: np.ndarray) -> BothMove:
    """Move infeasible candidates inward and feasible interior ones outward onto the requirement boundary.

    An unstable candidate is first scaled down to a stable one (:func:`_stabilised`).

    Parameters
    ----------
    ev
        The evaluator of the plant the gains are for (its requirement estimate and cost).
    tuned
        (B, d) tuned gains.

    Returns
    -------
    BothMove
        The gains (each row the lower-cost of where it was and where it moved), their violation,
        the scale applied, which rows moved, and their :class:`Scores`.
    """
    given = np.atleast_2d(np.asarray(tuned, dtype=float))
    tuned = _stabilised(ev, given, loop_gain_exponents(ev))
    inward = onto_boundary_estimate(ev, tuned)
    out = inward.tuned.copy()
    d = loop_gain_exponents(ev)
    v, g = ev.requirement_scores(out)
    rows = np.nonzero((v <= 0) & (g < -TOL) & ~inward.repaired)[0]
    alpha = inward.alpha.copy()
    if rows.size and d.any():
        moved, did = _outward_all(ev, out[rows], d)
        rows, moved = rows[did], moved[did]
        full_v = ev.requirement_scores(moved)[0]  # stability included: the moved point must hold in full
        ok = full_v <= 0
        rows, moved = rows[ok], moved[ok]
        if rows.size:
            both = ev.evaluate(np.vstack([out[rows], moved]))
            k = rows.size
            better = both.merit[k:] < both.merit[:k]
            alpha[rows[better]] = (moved[better] / out[rows[better]])[:, np.argmax(d)]
            out[rows[better]] = moved[better]
    scores = ev.evaluate(out)
    if d.any():  # the scale applied to the given gains, stabilising step included
        k = int(np.argmax(d))
        alpha = out[:, k] / given[:, k]
    res = BothMove(out, scores.violation, alpha, np.any(out != given, axis=1))
    res.scores = scores
    return res
