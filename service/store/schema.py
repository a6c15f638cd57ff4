"""The store's schema: Alembic migrations shipped in ``service/migrations``, and the start-up check.

:func:`ensure_schema` (called when a store is opened with ``create=True``) brings a database
to the newest revision:

* an empty database gets the models' tables (``create_all``) and is stamped with the newest
  revision - the fast path of the embedded SQLite default; a test checks that this schema and
  the one the migrations build are the same;
* a database with an ``alembic_version`` is upgraded when it is behind;
* a database made by ``create_all`` before migrations existed (tables, no version) is stamped
  with the first revision (:data:`BASELINE`) and upgraded from there.

On PostgreSQL the check runs in one transaction under an advisory lock, so an API server and
workers starting together do not race; DDL is transactional there, so a failed migration
leaves nothing half done. ``pba db upgrade`` and ``alembic -c service/alembic.ini`` run the
same migrations by hand.

Adding a column or table: change the model in :mod:`service.store.rows`, then add a revision
(``PBA_DATABASE_URL=sqlite:////tmp/x.sqlite3 alembic -c service/alembic.ini revision
--autogenerate -m "..."`` on a database at head, review the file), and the schema test passes
again.
"""

from __future__ import annotations

from functools import lru_cache
from pathlib import Path
from typing import Any, Literal

from sqlalchemy import inspect, text
from sqlalchemy.engine import Connection, Engine

from service.store.rows import Base

MIGRATIONS_DIR = Path(__file__).resolve().parent.parent / "migrations"
BASELINE = "0001"  # the schema of the stores created before migrations existed
VERSION_TABLE = "alembic_version"
LOCK_KEY = 0x70626173  # "pbas": pg_advisory_xact_lock key of schema changes

Outcome = Literal["created", "upgraded", "current"]


def alembic_config(connection: Connection | None = None, url: str | None = None) -> Any:
    """An Alembic ``Config`` for the shipped migrations (no ini file needed)."""
    from alembic.config import Config

    cfg = Config()
    cfg.set_main_option("script_location", str(MIGRATIONS_DIR))
    if url is not None:
        cfg.set_main_option("sqlalchemy.url", url.replace("%", "%%"))
    if connection is not None:
        cfg.attributes["connection"] = connection
    return cfg


@lru_cache(maxsize=1)
def _script() -> Any:
    from alembic.script import ScriptDirectory

    return ScriptDirectory(str(MIGRATIONS_DIR))


def head_revision() -> str:
    """The newest revision shipped with this package."""
    head = _script().get_current_head()
    assert head is not None, "no migrations found in " + str(MIGRATIONS_DIR)
    return head


def current_revision(conn: Connection) -> str | None:
    """The revision a database is at (None: not under migration control)."""
    if VERSION_TABLE not in inspect(conn).get_table_names():
        return None
    return conn.execute(text(f"SELECT version_num FROM {VERSION_TABLE}")).scalar_one_or_none()


def _stamp(conn: Connection, revision: str) -> None:
    from alembic.runtime.migration import MigrationContext

    MigrationContext.configure(conn).stamp(_script(), revision)


def _upgrade(conn: Connection, revision: str = "head") -> None:
    from alembic import command

    command.upgrade(alembic_config(conn), revision)


def _locked(conn: Connection) -> None:
    if conn.dialect.name == "postgresql":
        conn.execute(text("SELECT pg_advisory_xact_lock(:k)"), {"k": LOCK_KEY})


def ensure_schema(engine: Engine) -> Outcome:
    """Bring the database to the newest revision (see module docstring); what was done."""
    with engine.begin() as conn:
        _locked(conn)
        tables = set(inspect(conn).get_table_names())
        if VERSION_TABLE in tables:
            if current_revision(conn) == head_revision():
                return "current"
            _upgrade(conn)
            return "upgraded"
        if tables & set(Base.metadata.tables):
            _stamp(conn, BASELINE)  # made by create_all before migrations existed
            _upgrade(conn)
            return "upgraded"
        Base.metadata.create_all(conn)
        _stamp(conn, "head")
        return "created"


def upgrade(engine: Engine, revision: str = "head") -> str | None:
    """Run the migrations up to ``revision`` (``pba db upgrade``); the revision reached."""
    with engine.begin() as conn:
        _locked(conn)
        tables = set(inspect(conn).get_table_names())
        if VERSION_TABLE not in tables and tables & set(Base.metadata.tables):
            _stamp(conn, BASELINE)  # made by create_all before migrations existed
        _upgrade(conn, revision)
        return current_revision(conn)


def schema_differences(engine: Engine) -> list[Any]:
    """Differences between the database and the models (Alembic's autogenerate comparison);
    empty when they agree."""
    from alembic.autogenerate import compare_metadata
    from alembic.runtime.migration import MigrationContext

    with engine.connect() as conn:
        ctx = MigrationContext.configure(conn, opts={"compare_type": True})
        return list(compare_metadata(ctx, Base.metadata))
