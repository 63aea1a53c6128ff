"""Operations: ``/healthz`` (liveness), ``/readyz`` (database, workers, warm-up), ``/metrics`` (Prometheus)."""

from __future__ import annotations

from typing import Annotated

from fastapi import APIRouter, Request, Security
from fastapi.responses import JSONResponse, PlainTextResponse

from api.deps import SettingsDep, api_key_header, check_key
from api.schemas import Health, Ready

router = APIRouter(tags=["ops"])


@router.get("/healthz", response_model=Health, summary="Liveness")
async def healthz() -> Health:
    return Health()


@router.get("/readyz", response_model=Ready, summary="Readiness: database reachable, workers alive, warmed up",
            responses={503: {"model": Ready, "description": "Not ready."}})
def readyz(request: Request) -> JSONResponse:
    st = request.app.state
    try:
        st.store.ping()
        db = True
        depth = st.store.counts()["queued"]
    except Exception:  # noqa: BLE001
        db, depth = False, 0
    sup = st.supervisor
    alive = sup.alive if sup is not None else 0
    configured = st.settings.workers
    ok = db and alive == configured and st.warm.is_set()
    body = Ready(status="ready" if ok else "not_ready", database=db, workers_alive=alive,
                 workers_configured=configured, queue_depth=depth)
    return JSONResponse(body.model_dump(), status_code=200 if ok else 503)


@router.get("/metrics", response_class=PlainTextResponse, summary="Prometheus metrics",
            responses={200: {"content": {"text/plain": {}}}})
def metrics(request: Request, settings: SettingsDep,
            key: Annotated[str | None, Security(api_key_header)] = None) -> PlainTextResponse:
    if not settings.metrics_public:
        check_key(settings, key)
    st = request.app.state
    counts = st.store.counts()
    sup = st.supervisor
    text = st.metrics.render(counts, counts["queued"], sup.alive if sup else 0, settings.workers,
                             sup.restarts if sup else 0)
    return PlainTextResponse(text, media_type="text/plain; version=0.0.4; charset=utf-8")
