"""The accounting table shown to admins (``GET /admin/users``, ``pba admin usage``, the admin
page): every user's fair-share settings, current load and the usage recorded in the store."""

from __future__ import annotations

from service.schemas import UserAccount
from service.store import Store


def accounting(store: Store) -> list[UserAccount]:
    """One row per user, by name."""
    usage = {u.user_id: u for u in store.usage()}
    active = store.active_by_owner()
    rows = []
    for user in store.list_users():
        u = usage[user.id] if user.id in usage else None
        waiting, running = active.get(user.id, (0, 0))
        rows.append(
            UserAccount(
                user=user.name,
                is_admin=user.is_admin,
                weight=user.weight or 1.0,
                max_running_jobs=user.max_running_jobs,
                max_queued_jobs=user.max_queued_jobs,
                max_job_observations=user.max_job_observations,
                waiting=waiting,
                running=running,
                jobs_successful=u.jobs_successful if u else 0,
                jobs_failed=u.jobs_failed if u else 0,
                jobs_dismissed=u.jobs_dismissed if u else 0,
                cpu_seconds=u.cpu_s if u else 0.0,
                solve_seconds=u.solve_s if u else 0.0,
            )
        )
    return rows
