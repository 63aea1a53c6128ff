"""The move onto the requirement boundary from both sides: what a trained tuner answers.

:func:`gaintune.evaluation.boundary_estimate.onto_boundary_estimate` moves an infeasible
candidate inward onto the boundary. A tuner must not stop there: a feasible answer that sits
inside the boundary (Ms 1.2 under a 1.4 limit, say) is conservative, and its cost is usually
higher than that of the same controller shape on the boundary. :func:`onto_boundary` therefore
also moves every feasible interior candidate **outward** along its loop-gain scale
(``tuned * alpha**d``, alpha > 1, the same move), onto the boundary of the estimate, and keeps
the outward point only where it lowers the plain cost (one evaluation of both). A
constrained optimum usually lies on the boundary, so the policy then only has to choose the
controller's shape; the repair chooses its scale, for every context.
"""

from __future__ import annotations

import numpy as np

from gaintune.evaluation.boundary import alpha_ceiling, alpha_floor, loop_gain_exponents
from gaintune.evaluation.boundary_estimate import EstimateMove, _Bracket, _regula_falsi
from gaintune.evaluation.evaluator import Evaluator, Scores

__all__ = ["BothMove", "onto_boundary", "SCAN"]

#: Loop-gain scales scanned in one estimate (log-spaced, 1 included at index :data:`_ONE`): they bracket the
#: boundary below and above the given gains, from an unstable start (1e-3) to a timid one (1e3).
SCAN = np.geomspace(1e-3, 1e3, 31)
_ONE = 15


class BothMove(EstimateMove):
    """:class:`EstimateMove` plus the scores of the returned gains (the cost comparison evaluated them)."""

    scores: Scores


def _take(scores: Scores, idx: np.ndarray) -> Scores:
    """The scores of rows ``idx`` (cost, violation, flags and metrics; no traces)."""
    return Scores(scores.cost[idx], scores.violation[idx], scores.diverged[idx], scores.tripped[idx],
                  {k: v[idx] for k, v in scores.metrics.items()}, [])


def _evaluate(ev: Evaluator, rows: np.ndarray, violation: np.ndarray) -> Scores:
    """``ev.evaluate(rows, violation=violation)`` one row at a time (no traces kept).

    For a single candidate (a tuner's query: its moved and its given gains). One gain set runs on the
    simulator's single-lane variant, as the verification's runs do, so a query in a fresh process loads one
    compiled kernel variant instead of two (~30 ms of CPU each). The numbers are those of the batched call,
    bit for bit: the variants compute each lane alike (:mod:`gaintune.sim.kernel.drivers`).
    """
    parts = [ev.evaluate(rows[i : i + 1], violation=violation[i : i + 1]) for i in range(len(rows))]
    if len(parts) == 1:
        return parts[0]
    cat = np.concatenate
    return Scores(cat([p.cost for p in parts]), cat([p.violation for p in parts]), cat([p.diverged for p in parts]),
                  cat([p.tripped for p in parts]), {k: cat([p.metrics[k] for p in parts]) for k in parts[0].metrics},
                  [])


def _feasible_end(ok: np.ndarray) -> int | None:
    """Index of the scan's feasible point to move from: the top of the feasible run that holds the given
    gains, or, when they are infeasible, the largest feasible scale below them (None: no feasible scale)."""
    if ok[_ONE]:
        j = _ONE
        while j + 1 < ok.size and ok[j + 1]:
            j += 1
        return j
    below = np.nonzero(ok[:_ONE])[0]
    return int(below[-1]) if below.size else None


def _scan(ev: Evaluator, given: np.ndarray, d: np.ndarray) -> tuple[np.ndarray, np.ndarray, list[int | None]]:
    """The scan's log scales (B, L), kept inside the box, with the estimate's verdict and shortfall at each."""
    B = len(given)
    lo = np.log(np.maximum(alpha_floor(ev.layout, given, d), 1e-300))
    hi = np.log(alpha_ceiling(ev.layout, given, d))
    xs = np.clip(np.log(SCAN)[None, :], lo[:, None], hi[:, None])
    n = xs.shape[1]
    # margins only (stability costs ~4x per row); the point the move lands on is checked in full
    v, g = ev.requirement_scores((given[:, None, :] * np.exp(xs)[..., None] ** d).reshape(B * n, -1),
                                 stability=False)
    ok = v.reshape(B, n) <= 0
    return xs, g.reshape(B, n), [_feasible_end(row) for row in ok]


def _largest_stable(ev: Evaluator, t: np.ndarray, d: np.ndarray, xs: np.ndarray, end: int | None) -> float:
    """The largest scan scale at or below ``end`` that the full estimate (stability included) takes; 0 (the
    given gains) when none does."""
    if end is None:
        return 0.0
    cand = xs[: end + 1][::-1]
    v = ev.requirement_scores(t[None, :] * np.exp(cand)[:, None] ** d)[0]
    good = np.nonzero(v <= 0)[0]
    return float(cand[good[0]]) if good.size else 0.0


