"""The ``match`` process: tie points from uploaded rasters and from rasters under the server's
image root (``PBA_IMAGE_ROOT``, one folder per user name), run by the worker code with its
progress and cancel hooks, and every bad raster input a 4xx naming the input.

The rasters are the real Pleiades pair of tests/data/matching (Mont Ventoux, with RPCs); the
job orienting them is their delivered RPCs (RPC-SHIFT images, no measurement yet).
"""

from __future__ import annotations

import base64
import csv
import io
import os
import shutil
import sys
from pathlib import Path
from typing import Any

import pytest
from fastapi.testclient import TestClient

from service.app import create_app
from service.auth import create_key
from service.execution import RunLimits, run_claimed_job
from service.processes import MATCH, PROCESSES
from service.settings import Settings
from service.states import JobStatus
from solver.raster_gate import create_raster

sys.path.insert(0, str(Path(__file__).parent.parent))
from test_matching_real import DATA, MIN_TIE_POINTS, PAIRS, _rpc_job  # noqa: E402

pytestmark = [pytest.mark.slow, pytest.mark.filterwarnings("ignore::rasterio.errors.NotGeoreferencedWarning")]

LEFT, RIGHT, HEIGHTS = PAIRS["ventoux"]
HEIGHTS_M = [float(h) for h in HEIGHTS.split(",")]
FAST = {"grid": 8}  # fewer tiles than the default 16: the same checks in a quarter of the time
MIN_TIES_FAST = MIN_TIE_POINTS // 4


def _b64(path: Path) -> str:
    return base64.b64encode(path.read_bytes()).decode()


def _inputs(images: list[dict[str, Any]], **extra: Any) -> dict[str, Any]:
    return {"inputs": {"job": _rpc_job([LEFT, RIGHT], []), "images": images, "heights_m": HEIGHTS_M, "match": FAST, **extra}}


@pytest.fixture()
def served(tmp_path: Path):
    root = tmp_path / "images"
    (root / "alice" / "pleiades").mkdir(parents=True)
    (root / "bob").mkdir()
    for name in (LEFT, RIGHT):
        shutil.copyfile(DATA / f"{name}.tif", root / "alice" / "pleiades" / f"{name}.tif")
    shutil.copyfile(DATA / f"{LEFT}.tif", root / "bob" / "secret.tif")
    settings = Settings(data_dir=tmp_path / "data", workers=0, require_api_keys=True, image_root=root,
                        max_image_upload_bytes=1_000_000)
    app = create_app(settings)
    with TestClient(app) as c:
        store = app.state.services.store
        yield c, store, {"X-API-Key": create_key(store, "alice")[0]}, root


def _submit(c: TestClient, alice: dict[str, str], body: dict[str, Any]):
    return c.post(f"/processes/{MATCH}/execution", json=body, headers={**alice, "Prefer": "respond-async"})


def _run(store, job_id: str) -> JobStatus | None:
    claimed = store.claim(job_id, "test-worker")
    assert claimed is not None
    return run_claimed_job(store, claimed, "test-worker", RunLimits(job_time_limit_s=600))


def _problem(r, pointer: str, *words: str) -> None:
    assert r.status_code == 422, r.text
    body = r.json()
    assert pointer in [e["pointer"] for e in body["errors"]], body
    text = body["detail"] + " ".join(e["message"] for e in body["errors"])
    for w in words:
        assert w in text, text


def test_match_is_listed_and_described(served):
    c, _store, alice, _root = served
    assert MATCH in {p["id"] for p in c.get("/processes", headers=alice).json()["processes"]}
    d = c.get(f"/processes/{MATCH}", headers=alice).json()
    assert {"job", "images", "heights_m", "match"} <= set(d["inputs"])
    assert d["outputs"]["report"]["title"] == "Tie points"


