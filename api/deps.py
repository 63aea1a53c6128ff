"""Typed dependency aliases: settings, job store, job files, and the caller's identity (API key)."""

from __future__ import annotations

import hashlib
import hmac
from typing import Annotated

from fastapi import Depends, Request, Security
from fastapi.security import APIKeyHeader

from gaintune_api.jobfiles import JobFiles
from gaintune_api.problem_details import ApiError
from gaintune_api.settings import Settings
from gaintune_api.stores import Store

__all__ = ["SettingsDep", "StoreDep", "FilesDep", "OwnerDep", "require_key", "owner_of", "check_key", "api_key_header",
           "run_compute", "run_pooled"]

api_key_header = APIKeyHeader(name="X-API-Key", auto_error=False,
                              description="API key (when the server has keys configured).")


async def run_compute(request: Request, fn, *args):
    """Run CPU-bound ``fn(*args)`` in a worker thread, at most ``compute_threads`` at a time (off the event loop)."""
    import anyio

    st = request.app.state
    if getattr(st, "compute_limiter", None) is None:
        st.compute_limiter = anyio.CapacityLimiter(st.settings.compute_threads)
    return await anyio.to_thread.run_sync(fn, *args, limiter=st.compute_limiter)


async def run_pooled(request: Request, fn, *args, ref: tuple[int, str] | None = None):
    """``fn(*args)`` in the compute process pool; None when there is none (or it just broke):
    the caller then uses :func:`run_compute`. ``fn`` must be picklable and never raise for bad input.
    ``ref``: see :meth:`gaintune_api.compute.ComputePool.run` (send a known spec by its hash only)."""
    pool = getattr(request.app.state, "compute_pool", None)
    if pool is None:
        return None
    return await pool.run(fn, *args, ref=ref)


# The dependencies are ``async def``: FastAPI runs a plain ``def`` dependency in a worker thread,
# a thread hop on every request for what is an attribute lookup or a key comparison.


async def get_settings(request: Request) -> Settings:
    """The app's settings (dependency)."""
    return request.app.state.settings


async def get_store(request: Request) -> Store:
    """The app's job store (dependency)."""
    return request.app.state.store


async def get_files(request: Request) -> JobFiles:
    """The app's artefact layer (dependency)."""
    return request.app.state.files


SettingsDep = Annotated[Settings, Depends(get_settings)]
StoreDep = Annotated[Store, Depends(get_store)]
FilesDep = Annotated[JobFiles, Depends(get_files)]


def owner_of(key: str | None) -> str:
    """Stable owner id of an API key (a hash: keys are never stored)."""
    if key is None:
        return "anonymous"
    return "key:" + hashlib.sha256(key.encode()).hexdigest()[:32]


async def authenticate(settings: SettingsDep, key: Annotated[str | None, Security(api_key_header)] = None) -> str:
    """The caller's owner id; 401 when keys are configured and none (or a wrong one) is given."""
    return check_key(settings, key)


def check_key(settings: Settings, key: str | None) -> str:
    """:func:`authenticate` for plain functions: the owner id, or ApiError 401."""
    if not settings.api_keys:
        return owner_of(None)
    if key:
        given = key.encode()
        for k in settings.api_keys:
            if hmac.compare_digest(k.encode(), given):
                return owner_of(k)
    raise ApiError(401, "Send a valid API key in the X-API-Key header.", headers={"WWW-Authenticate": "ApiKey"})


OwnerDep = Annotated[str, Depends(authenticate)]
#: Router-level dependency for routes that need a key but not the owner.
require_key = Depends(authenticate)
