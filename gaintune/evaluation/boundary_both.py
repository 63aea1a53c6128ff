"""The move onto the requirement boundary from both sides: what a trained tuner answers.

:func:`gaintune.evaluation.boundary_estimate.onto_boundary_estimate` moves an infeasible
candidate inward onto the boundary. A tuner must not stop there: a feasible answer that sits
inside the boundary (Ms 1.2 under a 1.4 limit, say) is conservative, and its cost is usually
higher than that of the same controller shape on the boundary. :func:`onto_boundary` therefore
also moves every feasible interior candidate **outward** along its loop-gain scale
(``tuned * alpha**d``, alpha > 1, the same move), onto the boundary of the estimate, and keeps
the outward point only where it lowers the plain cost (one evaluation of both). Where the
feasible scales form several runs (a lag-dominant PID: feasible at low gain and again on an
island of high gain), the upper boundary of each run is a landing, and the cheapest is kept. A
constrained optimum usually lies on the boundary, so the policy then only has to choose the
controller's shape; the repair chooses its scale, for every context.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from gaintune.evaluation.boundary import alpha_ceiling, alpha_floor, loop_gain_exponents
from gaintune.evaluation.boundary_estimate import EstimateMove, _Bracket, _regula_falsi
from gaintune.evaluation.evaluator import Evaluator, Scores

__all__ = ["BothMove", "onto_boundary", "SCAN"]

#: Loop-gain scales scanned in one estimate (log-spaced, 1 included at index :data:`_ONE`): they bracket the
#: boundary below and above the given gains, from an unstable start (1e-3) to a timid one (1e3).
SCAN = np.geomspace(1e-3, 1e3, 31)
_ONE = 15
#: Steps that close a landing's bracket (a row stops once within the tolerance): the search repair's regula-falsi
#: steps, then the Illinois form. An answer is moved once, and where a PID shape's shortfall bends sharply inside
#: the bracket, regula falsi alone stops short of the boundary (12 % above the cost on it, on a lag-dominant plant).
CLOSE_STEPS = 10


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


def _start_points(ok: np.ndarray) -> list[int]:
    """The scan points the move starts from: the top of every feasible run of the scan, the one next to the
    given gains first (the top of the run that holds them or, when they are infeasible, of the nearest run
    below them); empty when no scale is feasible.

    Along the loop-gain scale the feasible set can be several runs: a lag-dominant PID shape is feasible at
    low gain, infeasible over a band, and feasible again on an island of high gain, where its optimum lies
    (the regression test ``test_move_finds_the_high_gain_island_of_a_lag_dominant_pid``). Landing only next
    to the given gains made the answer depend on the gains' scale, which the tuner's action does not set,
    and put a cliff in the reward beside the optimum. Every run's upper boundary is therefore a candidate,
    and the cheapest landing is kept.
    """
    tops = [j for j in range(ok.size) if ok[j] and (j + 1 == ok.size or not ok[j + 1])]
    near = [j for j in tops if j >= _ONE][:1] if ok[_ONE] else [j for j in tops if j < _ONE][-1:]
    return near + [j for j in tops if j not in near]


def _scan(ev: Evaluator, given: np.ndarray,
          d: np.ndarray) -> tuple[np.ndarray, np.ndarray, list[list[int]], np.ndarray]:
    """The scan's log scales (B, L), kept inside the box, the estimate's shortfall at each, each row's
    :func:`_start_points`, and whether the given gains (scale 1) are feasible in it (B,)."""
    B = len(given)
    lo = np.log(np.maximum(alpha_floor(ev.layout, given, d), 1e-300))
    hi = np.log(alpha_ceiling(ev.layout, given, d))
    xs = np.clip(np.log(SCAN)[None, :], lo[:, None], hi[:, None])
    n = xs.shape[1]
    # margins only (stability costs ~4x per row); the point the move lands on is checked in full. The box
    # clips a third of the scales to its ends: each distinct gain set is estimated once (row by row, the same)
    rows, back = np.unique((given[:, None, :] * np.exp(xs)[..., None] ** d).reshape(B * n, -1), axis=0,
                           return_inverse=True)
    v, g = ev.requirement_scores(rows, stability=False)
    v, g = v[back.ravel()], g[back.ravel()]
    ok = v.reshape(B, n) <= 0
    return xs, g.reshape(B, n), [_start_points(row) for row in ok], ok[:, _ONE].copy()


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

    One estimate scans :data:`SCAN` scales of each candidate's loop gain (inside the search box). The
    boundary next to the given gains (above them when they are feasible, below when they are not, an
    unstable start included) is bracketed there, and so is the upper boundary of every other feasible run
    of the scan (:func:`_start_points`); each is closed to within :data:`gaintune.evaluation.boundary_estimate.TOL`
    in at most :data:`CLOSE_STEPS` steps (regula falsi, then its Illinois form). The lowest-cost landing is
    kept, and a feasible candidate keeps its given gains where no landing costs less (one evaluation of each;
    row by row for a single candidate, see :func:`_evaluate`). A candidate no scale makes feasible is left
    as it is.

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
    land = _landing(ev, given, d)
    x = land.x
    # a feasible candidate moved outward keeps the given gains where no move lowered the cost
    moved = np.zeros(B, dtype=np.bool_)
    np.logical_or.at(moved, land.row, x != 0.0)
    stay = land.keep & moved
    # the landing's full estimate was computed by the move (the given gains' too, where they may stay)
    v = np.concatenate([land.v_land, land.v_given[stay]])
    unknown = np.isnan(v)
    rows = np.vstack([given[land.row] * np.exp(x)[:, None] ** d, given[stay]])
    if unknown.any():
        v[unknown] = ev.requirement_violation(rows[unknown])
    both = _evaluate(ev, rows, v) if B == 1 else ev.evaluate(rows, violation=v)
    pick, scale = _cheapest(land, both.merit, stay, B)
    out = given * np.exp(scale)[:, None] ** d
    res = BothMove(out, both.violation[pick], np.exp(scale), scale != 0.0)
    res.scores = _take(both, pick)
    return res


def _cheapest(land: _Landing, merit: np.ndarray, stay: np.ndarray, B: int) -> tuple[np.ndarray, np.ndarray]:
    """(row of the evaluated rows to return, log scale applied) per candidate: the lowest-merit landing (the
    first on a tie, the one next to the given gains), or the given gains where they may stay and cost no more."""
    pick = np.full(B, -1)
    scale = np.zeros(B)
    for k, (b, x) in enumerate(zip(land.row.tolist(), land.x.tolist(), strict=True)):
        if pick[b] < 0 or merit[k] < merit[pick[b]]:
            pick[b], scale[b] = k, x
    for k, b in enumerate(np.nonzero(stay)[0].tolist(), start=land.row.size):
        if merit[k] <= merit[pick[b]]:
            pick[b], scale[b] = k, 0.0
    return pick, scale


@dataclass
class _Landing:
    """The move's landing points, one per start point of each row's scan (a row without one: its given
    gains, scale 0), the full estimate's violation at each, and at the given gains that may stay."""

    row: np.ndarray  # (C,) the candidate each landing belongs to, ascending
    x: np.ndarray  # (C,) log scale of the landing
    v_land: np.ndarray  # (C,) full estimate's violation at the landing
    keep: np.ndarray  # (B,) the given gains are feasible in the scan: they may stay
    v_given: np.ndarray  # (B,) full estimate's violation at the given gains (NaN where not kept)