def test_uploaded_rasters_are_matched(served):
    c, store, alice, _root = served
    r = _submit(c, alice, _inputs([{"id": LEFT, "value": _b64(DATA / f"{LEFT}.tif"), "mediaType": "image/tiff"},
                                   {"id": RIGHT, "value": _b64(DATA / f"{RIGHT}.tif")}]))
    assert r.status_code == 201, r.text
    job_id = r.json()["jobID"]
    assert _run(store, job_id) == JobStatus.successful
    status = c.get(f"/jobs/{job_id}", headers=alice).json()
    tables = [ln["href"] for ln in status["links"] if ln["type"] == "text/csv"]
    assert len(tables) == 1 and tables[0].endswith("/results/observations.csv")
    result = c.get(f"/jobs/{job_id}/results", headers=alice).json()["report"]
    assert result["kind"] == "tie-points" and result["summary"]["tie_points"] >= MIN_TIES_FAST
    rows = list(csv.DictReader(io.StringIO(c.get(f"/jobs/{job_id}/results/observations.csv", headers=alice).text)))
    assert list(rows[0]) == ["image", "point", "line", "column", "sigma_px"]
    assert len(rows) == result["summary"]["measurements"] and {r["image"] for r in rows} == {LEFT, RIGHT}


def test_rasters_under_the_image_root_are_matched(served):
    c, store, alice, _root = served
    r = _submit(c, alice, _inputs([{"id": LEFT, "path": f"pleiades/{LEFT}.tif"}, {"id": RIGHT, "path": f"pleiades/{RIGHT}.tif"}]))
    assert r.status_code == 201, r.text
    assert _run(store, r.json()["jobID"]) == JobStatus.successful


def test_paths_outside_the_users_folder_are_refused(served, tmp_path):
    c, store, alice, root = served
    right = {"id": RIGHT, "path": f"pleiades/{RIGHT}.tif"}

    def refused(path: str, *words: str) -> None:
        _problem(_submit(c, alice, _inputs([{"id": LEFT, "path": path}, right])), "/inputs/images/0/path", *words)

    refused("../bob/secret.tif", "..")
    refused("pleiades/../../bob/secret.tif", "..")
    refused(str(root / "bob" / "secret.tif"), "relative")
    refused("/etc/passwd", "relative")
    refused("pleiades/none.tif", "no such raster")
    outside = tmp_path / "outside.tif"
    shutil.copyfile(DATA / f"{LEFT}.tif", outside)
    os.symlink(outside, root / "alice" / "escape.tif")
    refused("escape.tif", "outside your image folder")
    os.symlink(root / "bob", root / "alice" / "bobs")
    refused("bobs/secret.tif", "outside your image folder")
    # a link inside the folder is fine
    os.symlink(root / "alice" / "pleiades" / f"{LEFT}.tif", root / "alice" / "left-link.tif")
    assert _submit(c, alice, _inputs([{"id": LEFT, "path": "left-link.tif"}, right])).status_code == 201

    # a file replaced by a link leaving the folder after submission: the worker refuses it
    r = _submit(c, alice, _inputs([{"id": LEFT, "path": "left-link.tif"}, right]))
    job_id = r.json()["jobID"]
    (root / "alice" / "left-link.tif").unlink()
    os.symlink(outside, root / "alice" / "left-link.tif")
    assert _run(store, job_id) == JobStatus.failed
    failed = c.get(f"/jobs/{job_id}/results", headers=alice)
    assert failed.status_code == 422 and "outside your image folder" in failed.text


