"""``POST /v1/simulate``: closed-loop traces and metrics of gains on the spec's scenarios (nominal plant)."""

from __future__ import annotations

import logging

from fastapi import APIRouter, Request, Response

from gaintune_api.compute import compute_simulate
from gaintune_api.deps import SettingsDep, require_key, run_compute, run_pooled
from gaintune_api.jsonbody import StrictJSONRoute
from gaintune_api.problem_details import ApiError
from gaintune_api.schemas import SimulateRequest, SimulateResponse
from gaintune_api.validation import checked_spec

router = APIRouter(prefix="/v1", tags=["simulate"], route_class=StrictJSONRoute, dependencies=[require_key])
log = logging.getLogger("gaintune.api")


@router.post(
    "/simulate",
    response_model=SimulateResponse,
    summary="Simulate gains on the spec's scenarios; traces decimated to max_points",
    responses={422: {"description": "Invalid spec, gains or scenario names.",
                     "content": {"application/problem+json": {}}}},
)
async def simulate(body: SimulateRequest, request: Request, settings: SettingsDep) -> Response:
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
    # the worker's JSON bytes as they are: validating and encoding 128,000 samples again cost ~300 ms
    return Response(data, media_type="application/json")
