"""The FastAPI app: wires settings, middleware, error handlers and routers. No endpoint logic lives here.

Start with ``gaintune serve --workers N`` (calls :func:`serve`), ``python -m gaintune_api``
or ``uvicorn gaintune_api.main:app`` (workers from ``GAINTUNE_WORKERS``).
"""

from __future__ import annotations

import asyncio
import logging
import sys
import threading
from contextlib import asynccontextmanager

from fastapi import FastAPI
from fastapi.middleware.cors import CORSMiddleware

from gaintune_api.compute import ComputePool
from gaintune_api.jobfiles import JobFiles
from gaintune_api.metrics import Metrics
from gaintune_api.middleware import BodySizeLimit, CatchAll, DocsAuth, LatencyMetrics
from gaintune_api.problem_details import SafeJSONResponse, install_handlers
from gaintune_api.routes import jobs, ops, plants, simulate, tuners, verify
from gaintune_api.routes.docs import install_docs
from gaintune_api.schemas import install_client_openapi
from gaintune_api.settings import Settings, warn_unknown_settings
from gaintune_api.storage_faults import FaultInjector, StorageFault
from gaintune_api.stores import Store, missing_extra, open_store
from gaintune_api.supervisor import Supervisor

__all__ = ["create_app", "app", "serve"]

log = logging.getLogger("gaintune.api")

API_DESCRIPTION = """\
Tune cascaded PID / LQ controller gains with reinforcement learning, verify them
(stability, margins, robustness) and simulate them.

* `POST /v1/tune` queues a job (the body is a gaintune spec); poll `GET /v1/jobs/{id}`.
* `POST /v1/verify` and `POST /v1/simulate` answer synchronously.
* `GET /v1/tuners` lists the trained tuners; `POST /v1/tuners/{name}/query` answers a plant's verified gains in
  milliseconds; `POST /v1/tuners` trains one (a job).
* Errors are RFC 7807 problems (`application/problem+json`) with field paths in `errors`.
* Send `X-API-Key` when the server has keys configured; jobs are visible only to the key that created them.
"""


def _warm_up(done: threading.Event, pool: ComputePool | None = None) -> None:
    """Load the compiled simulator and verification paths once, off the event loop
    (and wait for the compute workers to have done the same)."""
    try:
        if pool is not None:
            for f in pool.warm:
                f.result(timeout=300)
        from gaintune.spec import load_spec
        from gaintune.verification import verify

        spec = load_spec({"plant": {"tf": {"num": [1], "den": "(s+1)^2"}}, "loops": [{"type": "pi"}],
                          "scenario": {"dt": 0.05, "horizon": 5.0}})
        verify(spec, {"loop0": {"Kp": 1.0, "Ki": 0.5}})
    except Exception:  # noqa: BLE001 - warm-up is an optimisation only
        log.warning("warm-up failed", exc_info=True)
    finally:
        done.set()


def _supervisor(settings: Settings, store: Store) -> Supervisor:
    """The job workers' supervisor: local worker processes, or Ray tasks (``backend = "ray"``)."""
    if settings.backend == "ray":
        from gaintune_api.ray_backend import RaySupervisor

        return RaySupervisor(settings, store)
    return Supervisor(settings, store)


@asynccontextmanager
async def lifespan(app: FastAPI):
    """Open the job store and files, start the job workers' supervisor and the compute pool; stop them on shutdown."""
    settings: Settings = app.state.settings
    warn_unknown_settings(log)
    faults = FaultInjector(settings.test_storage_fault_file)
    store = open_store(settings, faults)
    files = JobFiles(settings.jobs_dir, faults)
    # A read-only or full disk must not stop the server: it starts, answers 503s naming the fault,
    # and /readyz says why it is not ready.
    try:
        store.init()
    except StorageFault as fault:
        log.warning("job database not initialised: %s", fault)
    try:
        files.ensure_root()
    except StorageFault as fault:
        log.warning("data directory not created: %s", fault)
    app.state.store = store
    app.state.files = files
    app.state.warm = threading.Event()
    pool = None
    if settings.compute_processes > 0:
        pool = ComputePool(settings.compute_processes)
        pool.start()  # spawned from this (main) thread: the workers die with it
    app.state.compute_pool = pool
    app.state.metrics.compute = pool  # its respawns and thread fallbacks in /metrics
    if settings.warmup:
        threading.Thread(target=_warm_up, args=(app.state.warm, pool), name="warmup", daemon=True).start()
    else:
        app.state.warm.set()
    sup = _supervisor(settings, store)
    sup.start()
    app.state.supervisor = sup
    task = asyncio.create_task(sup.watch())
    try:
        yield
    finally:
        task.cancel()
        sup.stop()
        app.state.compute_pool = None
        if pool is not None:
            pool.shutdown()
        close = getattr(store, "close", None)  # PostgreSQL: this process's connection pool
        if close is not None:
            close()


def create_app(settings: Settings | None = None) -> FastAPI:
    """Build the app. ``settings`` default: from the environment (``GAINTUNE_*``, ``.env``)."""
    settings = settings or Settings()
    app = FastAPI(
        title="gaintune API",
        version="1.0.0",
        description=API_DESCRIPTION,
        lifespan=lifespan,
        default_response_class=SafeJSONResponse,
        docs_url=None,  # served by routes/docs.py from local assets: FastAPI's pages need a CDN
        redoc_url=None,
    )
    app.state.settings = settings
    app.state.files = JobFiles(settings.jobs_dir, FaultInjector(settings.test_storage_fault_file))
    app.state.metrics = Metrics()
    app.state.supervisor = None
    app.state.verify_cache = None
    app.state.compute_limiter = None
    app.state.compute_pool = None
    app.state.check_cache = None
    app.state.tuners = None
    app.state.tuner_list = None
    install_handlers(app)
    for r in (jobs.router, tuners.router, verify.router, simulate.router, plants.router, ops.router):
        app.include_router(r)
    docs = install_docs(app)
    install_client_openapi(app)  # request schemas: defaulted fields optional for generated clients
    if settings.cors_origins:
        app.add_middleware(CORSMiddleware, allow_origins=settings.cors_origins, allow_methods=["*"],
                           allow_headers=["*"], expose_headers=["Location", "Retry-After"])
    if settings.api_keys and not settings.docs_public:
        app.add_middleware(DocsAuth, paths=docs, keys=settings.api_keys)
    app.add_middleware(BodySizeLimit, max_bytes=settings.max_body_bytes)
    app.add_middleware(LatencyMetrics, metrics=app.state.metrics)
    app.add_middleware(CatchAll, retry_after=settings.retry_after)  # outermost: nothing escapes to uvicorn
    return app


app = create_app()


def serve(host: str = "127.0.0.1", port: int = 8000, workers: int = 1, *, log_level: str | None = None) -> None:
    """Run the API with uvicorn and ``workers`` job worker processes (other settings from the environment)."""
    import uvicorn

    settings = Settings(workers=workers)
    missing = missing_extra(settings)
    if missing is not None:
        print(f"error: {missing}", file=sys.stderr)
        raise SystemExit(2)
    logging.basicConfig(level=(log_level or settings.log_level).upper(),
                        format="%(asctime)s %(name)s %(levelname)s %(message)s")
    uvicorn.run(create_app(settings), host=host, port=port, log_level=log_level or settings.log_level)
