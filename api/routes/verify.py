"""``POST /v1/verify``: synchronous verification of gains against a spec (runs in the thread pool)."""

from __future__ import annotations

import hashlib
import json
import logging
import threading
from collections import OrderedDict

from fastapi import APIRouter, Request, Response

from api.deps import SettingsDep, require_key, run_compute
from api.jsonbody import StrictJSONRoute
from api.problems import ApiError
from api.schemas import VerifyRequest
from api.validation import check_spec
from gaintune.errors import GaintuneError, problem_details
from gaintune.verify import VerificationReport

router = APIRouter(prefix="/v1", tags=["verify"], route_class=StrictJSONRoute, dependencies=[require_key])
log = logging.getLogger("gaintune.api")


class ReportCache:
    """LRU of serialized reports keyed by (spec hash, gains, options): verification is deterministic."""

    def __init__(self, size: int) -> None:
        self.size = size
        self._d: OrderedDict[str, bytes] = OrderedDict()
        self._lock = threading.Lock()

    def get(self, key: str) -> bytes | None:
        with self._lock:
            v = self._d.get(key)
            if v is not None:
                self._d.move_to_end(key)
            return v

    def put(self, key: str, value: bytes) -> None:
        if self.size <= 0:
            return
        with self._lock:
            self._d[key] = value
            self._d.move_to_end(key)
            while len(self._d) > self.size:
                self._d.popitem(last=False)


def _cache(request: Request) -> ReportCache:
    st = request.app.state
    if getattr(st, "verify_cache", None) is None:
        st.verify_cache = ReportCache(st.settings.verify_cache_size)
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
    return await run_compute(request, _verify, body, request, settings)


def _verify(body: VerifyRequest, request: Request, settings) -> Response:
    checked = check_spec(body.spec, settings, "verify", prefix="spec")
    key = hashlib.sha256(
        json.dumps([body.spec.content_hash(), body.gains, body.robust, body.nonlinear], sort_keys=True).encode()
    ).hexdigest()
    cache = _cache(request)
    hit = cache.get(key)
    if hit is not None:
        return Response(hit, media_type="application/json", headers={"X-Cache": "hit"})
    from gaintune.verify import verify

    try:
        report = verify(body.spec, body.gains, robust=body.robust, nonlinear=body.nonlinear,
                        plant=checked.plant, layout=checked.layout)
    except GaintuneError as exc:
        raise ApiError(422, "The gains are invalid for this spec.", errors=problem_details(exc)) from None
    except Exception as exc:  # noqa: BLE001 - user input must never produce a 500
        log.warning("verify failed unexpectedly", exc_info=True)
        raise ApiError(422, "These gains could not be verified for this spec.",
                       errors=[{"loc": "gains", "msg": f"{type(exc).__name__}: {str(exc)[:300]}"}]) from None
    data = report.model_dump_json().encode()
    cache.put(key, data)
    return Response(data, media_type="application/json", headers={"X-Cache": "miss"})
