"""Administration (admins only): the accounting table and per-user fair-share settings."""

from __future__ import annotations

from typing import Annotated

from fastapi import APIRouter, Depends, Path
from fastapi.concurrency import run_in_threadpool

from service.accounting import accounting
from service.deps import JSON_BODY, CurrentUser, ServicesDep
from service.errors import Forbidden, NotFound, problem_responses
from service.routes import StrictJSONRoute
from service.schemas import (
    Accounting,
    AdminOverview,
    FailedJob,
    RunningJob,
    UserAccount,
    UserSettingsUpdate,
)
from service.states import JobStatus
from service.store import UserRecord

RECENT_FAILURES = 20

router = APIRouter(prefix="/admin", tags=["admin"], route_class=StrictJSONRoute)


def require_admin(user: CurrentUser) -> UserRecord:
    """Dependency: the request's user, who must be an admin (403 otherwise)."""
    if not user.is_admin:
        raise Forbidden("this is for admins")
    return user


AdminUser = Annotated[UserRecord, Depends(require_admin)]


@router.get("/users", response_model=Accounting, responses={**problem_responses(401, 403)})
async def list_accounts(_: AdminUser, services: ServicesDep) -> Accounting:
    """Every user: fair-share weight and limits, waiting and running jobs, and the accounting
    of finished runs (job counts, CPU seconds, solve seconds)."""
    return Accounting(users=await run_in_threadpool(accounting, services.store))


@router.patch(
    "/users/{name}",
    response_model=UserAccount,
    dependencies=JSON_BODY,
    responses={**problem_responses(401, 403, 404, 415, 422)},
)
def update_user(
    name: Annotated[str, Path(max_length=128, description="user name")],
    body: UserSettingsUpdate,
    _: AdminUser,
    services: ServicesDep,
) -> UserAccount:
    """Set a user's fair-share weight and limits (fields left out are kept)."""
    store = services.store
    if not any(u.name == name for u in store.list_users()):
        raise NotFound(f"there is no user {name!r}")
    store.create_user(name, **body.model_dump(exclude_none=True))
    return next(a for a in accounting(store) if a.user == name)


@router.get("/overview", response_model=AdminOverview, responses={**problem_responses(401, 403)})
def overview(_: AdminUser, services: ServicesDep) -> AdminOverview:
    """The admin page's data: workers alive, running jobs with their workers and progress,
    recent failures, and every user's queue and accounting."""
    store = services.store
    names = {u.id: u.name for u in store.list_users()}
    failed, _total = store.list_jobs(None, [JobStatus.failed], limit=RECENT_FAILURES)
    ready, why = services.backend.ready()
    return AdminOverview(
        workers=services.backend.worker_count(),
        queue=f"{services.settings.queue}: {why}" + ("" if ready else " (not ready)"),
        running=[
            RunningJob(
                jobID=j.id,
                user=names.get(j.owner, j.owner),
                worker=j.worker,
                progress=j.progress,
                message=j.message,
                started=j.started,
            )
            for j in sorted(store.running_jobs(), key=lambda j: (j.started is None, j.started))
        ],
        failures=[
            FailedJob(
                jobID=j.id, user=names.get(j.owner, j.owner), finished=j.finished, message=j.message
            )
            for j in failed
        ],
        users=accounting(store),
    )
