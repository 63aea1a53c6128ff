"""Jobs: ``POST /v1/tune`` queues a tuning job (``POST /v1/tuners`` a tuner's training, :mod:`.tuners`);
``/v1/jobs`` lists, reads, cancels and serves their artifacts."""

from __future__ import annotations

from datetime import UTC, datetime
from pathlib import Path
from typing import Annotated, Any

from fastapi import APIRouter, Body, Header, Query, Response
from fastapi.responses import FileResponse, HTMLResponse

from gaintune.search.result import TuneResult
from gaintune.spec import TuningSpec
from gaintune_api.artifacts import EXPORT_MEDIA, export_gains, export_verdict, render_report, render_report_html
from gaintune_api.deps import FilesDep, OwnerDep, SettingsDep, StoreDep
from gaintune_api.job_store import IdempotencyConflict, JobRow, QueueFull, loads
from gaintune_api.jobfiles import ArtifactMismatch, ArtifactMissing
from gaintune_api.jsonbody import StrictJSONRoute
from gaintune_api.problem_details import ApiError, log
from gaintune_api.schemas import (
    ExportFormat,
    JobList,
    JobPublic,
    JobResultPublic,
    JobStatus,
    JobSummary,
    ProgressPublic,
    TunerPublic,
)
from gaintune_api.validation import check_spec

router = APIRouter(prefix="/v1", tags=["jobs"], route_class=StrictJSONRoute)

_PROBLEM: dict[str, Any] = {"content": {"application/problem+json": {}}}
NOT_FOUND: dict[int | str, dict[str, Any]] = {404: {"description": "No such job (for this API key).", **_PROBLEM}}
STORAGE: dict[int | str, dict[str, Any]] = {
    503: {"description": "Storage fault (read-only database or data directory; `cause` names it); "
                         "retry after Retry-After seconds.", **_PROBLEM},
    507: {"description": "Storage full (`cause` names which); retry after Retry-After seconds.", **_PROBLEM}}


def _ts(x: float | None) -> datetime | None:
    return None if x is None else datetime.fromtimestamp(x, tz=UTC)


def _progress(row: JobRow) -> ProgressPublic | None:
    p = loads(row.progress)
    if not p:
        return None
    budget = int(p.get("budget") or 0)
    sims = int(p.get("sims") or 0)
    fraction = min(1.0, sims / budget) if budget else 0.0
    episodes, total = p.get("episodes"), p.get("episodes_total")
    if row.kind == "tuner":  # a training's progress is in episodes; its simulations have no budget
        fraction = min(1.0, int(episodes or 0) / int(total)) if total else 0.0
    return ProgressPublic(
        sims=sims, budget=budget, fraction=fraction, best_cost=p.get("best_cost"),
        elapsed=float(p.get("elapsed") or 0.0), eta=p.get("eta"), phase=str(p.get("phase") or "search"),
        episodes=episodes, episodes_total=total, median_ratio=p.get("median_ratio"),
    )


def _agent_file(row: JobRow, result: dict[str, Any], jobs_dir: Path) -> Path | None:
    path = result.get("agent_path")
    if not path:
        return None
    p = Path(path).resolve()
    root = (jobs_dir / row.id).resolve()
    if root not in p.parents or not p.is_file():
        return None
    return p


def _summary_fields(row: JobRow) -> dict[str, Any]:
    return dict(
        id=row.id, kind=row.kind, status=row.status, spec_name=row.spec_name, spec_hash=row.spec_hash,
        created_at=_ts(row.created_at), updated_at=_ts(row.updated_at), started_at=_ts(row.started_at),
        finished_at=_ts(row.finished_at), progress=_progress(row), cancel_requested=row.cancel_requested_at is not None,
        attempts=row.attempts, error=row.error,
    )


