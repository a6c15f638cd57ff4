"""Operations: liveness, readiness, Prometheus metrics."""

from __future__ import annotations

from fastapi import APIRouter
from fastapi.concurrency import run_in_threadpool
from fastapi.responses import JSONResponse, Response
from prometheus_client import CONTENT_TYPE_LATEST

from service.deps import ServicesDep
from service.schemas import Health

router = APIRouter(tags=["operations"])


@router.get("/healthz", response_model=Health)
def healthz() -> Health:
    """Liveness: the server process answers."""
    return Health(status="ok")


@router.get("/readyz", response_model=Health, responses={503: {"model": Health}})
async def readyz(services: ServicesDep) -> JSONResponse:
    """Readiness: the store answers and the queue has workers."""
    checks: dict[str, str] = {}
    ok = True
    try:
        await run_in_threadpool(services.store.ping)
        checks["store"] = "ok"
    except Exception as exc:  # report, do not raise: readiness is an answer, not an error
        ok = False
        checks["store"] = f"unavailable: {type(exc).__name__}"
    ready, why = services.backend.ready()
    checks["queue"] = why
    ok = ok and ready
    body = Health(status="ok" if ok else "unavailable", checks=checks)
    return JSONResponse(body.model_dump(), status_code=200 if ok else 503)


@router.get(
    "/metrics", response_class=Response, responses={200: {"content": {CONTENT_TYPE_LATEST: {}}}}
)
async def metrics(services: ServicesDep) -> Response:
    """Prometheus metrics: jobs by state, queue depth, workers, solve durations."""
    text = await run_in_threadpool(services.metrics.render)
    return Response(text, media_type=CONTENT_TYPE_LATEST)
