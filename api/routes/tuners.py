"""Trained tuners: ``GET /v1/tuners`` lists the ready-made ones, ``POST /v1/tuners/{name}/query`` answers a plant,
``POST /v1/tuners`` trains one as a job.

A query runs in the compute pool (or a server thread, :func:`gaintune_api.compute.compute_tuner_query`);
loaded tuners are kept in an LRU. ``name`` is a ready-made tuner's name, or ``job:{id}`` for the tuner a
finished ``POST /v1/tuners`` job trained (only its owner's key sees it). Nothing here reads a path a client
gives: a shipped name must be one of the installed tuners, a job's folder is the job store's.
"""

from __future__ import annotations

import hashlib
from pathlib import Path
from typing import Annotated, Any

from fastapi import APIRouter, Header, Request, Response

from gaintune.cache import LRU
from gaintune.errors import GaintuneError, problem_details
from gaintune_api.compute import compute_tuner_query
from gaintune_api.deps import FilesDep, OwnerDep, SettingsDep, StoreDep, run_compute, run_pooled
from gaintune_api.job_store import IdempotencyConflict, QueueFull, loads
from gaintune_api.jobfiles import ArtifactMismatch, ArtifactMissing
from gaintune_api.jsonbody import StrictJSONRoute
from gaintune_api.problem_details import ApiError, log
from gaintune_api.routes.jobs import STORAGE, to_public
from gaintune_api.schemas import JobPublic, TunerAnswerPublic, TunerList, TunerPublic, TunerQuery, TunerTrainRequest
from gaintune_api.validation import check_spec, invalid

router = APIRouter(prefix="/v1", tags=["tuners"], route_class=StrictJSONRoute)

_PROBLEM: dict[str, Any] = {"content": {"application/problem+json": {}}}
#: The files a tuner folder's query reads, checked against the job's manifest.
TUNER_FILES = ("tuner.json", "policy.npz")


def _tuner_cache(request: Request) -> LRU[str, Any]:
    """The app's LRU of loaded tuners (queries computed in the server process), created on first use."""
    st = request.app.state
    if getattr(st, "tuners", None) is None:  # only the event loop calls this: no race
        st.tuners = LRU(st.settings.tuner_cache_size)
    return st.tuners


def _shipped(name: str) -> tuple[Path, str]:
    from gaintune.tuners import artefact

    if name not in artefact.shipped_names():
        raise ApiError(404, f"No tuner {name!r}: GET /v1/tuners lists the ready-made ones; a tuner a job trained "
                            "is job:{id}.")
    folder = artefact.SHIPPED_DIR / name
    return folder, f"shipped:{name}:{(folder / 'tuner.json').stat().st_mtime_ns}"


def _job_tuner(job_id: str, store: Any, files: Any, owner: str) -> tuple[Path, str]:
    """The folder of the tuner job ``job_id`` trained, its files checked against the job's manifest."""
    row = store.get(job_id, owner)
    if row is None or row.kind != "tuner":
        raise ApiError(404, f"No tuner job {job_id!r} (POST /v1/tuners starts one).")
    r = loads(row.result)
    if row.status != "succeeded" or not r:
        raise ApiError(409, f"Job {job_id} has no tuner (status: {row.status}).")
    digests = []
    for name in TUNER_FILES:
        try:
            _, digest = files.artifact(row.id, name, loads(row.artifacts))
        except ArtifactMissing as exc:
            raise ApiError(410, f"The tuner of job {job_id} was saved, but a file is gone: {exc}.") from None
        except ArtifactMismatch as exc:
            log.error("job %s: %s", row.id, exc)
            raise ApiError(500, f"A file of job {job_id}'s tuner was changed after the job finished: {exc}.",
                           title="Stored artefact does not match", extra={"cause": "artifact-mismatch"}) from None
        digests.append(digest or "")
    return files.job_dir(row.id), f"job:{row.id}:{hashlib.sha256(''.join(digests).encode()).hexdigest()[:16]}"


#: Most job-trained tuners ``GET /v1/tuners`` lists (the newest).
MAX_LISTED_JOBS = 200


@router.get("/tuners", response_model=TunerList, summary="The ready-made tuners, and those your jobs trained")
async def list_tuners(request: Request, owner: OwnerDep, store: StoreDep) -> TunerList:
    """Each ready-made tuner: family, controller, Ms limit, context ranges (FOTD: L/T), held-out validation
    (cost / per-plant optimum, passes), training record and folder size. As ``gaintune tuner list --json``.
    Then the tuners this API key's finished ``POST /v1/tuners`` jobs trained, newest first, named ``job:{id}``
    (the name their queries take)."""
    from gaintune.tuners.listing import shipped

    st = request.app.state
    if getattr(st, "tuner_list", None) is None:  # the installed tuners do not change while the server runs
        st.tuner_list = TunerList(items=[TunerPublic.model_validate(s) for s in await run_compute(request, shipped)])
    import anyio

    jobs = await anyio.to_thread.run_sync(store.finished_tuners, owner, MAX_LISTED_JOBS)  # a DB read: off the loop
    trained = [TunerPublic.model_validate({**r["tuner"], "name": f"job:{row.id}"})
               for row in jobs if (r := loads(row.result)) and isinstance(r.get("tuner"), dict)]
    return TunerList(items=[*st.tuner_list.items, *trained])


