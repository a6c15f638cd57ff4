"""Quotas that hold, on SQLite and PostgreSQL (127.0.0.1; ``make test`` starts it): the storage
check and the insert are one transaction (16 threads cannot pass it together), camera versions
count toward the creator's storage, and the HTTP side bounds camera sizes and version pages."""

from __future__ import annotations

import json
import threading
from pathlib import Path
from typing import Any

import pytest
from test_service_api import assert_problem, make_client
from test_service_store import store  # noqa: F401 - the parameterised store fixture

from service.auth import create_key
from service.settings import Settings
from service.store import QuotaExceeded, Store, open_store
from service.store.payloads import pack

DOC = {"job": {"name": "x", "padding": "p" * 2000}}


def test_concurrent_submissions_cannot_pass_the_quota_together(store: Store) -> None:  # noqa: F811
    user = store.create_user("racer")
    need = len(pack(json.dumps(DOC)))
    quota = 18 * need + need // 2  # room for exactly 18 jobs
    accepted, refused = [], []
    barrier = threading.Barrier(16)

    def submit() -> None:
        barrier.wait()
        for _ in range(2):
            try:
                accepted.append(store.create_job(user.id, "bundle-adjustment", DOC, 1, "x", quota_bytes=quota))
            except QuotaExceeded:
                refused.append(1)

    threads = [threading.Thread(target=submit) for _ in range(16)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    assert len(accepted) == 18 and len(refused) == 32 - 18
    assert store.storage_used(user.id) <= quota


def test_camera_versions_count_toward_the_creator_storage(store: Store) -> None:  # noqa: F811
    user = store.create_user("cams")
    definition = {"focal_mm": 1.0, "note": "n" * 1000}
    size = len(json.dumps(definition))
    store.add_camera("c", "", definition, user.id, quota_bytes=3 * size)
    store.add_camera("c", "", definition, user.id, quota_bytes=3 * size)
    assert store.storage_used(user.id) == 2 * size  # versions count, each its JSON text
    store.add_camera("c", "", definition, user.id, quota_bytes=3 * size)
    with pytest.raises(QuotaExceeded):
        store.add_camera("c", "", definition, user.id, quota_bytes=3 * size)
    with pytest.raises(QuotaExceeded):  # jobs and cameras share the quota
        store.create_job(user.id, "bundle-adjustment", DOC, 1, "x", quota_bytes=3 * size + 10)


CAMERA = {"focal_mm": 1939.0, "pixel_mm": 0.0071, "line_time_s": 0.00037, "lines": 1000, "columns": 1000}


def _keyed(tmp_path: Path, **settings: Any) -> tuple[Any, dict[str, str]]:
    client = make_client(tmp_path, require_api_keys=True, **settings)
    store = open_store(Settings(data_dir=tmp_path).resolved_database_url)
    keys = {u: create_key(store, u)[0] for u in ("alice", "bob")}
    store.close()
    return client, keys


def test_cameras_over_the_quota_are_refused(tmp_path: Path) -> None:
    # before: a user over the storage quota still stored 10 cameras of 2.14 MB
    client, keys = _keyed(tmp_path, user_storage_quota_mb=0.01)
    with client as c:
        h = {"X-API-Key": keys["alice"]}
        body = {"name": "big", "definition": {**CAMERA, "chips": [{"id": str(i), "first_column": i, "columns": 1} for i in range(40)]}}
        codes = [c.post("/cameras", json=body, headers=h).status_code for _ in range(10)]
        assert 201 in codes and codes[-1] == 413, codes
        assert_problem(c.post("/cameras", json=body, headers=h), 413)


def test_camera_size_is_bounded(tmp_path: Path) -> None:
    client, keys = _keyed(tmp_path, camera_max_bytes=4000)
    with client as c:
        h = {"X-API-Key": keys["alice"]}
        chips = [{"id": str(i), "first_column": i, "columns": 1} for i in range(200)]
        assert_problem(c.post("/cameras", json={"name": "huge", "definition": {**CAMERA, "chips": chips}}, headers=h), 413)


def test_version_lists_are_paginated(tmp_path: Path) -> None:
    # before: ?limit=1000 on a 100k-chip camera answered 266 MB to every user
    client, keys = _keyed(tmp_path)
    with client as c:
        h = {"X-API-Key": keys["alice"]}
        for _ in range(12):
            assert c.post("/cameras", json={"name": "cam", "definition": CAMERA}, headers=h).status_code == 201
        page = c.get("/cameras/cam/versions", headers=h).json()
        assert page["numberMatched"] == 12 and len(page["cameras"]) == 10  # the default page
        assert c.get("/cameras/cam/versions?limit=1000", headers=h).status_code == 400


def test_concurrent_http_submissions_hold_the_quota(tmp_path: Path, small_doc: dict[str, Any]) -> None:
    """The whole path (real server, SQLite): 16 clients submitting at once get exactly as many
    jobs accepted as one client submitting one at a time (before: 18 one at a time, 20 at once)."""
    from concurrent.futures import ThreadPoolExecutor

    from pba_service_harness import Server, execute_body

    body = execute_body(small_doc)
    async_ = {"Prefer": "respond-async"}
    srv = Server(tmp_path, workers=0, require_api_keys="true", max_queued_jobs=1000)
    srv.start()
    try:  # one job's stored size, to set a quota of 10.5 jobs
        probe = srv.create_key("probe")
        with srv.client(probe) as c:
            assert c.post("/processes/bundle-adjustment/execution", json=body, headers=async_).status_code == 201
        store = srv.store()
        size = store.storage_used(next(u.id for u in store.list_users() if u.name == "probe"))
        store.close()
    finally:
        srv.stop()
    srv = Server(tmp_path / "quota", workers=0, require_api_keys="true", max_queued_jobs=1000, user_storage_quota_mb=10.5 * size / 1e6)
    srv.start()
    try:
        one, many = srv.create_key("one"), srv.create_key("many")
        with srv.client(one) as c:
            codes = [c.post("/processes/bundle-adjustment/execution", json=body, headers=async_).status_code for _ in range(13)]
        assert codes == [201] * 10 + [413] * 3, codes
        with srv.client(many) as c, ThreadPoolExecutor(16) as pool:
            codes = list(pool.map(lambda _: c.post("/processes/bundle-adjustment/execution", json=body, headers=async_).status_code, range(32)))
        assert sorted(codes) == [201] * 10 + [413] * 22, codes
    finally:
        srv.stop()
