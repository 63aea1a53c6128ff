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
   best of them centres the box instead of the middle of 1e-3 .. 1e3. Sampled gain sets that
   overshoot a requirement are first moved onto its boundary
   (:func:`gaintune.evaluation.boundary_estimate.onto_boundary_estimate`),
   and :data:`ZOOM_STAGES` smaller samples around the best so far walk the centre toward the
   optimum (one unlucky best sample had Kd 50x below the optimum's, outside the final box).
   LQ specs keep their Riccati-based defaults.

Candidates are ranked on the search's aimed limits (``requirements.backoff`` inside the exact
ones), as every search ranks them.

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
from gaintune.classical.mimo_rules import loop_rule_candidates
from gaintune.controllers.layout import GainLayout
from gaintune.evaluation.boundary_estimate import onto_boundary_estimate
from gaintune.evaluation.evaluator import Evaluator
from gaintune.plants import build_plant
from gaintune.plants.plant import Plant
from gaintune.sim import Simulator
from gaintune.sim.simulator import needs_mimo
from gaintune.spec import Gains, TuningSpec
from gaintune.spec.backoff import BackoffSpec

__all__ = ["SearchBox", "SCALES", "GRID_POINTS", "ZOOM_STAGES", "ZOOM_POINTS", "ZOOM_STARTS", "search_box",
           "search_layout", "make_evaluator"]

#: Gain sets sampled when no classical rule applies (a power of two, as Sobol sampling wants).
GRID_POINTS = 1024

#: Zoom stages after the Sobol sample: each samples :data:`ZOOM_POINTS` gain sets in a box of
#: +-sqrt(BOUNDS_FACTOR) around the best so far, so the centre walks toward the optimum before
#: the final box (+-BOUNDS_FACTOR) is drawn around it.
ZOOM_STAGES = 3
ZOOM_POINTS = 64
#: Zoom walks start from this many distinct good Sobol designs (different valleys).
ZOOM_STARTS = 3

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
    sims
        Closed-loop simulations spent choosing the box (a search counts them against its budget).
    """

    layout: GainLayout
    centre: Gains | None
    source: str | None
    feasible: bool
    candidates: dict[str, tuple[bool, float, float]] = field(default_factory=dict)
    sims: int = 0


def _scale(gains: Gains, a: float, spec: TuningSpec) -> Gains:
    """Every loop's controller gains times ``a`` (ideal form: Kp only; Ti, Td are times)."""
    out = {}
    for name, loop in zip(spec.loop_names, spec.loops, strict=True):
        keep = {"Ti", "Td"} if loop.form == "ideal" else set()
        out[name] = {k: (v if k in keep else v * a) for k, v in gains[name].items()}
    return out


