"""Operations: ``/healthz`` (liveness), ``/readyz`` (storage writable, workers heartbeating, warm-up),
``/metrics`` (Prometheus)."""

from __future__ import annotations

from typing import Annotated

from fastapi import APIRouter, Request, Security
from fastapi.responses import JSONResponse, PlainTextResponse
from pydantic import Field

from gaintune_api.deps import SettingsDep, api_key_header, check_key
from gaintune_api.schemas import Health, Ready
from gaintune_api.storage_faults import StorageFault

router = APIRouter(tags=["ops"])


class Readiness(Ready):
    """``Ready`` with what readiness is made of, and why it is not ready."""

    database_writable: bool = Field(description="A one-row write to the job database committed just now.")
    data_dir_writable: bool = Field(description="One byte was written, synced and removed in the data directory.")
    workers_unresponsive: int = Field(
        0, description="Worker processes that exist but have not beaten their pulse for worker_liveness_timeout "
        "(frozen, e.g. SIGSTOP); they are killed and restarted after heartbeat_timeout.")
    warmed_up: bool = True
    reasons: list[str] = Field(default_factory=list, description="Why the server is not ready (empty when ready).")


@router.get("/healthz", response_model=Health, summary="Liveness")
async def healthz() -> Health:
    """The process answers (liveness only; readiness is /readyz)."""
    return Health()


@router.get("/readyz", response_model=Readiness,
            summary="Readiness: database and data directory writable, every worker heartbeating, warmed up",
            responses={503: {"model": Readiness, "description": "Not ready; `reasons` says why."}})
def readyz(request: Request) -> JSONResponse:
    """Ready only when a job could be accepted, run and saved now: each check really writes (a row, a byte),
    and a worker counts as alive only while its pulse is fresh (a frozen process does not)."""
    st = request.app.state
    reasons: list[str] = []
    db, depth = True, 0
    try:
        st.store.ping()
        depth = st.store.counts()["queued"]
    except Exception as exc:  # noqa: BLE001 - any failure means not ready, and says why
        db = False
        reasons.append(f"database unreadable: {exc}")
    checks = {}
    for name, probe in (("database", st.store.probe_write), ("data directory", st.files.probe)):
        try:
            probe()
            checks[name] = True
        except StorageFault as fault:
            checks[name] = False
            reasons.append(f"{fault.cause}: {fault.detail}")
        except Exception as exc:  # noqa: BLE001 - any failure means not ready, and says why
            checks[name] = False
            reasons.append(f"{name} not writable: {type(exc).__name__}: {exc}")
    sup = st.supervisor
    alive = sup.alive if sup is not None else 0
    frozen = sup.unresponsive if sup is not None else 0
    configured = st.settings.workers
    if alive < configured:
        reasons.append(f"{alive} of {configured} workers alive"
                       + (f" ({frozen} unresponsive: frozen?)" if frozen else ""))
    warm = st.warm.is_set()
    if not warm:
        reasons.append("warming up")
    ok = not reasons
    body = Readiness(status="ready" if ok else "not_ready", database=db, workers_alive=alive,
                     workers_configured=configured, queue_depth=depth, database_writable=checks["database"],
                     data_dir_writable=checks["data directory"], workers_unresponsive=frozen, warmed_up=warm,
                     reasons=reasons)
    return JSONResponse(body.model_dump(), status_code=200 if ok else 503,
                        headers=None if ok else {"Retry-After": str(st.settings.retry_after)})


@router.get("/metrics", response_class=PlainTextResponse, summary="Prometheus metrics",
            responses={200: {"content": {"text/plain": {}}}})
def metrics(request: Request, settings: SettingsDep,
            key: Annotated[str | None, Security(api_key_header)] = None) -> PlainTextResponse:
    """Request, job, worker and compute-pool metrics in the Prometheus text format."""
    if not settings.metrics_public:
        check_key(settings, key)
    st = request.app.state
    counts = st.store.counts()
    sup = st.supervisor
    text = st.metrics.render(counts, counts["queued"], sup.alive if sup else 0, settings.workers,
                             sup.restarts if sup else 0, workers_unresponsive=sup.unresponsive if sup else 0,
                             frozen_kills=sup.frozen_kills if sup else 0,
                             database_writable=None if sup is None else sup.db_fault is None)
    return PlainTextResponse(text, media_type="text/plain; version=0.0.4; charset=utf-8")
