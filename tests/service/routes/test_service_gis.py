"""The GIS result endpoints on a real server (service/routes/gis.py): RPC files that GDAL reads,
GeoJSON, ground <-> image transforms agreeing with the solver's own (solver.gis) on the same
job and report; bad input and unfinished or failed jobs are problem documents, never a 500."""

from __future__ import annotations

from typing import Any

import numpy as np
import pytest
import rasterio
from pba_service_harness import Server, execute_body, load_example

from solver.gis.model import load_model

LONLAT_DEG = 1e-12  # the endpoint's lon/lat vs our geodesy on the same ECEF point: the same arithmetic
SERVICE_PX = 1e-6  # ground-to-image through the endpoint vs the pixel the ground came from: the projection's iterations

PROBLEM = "application/problem+json"
pytestmark = pytest.mark.filterwarnings("ignore::rasterio.errors.NotGeoreferencedWarning")


@pytest.fixture(scope="module")
def solved_nadir(server: Server, keys: dict[str, str]) -> dict[str, Any]:
    job = load_example("prism-nadir.json")
    with server.client(keys["alice"]) as c:
        r = c.post("/processes/bundle-adjustment/execution", json=execute_body(job))
        assert r.status_code == 200, r.text[:500]
        job_id = r.headers["location"].rsplit("/", 1)[1]
        report = c.get(f"/jobs/{job_id}/results").json()["report"]
    return {"id": job_id, "job": job, "report": report}


def _problem(r, status: int) -> dict[str, Any]:
    assert r.status_code == status, r.text[:500]
    assert r.headers["content-type"].startswith(PROBLEM)
    return r.json()


def test_transform_endpoints_agree_with_the_solver(server: Server, keys: dict[str, str], solved_nadir) -> None:
    model = load_model(solved_nadir["job"], solved_nadir["report"])
    image_id = model.image_ids[0]
    img = model.image(image_id)
    with server.client(keys["alice"]) as c:
        r = c.post(
            f"/jobs/{solved_nadir['id']}/results/image-to-ground",
            json={"image": image_id, "pixels": [{"line": 100.0, "column": 200.0, "height": 400.0}, {"line": 8000, "column": 7000, "height": 500}], "sigmas": True},
        )
        assert r.status_code == 200, r.text[:500]
        rows = r.json()["rows"]
        assert rows[0]["sigma_east_m"] > 0
        expected = img.image_to_ground(np.array([100.0, 8000.0]), np.array([200.0, 7000.0]), np.array([400.0, 500.0]))
        from solver.geometry.geodesy import ecef_to_geodetic

        llh = ecef_to_geodetic(expected)
        assert rows[1]["lon"] == pytest.approx(llh[1, 0], abs=LONLAT_DEG) and rows[1]["lat"] == pytest.approx(llh[1, 1], abs=LONLAT_DEG)
        r = c.post(f"/jobs/{solved_nadir['id']}/results/ground-to-image", json={"image": image_id, "points": [{"lon": x["lon"], "lat": x["lat"], "height": x["height"]} for x in rows]})
        assert r.status_code == 200, r.text[:500]
        back = r.json()["rows"]
        assert back[0]["line"] == pytest.approx(100.0, abs=SERVICE_PX) and back[1]["column"] == pytest.approx(7000.0, abs=SERVICE_PX)
        # bad rows and CRS: 422 naming the row; unknown image: 404
        doc = _problem(c.post(f"/jobs/{solved_nadir['id']}/results/ground-to-image", json={"image": image_id, "points": [{"lon": 1, "lat": 2, "height": 3}, {"lon": 1}]}), 422)
        assert doc["errors"][0]["pointer"] == "/points/1"
        doc = _problem(c.post(f"/jobs/{solved_nadir['id']}/results/ground-to-image", json={"image": image_id, "crs": "EPSG:999999", "points": [{"lon": 1, "lat": 2, "height": 3}]}), 422)
        assert doc["errors"][0]["pointer"] == "/crs"
        _problem(c.post(f"/jobs/{solved_nadir['id']}/results/ground-to-image", json={"image": "nope", "points": [{"lon": 1, "lat": 2, "height": 3}]}), 404)


def test_rpc_endpoint_serves_files_gdal_reads(server: Server, keys: dict[str, str], solved_nadir, tmp_path) -> None:
    model = load_model(solved_nadir["job"], solved_nadir["report"])
    image_id = model.image_ids[0]
    with server.client(keys["alice"]) as c:
        r = c.get(f"/jobs/{solved_nadir['id']}/results/rpc/{image_id}", params={"format": "rpb", "chip": "2"})
        assert r.status_code == 200, r.text[:500]
        assert r.headers["content-disposition"].endswith(f'{image_id}_2.RPB"')
        assert float(r.headers["x-rpc-check-rms-px"]) < 0.01
        (tmp_path / "chip.RPB").write_text(r.text)
        r = c.get(f"/jobs/{solved_nadir['id']}/results/rpc/{image_id}")
        assert r.status_code == 200 and "LINE_NUM_COEFF_20" in r.text
        assert "warning" in {k.lower() for k in r.headers}  # 4-chip raw image: the whole-image RPC warns
        _problem(c.get(f"/jobs/{solved_nadir['id']}/results/rpc/{image_id}", params={"format": "xml"}), 400)
        _problem(c.get(f"/jobs/{solved_nadir['id']}/results/rpc/{image_id}", params={"chip": "9"}), 404)
        _problem(c.get("/jobs/nope/results/rpc/x"), 404)
    with rasterio.open(tmp_path / "chip.tif", "w", driver="GTiff", width=8, height=8, count=1, dtype="uint8") as dst:
        dst.write(np.zeros((1, 8, 8), np.uint8))
    with rasterio.open(tmp_path / "chip.tif") as src:
        assert src.rpcs is not None and src.rpcs.line_scale > 1000


def test_geojson_endpoint(server: Server, keys: dict[str, str], solved_nadir) -> None:
    with server.client(keys["alice"]) as c:
        r = c.get(f"/jobs/{solved_nadir['id']}/results/geojson")
        assert r.status_code == 200, r.text[:500]
        assert r.headers["content-type"].startswith("application/geo+json")
        doc = r.json()
    kinds = [f["properties"]["kind"] for f in doc["features"]]
    job = solved_nadir["job"]
    assert kinds.count("footprint") == len(job["images"])
    assert kinds.count("control") == sum(p["role"] == "gcp" for p in job["points"])
    assert kinds.count("check") == sum(p["role"] == "check" for p in job["points"])
    ring = next(f for f in doc["features"] if f["properties"]["kind"] == "footprint")["geometry"]["coordinates"][0]
    assert ring[0] == ring[-1] and len(ring) == 33
    # every known point lies inside its image's footprint (lon/lat bounding box of the ring)
    lons, lats = [p[0] for p in ring], [p[1] for p in ring]
    for f in doc["features"]:
        if f["properties"]["kind"] in ("control", "check"):
            x, y = f["geometry"]["coordinates"]
            assert min(lons) < x < max(lons) and min(lats) < y < max(lats)
