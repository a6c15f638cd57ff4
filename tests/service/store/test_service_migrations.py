"""The store's Alembic migrations (service/migrations) against the models, on SQLite and on a
fresh PostgreSQL database: the migrated schema equals the models' metadata, the create-all
path (embedded default) stamps the newest revision, a database made before migrations
existed is upgraded in place with its rows, and every migration can be undone."""

from __future__ import annotations

import json
import os
import subprocess
from pathlib import Path
from typing import Iterator

import pytest
from pba_celery_harness import pg_database
from pba_service_harness import PBA
from sqlalchemy import inspect, text
from sqlalchemy.engine import Engine

from service.states import JobStatus
from service.store import open_store
from service.store.rows import Base
from service.store.schema import (
    BASELINE,
    MIGRATIONS_DIR,
    alembic_config,
    current_revision,
    ensure_schema,
    head_revision,
    schema_differences,
    upgrade,
)
from service.store.sql import make_engine


@pytest.fixture(params=["sqlite", pytest.param("postgresql", marks=pytest.mark.services)])
def url(request: pytest.FixtureRequest, tmp_path: Path) -> Iterator[str]:
    if request.param == "sqlite":
        yield f"sqlite:///{tmp_path / 'store.sqlite3'}"
    else:
        with pg_database("mig") as u:
            yield u


@pytest.fixture
def engine(url: str) -> Iterator[Engine]:
    e = make_engine(url)
    try:
        yield e
    finally:
        e.dispose()


def revision_of(engine: Engine) -> str | None:
    with engine.connect() as conn:
        return current_revision(conn)


def test_migrations_build_the_models_schema(engine: Engine) -> None:
    assert upgrade(engine) == head_revision()
    assert schema_differences(engine) == []
    assert set(inspect(engine).get_table_names()) == set(Base.metadata.tables) | {"alembic_version"}


def test_create_all_path_is_stamped_and_equal(url: str, engine: Engine) -> None:
    store = open_store(url)  # the embedded default's path: create_all + stamp
    store.close()
    assert revision_of(engine) == head_revision()
    assert schema_differences(engine) == []
    assert ensure_schema(engine) == "current"


def test_database_from_before_migrations_is_upgraded(url: str, engine: Engine) -> None:
    """Tables as issue 4's create_all made them (no heartbeat column, no version table)."""
    from alembic import command

    with engine.begin() as conn:
        command.upgrade(alembic_config(conn), BASELINE)
        conn.execute(text("DROP TABLE alembic_version"))
    legacy = open_store(url, create=False)
    with engine.begin() as conn:  # a row written by the old code (it knows no heartbeat)
        conn.execute(
            text(
                "INSERT INTO jobs (id, owner, process_id, name, status, progress, message, "
                "created, updated, attempts, n_observations) VALUES ('j1', 'u', "
                "'bundle-adjustment', 'old', 'accepted', 0, 'queued', :t, :t, 0, 3)"
            ),
            {"t": "2026-01-01 00:00:00"},
        )
    legacy.close()
    assert ensure_schema(engine) == "upgraded"
    assert revision_of(engine) == head_revision()
    assert schema_differences(engine) == []
    store = open_store(url)
    try:
        rec = store.get_job("j1")
        assert rec is not None and rec.status == JobStatus.accepted and rec.name == "old"
    finally:
        store.close()


def test_downgrade_to_nothing_and_back(engine: Engine) -> None:
    from alembic import command

    upgrade(engine)
    with engine.begin() as conn:
        command.downgrade(alembic_config(conn), "base")
    assert set(inspect(engine).get_table_names()) <= {"alembic_version"}
    assert upgrade(engine) == head_revision()
    assert schema_differences(engine) == []


def test_models_changed_without_a_migration_are_caught(engine: Engine) -> None:
    """The comparison the schema tests rely on does see a missing column."""
    from alembic import command

    upgrade(engine)
    with engine.begin() as conn:
        command.downgrade(alembic_config(conn), BASELINE)
    diffs = schema_differences(engine)
    assert any(d[0] == "add_column" and d[3].name == "heartbeat" for d in diffs), diffs


def test_migrations_ship_inside_the_package() -> None:
    """The environment is found relative to the installed package, not the checkout."""
    assert MIGRATIONS_DIR == Path(__file__).resolve().parents[3] / "service" / "migrations"
    assert (MIGRATIONS_DIR / "env.py").is_file() and (MIGRATIONS_DIR / "script.py.mako").is_file()
    names = sorted(p.name for p in (MIGRATIONS_DIR / "versions").glob("*.py"))
    assert names[0].startswith(BASELINE)


def test_pba_db_commands(tmp_path: Path) -> None:
    env = {**os.environ, "PBA_DATA_DIR": str(tmp_path), "PBA_DATABASE_URL": ""}
    env.pop("PBA_DATABASE_URL")
    up = subprocess.run(
        [str(PBA), "db", "upgrade"], env=env, capture_output=True, text=True, timeout=60
    )
    assert up.returncode == 0, up.stderr
    assert f"revision {head_revision()}" in up.stderr
    cur = subprocess.run(
        [str(PBA), "db", "current"], env=env, capture_output=True, text=True, timeout=60
    )
    assert cur.returncode == 0 and cur.stdout.split()[0] == head_revision(), cur


def test_upgrade_from_0002_keeps_cameras_with_their_authors_and_old_payloads(
    url: str, engine: Engine
) -> None:
    """Revision 0003 on a 0002 store with rows: each camera version goes to the namespace of
    the user who wrote it (bob's ``bcam`` v1 and the v2 alice wrote under his name part), old
    plain payloads are still read and counted for the quota."""
    from service.store import SHARED

    assert upgrade(engine, "0002") == "0002"
    t = {"t": "2026-01-01 00:00:00"}
    with engine.begin() as conn:
        for version, author in ((1, "bob"), (2, "alice")):
            conn.execute(
                text(
                    "INSERT INTO cameras (name, version, description, definition, created, "
                    "created_by) VALUES ('bcam', :v, '', :d, :t, :a)"
                ),
                {"v": version, "a": author, "d": json.dumps({"focal_mm": float(version)}), **t},
            )
        conn.execute(
            text(
                "INSERT INTO jobs (id, owner, process_id, name, status, progress, message, "
                "created, updated, finished, attempts, n_observations) VALUES ('j1', 'bob', "
                "'bundle-adjustment', 'old', 'successful', 100, 'done', :t, :t, :t, 1, 3)"
            ),
            t,
        )
        conn.execute(
            text(
                "INSERT INTO job_payloads (job_id, document, results) "
                "VALUES ('j1', '{\"job\": {}}', '{\"report\": 1}')"
            )
        )
    assert upgrade(engine) == head_revision() == "0005"
    assert schema_differences(engine) == []
    store = open_store(url)
    try:
        bob = store.get_camera("bcam", owner="bob")
        alice = store.get_camera("bcam", owner="alice")
        assert bob is not None and bob.version == 1 and bob.definition == {"focal_mm": 1.0}
        assert alice is not None and alice.version == 2
        assert store.get_camera("bcam", owner=SHARED) is None
        assert store.add_camera("bcam", "", {}, "bob").version == 2  # per-namespace versions
        assert store.get_document("j1") == {"job": {}}
        assert store.get_results_text("j1") == '{"report": 1}'
        # his job's payloads and the JSON of the camera versions he created (v1 and the new one)
        cameras = len('{"focal_mm": 1.0}') + len("{}")
        assert store.storage_used("bob") == len('{"job": {}}') + len('{"report": 1}') + cameras
    finally:
        store.close()
