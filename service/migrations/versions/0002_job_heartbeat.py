"""Lease of a distributed worker's run: ``jobs.heartbeat`` (issue 8).

Revision ID: 0002
Revises: 0001
Create Date: 2026-11-22

A Celery worker renews the heartbeat of the job it runs; a running job whose heartbeat is
older than ``PBA_LEASE_S`` is re-queued (service.store.leases).
"""

from __future__ import annotations

from typing import Sequence

import sqlalchemy as sa
from alembic import op

revision: str = "0002"
down_revision: str | None = "0001"
branch_labels: str | Sequence[str] | None = None
depends_on: str | Sequence[str] | None = None


def upgrade() -> None:
    with op.batch_alter_table("jobs") as batch:
        batch.add_column(sa.Column("heartbeat", sa.DateTime(timezone=True), nullable=True))


def downgrade() -> None:
    with op.batch_alter_table("jobs") as batch:
        batch.drop_column("heartbeat")
