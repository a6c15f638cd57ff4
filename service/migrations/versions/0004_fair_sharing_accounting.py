"""Fair sharing and accounting (issue 19): the small-job lane, per-job and per-user usage,
per-user weight and running cap.

Revision ID: 0004
Revises: 0003
Create Date: 2026-11-23

* ``jobs.small``: the job takes the small-job lane (decided at submission; old jobs: false).
* ``jobs.cpu_s`` / ``jobs.solve_s``: CPU and wall seconds of the run that finished the job.
* ``users.weight`` / ``users.max_running_jobs``: set by an admin; NULL means the defaults.
* ``user_usage``: per-user totals of finished runs (counts by outcome, CPU and solve
  seconds), kept when jobs are pruned. Starts empty: earlier runs were not measured.
"""

from __future__ import annotations

from typing import Sequence

import sqlalchemy as sa
from alembic import op

revision: str = "0004"
down_revision: str | None = "0003"
branch_labels: str | Sequence[str] | None = None
depends_on: str | Sequence[str] | None = None


def upgrade() -> None:
    with op.batch_alter_table("jobs") as batch:
        batch.add_column(
            sa.Column("small", sa.Boolean(), nullable=False, server_default="0")
        )
        batch.add_column(sa.Column("cpu_s", sa.Float(), nullable=True))
        batch.add_column(sa.Column("solve_s", sa.Float(), nullable=True))
    with op.batch_alter_table("users") as batch:
        batch.add_column(sa.Column("weight", sa.Float(), nullable=True))
        batch.add_column(sa.Column("max_running_jobs", sa.Integer(), nullable=True))
    op.create_table(
        "user_usage",
        sa.Column("user_id", sa.String(36), primary_key=True),
        sa.Column("jobs_successful", sa.Integer(), nullable=False),
        sa.Column("jobs_failed", sa.Integer(), nullable=False),
        sa.Column("jobs_dismissed", sa.Integer(), nullable=False),
        sa.Column("cpu_s", sa.Float(), nullable=False),
        sa.Column("solve_s", sa.Float(), nullable=False),
    )


def downgrade() -> None:
    op.drop_table("user_usage")
    with op.batch_alter_table("users") as batch:
        batch.drop_column("max_running_jobs")
        batch.drop_column("weight")
    with op.batch_alter_table("jobs") as batch:
        batch.drop_column("solve_s")
        batch.drop_column("cpu_s")
        batch.drop_column("small")