def to_public(row: JobRow, jobs_dir: Path) -> JobPublic:
    base = f"/v1/jobs/{row.id}"
    links = {"self": base}
    result = None
    tuner = None
    r = loads(row.result)
    if r is not None:
        agent = _agent_file(row, r, jobs_dir) is not None
        if row.kind == "tuner":
            tuner = TunerPublic.model_validate(r["tuner"])
            links["query"] = f"/v1/tuners/job:{row.id}/query"
        else:
            result = _result_public(_tune_result(r), agent)
            links.update(report=f"{base}/report", export=f"{base}/export?format=json")
        if agent:
            links["agent"] = f"{base}/agent"
    return JobPublic(**_summary_fields(row), result=result, tuner=tuner, links=links)


def _get(store, job_id: str, owner: str) -> JobRow:
    row = store.get(job_id, owner)
    if row is None:
        raise ApiError(404, f"No job {job_id!r}.")
    return row


@router.post(
    "/tune",
    status_code=202,
    response_model=JobPublic,
    summary="Queue a tuning job",
    responses={
        202: {"description": "Accepted; poll the URL in the Location header."},
        409: {"description": "Idempotency-Key reused with a different spec.", **_PROBLEM},
        413: {"description": "Body too large.", **_PROBLEM},
        422: {"description": "Invalid spec (field paths in `errors`).", **_PROBLEM},
        **STORAGE,
        503: {"description": "Queue full, or a storage fault (`cause` names it); retry after Retry-After seconds.",
              **_PROBLEM},
    },
)
def submit_tune(
    spec: Annotated[TuningSpec, Body(description="The tuning problem (gaintune spec schema).")],
    response: Response,
    settings: SettingsDep,
    store: StoreDep,
    files: FilesDep,
    owner: OwnerDep,
    idempotency_key: Annotated[str | None, Header(alias="Idempotency-Key", max_length=200)] = None,
) -> JobPublic:
    """Validate the spec fully (schema, limits, plant build, names, gain layout) and queue it.

    A retried request with the same ``Idempotency-Key`` (per API key) returns the same job. A data
    directory that cannot be written (read-only, full) is refused with 503/507 before anything is stored.
    """
    check_spec(spec, settings, "tune")
    # A job whose folder cannot be written would only fail later: refuse it now, naming the fault
    # (StorageFault -> 503 read-only / 507 full, with its cause and Retry-After).
    files.probe()
    try:
        row, created = store.create(owner, spec.model_dump_json(), spec.content_hash(), spec.name,
                                    idem_key=idempotency_key, max_queue=settings.max_queue)
    except QueueFull:
        raise ApiError(503, f"The job queue is full ({settings.max_queue} jobs); retry later.",
                       headers={"Retry-After": str(settings.retry_after)}) from None
    except IdempotencyConflict as exc:
        raise ApiError(409, f"Idempotency-Key was already used for job {exc.args[0]} with a different spec.") from None
    response.headers["Location"] = f"/v1/jobs/{row.id}"
    if not created:
        response.headers["Idempotent-Replayed"] = "true"
    return to_public(row, settings.jobs_dir)


@router.get("/jobs", response_model=JobList, summary="List your jobs (newest first)")
def list_jobs(
    settings: SettingsDep,
    store: StoreDep,
    owner: OwnerDep,
    status: JobStatus | None = None,
    limit: Annotated[int, Query(ge=1, le=200)] = 50,
    offset: Annotated[int, Query(ge=0, le=10_000_000)] = 0,
) -> JobList:
    """Your jobs, newest first, optionally of one status; ``next_offset`` pages on."""
    rows, total = store.list(owner, status, limit, offset)
    items = [JobSummary(**_summary_fields(r)) for r in rows]
    nxt = offset + len(rows) if offset + len(rows) < total else None
    return JobList(items=items, total=total, limit=limit, offset=offset, next_offset=nxt)


@router.get("/jobs/{job_id}", response_model=JobPublic, responses=NOT_FOUND, summary="Status, progress and result")
def get_job(job_id: str, settings: SettingsDep, store: StoreDep, owner: OwnerDep) -> JobPublic:
    """Status and progress; once finished, the result: accepted gains (only on a `pass` verdict),
    verification report, metrics, training curve and provenance."""
    return to_public(_get(store, job_id, owner), settings.jobs_dir)


