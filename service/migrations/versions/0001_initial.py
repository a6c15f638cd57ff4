"""The store's first schema: jobs, job payloads, users, API keys, cameras (issue 4).

Revision ID: 0001
Revises:
Create Date: 2026-11-22

Databases created before migrations existed (``create_all``) have exactly these tables; the
store stamps them with this revision and upgrades from here (service.store.schema).
"""

from __future__ import annotations

from typing import Sequence

import sqlalchemy as sa
from alembic import op

revision: str = "0001"
down_revision: str | None = None
branch_labels: str | Sequence[str] | None = None
depends_on: str | Sequence[str] | None = None

UTC = sa.DateTime(timezone=True)


def upgrade() -> None:
    op.create_table(
        "jobs",
        sa.Column("id", sa.String(36), primary_key=True),
        sa.Column("owner", sa.String(36), nullable=False),
        sa.Column("process_id", sa.String(64), nullable=False),
        sa.Column("name", sa.String(200), nullable=False),
        sa.Column("status", sa.String(16), nullable=False),
        sa.Column("progress", sa.Integer(), nullable=False),
        sa.Column("message", sa.Text(), nullable=False),
        sa.Column("created", UTC, nullable=False),
        sa.Column("updated", UTC, nullable=False),
        sa.Column("started", UTC, nullable=True),
        sa.Column("finished", UTC, nullable=True),
        sa.Column("attempts", sa.Integer(), nullable=False),
        sa.Column("worker", sa.String(128), nullable=True),
        sa.Column("cancel_requested", sa.String(32), nullable=True),
        sa.Column("n_observations", sa.Integer(), nullable=False),
        sa.Column("error", sa.Text(), nullable=True),
    )
    op.create_index("ix_jobs_owner", "jobs", ["owner"])
    op.create_index("ix_jobs_finished", "jobs", ["finished"])
    op.create_index("ix_jobs_worker", "jobs", ["worker"])
    op.create_index("ix_jobs_status_created", "jobs", ["status", "created"])
    op.create_index("ix_jobs_owner_created", "jobs", ["owner", "created"])

    op.create_table(
        "job_payloads",
        sa.Column(
            "job_id",
            sa.String(36),
            sa.ForeignKey("jobs.id", ondelete="CASCADE"),
            primary_key=True,
        ),
        sa.Column("document", sa.Text(), nullable=True),
        sa.Column("results", sa.Text(), nullable=True),
    )

    op.create_table(
        "users",
        sa.Column("id", sa.String(36), primary_key=True),
        sa.Column("name", sa.String(128), nullable=False, unique=True),
        sa.Column("is_admin", sa.Boolean(), nullable=False),
        sa.Column("created", UTC, nullable=False),
        sa.Column("max_queued_jobs", sa.Integer(), nullable=True),
        sa.Column("max_job_observations", sa.Integer(), nullable=True),
    )

    op.create_table(
        "api_keys",
        sa.Column("key_hash", sa.String(64), primary_key=True),
        sa.Column("prefix", sa.String(16), nullable=False),
        sa.Column(
            "user_id", sa.String(36), sa.ForeignKey("users.id", ondelete="CASCADE"), nullable=False
        ),
        sa.Column("created", UTC, nullable=False),
    )
    op.create_index("ix_api_keys_prefix", "api_keys", ["prefix"])

    op.create_table(
        "cameras",
        sa.Column("id", sa.Integer(), primary_key=True, autoincrement=True),
        sa.Column("name", sa.String(128), nullable=False),
        sa.Column("version", sa.Integer(), nullable=False),
        sa.Column("description", sa.Text(), nullable=False),
        sa.Column("definition", sa.Text(), nullable=False),
        sa.Column("created", UTC, nullable=False),
        sa.Column("created_by", sa.String(36), nullable=False),
        sa.Column("source_job", sa.String(36), nullable=True),
        sa.UniqueConstraint("name", "version", name="uq_cameras_name_version"),
    )


def downgrade() -> None:
    op.drop_table("cameras")
    op.drop_index("ix_api_keys_prefix", table_name="api_keys")
    op.drop_table("api_keys")
    op.drop_table("users")
    op.drop_table("job_payloads")
    for name in (
        "ix_jobs_owner_created",
        "ix_jobs_status_created",
        "ix_jobs_worker",
        "ix_jobs_finished",
        "ix_jobs_owner",
    ):
        op.drop_index(name, table_name="jobs")
    op.drop_table("jobs")
