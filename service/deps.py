"""FastAPI dependencies shared by every router (and the plug points for later routers).

* :data:`CurrentUser` - the user of the request's API key (``X-API-Key`` header,
  ``Authorization: Bearer``, or ``?api_key=`` for browser EventSource), or the local user in
  local single-user mode;
* :func:`get_settings`, :data:`SettingsDep`, :data:`ServicesDep`;
* :func:`get_job_for_user` - a job the user may see (404 otherwise); its record exposes
  ``.id``, ``.status`` and ``.results`` (the report dict, None unless successful). It reads
  the store, so call it from ``def`` (thread-pool) handlers;
* :data:`VisibleJob` - the same as a dependency on the ``jobId`` path parameter;
* :data:`JSON_BODY` - route dependencies of every endpoint that reads a JSON body (415 for
  another Content-Type).
"""

from __future__ import annotations

import email.message
from contextvars import ContextVar
from dataclasses import dataclass
from typing import Annotated

from fastapi import Depends, Path, Request, Security
from fastapi.security import APIKeyHeader, APIKeyQuery, HTTPAuthorizationCredentials, HTTPBearer

from service.auth import user_for_key
from service.errors import NotReady, Unauthorized, UnsupportedMediaType
from service.gis_process import GisProcess
from service.jobs import JobService
from service.metrics import Metrics
from service.queue import QueueBackend
from service.settings import Settings, is_loopback
from service.store import JobRecord, Store, UserRecord


@dataclass
class Services:
    """What the running app holds (``app.state.services``, set at start-up)."""

    settings: Settings
    store: Store
    backend: QueueBackend
    jobs: JobService
    metrics: Metrics
    local_user: UserRecord | None
    gis: GisProcess  # the process the GIS result endpoints compute in


_current: ContextVar[Services | None] = ContextVar("pba_services", default=None)


def set_current_services(services: Services | None) -> object:
    """Bind the services of the app handling this request (done by a middleware)."""
    return _current.set(services)


def reset_current_services(token: object) -> None:
    """Undo :func:`set_current_services`."""
    _current.reset(token)  # type: ignore[arg-type]


def current_services() -> Services:
    """The services of the app handling the current request."""
    services = _current.get()
    if services is None:
        raise NotReady("the server is starting or stopping")
    return services


def get_services(request: Request) -> Services:
    """Dependency: the app's services."""
    services = getattr(request.app.state, "services", None)
    if services is None:
        raise NotReady("the server is starting or stopping")
    return services


def get_settings(request: Request) -> Settings:
    """Dependency: the app's settings."""
    return request.app.state.settings


ServicesDep = Annotated[Services, Depends(get_services)]
SettingsDep = Annotated[Settings, Depends(get_settings)]

_key_header = APIKeyHeader(name="X-API-Key", auto_error=False, description="API key")
_bearer = HTTPBearer(auto_error=False, description="API key as a bearer token")
_key_query = APIKeyQuery(
    name="api_key", auto_error=False, description="API key in the URL (for EventSource)"
)


def current_user(
    services: ServicesDep,
    header_key: Annotated[str | None, Security(_key_header)] = None,
    bearer: Annotated[HTTPAuthorizationCredentials | None, Security(_bearer)] = None,
    query_key: Annotated[str | None, Security(_key_query)] = None,
) -> UserRecord:
    """Resolve the request's API key; without one, the local user when keys are optional."""
    key = header_key or (bearer.credentials if bearer else None) or query_key
    if key:
        user = user_for_key(services.store, key)
        if user is None:
            raise Unauthorized("the API key is not valid")
        return user
    if services.local_user is None or services.settings.auth_required:
        raise Unauthorized("an API key is required (X-API-Key header or Authorization: Bearer)")
    return services.local_user


CurrentUser = Annotated[UserRecord, Depends(current_user)]


def get_job_for_user(job_id: str, user: UserRecord) -> JobRecord:
    """The job ``job_id`` if ``user`` owns it or is an admin; NoSuchJob (404) otherwise."""
    return current_services().jobs.get_visible(job_id, user)


def visible_job(
    jobId: Annotated[str, Path(max_length=64, description="job id")], user: CurrentUser
) -> JobRecord:
    """Dependency: the path's job, visible to the current user."""
    return get_job_for_user(jobId, user)


VisibleJob = Annotated[JobRecord, Depends(visible_job)]


def base_url(request: Request) -> str:
    """Base URL for links, ending with ``/``: ``PBA_PUBLIC_URL``; else the request's when its
    host is trusted (loopback, the bound address or ``PBA_TRUSTED_HOSTS``), else the bound
    address: a client's ``Host`` header never chooses where links point."""
    settings = request.app.state.settings
    if settings.public_url:
        return settings.public_url.rstrip("/") + "/"
    host = request.url.hostname or ""
    if is_loopback(host) or host == settings.host or host in settings.trusted_hosts:
        return str(request.base_url)
    bound = f"[{settings.host}]" if ":" in settings.host else settings.host
    return f"http://{bound}:{settings.port}/"


BaseUrl = Annotated[str, Depends(base_url)]


def is_json_media_type(content_type: str) -> bool:
    """True for ``application/json`` and ``application/*+json`` (parameters ignored)."""
    message = email.message.Message()
    message["content-type"] = content_type
    if message.get_content_maintype() != "application":
        return False
    subtype = message.get_content_subtype()
    return subtype == "json" or subtype.endswith("+json")


def require_json(request: Request) -> None:
    """Dependency: refuse a request whose Content-Type is not JSON (415 problem). A request
    without the header is read as JSON, as FastAPI does."""
    content_type = request.headers.get("content-type")
    if content_type is not None and not is_json_media_type(content_type):
        raise UnsupportedMediaType(content_type[:100])


JSON_BODY = [Depends(require_json)]
