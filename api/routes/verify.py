"""``POST /v1/verify``: synchronous verification of gains against a spec.

Computed in the compute pool (:mod:`gaintune_api.compute`).
"""

from __future__ import annotations

import hashlib
import json
import logging

from fastapi import APIRouter, Request, Response

from gaintune.cache import LRU
from gaintune.verification import VerificationReport
from gaintune_api.compute import compute_verify
from gaintune_api.deps import SettingsDep, require_key, run_compute, run_pooled
from gaintune_api.jsonbody import StrictJSONRoute
from gaintune_api.problem_details import ApiError
from gaintune_api.schemas import VerifyRequest
from gaintune_api.validation import checked_spec

router = APIRouter(prefix="/v1", tags=["verify"], route_class=StrictJSONRoute, dependencies=[require_key])
log = logging.getLogger("gaintune.api")


def _cache(request: Request) -> LRU[str, bytes]:
    """The app's LRU of serialized reports keyed by (spec hash, gains, options), created on first use.

    Verification is deterministic, so an identical request gets the stored bytes. Sized by
    ``settings.verify_cache_size`` (0: nothing is stored)."""
    st = request.app.state
    if getattr(st, "verify_cache", None) is None:
        st.verify_cache = LRU(st.settings.verify_cache_size)  # only the event loop calls this: no race
    return st.verify_cache


@router.post(
    "/verify",
    response_model=VerificationReport,
    summary="Verify gains: stability, margins, robustness, nonlinear check, verdict",
    responses={422: {"description": "Invalid spec or gains.", "content": {"application/problem+json": {}}}},
)
async def verify_gains(body: VerifyRequest, request: Request, settings: SettingsDep) -> Response:
    """Returns the VerificationReport. Non-finite figures (e.g. an infinite gain margin) are the strings
    ``"Infinity"``/``"-Infinity"``."""
    spec_hash = body.spec.content_hash()
    checked = await checked_spec(request, body.spec, "verify", spec_hash=spec_hash)
    key = hashlib.sha256(
        json.dumps([spec_hash, body.gains, body.robust, body.nonlinear], sort_keys=True).encode()
    ).hexdigest()
    cache = _cache(request)
    hit = cache.get(key)
    if hit is not None:
        return Response(hit, media_type="application/json", headers={"X-Cache": "hit"})
    args = (body.spec, body.gains, body.robust, body.nonlinear)
    out = await run_pooled(request, compute_verify, *args, None, None, spec_hash, ref=(0, spec_hash))
    if out is None:  # no pool: compute here (in a thread), reusing the validated plant and layout
        out = await run_compute(request, compute_verify, *args, checked.plant, checked.layout, spec_hash)
    tag, data = out
    if tag == "gains":
        raise ApiError(422, "The gains are invalid for this spec.", errors=data)
    if tag != "ok":
        raise ApiError(422, "These gains could not be verified for this spec.", errors=[{"loc": "gains", "msg": data}])
    cache.put(key, data)
    return Response(data, media_type="application/json", headers={"X-Cache": "miss"})
