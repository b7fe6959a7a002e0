"""Builds the FastAPI application; ``create_app`` is the uvicorn factory."""

import logging
from collections.abc import AsyncIterator
from contextlib import asynccontextmanager

import anyio
from fastapi import Depends, FastAPI

from app import __version__
from app.api.admission import AdmissionMiddleware
from app.api.deps import refuse_repeated_parameters
from app.api.metrics import MetricsMiddleware
from app.api.metrics import router as metrics_router
from app.api.operands import MAX_OPERANDS
from app.api.pages import install_pages
from app.api.problems import install_problem_handlers
from app.api.resources import Resources
from app.api.routes import (
    correspondence,
    health,
    localize,
    models,
    overlap,
    reconstruct,
    retrieve,
    session_person,
    sessions,
    shapes,
    spectrum,
    unions,
)
from app.api.shutdown import flip_readiness_on_exit_signals
from app.api.solver import SolverPool
from app.api.upload_limit import UploadLimitMiddleware
from app.core.config import Settings, get_settings

# Multipart parsing limits (the 2024 Starlette/python-multipart DoS fixes make them enforceable):
# no route takes more than MAX_OPERANDS files or a handful of text fields (a client that sends its
# files without file names sends them as text fields), and the largest text field, 32 spectra of
# 200 eigenvalues as JSON, is far below a MiB.
MAX_FORM_FIELDS = MAX_OPERANDS + 8
# uvicorn's own logger: its handler is the one configured when the service runs under uvicorn.
STARTUP_LOG = logging.getLogger("uvicorn.error")
MAX_FORM_FIELD_BYTES = 1024 * 1024
API_PREFIX = "/v1"


def create_app(settings: Settings | None = None) -> FastAPI:
    """A configured app; the lifespan opens what the endpoints need and flips readiness."""
    settings = settings or get_settings()

    @asynccontextmanager
    async def lifespan(app: FastAPI) -> AsyncIterator[None]:
        solver = SolverPool(
            settings.solver_concurrency,
            settings.solve_timeout_seconds,
            settings.solve_memory_mb,
            settings.solves_per_worker,
        )
        await solver.start()
        app.state.solver = solver
        resources = Resources(settings)
        await anyio.to_thread.run_sync(resources.open)  # what fails is reported by /readyz, not fatal
        app.state.resources = resources
        STARTUP_LOG.info("spectral-unions %s: %s", __version__, await anyio.to_thread.run_sync(resources.summary))
        app.state.ready = True
        flip_readiness_on_exit_signals(app)
        try:
            yield
        finally:
            app.state.ready = False
            solver.close()
            await anyio.to_thread.run_sync(resources.close)

    app = FastAPI(
        title="spectral-unions",
        version=__version__,
        summary="Laplace–Beltrami spectra of partial deformable 3D shapes.",
        lifespan=lifespan,
        docs_url=None,
        redoc_url=None,
        dependencies=[Depends(refuse_repeated_parameters)],
        form_limits={"max_files": MAX_OPERANDS, "max_fields": MAX_FORM_FIELDS, "max_part_size": MAX_FORM_FIELD_BYTES},
    )
    app.state.settings = settings
    app.add_middleware(
        AdmissionMiddleware,
        capacity=settings.solver_concurrency + settings.max_queued_solves,
        byte_budget=settings.max_inflight_upload_bytes,
        max_body_bytes=settings.max_upload_bytes,
        solving_paths=frozenset({API_PREFIX + reconstruct.ROUTE, API_PREFIX + retrieve.ROUTE}),
        solving_suffixes=(session_person.BODY, session_person.IDENTITY),
    )
    app.add_middleware(
        UploadLimitMiddleware, max_bytes=settings.max_upload_bytes, body_timeout_s=settings.body_timeout_seconds
    )
    app.add_middleware(MetricsMiddleware)
    install_problem_handlers(app)
    install_pages(app)
    app.include_router(health.router)
    app.include_router(metrics_router)
    app.include_router(spectrum.router, prefix=API_PREFIX)
    routers = (
        unions,
        overlap,
        localize,
        correspondence,
        reconstruct,
        models,
        retrieve,
        shapes,
        sessions,
        session_person,
    )
    for routes in routers:
        app.include_router(routes.router, prefix=API_PREFIX)
    return app
