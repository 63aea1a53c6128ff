"""The tuner's gain box: the classical starts over the family's corners, widened by :data:`WIDEN` each way.

Each corner context (and the centre) gets the start every search starts from
(:func:`gaintune.evaluation.search_box.search_box`: the best classical rule by the requirements,
detuned until feasible); the tuner's box spans all of them, widened by :data:`WIDEN` each way.
A tight box matters: the policy explores in it, and a box of many decades turns a small
exploration noise into a large gain change.
"""

from __future__ import annotations

import itertools
import warnings

import numpy as np

from gaintune.evaluation.search_box import search_box
from gaintune.plants import build_plant
from gaintune.tuners.problems import GainBox, TunerProblem

__all__ = ["fit_box", "corner_contexts", "WIDEN"]

#: Factor each way around the span of the classical starts.
WIDEN = 8.0


def corner_contexts(problem: TunerProblem, max_corners: int = 16) -> list[dict[str, float]]:
    """The centre and up to ``max_corners`` corners of the context ranges."""
    out = [problem.centre()]
    for combo in itertools.islice(itertools.product(*[(v.lo, v.hi) for v in problem.variables]), max_corners):
        out.append({v.name: float(x) for v, x in zip(problem.variables, combo, strict=True)})
    return out


def fit_box(problem: TunerProblem) -> GainBox:
    """The union of the search boxes at :func:`corner_contexts` (log bounds per tuned gain)."""
    problem.box = None
    slots: tuple[tuple[str, str], ...] | None = None
    lo: np.ndarray | None = None
    hi: np.ndarray | None = None
    for ctx in corner_contexts(problem):
        spec = problem.spec_at(ctx)
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")  # FOTD fits of stiff corners warn about conditioning
            sb = search_box(spec, build_plant(spec.plant))
        layout = sb.layout
        here = tuple((s.loop_name, s.name) for s in layout.tuned_slots)
        bounds = np.array([s.bounds for s in layout.tuned_slots], dtype=float)
        # the classical start (the box's geometric middle when no rule applies), kept inside the search box
        mid = np.sqrt(bounds[:, 0] * bounds[:, 1])
        c = np.array([abs(sb.centre[lp][g]) if sb.centre and g in sb.centre.get(lp, {}) else m
                      for (lp, g), m in zip(here, mid, strict=True)])
        b = np.log(np.column_stack([np.maximum(c / WIDEN, bounds[:, 0]), np.minimum(c * WIDEN, bounds[:, 1])]))
        if slots is None:
            slots, lo, hi = here, b[:, 0], b[:, 1]
        else:
            assert lo is not None and hi is not None and here == slots
            lo, hi = np.minimum(lo, b[:, 0]), np.maximum(hi, b[:, 1])
    assert slots is not None and lo is not None and hi is not None
    from gaintune.evaluation.boundary import loop_gain_exponents
    from gaintune.evaluation.evaluator import Evaluator

    axis = loop_gain_exponents(Evaluator(problem.spec_at(problem.centre())))
    box = GainBox(slots, lo, hi, axis)
    problem.box = box
    return box