@router.delete(
    "/jobs/{job_id}",
    response_model=JobPublic,
    responses={**NOT_FOUND, 202: {"description": "Cancellation accepted; the running job ends `cancelled` (its "
                                            "search stops within seconds)."},
               409: {"description": "The job already finished.", **_PROBLEM}, **STORAGE},
    summary="Cancel a job",
)
def cancel_job(job_id: str, response: Response, settings: SettingsDep, store: StoreDep, owner: OwnerDep) -> JobPublic:
    """Queued jobs are cancelled at once (200). Running ones are signalled (202) and end `cancelled`:
    their search stops within ``cancel_grace`` seconds, and one that finished before it saw the request
    is still recorded as `cancelled` (its result kept). One transaction decides, so a job that finished
    first gives 409."""
    before = _get(store, job_id, owner)  # a read: a finished job gets its 409 even when the database is read-only
    if before.status in ("succeeded", "failed", "cancelled"):
        raise ApiError(409, f"Job {job_id} already finished ({before.status}).")
    row, accepted = store.request_cancel(job_id, owner)
    if row is None:
        raise ApiError(404, f"No job {job_id!r}.")
    if not accepted:
        raise ApiError(409, f"Job {job_id} already finished ({row.status}).")
    if row.status == "running":
        response.status_code = 202
    return to_public(row, settings.jobs_dir)


def _finished_result(row: JobRow) -> dict[str, Any]:
    r = loads(row.result)
    if r is None:
        raise ApiError(409, f"Job {row.id} has no result (status: {row.status}).")
    return r


def _tuning_result(row: JobRow) -> dict[str, Any]:
    """A finished tuning job's result; 409 for a tuner-training job (it has a tuner, no gains)."""
    if row.kind == "tuner":
        raise ApiError(409, f"Job {row.id} trained a tuner: it has no gains to report or export; query it at "
                            f"POST /v1/tuners/job:{row.id}/query.")
    return _finished_result(row)


def _tune_result(r: dict[str, Any]) -> TuneResult:
    return TuneResult.model_validate(r)


def _result_public(result: TuneResult, agent_available: bool) -> JobResultPublic:
    """The job's answer, read from the result model: its verdict and accepted gains are the model's."""
    fields = result.model_dump(include=set(JobResultPublic.model_fields))
    return JobResultPublic.model_validate({**fields, "verdict": result.verdict, "accepted_gains": result.accepted_gains,
                                          "agent_available": agent_available})


@router.get("/jobs/{job_id}/report", response_class=HTMLResponse, summary="HTML report of a finished job",
            responses={**NOT_FOUND, 409: {"description": "No result yet.", **_PROBLEM},
                       501: {"description": "Reports not installed.", **_PROBLEM}, **STORAGE})
def job_report(job_id: str, store: StoreDep, files: FilesDep, owner: OwnerDep) -> Response:
    """Rendered on first request and cached in the job's folder. If the data directory cannot be written
    (read-only or full), the report is rendered in memory and served uncached (``X-Report-Cache: off``)."""
    from gaintune_api.storage_faults import StorageFault

    row = _get(store, job_id, owner)
    r = _tuning_result(row)
    path = files.job_dir(row.id) / "report.html"
    if path.is_file():
        return FileResponse(path, media_type="text/html; charset=utf-8")
    result = _tune_result(r)
    try:
        path = files.write_report(row.id, lambda tmp: render_report(result, tmp))
    except StorageFault as fault:
        html = render_report_html(result)
        if html is None:
            raise
        log.warning("report of job %s served uncached: %s", row.id, fault)
        return HTMLResponse(html, headers={"X-Report-Cache": f"off ({fault.cause})"})
    return FileResponse(path, media_type="text/html; charset=utf-8")