def _sobol_candidates(
    layout: GainLayout, seed: int, n: int = GRID_POINTS, prefix: str = "grid"
) -> dict[str, Gains]:
    """``n`` gain sets, log-uniform over the layout's bounds (a scrambled Sobol sample)."""
    from scipy.stats import qmc

    u = qmc.Sobol(d=layout.n_tuned, scramble=True, seed=seed).random(n)
    tuned = layout.action_to_tuned(2.0 * u - 1.0)
    return {f"{prefix} {i}": layout.to_dict(layout.full(t)) for i, t in enumerate(tuned)}


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
    # several inputs or a loop graph: the single-input rules loop by loop, where each loop has its own path
    rules = loop_rule_candidates(spec, plant) if needs_mimo(spec, plant) else rule_candidates(spec, plant)
    if not rules and (any(lp.is_lq for lp in spec.loops) or plain.n_tuned == 0):
        return SearchBox(plain, None, None, False)
    ev = Evaluator(spec, Simulator(spec, plant, plain))

    def score(named: dict[str, Gains], project: bool) -> list[tuple[float, str, dict, bool, float, float]]:
        names = list(named)
        tuned = np.array([plain.from_dict(named[n])[plain.tuned_idx] for n in names])
        violation = None
        # sampled gains that overshoot a requirement are scored on its boundary (gaintune.evaluation.boundary_estimate)
        if project:
            r = onto_boundary_estimate(ev, tuned)
            tuned, violation = r.tuned, r.violation
            named = {n: plain.to_dict(plain.full(t)) for n, t in zip(names, tuned, strict=True)}
        s = ev.evaluate(tuned, violation=violation)
        return [(float(s.merit[i]), n, named[n], bool(s.feasible[i]), float(s.violation[i]), float(s.cost[i]))
                for i, n in enumerate(names)]

    if rules:  # the rules tune the loops; tuned static-block entries (a feedforward) start at their spec values
        start = plain.to_dict(plain.full(plain.initial_tuned()))
        blocks = {k: v for k, v in start.items() if k not in spec.loop_names}
        named = {(m if a == 1.0 else f"{m} x {a:.3g}"): {**_scale(g, a, spec), **blocks}
                 for m, g in rules.items() for a in SCALES}
        scored = score(named, project=False)
    else:
        seed = spec.search.seed
        grid = score(_sobol_candidates(plain, seed), project=True)
        scored = list(grid)
        for k, start in enumerate(_distinct_starts(plain, grid, ZOOM_STARTS)):
            walk = [start]
            for stage in range(ZOOM_STAGES):
                centre = min(walk, key=lambda r: r[0])[2]
                zoom = GainLayout(spec, plant.states, auto_bounds=auto_bounds(spec, centre, BOUNDS_FACTOR), plant=plant)
                label = f"zoom{k + 1}.{stage + 1}"
                walk += score(_sobol_candidates(zoom, seed + 1 + stage + 10 * k, ZOOM_POINTS, label), project=True)
            scored += walk[1:]
    best = min(scored, key=lambda r: r[0])
    _, source, centre, feasible, _, _ = best
    layout = GainLayout(spec, plant.states, auto_bounds=auto_bounds(spec, centre, BOUNDS_FACTOR), plant=plant)
    return SearchBox(layout, centre, source, feasible, {r[1]: (r[3], r[4], r[5]) for r in scored}, ev.n_sims)


def _distinct_starts(layout: GainLayout, scored: list, n: int) -> list:
    """The ``n`` best-ranked scored designs that lie in different regions (every pair differs by more
    than BOUNDS_FACTOR in some gain), so the zoom walks explore different valleys."""
    out: list = []
    logs: list[np.ndarray] = []
    for r in sorted(scored, key=lambda r: r[0]):
        x = np.log(np.abs(layout.from_dict(r[2])[layout.tuned_idx]) + 1e-300)
        if all(np.max(np.abs(x - y)) > np.log(BOUNDS_FACTOR) for y in logs):
            out.append(r)
            logs.append(x)
            if len(out) == n:
                break
    return out


def search_layout(spec: TuningSpec, plant: Plant) -> GainLayout:
    """The layout every optimiser shares: spec bounds, else the box of :func:`search_box`."""
    return search_box(spec, plant).layout


def make_evaluator(spec: TuningSpec, plant: Plant | None = None, exact: bool = False) -> Evaluator:
    """An :class:`~gaintune.evaluation.evaluator.Evaluator` on the problem's default search box.

    ``exact``: its requirement estimate (and a :func:`gaintune.evaluation.boundary_exact.onto_boundary_exact` on it)
    judges the
    exact limits, without ``requirements.backoff``, in the same box: for the benchmark reference,
    which is the exact-limit optimum.
    """
    plant = plant if plant is not None else build_plant(spec.plant)
    layout = search_layout(spec, plant)
    if exact:
        req = spec.requirements.model_copy(update={"backoff": BackoffSpec.model_validate(0)})
        spec = spec.model_copy(update={"requirements": req})
    return Evaluator(spec, Simulator(spec, plant, layout))
