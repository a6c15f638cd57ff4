"""Camera namespaces and retention (issue 13): ``cameras.owner``, compressed job payloads,
``jobs.stored_bytes``.

Revision ID: 0003
Revises: 0002
Create Date: 2026-11-23

* ``cameras.owner``: every camera belongs to a namespace, a user's id or ``shared``. Existing
  versions go to the user who created them (so a version another user added under someone's
  name stays with its author); names are unique per (owner, name, version).
* ``job_payloads.document_z`` / ``results_z``: zlib-compressed JSON of new rows. Old rows keep
  their plain text in ``document`` / ``results`` and are read as before (not rewritten here:
  that would hold the migration's lock for minutes on a big store).
* ``jobs.stored_bytes``: payload bytes per job for the storage quota; old rows get the length
  of their plain JSON.

Downgrading drops the compressed payloads (the old code cannot read them) and fails when two
users have a camera of the same name and version.
"""

from __future__ import annotations

from typing import Sequence

import sqlalchemy as sa
from alembic import op

revision: str = "0003"
down_revision: str | None = "0002"
branch_labels: str | Sequence[str] | None = None
depends_on: str | Sequence[str] | None = None


def upgrade() -> None:
    with op.batch_alter_table("cameras") as batch:
        batch.add_column(sa.Column("owner", sa.String(36), nullable=True))
    op.execute("UPDATE cameras SET owner = created_by")
    with op.batch_alter_table("cameras") as batch:
        batch.alter_column("owner", existing_type=sa.String(36), nullable=False)
        batch.drop_constraint("uq_cameras_name_version", type_="unique")
        batch.create_unique_constraint(
            "uq_cameras_owner_name_version", ["owner", "name", "version"]
        )
    with op.batch_alter_table("job_payloads") as batch:
        batch.add_column(sa.Column("document_z", sa.LargeBinary(), nullable=True))
        batch.add_column(sa.Column("results_z", sa.LargeBinary(), nullable=True))
    with op.batch_alter_table("jobs") as batch:
        batch.add_column(
            sa.Column("stored_bytes", sa.Integer(), nullable=False, server_default="0")
        )
    op.execute(
        "UPDATE jobs SET stored_bytes = (SELECT COALESCE(LENGTH(p.document), 0) + "
        "COALESCE(LENGTH(p.results), 0) FROM job_payloads p WHERE p.job_id = jobs.id) "
        "WHERE EXISTS (SELECT 1 FROM job_payloads p WHERE p.job_id = jobs.id)"
    )


def downgrade() -> None:
    with op.batch_alter_table("jobs") as batch:
        batch.drop_column("stored_bytes")
    with op.batch_alter_table("job_payloads") as batch:
        batch.drop_column("results_z")
        batch.drop_column("document_z")
    with op.batch_alter_table("cameras") as batch:
        batch.drop_constraint("uq_cameras_owner_name_version", type_="unique")
        batch.create_unique_constraint("uq_cameras_name_version", ["name", "version"])
        batch.drop_column("owner")
