"""The move onto the requirement boundary on the search estimate: the RL search's constraint projection.

A policy samples gain sets around its mean. With feasibility-first rewards, every
sample that crosses a requirement boundary (Ms > 1.4, say) scores far below every
feasible one, so the policy mean learns to stay well inside the boundary, while a
constrained optimum usually lies on it. This module removes that cliff the way a
safety layer does in constrained RL: a sampled gain set that violates a requirement
(but not by instability) is moved onto the boundary along its **loop-gain scale**
before it is simulated, and the policy is rewarded for the repaired gains. Samples
beyond the boundary then score like the boundary point they project to, and the
policy is free to move along it.

The move (:mod:`gaintune.evaluation.boundary`) is the one :mod:`gaintune.evaluation.boundary_exact` makes
exactly, here on the search's fast estimate
(:meth:`gaintune.evaluation.evaluator.Evaluator.requirement_violation`) and batched: every tuned gain
of every PID loop is multiplied by ``alpha**d`` with ``d = 1`` on
Kp, Ki and Kd of a parallel loop (on Kp of an ideal loop), which multiplies each
controller by alpha. A coarse ladder of alphas below 1 finds, per candidate, the
largest feasible scale, and a few bisection steps close the bracket. A candidate that
no scale in the search box makes feasible is left as it is (and keeps its violation).

The boundary is the estimate's: each limit moved inside by ``requirements.backoff``
(:meth:`gaintune.evaluation.evaluator.Evaluator.requirement_scores` aims there), so repaired gains keep
the same margin to the exact limits as every other answer.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from gaintune.evaluation.boundary import alpha_floor, loop_gain_exponents
from gaintune.evaluation.evaluator import Evaluator
from gaintune.verification.quick import UNSTABLE_VIOLATION

__all__ = ["EstimateMove", "onto_boundary_estimate", "LADDER", "SECANT_STEPS", "TOL"]

#: Relative gain reductions tried at once (alpha = 1 - step): they bracket the boundary.
LADDER = (0.02, 0.1, 0.3, 0.6, 0.85)
#: Safeguarded regula-falsi steps in log alpha after the ladder.
SECANT_STEPS = 3
#: A repaired row is done once its shortfall is within this of zero (relative to the limit, inside).
TOL = 1e-3

@dataclass
class EstimateMove:
    """Outcome of :func:`onto_boundary_estimate` for B candidates.

    Attributes
    ----------
    tuned
        (B, d) gains: repaired rows moved onto the boundary, the others unchanged.
    violation
        (B,) estimated violation of the returned gains.
    alpha
        (B,) loop-gain scale applied (1 where unchanged).
    repaired
        (B,) rows that were moved.
    """

    tuned: np.ndarray
    violation: np.ndarray
    alpha: np.ndarray
    repaired: np.ndarray


def onto_boundary_estimate(ev: Evaluator, tuned: np.ndarray, per_loop: bool = False) -> EstimateMove:
    """Move each stable but infeasible candidate onto the requirement boundary (see the module docstring).

    The search estimate's signed shortfall ``g`` (<= 0 when every requirement holds) is solved for
    ``g = -TOL/2`` in x = log alpha: a ladder of scales brackets the root, then a few regula-falsi
    steps (bisection where the bracket's end is unstable) close it to within ``TOL``.

    Parameters
    ----------
    ev
        The search's evaluator (spec, layout and the requirement estimate).
    tuned
        (B, d) tuned gains.
    per_loop
        Scale only the loops whose own break point misses a requirement
        (:func:`gaintune.evaluation.boundary_loops.loop_shortfalls`), every loop together where
        that does not reach a feasible point; False: every loop together.
    """
    tuned = np.atleast_2d(np.asarray(tuned, dtype=float))
    v, g0 = ev.requirement_scores(tuned)
    B = len(tuned)
    out, v_out, alpha = tuned.copy(), v.copy(), np.ones(B)
    mask = np.zeros(B, dtype=bool)
    d = loop_gain_exponents(ev)
    rows = np.nonzero((v > 0) & (v < UNSTABLE_VIOLATION))[0]
    if not rows.size or not d.any():
        return EstimateMove(out, v_out, alpha, mask)
    if per_loop:
        dirs = _violating_loops(ev, tuned[rows], d)
        done = _move(ev, tuned, rows, dirs, g0, (out, v_out, alpha, mask))
        rows = rows[~done]  # where the violating loops alone do not get there: every loop together
    if rows.size:
        _move(ev, tuned, rows, np.broadcast_to(d, (rows.size, d.size)), g0, (out, v_out, alpha, mask))
    return EstimateMove(out, v_out, alpha, mask)


def _violating_loops(ev: Evaluator, tuned: np.ndarray, d: np.ndarray) -> np.ndarray:
    """(B, d) per-row direction: the exponents of the loops whose own break point misses a requirement
    (every loop's, ``d``, on a row where no single loop is to blame)."""
    from gaintune.evaluation.boundary_loops import loop_directions, loop_shortfalls

    flags = loop_shortfalls(ev, tuned) > 0
    dirs = np.minimum(flags.astype(float) @ loop_directions(ev), 1.0)
    none = ~dirs.any(axis=1)
    dirs[none] = d
    return dirs


def _move(ev: Evaluator, tuned: np.ndarray, rows: np.ndarray, dirs: np.ndarray, g0: np.ndarray,
          into: tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]) -> np.ndarray:
    """Move ``tuned[rows]`` along their directions ``dirs`` (one row each) onto the boundary, writing the rows
    that land feasibly into ``into`` = (gains, violation, alpha, moved); returns which of ``rows`` landed."""
    out, v_out, alpha, mask = into
    done = np.zeros(rows.size, dtype=bool)
    br = _ladder(ev, tuned[rows], dirs, g0[rows])
    found = np.nonzero(br.found)[0]
    if not found.size:
        return done
    br, dirs = br.subset(br.found), dirs[br.found]
    _regula_falsi(ev, br, dirs)
    moved = br.t * np.exp(br.xg)[:, None] ** dirs
    ok = ev.requirement_scores(moved)[0] <= 0  # the full estimate, stability included, decides
    land = rows[found[ok]]
    out[land] = moved[ok]
    v_out[land] = 0.0
    alpha[land] = np.exp(br.xg[ok])
    mask[land] = True
    done[found[ok]] = True
    return done


@dataclass
class _Bracket:
    """Per candidate, a bracket in x = log alpha: its feasible end ``xg`` (shortfall ``gg`` <= 0) and infeasible end
    ``xb`` (shortfall ``gb``); ``found`` where the ladder found a feasible scale at all."""

    t: np.ndarray
    xg: np.ndarray
    gg: np.ndarray
    xb: np.ndarray
    gb: np.ndarray
    found: np.ndarray

    def subset(self, rows: np.ndarray) -> _Bracket:
        """The brackets of ``rows`` only (a boolean mask or indices; copies)."""
        return _Bracket(self.t[rows], self.xg[rows], self.gg[rows], self.xb[rows], self.gb[rows], self.found[rows])


def _ladder(ev: Evaluator, t: np.ndarray, d: np.ndarray, g0: np.ndarray) -> _Bracket:
    """Bracket the boundary of each candidate in ``t`` with the :data:`LADDER` of scales.

    ``d``: the move's exponents, (n,) for every candidate or one row per candidate. The largest feasible
    scale brackets the boundary with the rung before it. The single-loop estimate scores every rung in one
    batch; a MIMO check costs a whole loop analysis per row, so there the rungs are scored one at a time,
    each only on the rows no earlier rung made feasible: the same bracket from fewer checks.
    """
    x_floor = np.log(alpha_floor(ev.layout, t, d))
    xs = np.maximum(np.log1p(-np.array(LADDER))[None, :], x_floor[:, None])  # (n, L)
    n, n_ladder = xs.shape
    dd = np.broadcast_to(d, t.shape)[:, None, :]  # one direction per candidate
    trial = t[:, None, :] * np.exp(xs)[..., None] ** dd  # (n, L, d)
    lv, lg = np.full((n, n_ladder), np.inf), np.full((n, n_ladder), np.inf)
    # the root find checks margins only (stability is 2/3 of the estimate's cost); the answer is checked in full
    if not ev.is_mimo:
        v, g = ev.requirement_scores(trial.reshape(n * n_ladder, -1), stability=False)
        lv, lg = v.reshape(n, n_ladder), g.reshape(n, n_ladder)
    else:
        open_ = np.arange(n)
        for k in range(n_ladder):
            lv[open_, k], lg[open_, k] = ev.requirement_scores(trial[open_, k], stability=False)
            open_ = open_[lv[open_, k] > 0]
            if not open_.size:
                break
    ok = lv <= 0
    first = np.argmax(ok, axis=1)  # the largest feasible scale on the ladder
    i = np.arange(n)
    prev = np.maximum(first - 1, 0)
    return _Bracket(t=t, xg=xs[i, first], gg=lg[i, first], xb=np.where(first > 0, xs[i, prev], 0.0),
                    gb=np.where(first > 0, lg[i, prev], g0), found=np.asarray(ok.any(axis=1)))


def _regula_falsi(ev: Evaluator, br: _Bracket, d: np.ndarray, steps: int = SECANT_STEPS) -> None:
    """Close each bracket onto ``g = -TOL/2`` with ``steps`` safeguarded steps (in place): regula falsi for
    the first :data:`SECANT_STEPS`, its Illinois form after them.

    A step whose secant is undefined, or whose infeasible end is unstable, bisects instead. Plain regula
    falsi keeps one end for good where the shortfall bends inside the bracket (another peak taking over at
    the limit, on a PID loop): each step then moves the other end a few per cent of the bracket only. The
    Illinois form halves the weight of an end kept twice running, so the trials cross the boundary and the
    bracket closes. The first :data:`SECANT_STEPS` are the search repair's, unchanged.
    """
    xg, gg, xb, gb = br.xg, br.gg, br.xb, br.gb
    dd = np.broadcast_to(d, br.t.shape)  # one direction per candidate
    target = -0.5 * TOL
    wg, wb = np.ones(xg.shape), np.ones(xg.shape)  # Illinois weights of each end's distance to the target
    last = np.zeros(xg.shape, dtype=np.int8)  # the end the previous trial replaced: 1 feasible, -1 infeasible
    for step in range(steps):
        act = gg < -TOL  # rows whose feasible end is still too far inside
        if not act.any():
            break
        with np.errstate(all="ignore"):
            if step < SECANT_STEPS:  # the weighted form below with unit weights, written as before: the same bits
                xs_ = xg + (target - gg) * (xb - xg) / (gb - gg)
            else:
                hg, hb = (gg - target) * wg, (gb - target) * wb
                xs_ = xg - hg * (xb - xg) / (hb - hg)
        bisect = ~np.isfinite(xs_) | (gb >= UNSTABLE_VIOLATION)
        xm = np.where(bisect, 0.5 * (xg + xb), xs_)
        w = xb - xg  # keep the trial strictly inside the bracket
        xm = np.clip(xm, xg + 0.02 * w, xb - 0.02 * w)
        a = np.nonzero(act)[0]
        tv, tg = ev.requirement_scores(br.t[a] * np.exp(xm[a])[:, None] ** dd[a], stability=False)
        good = tv <= 0
        xg[a] = np.where(good, xm[a], xg[a])
        gg[a] = np.where(good, tg, gg[a])
        xb[a] = np.where(good, xb[a], xm[a])
        gb[a] = np.where(good, gb[a], tg)
        wg[a] = np.where(good, 1.0, np.where(last[a] == -1, 0.5 * wg[a], wg[a]))
        wb[a] = np.where(good, np.where(last[a] == 1, 0.5 * wb[a], wb[a]), 1.0)
        last[a] = np.where(good, 1, -1)
