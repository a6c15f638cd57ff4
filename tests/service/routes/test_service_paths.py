"""Every path a client sends is checked as text before the file system sees it, and the image
folder is held by path components: through the real app (TestClient), each hostile name of a
``match`` raster is a 422 problem pointing at ``/inputs/images/<k>/path``, never a 500.

The rasters are the real Pleiades pair of tests/data/matching, so a check that let a name
through would accept the job (201): the refusals below come from the name or the folder check,
not from an unreadable file.
"""

from __future__ import annotations

import json
import os
import shutil
from pathlib import Path
from typing import Any

import pytest
from fastapi.testclient import TestClient
from test_matching_real import DATA, PAIRS, _rpc_job

from service.app import create_app
from service.auth import create_key
from service.processes import MATCH
from service.settings import Settings

pytestmark = pytest.mark.filterwarnings("ignore::rasterio.errors.NotGeoreferencedWarning")

LEFT, RIGHT, _HEIGHTS = PAIRS["ventoux"]


@pytest.fixture(scope="module")
def job_doc() -> dict[str, Any]:
    return _rpc_job([LEFT, RIGHT], [])


@pytest.fixture()
def served(tmp_path: Path):
    root = tmp_path / "images"
    (root / "alice").mkdir(parents=True)
    (root / "alice2").mkdir()
    for name in (LEFT, RIGHT):
        shutil.copyfile(DATA / f"{name}.tif", root / "alice" / f"{name}.tif")
    shutil.copyfile(DATA / f"{LEFT}.tif", root / "alice2" / "x.tif")
    settings = Settings(data_dir=tmp_path / "data", workers=0, require_api_keys=True, image_root=root)
    app = create_app(settings)
    with TestClient(app, raise_server_exceptions=False) as c:
        store = app.state.services.store
        yield c, {"X-API-Key": create_key(store, "alice")[0]}, root


def _submit(c: TestClient, key: dict[str, str], doc: dict[str, Any], path: str):
    images = [{"id": LEFT, "path": path}, {"id": RIGHT, "path": f"{RIGHT}.tif"}]
    body = json.dumps({"inputs": {"job": doc, "images": images}})  # ASCII: a lone surrogate as JSON escapes it
    return c.post(f"/processes/{MATCH}/execution", content=body,
                  headers={**key, "Prefer": "respond-async", "Content-Type": "application/json"})


def _refused(r, *words: str) -> str:
    assert r.status_code == 422, r.text
    assert r.headers["content-type"].startswith("application/problem+json")
    body = r.json()
    assert "/inputs/images/0/path" in [e["pointer"] for e in body["errors"]], body
    text = body["detail"] + " ".join(e["message"] for e in body["errors"])
    for w in words:
        assert w in text, text
    return text


def test_a_good_path_is_accepted(served, job_doc):
    """The control: the same request with a plain name is a job."""
    c, alice, _root = served
    assert _submit(c, alice, job_doc, f"{LEFT}.tif").status_code == 201


@pytest.mark.parametrize(
    ("path", "words"),
    [
        (f"{LEFT}\x00.tif", ("NUL or control character",)),  # before: a ValueError, a 500
        (f"\x00{LEFT}.tif", ("NUL or control character",)),
        (f"{LEFT}.tif\x00../../bob/secret.tif", ("NUL or control character",)),
        (f"{LEFT}\n.tif", ("NUL or control character",)),
        (f"{LEFT}\r.tif", ("NUL or control character",)),
        (f"{LEFT}\x1b[2J.tif", ("NUL or control character",)),
        (f"{LEFT}\x7f.tif", ("NUL or control character",)),
        ("x" * 1024, ("longer than 255 bytes",)),  # before: OSError File name too long, a 500
        ("a" * 256 + ".tif", ("longer than 255 bytes",)),
        ("\u00e9" * 128, ("longer than 255 bytes",)),  # 128 characters, 256 bytes of UTF-8
        ("d/" * 511 + "x", ()),  # 1023 characters of short components: no such raster, not a 500
        ("\u00e9/" * 512, ("longer than 1024 bytes",)),  # 1024 characters, 1536 bytes
        ("\ud800.tif", ()),  # a lone surrogate, as JSON can escape it: not a string of the schema
    ],
    ids=["nul", "nul-first", "nul-truncation", "newline", "carriage-return", "escape", "delete",
         "1024-char-component", "256-byte-component", "256-byte-utf8-component", "1023-char-path",
         "1536-byte-path", "surrogate"],
)
def test_hostile_names_are_a_422_naming_the_path(served, job_doc, path, words):
    c, alice, _root = served
    _refused(_submit(c, alice, job_doc, path), *words)


