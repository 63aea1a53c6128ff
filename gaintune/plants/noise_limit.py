"""The noise-sensitivity limit of each loop: the spec's ``requirements.mks_max``, with ``auto`` resolved from the plant.

Mks is the peak gain from a loop's measurement noise to the plant input (SISO: ``max |C S|``).
Where the plant itself bounds how fast a loop can be (dead time, or a path whose phase falls
below -90 degrees at high frequency), the sensitivity limit Ms binds first and no noise limit
is needed. Where nothing does - a **delay-free, stable path of relative degree <= 1**, such
as a tank level or a motor current - a PI loop meets any Ms limit with an ever higher gain,
and without a noise limit the answer is set by the sample time (the half-sample delay of the
hold is then the only "dead time" left). ``auto`` gives exactly those loops the limit

    Mks <= AUTO_SPEEDUP / |K|,      K = the path's static gain (u -> the loop's measurement),

i.e. at high frequency the controller amplifies noise at most ``AUTO_SPEEDUP`` times the
inverse plant gain; for a first-order path ``K/(T s + 1)`` under PI the closed loop is then
at most about ``AUTO_SPEEDUP + 1`` times faster than the open loop. The limit depends on the
plant alone, so such a loop gets the same design at any sample time fast enough for it.

Integrating or unstable paths have no static gain to scale by; ``auto`` then sets no limit
and says so (:func:`noise_limits` returns the reason), so an engineer can give a number.
Only numpy is used (this runs on every verification).
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from gaintune.lti.modes import observable_split
from gaintune.plants.plant import LinearModel
from gaintune.spec import TuningSpec

__all__ = ["AUTO_SPEEDUP", "NoiseLimit", "noise_limits", "path_relative_degree"]

#: ``auto``: the controller's noise gain may reach this many times the inverse static plant gain.
AUTO_SPEEDUP = 10.0


class NoiseLimit(NamedTuple):
    """One loop's noise-sensitivity limit and where it comes from."""

    limit: float | None
    #: ``spec``, ``auto: ...`` or why there is none
    source: str
    #: something the engineer should be told in the report (a limit they may want to set), else None
    note: str | None = None


def path_relative_degree(A: np.ndarray, B: np.ndarray, c: np.ndarray, d: float, max_degree: int = 2) -> int:
    """Relative degree of ``c (sI - A)^-1 B + d`` from its Markov parameters (capped at ``max_degree``).

    The Markov parameters ``d, cB, cAB, ...`` do not depend on the realisation, so a
    non-minimal model (other outputs' states) gives the same answer.
    """
    scale = max(float(np.max(np.abs(A))) if A.size else 0.0, 1.0)
    if abs(d) > 1e-12 * max(abs(d), float(np.linalg.norm(c)) * float(np.linalg.norm(B)), 1e-300):
        return 0
    v = B[:, 0] if B.ndim == 2 else B
    for k in range(1, max_degree):
        m = float(c @ v)
        if abs(m) > 1e-9 * float(np.linalg.norm(c)) * float(np.linalg.norm(v)) and m != 0.0:
            return k
        v = A @ v / scale
    return max_degree


def _auto(lin: LinearModel, out: int) -> NoiseLimit:
    """The ``auto`` limit of the path u -> output ``out`` (see the module docstring)."""
    if lin.delay > 0:
        return NoiseLimit(None, "auto: none (the plant's dead time bounds the loop's speed)")
    A, B, c, d = lin.A, lin.B, lin.C[out], float(lin.D[out, 0])
    split = observable_split(A, c[None, :]) if A.size else None
    if split is not None:  # modes this output does not see (e.g. a motor's position, seen from its current)
        V1 = split[0]
        A, B, c = V1.T @ A @ V1, V1.T @ B, c @ V1
    if path_relative_degree(A, B, c, d) > 1:
        return NoiseLimit(None, "auto: none (the path's phase lag bounds the loop's speed)")
    eig = np.linalg.eigvals(A) if A.size else np.zeros(0)
    scale = max(1.0, float(np.max(np.abs(eig)))) if eig.size else 1.0
    if eig.size and np.max(eig.real) > -1e-9 * scale:
        return NoiseLimit(None, "auto: none (integrating or unstable path)",
                          "no automatic noise-sensitivity limit (a delay-free integrating or unstable path has no "
                          "static gain to scale by); set requirements.mks_max to limit the noise gain")
    K = d - float(c @ np.linalg.solve(A, B[:, 0])) if A.size else d
    if not np.isfinite(K) or K == 0.0:
        return NoiseLimit(None, "auto: none (the path has no static gain)")
    return NoiseLimit(
        AUTO_SPEEDUP / abs(K), f"auto: {AUTO_SPEEDUP:g}/|K|, K = {K:.4g} (delay-free path of relative degree <= 1)"
    )


def noise_limits(spec: TuningSpec, lin: LinearModel) -> list[NoiseLimit]:
    """Per loop (outer first): the noise-sensitivity limit and where it comes from.

    LQ loops have none (their feedback is the whole state, not one measurement).
    ``lin``: the nominal linear model (the limit is a property of the plant, not of a
    randomised sample).
    """
    req = spec.requirements.mks_max
    out: list[NoiseLimit] = []
    for loop in spec.loops:
        if loop.is_lq:
            out.append(NoiseLimit(None, "none for an LQ loop"))
        elif req is None:
            out.append(NoiseLimit(None, "none (requirements.mks_max is null)"))
        elif isinstance(req, dict):
            v = req.get(loop.name) if loop.name is not None else None
            out.append(NoiseLimit(float(v), "spec") if v is not None else NoiseLimit(None, "none for this loop"))
        elif req == "auto":
            out.append(_auto(lin, lin.outputs.index(loop.measure) if loop.measure in lin.outputs else 0))
        else:
            out.append(NoiseLimit(float(req), "spec"))
    return out
