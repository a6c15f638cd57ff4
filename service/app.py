"""The FastAPI application: :func:`create_app` gathers the routers and wires the services.

Routers live in ``service/routes/``, one module per resource, each imported here and listed
once in :data:`ROUTER_MODULES` (a new router is its module, one import and one line). Services (store, queue backend, job service, metrics) are created at start-up (the
lifespan), so building the app - e.g. for ``make openapi`` - touches nothing on disk.
"""

from __future__ import annotations

import logging
from collections.abc import AsyncIterator
from contextlib import asynccontextmanager
from types import ModuleType

from fastapi import FastAPI
from fastapi.middleware.cors import CORSMiddleware
from fastapi.routing import APIRoute
from fastapi.staticfiles import StaticFiles

from service.auth import local_user
from service.cameras import ensure_presets
from service.deps import Services
from service.errors import install_error_handlers, problem_responses
from service.gis_process import GisProcess
from service.jobs import JobService
from service.metrics import Metrics
from service.middleware import (
    AccessLogMiddleware,
    BodyLimitMiddleware,
    SecurityHeadersMiddleware,
    ServicesContextMiddleware,
    UrlTextMiddleware,
)
from service.queue import make_backend
from service.raster_checks import stop_pool
from service.retention import RetentionLoop
from service.routes import admin, cameras, compose, gis, jobs, landing, ops, plots, processes, ui
from service.settings import Settings
from service.store import open_store
from solver.raster_gate import harden_gdal_environment

log = logging.getLogger("pba.service")

# every router module (each has a ``router``), in the order their routes are matched
ROUTER_MODULES: tuple[ModuleType, ...] = (
    landing,
    processes,
    compose,
    jobs,
    cameras,
    ops,
    admin,
    ui,
    plots,
    gis,
)

API_VERSION = "1.0.0"


def _operation_id(route: APIRoute) -> str:
    """Stable operation ids: ``<tag>-<function name>``."""
    tag = route.tags[0] if route.tags else "default"
    return f"{tag}-{route.name}"


def _start_services(settings: Settings) -> Services:
    settings.data_dir.mkdir(mode=0o700, parents=True, exist_ok=True)
    store = open_store(settings.resolved_database_url)
    ensure_presets(store)  # the sensor presets in the shared camera library
    backend = make_backend(settings, store)
    services = Services(
        settings=settings,
        store=store,
        backend=backend,
        jobs=JobService(settings, store, backend),
        metrics=Metrics(store, backend),
        local_user=None if settings.auth_required else local_user(store),
        gis=GisProcess(settings.resolved_database_url, settings.gis_processes, settings.gis_small_rows),
    )
    backend.start()
    return services


@asynccontextmanager
async def lifespan(app: FastAPI) -> AsyncIterator[None]:
    """Start the store and the queue backend; stop the workers on shutdown."""
    settings: Settings = app.state.settings
    harden_gdal_environment()  # before any worker or GIS process starts: they inherit it
    services = _start_services(settings)
    app.state.services = services
    if getattr(app.state, "start_gis_early", False):  # pba serve: the GIS process loads while the server starts
        services.gis.start()
    retention = None
    if settings.job_retention_days > 0:
        retention = RetentionLoop(
            services.store, settings.job_retention_days, settings.retention_interval_s
        )
        retention.start()
    log.info(
        "server ready: store %s, queue %s, %d workers, keys %s",
        settings.resolved_database_url.split("://")[0],
        settings.queue,
        settings.workers,
        "required" if settings.auth_required else "optional (local mode)",
    )
    try:
        yield
    finally:
        app.state.services = None
        if retention is not None:
            retention.stop()
        services.backend.stop()
        services.gis.stop()
        stop_pool()  # the raster check processes (service.raster_checks)
        services.store.close()
        log.info("server stopped")


def create_app(settings: Settings | None = None) -> FastAPI:
    """Build the application (nothing starts until the ASGI lifespan runs)."""
    settings = settings or Settings()
    app = FastAPI(
        title="Pushbroom orientation server",
        version=API_VERSION,
        description=(
            "OGC API - Processes 1.0 server for bundle adjustment of pushbroom (linear-array) "
            "satellite images. Errors are RFC 7807 problem documents. Authenticate with an API "
            "key in `X-API-Key` (or `Authorization: Bearer`); a server bound to 127.0.0.1 may "
            "run without keys (local single-user mode)."
        ),
        lifespan=lifespan,
        generate_unique_id_function=_operation_id,
        responses=problem_responses(400, 422),
    )
    app.state.settings = settings
    app.state.services = None
    install_error_handlers(app)
    app.state.router_modules = []
    for module in ROUTER_MODULES:
        app.include_router(module.router)
        app.state.router_modules.append(module.__name__.rpartition(".")[2])
    docs_site = settings.resolved_docs_site_dir
    if docs_site is not None:  # the documentation site (make docs), static files as built
        app.mount("/docs-site", StaticFiles(directory=docs_site, html=True), name="docs-site")
    # middlewares: the last added runs first
    app.add_middleware(ServicesContextMiddleware)
    app.add_middleware(BodyLimitMiddleware, max_bytes=settings.max_body_bytes)
    app.add_middleware(UrlTextMiddleware)
    if settings.cors_origins:
        app.add_middleware(
            CORSMiddleware,
            allow_origins=settings.cors_origins,
            allow_methods=["GET", "POST", "DELETE", "OPTIONS"],
            allow_headers=["X-API-Key", "Authorization", "Content-Type", "Prefer", "Last-Event-ID"],
            expose_headers=["Location", "Preference-Applied"],
        )
    app.add_middleware(AccessLogMiddleware)
    app.add_middleware(SecurityHeadersMiddleware)  # outermost: every response, errors included
    return app
