"""The move onto the requirement boundary: scale the loop gain, at two fidelities.

A constrained optimum lies on an active requirement (Ms = 1.4, not 1.36), and a gain set just
across the boundary is infeasible however good its cost. Both steps that move gains onto the
boundary move them along one direction, the **loop-gain scale**: every tuned gain that scales a
PID controller is multiplied by ``alpha**d`` (``d = 1`` on Kp, Ki and Kd of a parallel loop, on
Kp of an ideal loop, 0 elsewhere), which multiplies the controller, hence its loop transfer
function, by alpha. Margins and peaks move monotonically with alpha near the boundary of a
well-posed design, so a one-dimensional root find on alpha lands on it.

The two fidelities of that move:

* :func:`gaintune.evaluation.boundary_estimate.onto_boundary_estimate`: on the search's fast
  requirement estimate (:meth:`gaintune.evaluation.evaluator.Evaluator.requirement_scores`),
  batched, for many candidates at once: the RL search's samples (``search.repair``) and the
  search box's Sobol samples;
* :func:`gaintune.evaluation.boundary_exact.onto_boundary_exact`: on the exact verification,
  for one answer: the last step of every search (pull an infeasible answer inside, push an
  almost-active one out).

Both aim at the same boundary, each limit moved ``requirements.backoff`` inside the limit the
verdict judges. This module holds what they share: the move's exponents and the box's bound on it.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

if TYPE_CHECKING:  # pragma: no cover
    from gaintune.evaluation.evaluator import Evaluator

__all__ = ["loop_gain_exponents", "alpha_floor", "alpha_ceiling"]


def loop_gain_exponents(ev: Evaluator, loop: str | None = None) -> np.ndarray:
    """(d,) exponents of the loop-gain move ``tuned * alpha**d``: 1 on the gains that scale a PID
    controller (Kp, Ki, Kd of a parallel loop; Kp of an ideal one), of ``loop``, or of every PID loop
    when None (0 for LQ loops)."""
    out = np.zeros(ev.layout.n_tuned)
    forms = {lp.name: lp.form for lp in ev.spec.loops if not lp.is_lq and (loop is None or lp.name == loop)}
    for k, slot in enumerate(ev.layout.tuned_slots):
        form = forms.get(slot.loop_name)
        if form is not None and (slot.name == "Kp" or (form == "parallel" and slot.name in ("Ki", "Kd"))):
            out[k] = 1.0
    return out


def alpha_floor(layout, tuned: np.ndarray, d: np.ndarray) -> np.ndarray:
    """(B,) smallest alpha <= 1 that keeps each row of ``tuned * alpha**d`` (B, n) inside the search box;
    0 where ``d`` moves nothing. ``d`` is (n,) or one row per gain set."""
    lo, hi = np.exp(layout.log_lo), np.exp(layout.log_hi)
    tuned = np.atleast_2d(tuned)
    d = np.broadcast_to(d, tuned.shape)
    with np.errstate(divide="ignore", invalid="ignore"):
        lim = np.where(d > 0, lo / tuned, np.where(d < 0, tuned / hi, -np.inf)).max(axis=1)
    return np.where(np.isfinite(lim), np.minimum(lim, 1.0), 0.0)


def alpha_ceiling(layout, tuned: np.ndarray, d: np.ndarray) -> np.ndarray:
    """(B,) largest alpha >= 1 that keeps each row of ``tuned * alpha**d`` inside the search box (the mirror of
    :func:`alpha_floor`; inf where ``d`` moves nothing up)."""
    hi = np.exp(layout.log_hi)
    tuned = np.atleast_2d(tuned)
    with np.errstate(divide="ignore", invalid="ignore"):
        lim = np.where(d > 0, hi / tuned, np.inf).min(axis=1)
    return np.maximum(lim, 1.0)
