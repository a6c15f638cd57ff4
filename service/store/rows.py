"""The store's tables: SQLAlchemy declarative rows (:class:`Base` and one class per table).

The table definitions alone, imported by the store (:mod:`service.store.sql`), by its schema
check (:mod:`service.store.schema`) and by the migrations (``service/migrations/env.py``), so
none of those imports another to reach them. Times are timezone-aware UTC on every backend
(:class:`UTCDateTime`). Adding a column or table: change it here, then add a revision
(:mod:`service.store.schema`).
"""

from __future__ import annotations

from datetime import datetime, timezone
from typing import Any

from sqlalchemy import (
    Boolean,
    DateTime,
    Float,
    ForeignKey,
    Index,
    Integer,
    LargeBinary,
    String,
    Text,
    TypeDecorator,
    UniqueConstraint,
)
from sqlalchemy.orm import DeclarativeBase, Mapped, mapped_column


class UTCDateTime(TypeDecorator[datetime]):
    """Timezone-aware UTC datetimes on every backend (SQLite keeps no zone)."""

    impl = DateTime(timezone=True)
    cache_ok = True

    def process_bind_param(self, value: datetime | None, dialect: Any) -> datetime | None:
        if value is not None and value.tzinfo is not None:
            value = value.astimezone(timezone.utc)
            if dialect.name == "sqlite":
                value = value.replace(tzinfo=None)
        return value

    def process_result_value(self, value: datetime | None, dialect: Any) -> datetime | None:
        if value is not None and value.tzinfo is None:
            value = value.replace(tzinfo=timezone.utc)
        return value


class Base(DeclarativeBase):
    """Declarative base of the store's tables."""


class JobRow(Base):
    """``jobs``: one row per job; the big payloads live in :class:`JobPayloadRow`."""

    __tablename__ = "jobs"
    id: Mapped[str] = mapped_column(String(36), primary_key=True)
    owner: Mapped[str] = mapped_column(String(36), index=True)
    process_id: Mapped[str] = mapped_column(String(64))
    name: Mapped[str] = mapped_column(String(200), default="")
    status: Mapped[str] = mapped_column(String(16))
    progress: Mapped[int] = mapped_column(Integer, default=0)
    message: Mapped[str] = mapped_column(Text, default="")
    created: Mapped[datetime] = mapped_column(UTCDateTime)
    updated: Mapped[datetime] = mapped_column(UTCDateTime)
    started: Mapped[datetime | None] = mapped_column(UTCDateTime, nullable=True)
    finished: Mapped[datetime | None] = mapped_column(UTCDateTime, nullable=True, index=True)
    attempts: Mapped[int] = mapped_column(Integer, default=0)
    worker: Mapped[str | None] = mapped_column(String(128), nullable=True, index=True)
    # lease of a distributed worker's run (service.store.leases); NULL for local workers
    heartbeat: Mapped[datetime | None] = mapped_column(UTCDateTime, nullable=True)
    cancel_requested: Mapped[str | None] = mapped_column(String(32), nullable=True)
    n_observations: Mapped[int] = mapped_column(Integer, default=0)
    error: Mapped[str | None] = mapped_column(Text, nullable=True)
    # bytes of this job's payloads as stored (the per-user storage quota sums these)
    stored_bytes: Mapped[int] = mapped_column(Integer, default=0, server_default="0")
    # the small-job lane (service.store.fair), decided at submission
    small: Mapped[bool] = mapped_column(Boolean, default=False, server_default="0")
    # what the job counts for in its user's share while it runs (service.lanes.share_of)
    share: Mapped[float] = mapped_column(Float, default=1.0, server_default="1")
    # accounting of the run that finished it: CPU seconds of the solving process, wall seconds
    cpu_s: Mapped[float | None] = mapped_column(Float, nullable=True)
    solve_s: Mapped[float | None] = mapped_column(Float, nullable=True)

    __table_args__ = (
        Index("ix_jobs_status_created", "status", "created"),
        Index("ix_jobs_owner_created", "owner", "created"),
    )


class JobPayloadRow(Base):
    """``job_payloads``: the execute inputs and the report as zlib-compressed JSON
    (``document_z``, ``results_z``; service.store.payloads). Rows written before revision
    0003 keep plain JSON text in ``document`` / ``results``; readers take whichever is set."""

    __tablename__ = "job_payloads"
    job_id: Mapped[str] = mapped_column(
        String(36), ForeignKey("jobs.id", ondelete="CASCADE"), primary_key=True
    )
    document: Mapped[str | None] = mapped_column(Text, nullable=True)
    results: Mapped[str | None] = mapped_column(Text, nullable=True)
    document_z: Mapped[bytes | None] = mapped_column(LargeBinary, nullable=True)
    results_z: Mapped[bytes | None] = mapped_column(LargeBinary, nullable=True)


class UserRow(Base):
    """``users``."""

    __tablename__ = "users"
    id: Mapped[str] = mapped_column(String(36), primary_key=True)
    name: Mapped[str] = mapped_column(String(128), unique=True)
    is_admin: Mapped[bool] = mapped_column(Boolean, default=False)
    created: Mapped[datetime] = mapped_column(UTCDateTime)
    max_queued_jobs: Mapped[int | None] = mapped_column(Integer, nullable=True)
    max_job_observations: Mapped[int | None] = mapped_column(Integer, nullable=True)
    weight: Mapped[float | None] = mapped_column(Float, nullable=True)
    max_running_jobs: Mapped[int | None] = mapped_column(Integer, nullable=True)


class UsageRow(Base):
    """``user_usage``: per-user accounting of finished runs (kept when jobs are pruned)."""

    __tablename__ = "user_usage"
    user_id: Mapped[str] = mapped_column(String(36), primary_key=True)
    jobs_successful: Mapped[int] = mapped_column(Integer, default=0)
    jobs_failed: Mapped[int] = mapped_column(Integer, default=0)
    jobs_dismissed: Mapped[int] = mapped_column(Integer, default=0)
    cpu_s: Mapped[float] = mapped_column(Float, default=0.0)
    solve_s: Mapped[float] = mapped_column(Float, default=0.0)


class ApiKeyRow(Base):
    """``api_keys``: SHA-256 of each key (keys are 256-bit random), never the key."""

    __tablename__ = "api_keys"
    key_hash: Mapped[str] = mapped_column(String(64), primary_key=True)
    prefix: Mapped[str] = mapped_column(String(16), index=True)
    user_id: Mapped[str] = mapped_column(String(36), ForeignKey("users.id", ondelete="CASCADE"))
    created: Mapped[datetime] = mapped_column(UTCDateTime)


class CameraRow(Base):
    """``cameras``: named, versioned camera definitions, each name in the namespace of its
    ``owner`` (a user id, or :data:`~service.store.base.SHARED` for the shared namespace)."""

    __tablename__ = "cameras"
    id: Mapped[int] = mapped_column(Integer, primary_key=True, autoincrement=True)
    owner: Mapped[str] = mapped_column(String(36))
    name: Mapped[str] = mapped_column(String(128))
    version: Mapped[int] = mapped_column(Integer)
    description: Mapped[str] = mapped_column(Text, default="")
    definition: Mapped[str] = mapped_column(Text)
    created: Mapped[datetime] = mapped_column(UTCDateTime)
    created_by: Mapped[str] = mapped_column(String(36))
    source_job: Mapped[str | None] = mapped_column(String(36), nullable=True)

    __table_args__ = (
        UniqueConstraint("owner", "name", "version", name="uq_cameras_owner_name_version"),
    )
