"""``POST /v1/simulate``: closed-loop traces and metrics of gains on the spec's scenarios (nominal plant)."""

from __future__ import annotations

import logging
import math

import numpy as np
from fastapi import APIRouter, Request

from api.compute import compute_simulate
from api.deps import SettingsDep, require_key, run_compute, run_pooled
from api.jsonbody import StrictJSONRoute
from api.problems import ApiError
from api.schemas import ScenarioTrace, SimulateRequest, SimulateResponse
from api.validation import checked_spec

router = APIRouter(prefix="/v1", tags=["simulate"], route_class=StrictJSONRoute, dependencies=[require_key])
log = logging.getLogger("gaintune.api")


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


@router.post(
    "/simulate",
    response_model=SimulateResponse,
    summary="Simulate gains on the spec's scenarios; traces decimated to max_points",
    responses={422: {"description": "Invalid spec, gains or scenario names.", "content": {"application/problem+json": {}}}},
)
async def simulate(body: SimulateRequest, request: Request, settings: SettingsDep) -> SimulateResponse:
    """Nominal-plant closed-loop traces (``y.<loop>``, ``sp.<loop>``, ``u``) and metrics per scenario."""
    checked = await checked_spec(request, body.spec, "simulate")
    spec = body.spec
    names = [sc.name for sc in spec.scenarios]
    if body.scenarios is not None:
        unknown = [n for n in body.scenarios if n not in names]
        if unknown:
            raise ApiError(422, "Unknown scenario name(s).",
                           errors=[{"loc": "scenarios", "msg": f"unknown {unknown}; the spec has {names}"}])
        chosen = [i for i, n in enumerate(names) if n in body.scenarios]
    else:
        chosen = list(range(len(names)))
    max_points = min(body.max_points, settings.simulate_max_points)
    args = (spec, body.gains, chosen, max_points)
    out = await run_pooled(request, compute_simulate, *args)
    if out is None:
        out = await run_compute(request, compute_simulate, *args, checked.plant, checked.layout)
    tag, data = out
    if tag == "gains":
        raise ApiError(422, "The gains are invalid for this spec.", errors=data)
    if tag != "ok":
        raise ApiError(422, "These gains could not be simulated for this spec.", errors=[{"loc": "gains", "msg": data}])
    return data


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
        sc = spec.scenarios[i]
        idx, stride = decimate(len(res.t), max_points)
        traces = {k: [_num(v) for v in arr[0, idx]] for k, arr in res.traces.items()}
        metrics = {k: (bool(v[0]) if v.dtype == bool else _num(v[0])) for k, v in res.metrics.items()}
        n = saturation_switches(res.traces["u"][0], spec.actuator.limits)  # from the full trace, not the decimated one
        metrics.update(saturation_switches=n, chattering=n >= CHATTER_SWITCHES)
        out.append(ScenarioTrace(name=sc.name, dt=sc.dt, n_steps=sc.n_steps, stride=stride,
                                 t=[float(x) for x in res.t[idx]], traces=traces, metrics=metrics))
    return SimulateResponse(gains=ctx.layout.to_dict(full), max_points=max_points, scenarios=out)
