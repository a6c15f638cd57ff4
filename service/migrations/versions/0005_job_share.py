"""A job's fair-share weight from its cost: ``jobs.share``.

Revision ID: 0005
Revises: 0004
Create Date: 2026-11-29

* ``jobs.share``: what the job counts for in its user's share while it runs (service.lanes:
  one unit per small job's worth of observations or pixels; at least 1). Old jobs: 1, as every
  running job counted before.
"""

from __future__ import annotations

from typing import Sequence

import sqlalchemy as sa
from alembic import op

revision: str = "0005"
down_revision: str | None = "0004"
branch_labels: str | Sequence[str] | None = None
depends_on: str | Sequence[str] | None = None


def upgrade() -> None:
    with op.batch_alter_table("jobs") as batch:
        batch.add_column(sa.Column("share", sa.Float(), nullable=False, server_default="1"))


def downgrade() -> None:
    with op.batch_alter_table("jobs") as batch:
        batch.drop_column("share")
