"""Persistence of jobs, users, keys and cameras behind the :class:`Store` interface."""

from service.store.base import (
    SHARED,
    CameraRecord,
    FinishedRun,
    JobRecord,
    PrunedJob,
    QuotaExceeded,
    Store,
    UsageRecord,
    UserRecord,
)


def open_store(url: str, create: bool = True) -> Store:
    """Open the store at a SQLAlchemy URL (``sqlite:///...`` or ``postgresql+psycopg://...``)."""
    from service.store.sql import SqlStore

    return SqlStore(url, create=create)


__all__ = [
    "SHARED",
    "CameraRecord",
    "FinishedRun",
    "JobRecord",
    "PrunedJob",
    "QuotaExceeded",
    "Store",
    "UsageRecord",
    "UserRecord",
    "open_store",
]
