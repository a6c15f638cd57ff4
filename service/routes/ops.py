"""Operations: liveness, readiness, Prometheus metrics."""

from __future__ import annotations

import hmac
from typing import Annotated

from fastapi import APIRouter, Depends, Security
from fastapi.concurrency import run_in_threadpool
from fastapi.responses import JSONResponse, Response
from fastapi.security import APIKeyHeader, HTTPAuthorizationCredentials, HTTPBearer
from prometheus_client import CONTENT_TYPE_LATEST

from service.auth import user_for_key
from service.deps import ServicesDep
from service.errors import Forbidden, Unauthorized, problem_responses
from service.schemas import Health
from solver.engine import native

router = APIRouter(tags=["operations"])


@router.get("/healthz", response_model=Health)
def healthz() -> Health:
    """Liveness: the server process answers; `checks.evaluation` says whether solves use the compiled cost functions."""
    return Health(status="ok", checks={"evaluation": evaluation_check()})


def evaluation_check() -> str:
    built, why = native.built()
    return "compiled" if built else f"python (slower): {why}"


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
    checks["evaluation"] = evaluation_check()
    ok = ok and ready
    body = Health(status="ok" if ok else "unavailable", checks=checks)
    return JSONResponse(body.model_dump(), status_code=200 if ok else 503)


# the same security schemes as service.deps (same names and descriptions in the OpenAPI);
# /metrics takes no ?api_key= (a scraper sends a header)
_key_header = APIKeyHeader(name="X-API-Key", auto_error=False, description="API key")
_bearer = HTTPBearer(auto_error=False, description="API key as a bearer token")


def metrics_reader(
    services: ServicesDep,
    header_key: Annotated[str | None, Security(_key_header)] = None,
    bearer: Annotated[HTTPAuthorizationCredentials | None, Security(_bearer)] = None,
) -> None:
    """Dependency: when keys are required, /metrics needs ``PBA_METRICS_TOKEN`` as a bearer
    token or an admin's API key (the figures cover every user's jobs)."""
    settings = services.settings
    if not settings.auth_required:
        return
    key = header_key or (bearer.credentials if bearer else None)
    if not key:
        raise Unauthorized("/metrics needs an admin's API key or the metrics token")
    token = settings.metrics_token
    if token is not None and hmac.compare_digest(
        key.encode("utf-8"), token.get_secret_value().encode("utf-8")
    ):
        return
    user = user_for_key(services.store, key)
    if user is None:
        raise Unauthorized("the API key is not valid")
    if not user.is_admin:
        raise Forbidden("/metrics is for admins and the metrics token")


@router.get(
    "/metrics",
    response_class=Response,
    dependencies=[Depends(metrics_reader)],
    responses={200: {"content": {CONTENT_TYPE_LATEST: {}}}, **problem_responses(401, 403)},
)
async def metrics(services: ServicesDep) -> Response:
    """Prometheus metrics: jobs by state, queue depth, workers, solve durations."""
    text = await run_in_threadpool(services.metrics.render)
    return Response(text, media_type=CONTENT_TYPE_LATEST)