def test_bad_uploads_and_inputs_are_refused(served, tmp_path, triplet_doc):
    c, _store, alice, _root = served
    good = {"id": RIGHT, "value": _b64(DATA / f"{RIGHT}.tif")}

    def refused(first: dict[str, Any], pointer: str, *words: str, **extra: Any) -> None:
        _problem(_submit(c, alice, _inputs([first, good], **extra)), pointer, *words)

    data = (DATA / f"{LEFT}.tif").read_bytes()
    refused({"id": LEFT, "value": base64.b64encode(data[: len(data) // 2]).decode()}, "/inputs/images/0/value", "truncated")
    refused({"id": LEFT, "value": "not base64!"}, "/inputs/images/0/value", "base64")
    vrt = b'<VRTDataset rasterXSize="2000000" rasterYSize="10"><VRTRasterBand dataType="Byte" band="1"/></VRTDataset>'
    refused({"id": LEFT, "value": base64.b64encode(vrt).decode()}, "/inputs/images/0/value", "not a supported raster format")
    huge = tmp_path / "huge.tif"
    with create_raster(huge, driver="GTiff", width=2_000_000, height=10, count=1, dtype="uint8", tiled=True, sparse_ok=True):
        pass
    refused({"id": LEFT, "value": _b64(huge)}, "/inputs/images/0/value", "2000000 x 10")
    refused({"id": LEFT, "value": base64.b64encode(b"hello").decode()}, "/inputs/images/0/value", "not a supported raster format")
    refused({"id": LEFT, "value": base64.b64encode(b"\0" * 1_100_000).decode()}, "/inputs/images/0/value", "larger than")
    refused({"id": "nadir", "value": good["value"]}, "/inputs/images/0/id", "no image")
    refused({"id": RIGHT, "value": good["value"]}, "/inputs/images/1/id", "twice")
    refused({"id": LEFT, "value": good["value"]}, "/inputs/heights_m", "below", heights_m=[700.0, 400.0])
    one = _submit(c, alice, {"inputs": {"job": _rpc_job([LEFT, RIGHT], []), "images": [good]}})
    assert one.status_code == 422 and one.json()["errors"][0]["pointer"] == "/inputs/images"
    # the match inputs are not inputs of the adjustment
    r = c.post("/processes/bundle-adjustment/execution", json={"inputs": {"job": triplet_doc, "images": [good, good]}},
               headers={**alice, "Prefer": "respond-async"})
    assert r.status_code == 422 and r.json()["errors"][0]["pointer"] == "/inputs/images"


def test_no_image_root_means_uploads_only(tmp_path):
    app = create_app(Settings(data_dir=tmp_path, workers=0, require_api_keys=True))
    with TestClient(app) as c:
        alice = {"X-API-Key": create_key(app.state.services.store, "alice")[0]}
        r = _submit(c, alice, _inputs([{"id": LEFT, "path": f"{LEFT}.tif"}, {"id": RIGHT, "path": f"{RIGHT}.tif"}]))
        _problem(r, "/inputs/images/0/path", "PBA_IMAGE_ROOT")


def test_a_non_overlapping_pair_fails_with_422(served):
    """The orientation says the images do not overlap at these heights: the job fails with the
    matching's message (422), the worker goes on."""
    c, store, alice, _root = served
    r = _submit(c, alice, _inputs([{"id": LEFT, "path": f"pleiades/{LEFT}.tif"}, {"id": RIGHT, "path": f"pleiades/{RIGHT}.tif"}],
                                  heights_m=[3000.0, 3100.0]))
    job_id = r.json()["jobID"]
    assert _run(store, job_id) == JobStatus.failed
    failed = c.get(f"/jobs/{job_id}/results", headers=alice)
    assert failed.status_code == 422 and "overlap" in failed.text


def test_progress_and_cancel(served):
    """The worker's hooks reach the matching: progress rises, and a cancel request stops it."""
    c, store, alice, _root = served
    body = _inputs([{"id": LEFT, "path": f"pleiades/{LEFT}.tif"}, {"id": RIGHT, "path": f"pleiades/{RIGHT}.tif"}])
    job_id = _submit(c, alice, body).json()["jobID"]
    document = store.get_document(job_id)
    seen: list[float] = []
    PROCESSES[MATCH].run(document, lambda f, m, *a: seen.append(f), lambda: False)
    assert seen and seen == sorted(seen) and seen[-1] == 1.0

    job_id = _submit(c, alice, body).json()["jobID"]
    claimed = store.claim(job_id, "test-worker")
    store.request_cancel(job_id, "user")
    assert run_claimed_job(store, claimed, "test-worker", RunLimits(job_time_limit_s=600, cancel_poll_interval_s=0.0)) == JobStatus.dismissed
