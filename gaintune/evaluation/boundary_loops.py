"""Which loops violate: per-loop requirement shortfalls and loop-gain directions, for the per-loop repair.

The RL search's repair (:func:`gaintune.evaluation.boundary_estimate.onto_boundary_estimate`) moves a
stable, infeasible sample onto the requirement boundary along a loop-gain scale. Scaling **every**
loop together is the right move for one loop, and for a cascade whose loops are all too aggressive;
a sample of many gains usually has one or two loops past a limit and the others well inside. The
per-loop move scales only the loops whose own break point (the loop's controller output, all other
loops closed) or own noise sensitivity misses a requirement, so a policy that pushes one loop too
far is not charged for the others.

Everything here works on any :class:`~gaintune.controllers.layout.GainLayout`: loops are taken from
the layout's slots (it orders gains per loop), and break points are matched to loops by name.
"""

from __future__ import annotations

import numpy as np

from gaintune.evaluation.boundary import loop_gain_exponents
from gaintune.evaluation.evaluator import Evaluator
from gaintune.verification.quick import FEASIBILITY_MARGIN, MAX_TERM, margin_terms, noise_limit_array, quick_margins

__all__ = ["loop_names", "loop_directions", "loop_shortfalls"]


def loop_names(ev: Evaluator) -> list[str]:
    """Names of the loops that own tuned gains, in the layout's order."""
    return list(dict.fromkeys(s.loop_name for s in ev.layout.tuned_slots))


def loop_directions(ev: Evaluator) -> np.ndarray:
    """(n_loops, d) exponents of each loop's own loop-gain move (rows of :func:`loop_names`; zero for LQ loops)."""
    names = loop_names(ev)
    if not names:
        return np.zeros((0, ev.layout.n_tuned))
    return np.array([loop_gain_exponents(ev, name) for name in names])


def loop_shortfalls(ev: Evaluator, tuned: np.ndarray) -> np.ndarray:
    """(B, n_loops) signed shortfall of each loop at its own break point (> 0: that loop misses a requirement).

    The worst over the requirement terms at the loop's controller-output break and its Mks, on every
    constraint model, with the search's aimed limits (``requirements.backoff``). Stability is not
    checked (an unstable loop is the caller's business: the repair leaves it alone).
    """
    tuned = np.atleast_2d(np.asarray(tuned, dtype=float))
    names = loop_names(ev)
    spec = ev.spec.model_copy(update={"requirements": ev.spec.requirements.aimed()})
    req = spec.requirements
    aim = ev.spec.requirements.backoff.aim
    noise = np.array([aim("mks_max", x) for x in noise_limit_array(ev.spec, ev.plant)])
    has_noise = np.isfinite(noise)
    peaks = tuple(n for n, on in (("ms", req.ms_max is not None), ("mt", req.mt_max is not None),
                                  ("mks", bool(has_noise.any()))) if on)
    full = ev.layout.full(tuned)
    out = np.full((len(tuned), len(names)), -np.inf)
    for lin in ev.constraint_models:
        q = quick_margins(spec, ev.plant, ev.layout, full, lin, stability=False, peaks=peaks)
        col = {loop: k for k, (loop, where) in enumerate(q.breaks) if where == "controller_output"}
        with np.errstate(all="ignore"):
            for j, name in enumerate(names):
                if name not in col:
                    continue
                i = col[name]  # the loop's row of the cascade: its break, its Mks and its noise limit
                parts = [t[:, i] for t in margin_terms(req, q)]
                if i < q.mks.shape[1] and has_noise[i]:
                    parts.append((q.mks[:, i] - noise[i]) / noise[i])
                for t in parts:
                    t = np.nan_to_num(t, nan=MAX_TERM, posinf=MAX_TERM, neginf=-MAX_TERM)
                    out[:, j] = np.maximum(out[:, j], np.minimum(t + FEASIBILITY_MARGIN, MAX_TERM))
    return out