def onto_boundary(ev: Evaluator, tuned: np.ndarray) -> BothMove:
    """Move infeasible candidates inward and feasible interior ones outward onto the requirement boundary.

    One estimate scans :data:`SCAN` scales of each candidate's loop gain (inside the search box); the
    boundary next to the given gains (above them when they are feasible, below when they are not, an
    unstable start included) is bracketed there and closed by regula falsi to within
    :data:`gaintune.evaluation.boundary_estimate.TOL`. A feasible candidate keeps the lower-cost of where it
    was and where it moved (one evaluation of both; row by row for a single candidate, see :func:`_evaluate`).
    A candidate no scale makes feasible is left as it is.

    Parameters
    ----------
    ev
        The evaluator of the plant the gains are for (its requirement estimate and cost).
    tuned
        (B, d) tuned gains.

    Returns
    -------
    BothMove
        The gains, their violation, the scale applied, which rows moved, and their :class:`Scores`.
    """
    given = np.atleast_2d(np.asarray(tuned, dtype=float))
    B = len(given)
    d = loop_gain_exponents(ev)
    if not d.any():
        scores = ev.evaluate(given)
        res = BothMove(given.copy(), scores.violation, np.ones(B), np.zeros(B, dtype=bool))
        res.scores = scores
        return res
    x, ends, v_land, v_given = _landing(ev, given, d)
    # a feasible candidate moved outward keeps the given gains where the move did not lower the cost
    stay = np.array([e is not None and e >= _ONE and x[b] != 0.0 for b, e in enumerate(ends)], dtype=np.bool_)
    # the landing's full estimate was computed by the move (the given gains' too, where they may stay)
    v = np.concatenate([v_land, v_given[stay]])
    unknown = np.isnan(v)
    rows = np.vstack([given * np.exp(x)[:, None] ** d, given[stay]])
    if unknown.any():
        v[unknown] = ev.requirement_violation(rows[unknown])
    both = _evaluate(ev, rows, v) if B == 1 else ev.evaluate(rows, violation=v)
    pick = np.arange(B)
    for k, b in zip(B + np.arange(int(stay.sum())), np.nonzero(stay)[0], strict=True):
        if both.merit[k] <= both.merit[b]:
            pick[b], x[b] = k, 0.0
    out = given * np.exp(x)[:, None] ** d
    res = BothMove(out, both.violation[pick], np.exp(x), x != 0.0)
    res.scores = _take(both, pick)
    return res


def _landing(ev: Evaluator, given: np.ndarray,
             d: np.ndarray) -> tuple[np.ndarray, list[int | None], np.ndarray, np.ndarray]:
    """(log scale to apply per row, the scan's feasible end per row, the full estimate's violation at the
    landing point and at the given gains (NaN where not computed)): the scan, the bracket closed by regula
    falsi, and the full estimate's check of the landing point."""
    xs, g, ends = _scan(ev, given, d)
    B = len(given)
    x = np.zeros(B)
    for b, e in enumerate(ends):
        if e is not None:
            x[b] = xs[b, e]
    rows = [b for b, e in enumerate(ends) if e is not None and e + 1 < xs.shape[1] and xs[b, e + 1] > xs[b, e]]
    if rows:
        r = np.array(rows)
        lo = np.array([ends[b] for b in rows], dtype=np.int64)
        br = _Bracket(t=given[r], xg=xs[r, lo].copy(), gg=g[r, lo].copy(), xb=xs[r, lo + 1].copy(),
                      gb=g[r, lo + 1].copy(), found=np.ones(r.size, dtype=np.bool_))
        _regula_falsi(ev, br, d)
        x[r] = br.xg
    # the full estimate (stability included) decides; where it refuses the point, the largest scan point it takes.
    # The given gains that may stay (feasible in the scan) are checked in the same call: the caller's cost
    # comparison needs their violation (the estimate is row by row, so batching changes nothing).
    keep = np.array([e is not None and e >= _ONE for e in ends], dtype=np.bool_)
    v = ev.requirement_scores(np.vstack([given * np.exp(x)[:, None] ** d, given[keep]]))[0]
    v_land, v_given = v[:B].copy(), np.full(B, np.nan)
    v_given[keep] = v[B:]
    for row in np.nonzero(v_land > 0)[0].tolist():
        x[row] = _largest_stable(ev, given[row], d, xs[row], ends[row])
        # the largest scan point the full estimate takes is feasible; none: the given gains, not checked here
        v_land[row] = 0.0 if x[row] != 0.0 else v_given[row]
    return x, ends, v_land, v_given