def test_a_name_longer_than_the_schema_allows_is_a_422(served, job_doc):
    c, alice, _root = served
    r = _submit(c, alice, job_doc, "a" * 5000)
    assert r.status_code == 422, r.text
    assert any(e["pointer"] == "/inputs/images/0/path" for e in r.json()["errors"]), r.text


def test_a_sibling_folder_sharing_the_prefix_is_outside(served, job_doc):
    """``alice2/`` starts with the text ``alice`` but is not inside ``alice/``: the folder check
    compares path components. A link ``alice/sib.tif -> ../alice2/x.tif`` (a readable raster) and
    a link to the folder ``alice2`` itself are refused."""
    c, alice, root = served
    os.symlink("../alice2/x.tif", root / "alice" / "sib.tif")
    _refused(_submit(c, alice, job_doc, "sib.tif"), "outside your image folder")
    os.symlink("../alice2", root / "alice" / "sibdir")
    _refused(_submit(c, alice, job_doc, "sibdir/x.tif"), "outside your image folder")
    # the same file linked from inside alice's own folder is accepted: the refusals above are the folder's
    shutil.copyfile(root / "alice2" / "x.tif", root / "alice" / "x.tif")
    os.symlink("x.tif", root / "alice" / "own.tif")
    assert _submit(c, alice, job_doc, "own.tif").status_code == 201


def test_the_image_root_itself_is_outside(served, job_doc):
    """A link up to the image root (or to the user's folder itself) is not a raster inside it."""
    c, alice, root = served
    shutil.copyfile(DATA / f"{LEFT}.tif", root / "top.tif")
    os.symlink("../top.tif", root / "alice" / "top.tif")
    _refused(_submit(c, alice, job_doc, "top.tif"), "outside your image folder")


URLS = [
    ("GET", "/jobs/%00", "/path/jobId"),
    ("GET", "/jobs/a%00b/results", "/path/jobId"),
    ("DELETE", "/jobs/%00", "/path/jobId"),
    ("GET", "/jobs/x/results/rpc/a%0Ab", "/path/image"),
    ("GET", "/cameras/%00", "/path/name"),
    ("GET", "/cameras/a%1Bb/versions", "/path/name"),
    ("GET", "/cameras/shared/%00", "/path/name"),
    ("GET", "/processes/%00", "/path/processId"),
    ("GET", "/jobs?name=%00", "/query/name"),
    ("GET", "/jobs?status=a%7Fb", "/query/status"),
    ("GET", "/no/such/%00/route", "/path"),
]


@pytest.fixture(params=["sqlite", pytest.param("postgresql", marks=pytest.mark.services)])
def any_store_app(request, tmp_path: Path):
    """The app on SQLite and on PostgreSQL (which refuses NUL in text: before, a 500)."""
    if request.param == "sqlite":
        urls = iter([None])
    else:
        from test_service_store import _pg_database

        urls = _pg_database()
    url = next(urls)
    settings = Settings(data_dir=tmp_path / "data", workers=0, require_api_keys=True, database_url=url)
    app = create_app(settings)
    try:
        with TestClient(app, raise_server_exceptions=False) as c:
            yield c, {"X-API-Key": create_key(app.state.services.store, "alice")[0]}
    finally:
        for _ in urls:  # drops the database
            pass


def test_a_control_character_in_the_url_is_a_400_naming_the_parameter(any_store_app):
    c, alice = any_store_app
    for method, url, pointer in URLS:
        r = c.request(method, url, headers=alice)
        assert r.status_code == 400, (url, r.text)
        assert r.headers["content-type"].startswith("application/problem+json")
        assert pointer in [e["pointer"] for e in r.json()["errors"]], (url, r.text)
    # the same URLs without the control character reach the routes (404: nothing of that name)
    assert c.get("/jobs/a", headers=alice).status_code == 404
    assert c.get("/cameras/ab/versions", headers=alice).status_code == 404
    assert c.get("/jobs?name=a", headers=alice).status_code == 200