def _checked_agent(row: JobRow, files) -> tuple[Path, str | None, dict[str, Any]]:
    """(path, SHA-256, result) of a finished job's agent, checked against the digest recorded when it finished."""
    r = _finished_result(row)
    if not r.get("agent_path"):
        raise ApiError(409, f"Job {row.id} saved no agent.")
    try:
        path, digest = files.artifact(row.id, Path(r["agent_path"]).name, loads(row.artifacts))
    except ArtifactMissing as exc:
        raise ApiError(410, f"The agent of job {row.id} was saved, but its file is gone: {exc}.") from None
    except ArtifactMismatch as exc:
        log.error("job %s: %s", row.id, exc)
        raise ApiError(500, f"The agent file of job {row.id} was changed after the job finished: {exc}.",
                       title="Stored artefact does not match", extra={"cause": "artifact-mismatch"}) from None
    return path, digest, r


@router.get("/jobs/{job_id}/agent", summary="Trained SB3 agent (zip)",
            responses={**NOT_FOUND, 200: {"content": {"application/zip": {}}},
                       409: {"description": "No result, or the job saved no agent.", **_PROBLEM},
                       410: {"description": "The agent file is gone from the data directory.", **_PROBLEM},
                       500: {"description": "The agent file does not match the one the job saved "
                             "(`cause`: artifact-mismatch).", **_PROBLEM}})
def job_agent(job_id: str, store: StoreDep, files: FilesDep, owner: OwnerDep) -> Response:
    """The file is checked against the SHA-256 recorded when the job finished (sent as ``Repr-Digest``)."""
    import base64

    row = _get(store, job_id, owner)
    path, digest, _ = _checked_agent(row, files)
    headers = {}
    if digest is not None:
        headers["Repr-Digest"] = f"sha-256=:{base64.b64encode(bytes.fromhex(digest)).decode()}:"
        headers["ETag"] = f'"{digest}"'
    return FileResponse(path, media_type="application/zip", filename=f"agent_{row.id}.zip", headers=headers)


@router.get("/jobs/{job_id}/export",
            summary="Gains exported as json, yaml, C, MATLAB or Python, verified at the export dt",
            responses={**NOT_FOUND,
                       409: {"description": "No result, or the gains' verdict at this dt is not pass.", **_PROBLEM},
                       422: {"description": "Bad format or dt (the field is named in `errors`).", **_PROBLEM},
                       501: {"description": "Exports not installed.", **_PROBLEM}})
def job_export(
    job_id: str,
    settings: SettingsDep,
    store: StoreDep,
    owner: OwnerDep,
    format: ExportFormat = "json",
    dt: Annotated[float | None, Query(gt=0, allow_inf_nan=False, description=(
        "Sample time (s) of the exported controller. Default: the dt the job's result was verified at (its largest "
        "scenario dt). At any other dt the gains are re-verified at that dt before they are exported."))] = None,
    allow_unverified: Annotated[bool, Query(description=(
        "Export gains whose verdict at this dt is not pass; the file is then marked FAILED, with the reason.")
    )] = False,
) -> Response:
    """The file carries the verdict at ``dt``: the stored one at the verified dt, else a fresh verification."""
    from gaintune.errors import GaintuneError

    row = _get(store, job_id, owner)
    r = _tuning_result(row)
    result = _tune_result(r)
    try:
        checked = export_verdict(result, dt, settings.max_steps)
    except GaintuneError as exc:
        if exc.field != "dt":
            raise
        raise ApiError(422, f"Cannot export at dt = {dt:g} s.",
                       errors=[{"loc": "query.dt", "msg": exc.message}]) from None
    verdict, report = checked
    if verdict != "pass" and not allow_unverified:
        reasons = (report or {}).get("reasons") if isinstance(report, dict) else None
        reason = reasons[0] if reasons else "no reason recorded"
        where = "at the dt it was verified at" if dt is None else f"at dt = {dt:g} s"
        raise ApiError(409, f"Job {job_id}'s gains are not accepted {where} (verdict: {verdict}; {reason}). "
                            "Re-tune at this sample time, or pass allow_unverified=true to export them anyway "
                            "(the file is then marked FAILED).")
    text = export_gains(result, format, dt, checked)
    media, ext = EXPORT_MEDIA[format]
    return Response(content=text, media_type=media,
                    headers={"Content-Disposition": f'attachment; filename="gains_{row.id}.{ext}"'})
