"""Domain logic of ``POST /v1/simulate``: traces and metrics of gains on a spec's scenarios.

Kept out of the route so that the compute pool (``gaintune_api.compute``) and the route both import
downward, from here.
"""

from __future__ import annotations

import math

import numpy as np

from gaintune_api.schemas import ScenarioTrace, SimulateResponse

__all__ = ["decimate", "simulate_response"]


def _num(x: float):
    x = float(x)
    if math.isfinite(x):
        return x
    return "NaN" if math.isnan(x) else ("Infinity" if x > 0 else "-Infinity")


def decimate(n: int, max_points: int) -> tuple[np.ndarray, int]:
    """Indices of every stride-th sample, plus the last one, at most ``max_points`` in all."""
    if n <= max_points:
        return np.arange(n), 1
    stride = math.ceil((n - 1) / (max_points - 1))
    idx = np.arange(0, n, stride)
    if idx[-1] != n - 1:
        idx = np.append(idx, n - 1)
    return idx, stride


def simulate_response(spec, gains, chosen: list[int], max_points: int, plant=None, layout=None) -> SimulateResponse:
    """Traces and metrics of ``gains`` on the chosen scenarios (the spec's cached simulator)."""
    from gaintune.sim.chatter import CHATTER_SWITCHES, saturation_switches
    from gaintune.verify.context import spec_context

    ctx = spec_context(spec, plant, layout)
    full = ctx.layout.from_dict(gains)
    sim = ctx.simulator(spec)
    if sim is None:
        raise RuntimeError("the simulator (gaintune.sim) is not available")
    out = []
    for i in chosen:
        res = sim.run(full[None, :], scenario=i, traces=True)
        sc = sim.spec.scenarios[i]  # dt/horizon derived from the plant where the spec left them out
        idx, stride = decimate(len(res.t), max_points)
        traces = {k: [_num(v) for v in arr[0, idx]] for k, arr in res.traces.items()}
        metrics = {k: (bool(v[0]) if v.dtype == bool else _num(v[0])) for k, v in res.metrics.items()}
        n = saturation_switches(res.traces["u"][0], spec.actuator.limits)  # from the full trace, not the decimated one
        metrics.update(saturation_switches=n, chattering=n >= CHATTER_SWITCHES)
        out.append(ScenarioTrace(name=sc.name, dt=sc.dt, n_steps=sc.n_steps, stride=stride,
                                 t=[float(x) for x in res.t[idx]], traces=traces, metrics=metrics))
    return SimulateResponse(gains=ctx.layout.to_dict(full), max_points=max_points, scenarios=out)
