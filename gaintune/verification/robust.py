"""The robust sample set: box corners of the randomised parameters (and delay) plus Monte-Carlo draws."""

from __future__ import annotations

import itertools

import numpy as np

from gaintune.sim.draws import draw_dist as _draw
from gaintune.spec import DistSpec, TuningSpec

__all__ = ["robust_samples", "MAX_CORNERS", "DELAY_KEY"]

#: Most box corners used (a random subset when 2^d is larger).
MAX_CORNERS = 256
#: Key of the delay in a sample dict.
DELAY_KEY = "__delay__"


def robust_samples(spec: TuningSpec) -> tuple[list[dict[str, float]], int, int]:
    """Samples as dicts {param: value} (delay under :data:`DELAY_KEY`), n_corners, n_monte_carlo.

    Seeded from ``spec.search.seed``; the same spec always gives the same set.
    """
    dims: list[tuple[str, DistSpec]] = list(spec.randomize.params.items())
    if spec.randomize.delay is not None:
        dims.append((DELAY_KEY, spec.randomize.delay))
    if not dims:
        return [], 0, 0
    rng = np.random.default_rng(spec.search.seed)
    boxes = [d.box for _, d in dims]
    n_all = 2 ** len(dims)
    if n_all <= MAX_CORNERS:
        corners = list(itertools.product(*boxes))
    else:
        bits = rng.integers(0, 2, size=(MAX_CORNERS, len(dims)))
        corners = [tuple(boxes[j][b] for j, b in enumerate(row)) for row in bits]
    samples = [dict(zip([k for k, _ in dims], map(float, c))) for c in corners]
    n_mc = spec.verify.robust_samples
    if n_mc:
        cols = {k: _draw(d, rng, n_mc) for k, d in dims}
        samples += [{k: float(cols[k][i]) for k in cols} for i in range(n_mc)]
    for s in samples:
        if DELAY_KEY in s:
            s[DELAY_KEY] = max(0.0, s[DELAY_KEY])
    return samples, len(corners), n_mc
