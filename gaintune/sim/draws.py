"""Episode draws: the randomised plant parameters, delay, actuator limits, reference and disturbance.

A :class:`Draws` holds one row per simulated candidate. ``nominal`` gives the
spec's own values; ``sample`` draws from ``spec.randomize`` with a numpy
Generator, so seeded runs are reproducible. ``context`` normalises a draw into
the observation a policy conditions on.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from gaintune.plants.plant import Plant
from gaintune.spec import DistSpec, TuningSpec

__all__ = ["Draws", "REF_KINDS", "nominal", "draw_dist", "sample", "corners", "context", "context_size", "take"]

#: Reference kinds a draw can select; -1 keeps the scenario's own profile.
REF_KINDS = ("step", "ramp", "impulse")


@dataclass(frozen=True)
class Draws:
    """Per-candidate draws, all arrays of length B (params: (B, P))."""

    params: np.ndarray
    delay: np.ndarray
    act_scale: np.ndarray
    ref_kind: np.ndarray  # int: index into REF_KINDS, or -1 = scenario's own
    ref_amp: np.ndarray  # NaN = scenario's own
    dist_size: np.ndarray  # NaN = scenario's own
    dist_time: np.ndarray  # NaN = scenario's own
    noise_seed: np.ndarray  # int64

    def __len__(self) -> int:
        return int(self.delay.shape[0])


def nominal(spec: TuningSpec, plant: Plant, n: int = 1, seed: int = 0) -> Draws:
    """The spec's nominal values, repeated n times."""
    p = np.tile(plant.param_vector(), (n, 1))
    nan = np.full(n, np.nan)
    return Draws(
        params=p,
        delay=np.full(n, plant.delay()),
        act_scale=np.ones(n),
        ref_kind=np.full(n, -1, dtype=np.int64),
        ref_amp=nan.copy(),
        dist_size=nan.copy(),
        dist_time=nan.copy(),
        noise_seed=np.arange(seed, seed + n, dtype=np.int64),
    )


def draw_dist(d: DistSpec, rng: np.random.Generator, n: int) -> np.ndarray:
    """n samples of one spec distribution (uniform, log-uniform or normal)."""
    if d.dist == "uniform":
        return rng.uniform(_given(d.low), _given(d.high), n)
    if d.dist == "loguniform":
        return np.exp(rng.uniform(np.log(_given(d.low)), np.log(_given(d.high)), n))
    return rng.normal(_given(d.mean), _given(d.std), n)


def _given(x: float | None) -> float:
    # DistSpec's validator requires the fields of its distribution; None here is a bug, not input
    if x is None:
        raise ValueError("a distribution without the bounds its kind needs")
    return x


def sample(spec: TuningSpec, plant: Plant, rng: np.random.Generator, n: int) -> Draws:
    """Draw n episodes from ``spec.randomize`` (nominal where nothing is randomised)."""
    rz = spec.randomize
    base = nominal(spec, plant, n)
    params = base.params.copy()
    names = plant.param_names
    for name, dist in rz.params.items():
        params[:, names.index(name)] = draw_dist(dist, rng, n)
    delay = np.maximum(draw_dist(rz.delay, rng, n), 0.0) if rz.delay else base.delay
    scale = np.maximum(draw_dist(rz.actuator_scale, rng, n), 1e-6) if rz.actuator_scale else base.act_scale
    kinds = (
        np.array([REF_KINDS.index(k) for k in rz.reference_kinds])[rng.integers(0, len(rz.reference_kinds), n)]
        if rz.reference_kinds
        else base.ref_kind
    )
    amp = draw_dist(rz.reference_amplitude, rng, n) if rz.reference_amplitude else base.ref_amp
    dsize = draw_dist(rz.disturbance_size, rng, n) if rz.disturbance_size else base.dist_size
    dtime = np.maximum(draw_dist(rz.disturbance_time, rng, n), 0.0) if rz.disturbance_time else base.dist_time
    seeds = rng.integers(0, 2**62, n, dtype=np.int64)
    return Draws(params, delay, scale, kinds.astype(np.int64), amp, dsize, dtime, seeds)


def corners(spec: TuningSpec, plant: Plant, max_corners: int = 256) -> Draws:
    """Corners of the randomised parameter/delay box (robust verification)."""
    rz = spec.randomize
    axes: list[tuple[str, tuple[float, float]]] = [(k, d.box) for k, d in rz.params.items()]
    if rz.delay:
        axes.append(("__delay__", rz.delay.box))
    if not axes:
        return nominal(spec, plant, 1)
    n = min(2 ** len(axes), max_corners)
    base = nominal(spec, plant, n)
    params = base.params.copy()
    delay = base.delay.copy()
    names = plant.param_names
    for i in range(n):
        for a, (name, (lo, hi)) in enumerate(axes):
            v = hi if (i >> a) & 1 else lo
            if name == "__delay__":
                delay[i] = max(v, 0.0)
            else:
                params[i, names.index(name)] = v
    return replace(base, params=params, delay=delay)


def take(d: Draws, idx: np.ndarray) -> Draws:
    """Rows ``idx`` of a draw (e.g. to repeat each draw for several candidates)."""
    return Draws(*(getattr(d, f)[idx] for f in Draws.__dataclass_fields__))


def context_size(spec: TuningSpec) -> int:
    """Length of the observation vector built by :func:`context`."""
    rz = spec.randomize
    return max(
        1,
        len(rz.params) + (1 if rz.delay else 0) + (1 if rz.actuator_scale else 0)
        + (len(REF_KINDS) if rz.reference_kinds else 0) + (1 if rz.reference_amplitude else 0)
        + (1 if rz.disturbance_size else 0) + (1 if rz.disturbance_time else 0),
    )


def context(spec: TuningSpec, plant: Plant, d: Draws) -> np.ndarray:
    """Normalised episode context, (B, context_size) in about [-1, 1]; a constant 0 when nothing is randomised."""
    rz = spec.randomize
    cols: list[np.ndarray] = []

    def norm(v: np.ndarray, dist: DistSpec) -> np.ndarray:
        lo, hi = dist.box
        if dist.dist == "loguniform":
            v, lo, hi = np.log(v), np.log(lo), np.log(hi)
        return np.clip(2 * (v - lo) / max(hi - lo, 1e-12) - 1, -3, 3)

    names = plant.param_names
    for name, dist in rz.params.items():
        cols.append(norm(d.params[:, names.index(name)], dist))
    if rz.delay:
        cols.append(norm(d.delay, rz.delay))
    if rz.actuator_scale:
        cols.append(norm(d.act_scale, rz.actuator_scale))
    if rz.reference_kinds:
        for i in range(len(REF_KINDS)):
            cols.append((d.ref_kind == i).astype(float))
    drawn = ((rz.reference_amplitude, d.ref_amp), (rz.disturbance_size, d.dist_size),
             (rz.disturbance_time, d.dist_time))
    for box, v in drawn:
        if box is not None:
            # NaN = "the scenario's own value" (the nominal draw): the centre of the box, 0, as the
            # policy's input must be a number (a NaN observation made torch refuse the policy)
            with np.errstate(invalid="ignore"):
                cols.append(np.where(np.isnan(v), 0.0, norm(v, box)))
    if not cols:
        return np.zeros((len(d), 1), dtype=np.float32)
    return np.stack(cols, axis=1).astype(np.float32)