@router.post("/tuners/{name}/query", response_model=TunerAnswerPublic,
             summary="A tuner's verified gains for one plant",
             responses={404: {"description": "No such tuner (or tuner job for this API key).", **_PROBLEM},
                        409: {"description": "The tuner job has not finished.", **_PROBLEM},
                        410: {"description": "A file of the job's tuner is gone.", **_PROBLEM},
                        422: {"description": "A bad or unknown parameter, a plant outside the tuner's family, or "
                                             "refine beyond the server's limit (the field is named).", **_PROBLEM}})
async def query_tuner(name: str, body: TunerQuery, request: Request, store: StoreDep, files: FilesDep,
                      owner: OwnerDep, settings: SettingsDep) -> Response:
    """The policy's answer for the plant (NumPy), moved onto its requirement boundary, optionally refined, and
    verified on it. A failing verdict is a 200 with ``accepted_gains: null``, as ``/v1/verify`` reports one.
    ``name``: a ready-made tuner, or ``job:{id}`` for the tuner a ``POST /v1/tuners`` job trained."""
    if body.refine > settings.max_tuner_refine:
        raise invalid([{"loc": "refine", "msg": f"{body.refine} exceeds this server's limit of "
                                                f"{settings.max_tuner_refine} simulations"}], "Refine less.")
    folder, key = _job_tuner(name[4:], store, files, owner) if name.startswith("job:") else _shipped(name)
    args = (str(folder), key, body.params, body.refine)
    out = await run_pooled(request, compute_tuner_query, *args)
    if out is None:  # no pool (or its worker died): compute in a server thread, with the app's cache
        out = await run_compute(request, compute_tuner_query, *args, _tuner_cache(request))
    tag, data = out
    if tag == "invalid":
        raise ApiError(422, f"Tuner {name} cannot answer these parameters.", errors=data)
    if tag != "ok":
        raise ApiError(422, f"Tuner {name} could not answer.", errors=[{"loc": "params", "msg": data}])
    return Response(data, media_type="application/json")


def _check_request(body: TunerTrainRequest, settings: Any) -> None:
    """422 naming the field: one of spec/family, the episodes limit, a spec that is no family."""
    from gaintune.tuners.problems import SpecProblem

    if (body.spec is None) == (body.family is None):
        raise invalid([{"loc": "family", "msg": "give either spec (with a randomize block) or family"}],
                      "The tuner request is invalid.")
    if body.spec is not None and (body.ctype is not None or body.ms_max is not None):
        field = "ctype" if body.ctype is not None else "ms_max"
        raise invalid([{"loc": field, "msg": "only with family; a spec's loops and requirements say it"}],
                      "The tuner request is invalid.")
    if body.episodes is not None and body.episodes > settings.max_tuner_episodes:
        raise invalid([{"loc": "episodes", "msg": f"{body.episodes} exceeds this server's limit of "
                                                  f"{settings.max_tuner_episodes}"}], "The tuner request is invalid.")
    if body.spec is not None:
        check_spec(body.spec, settings, "tune", prefix="spec")
        try:
            SpecProblem(body.spec)
        except GaintuneError as exc:
            raise invalid([{**d, "loc": f"spec.{d['loc']}"} for d in problem_details(exc)]) from None


@router.post("/tuners", status_code=202, response_model=JobPublic, summary="Train a tuner (a job)",
             responses={202: {"description": "Accepted; poll the URL in the Location header."},
                        409: {"description": "Idempotency-Key reused with a different request.", **_PROBLEM},
                        422: {"description": "Invalid request (field paths in `errors`).", **_PROBLEM},
                        **STORAGE,
                        503: {"description": "Queue full, or a storage fault; retry after Retry-After seconds.",
                              **_PROBLEM}})
def submit_tuner(body: TunerTrainRequest, response: Response, settings: SettingsDep, store: StoreDep,
                 files: FilesDep, owner: OwnerDep,
                 idempotency_key: Annotated[str | None, Header(alias="Idempotency-Key", max_length=200)] = None,
                 ) -> JobPublic:
    """Queue the training of a tuner for a family: a spec's ``randomize`` block, or a ready-made family. The job
    (``GET /v1/jobs/{id}``, kind ``tuner``) reports episodes as progress, survives restarts (a re-run resumes
    from the last checkpoint) and, once done, holds the tuner (``tuner``), queried at
    ``POST /v1/tuners/job:{id}/query``."""
    _check_request(body, settings)
    files.probe()
    text = body.model_dump_json()
    try:
        row, created = store.create(owner, text, hashlib.sha256(text.encode()).hexdigest(), body.label(),
                                    idem_key=idempotency_key, max_queue=settings.max_queue, kind="tuner")
    except QueueFull:
        raise ApiError(503, f"The job queue is full ({settings.max_queue} jobs); retry later.",
                       headers={"Retry-After": str(settings.retry_after)}) from None
    except IdempotencyConflict as exc:
        raise ApiError(409, f"Idempotency-Key was already used for job {exc.args[0]} with a different request.") \
            from None
    response.headers["Location"] = f"/v1/jobs/{row.id}"
    if not created:
        response.headers["Idempotent-Replayed"] = "true"
    return to_public(row, settings.jobs_dir)
