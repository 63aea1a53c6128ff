"""The search box and start gains of a problem, chosen by the requirements (not by one rule).

Every optimiser searches one box per problem: log-scale bounds on the tuned gains, the
same for RL, the black-box baselines and the reference, so their costs compare like with
like. Bounds the spec gives are kept. Elsewhere the box is centred on the best design we
know before any search, ranked like every search ranks (feasibility first, then cost):

1. every classical rule that applies (SIMC, AMIGO, IMC, Ziegler-Nichols step and
   ultimate-gain rules), each applied inner loop first (:func:`gaintune.classical.rule_candidates`);
2. each of them with every loop's gains scaled by 1/16 ... 16 (steps of sqrt 2): detuned, an
   aggressive rule may meet the requirements; boosted, a timid one (IMC on a process with a
   slow pole) reaches the performance the requirements allow. All candidates are scored in one
   batched evaluation.

3. when no rule applies to a PID spec (an open-loop unstable or oscillatory path, a double
   integrator), a scrambled Sobol sample of :data:`GRID_POINTS` gain sets spread log-uniformly
   over the layout's default bounds (scipy's ``qmc.Sobol``, seeded by ``search.seed``): the
   best of them centres the box instead of the middle of 1e-3 .. 1e3. LQ specs keep their
   Riccati-based defaults.

The chosen design is the start point of every search (the RL policy's action 0, CMA-ES's
mean, Nelder-Mead's first vertex), and the search never loses it: it is scored like any
other candidate. A SIMC rule built on the half-sample delay of a delay-free plant (far too
aggressive), or one that destabilises a deep cascade, is no longer the centre just because
it came first. :class:`SearchBox` records what was chosen and why.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from gaintune.cache import LRU
from gaintune.classical import BOUNDS_FACTOR, auto_bounds, rule_candidates
from gaintune.controllers.layout import GainLayout
from gaintune.objective import Evaluator
from gaintune.plants import build_plant
from gaintune.plants.plant import Plant
from gaintune.sim import Simulator
from gaintune.spec import TuningSpec

__all__ = ["SearchBox", "SCALES", "GRID_POINTS", "search_box", "search_layout", "make_evaluator"]

#: Gain sets sampled when no classical rule applies (a power of two, as Sobol sampling wants).
GRID_POINTS = 1024

#: Scales tried on every rule's gains (every loop at once): 1/16 ... 16 in steps of sqrt(2).
SCALES = tuple(float(2.0 ** (k / 2)) for k in range(-8, 9))


@dataclass
class SearchBox:
    """The default box of a problem and how its centre was chosen.

    Attributes
    ----------
    layout
        The gain layout with the box as its bounds (spec bounds kept).
    centre
        The start gains ``{loop: {gain: value}}``, or None when no rule applies (the layout's
        fixed default bounds are used).
    source
        e.g. ``"amigo"`` or ``"simc x 0.5"``; None without a rule.
    feasible
        Whether the start gains meet every requirement by the search's estimate.
    candidates
        ``{name: (feasible, violation, cost)}`` of everything scored.
    """

    layout: GainLayout
    centre: dict[str, dict[str, float]] | None
    source: str | None
    feasible: bool
    candidates: dict[str, tuple[bool, float, float]] = field(default_factory=dict)


def _scale(gains: dict[str, dict[str, float]], a: float, spec: TuningSpec) -> dict[str, dict[str, float]]:
    """Every loop's controller gains times ``a`` (ideal form: Kp only; Ti, Td are times)."""
    out = {}
    for loop in spec.loops:
        g = gains[loop.name]
        keep = {"Ti", "Td"} if loop.form == "ideal" else set()
        out[loop.name] = {k: (v if k in keep else v * a) for k, v in g.items()}
    return out


def _sobol_candidates(layout: GainLayout, seed: int) -> dict[str, dict[str, dict[str, float]]]:
    """:data:`GRID_POINTS` gain sets, log-uniform over the layout's bounds (a scrambled Sobol sample)."""
    from scipy.stats import qmc

    u = qmc.Sobol(d=layout.n_tuned, scramble=True, seed=seed).random(GRID_POINTS)
    tuned = layout.action_to_tuned(2.0 * u - 1.0)
    return {f"grid {i}": layout.to_dict(layout.full(t)) for i, t in enumerate(tuned)}


#: Boxes of recent specs: one tune asks for its box from the env, the baselines and the report.
_BOXES: LRU[str, SearchBox] = LRU(16)


def search_box(spec: TuningSpec, plant: Plant) -> SearchBox:
    """Choose the start gains and the box around them (see the module docstring).

    The box depends on the spec alone (the plant is built from it), so it is computed once per
    spec content and shared (treat the returned object as read-only).
    """
    return _BOXES.get_or_build(spec.content_hash(), lambda: _search_box(spec, plant))


def _search_box(spec: TuningSpec, plant: Plant) -> SearchBox:
    plain = GainLayout(spec, plant.states, plant=plant)
    rules = rule_candidates(spec, plant)
    if not rules and (any(lp.is_lq for lp in spec.loops) or plain.n_tuned == 0):
        return SearchBox(plain, None, None, False)
    ev = Evaluator(spec, Simulator(spec, plant, plain))

    def score(named: dict[str, dict[str, dict[str, float]]]) -> list[tuple[float, str, dict, bool, float, float]]:
        names = list(named)
        tuned = np.array([plain.from_dict(named[n])[plain.tuned_idx] for n in names])
        s = ev.evaluate(tuned)
        return [(float(s.merit[i]), n, named[n], bool(s.feasible[i]), float(s.violation[i]), float(s.cost[i]))
                for i, n in enumerate(names)]

    if rules:
        named = {(m if a == 1.0 else f"{m} x {a:.3g}"): _scale(g, a, spec) for m, g in rules.items() for a in SCALES}
    else:
        named = _sobol_candidates(plain, spec.search.seed)
    scored = score(named)
    best = min(scored, key=lambda r: r[0])
    _, source, centre, feasible, _, _ = best
    layout = GainLayout(spec, plant.states, auto_bounds=auto_bounds(spec, centre, BOUNDS_FACTOR), plant=plant)
    return SearchBox(layout, centre, source, feasible, {r[1]: (r[3], r[4], r[5]) for r in scored})


def search_layout(spec: TuningSpec, plant: Plant) -> GainLayout:
    """The layout every optimiser shares: spec bounds, else the box of :func:`search_box`."""
    return search_box(spec, plant).layout


def make_evaluator(spec: TuningSpec, plant: Plant | None = None) -> Evaluator:
    """An :class:`~gaintune.objective.Evaluator` on the problem's default search box."""
    plant = plant if plant is not None else build_plant(spec.plant)
    return Evaluator(spec, Simulator(spec, plant, search_layout(spec, plant)))