def _full_violation(ev: Evaluator, rows: np.ndarray, margins_hold: np.ndarray) -> np.ndarray:
    """The full estimate's violation of ``rows``; where ``margins_hold`` (a feasible scan point or bracket end:
    every margin holds, so its violation is 0 unless the loop is unstable) the stability check alone gives it."""
    if ev.is_mimo or not margins_hold.any():
        return ev.requirement_scores(rows)[0]
    v = np.empty(len(rows))
    v[margins_hold] = ev.unstable_violation(rows[margins_hold])
    if not margins_hold.all():
        v[~margins_hold] = ev.requirement_scores(rows[~margins_hold])[0]
    return v


def _landing(ev: Evaluator, given: np.ndarray, d: np.ndarray) -> _Landing:
    """The scan, each start point's bracket closed by regula falsi, and the full estimate's check of every
    landing point (where it refuses one, the largest scan point at or below it that it takes)."""
    xs, g, starts, keep = _scan(ev, given, d)
    B, n = xs.shape
    per_row: list[list[int | None]] = [list(s) if s else [None] for s in starts]  # None: no feasible scale
    row = np.array([b for b in range(B) for _ in per_row[b]], dtype=np.int64)
    end = [e for b in range(B) for e in per_row[b]]
    x = np.array([0.0 if e is None else xs[b, e] for b, e in zip(row.tolist(), end, strict=True)])
    open_ = [k for k, (b, e) in enumerate(zip(row.tolist(), end, strict=True))
             if e is not None and e + 1 < n and xs[b, e + 1] > xs[b, e]]
    if open_:
        r, lo = row[open_], np.array([end[k] for k in open_], dtype=np.int64)
        br = _Bracket(t=given[r], xg=xs[r, lo].copy(), gg=g[r, lo].copy(), xb=xs[r, lo + 1].copy(),
                      gb=g[r, lo + 1].copy(), found=np.ones(r.size, dtype=np.bool_))
        _regula_falsi(ev, br, d, CLOSE_STEPS)
        x[open_] = br.xg
    # the full estimate (stability included) decides. The given gains that may stay (feasible in the scan)
    # are checked in the same call: the caller's cost comparison needs their violation (the estimate is
    # row by row, so batching changes nothing).
    v = _full_violation(ev, np.vstack([given[row] * np.exp(x)[:, None] ** d, given[keep]]),
                        np.concatenate([[e is not None for e in end], np.ones(int(keep.sum()), dtype=bool)]))
    C = row.size
    v_land, v_given = v[:C].copy(), np.full(B, np.nan)
    v_given[keep] = v[C:]
    for k in np.nonzero(v_land > 0)[0].tolist():
        b = int(row[k])
        x[k] = _largest_stable(ev, given[b], d, xs[b], end[k])
        # the largest scan point the full estimate takes is feasible; none: the given gains, not checked here
        v_land[k] = 0.0 if x[k] != 0.0 else v_given[b]
    return _Landing(row, x, v_land, keep, v_given)
