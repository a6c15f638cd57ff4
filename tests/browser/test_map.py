"""The map view of a finished adjustment (service/static/ui/map.js) in headless Chromium: drawn
from /jobs/{id}/results/geojson with no request leaving the server (no tile server): one
footprint per image, one marker per point, one discrepancy arrow per check point, a scale bar
whose length agrees with the footprint's true size; the GIS download buttons are there."""

from __future__ import annotations

import math
import re
from pathlib import Path
from typing import Any

import httpx
import pytest
from pba_service_harness import Server, execute_body, load_example
from playwright.sync_api import expect

pytestmark = pytest.mark.browser
SOLVE_S = 240


def test_map_view_of_a_finished_job(page: Any, keyed_server: Server, api_key: str, artifacts: Path) -> None:
    job = load_example("prism-nadir.json")
    with httpx.Client(base_url=keyed_server.url, headers={"X-API-Key": api_key}, timeout=SOLVE_S) as c:
        r = c.post("/processes/bundle-adjustment/execution", json=execute_body(job))
        assert r.status_code == 200, r.text[:300]
        job_id = r.headers["location"].rsplit("/", 1)[1]
        geo = c.get(f"/jobs/{job_id}/results/geojson").json()
    requests: list[str] = []
    page.on("request", lambda req: requests.append(req.url))
    page.goto(f"{keyed_server.url}/ui")
    page.fill("#api-key", api_key)
    page.click("#key-form button[type=submit]")
    expect(page.locator("#key-status")).to_have_text("key in use (this tab)")
    page.goto(f"{keyed_server.url}/ui#job={job_id}")
    page.reload()  # the page opens the job of its #job= hash when it loads (the key stays in the tab)
    expect(page.locator("#map-svg")).to_be_visible(timeout=120_000)
    n_images = len(job["images"])
    n_points = sum(1 for f in geo["features"] if f["geometry"]["type"] == "Point")
    n_checks = sum(p["role"] == "check" for p in job["points"])
    expect(page.locator("#map-svg polygon.footprint")).to_have_count(n_images)
    expect(page.locator("#map-svg circle.point")).to_have_count(n_points)
    expect(page.locator("#map-svg circle.check")).to_have_count(n_checks)
    expect(page.locator("#map-svg line.discrepancy")).to_have_count(n_checks)
    expect(page.locator("#map-legend")).to_contain_text(re.compile(r"discrepancy arrows ×\d"))
    # the scale bar: its length in screen units / the footprint's width in screen units equals
    # the label's metres / the footprint's width in metres (equirectangular, 1 % tolerance)
    label = page.locator("#map-scale text").text_content()
    metres = float(label.split()[0]) * (1000 if label.endswith("km") else 1)
    bar = page.eval_on_selector("#map-scale line", "l => l.x2.baseVal.value - l.x1.baseVal.value")
    ring = next(f for f in geo["features"] if f["properties"]["kind"] == "footprint")["geometry"]["coordinates"][0]
    lat0 = sum(p[1] for p in ring) / len(ring)
    # the ring's first two corners are the first line's ends: ground width of the image
    span = page.eval_on_selector("#map-svg polygon.footprint", "p => { const a = p.points.getItem(0), b = p.points.getItem(8); return Math.hypot(b.x - a.x, b.y - a.y); }")
    k = math.pi / 180
    width_m = 6371008.8 * math.hypot(math.cos(lat0 * k) * (ring[8][0] - ring[0][0]) * k, (ring[8][1] - ring[0][1]) * k)
    assert abs((bar / span) / (metres / width_m) - 1) < 0.01
    expect(page.locator("#gis-downloads button")).to_have_count(1 + 2 * n_images)
    page.screenshot(path=str(artifacts / "map-view.png"), full_page=True)
    outside = [u for u in requests if not u.startswith(keyed_server.url) and not u.startswith(("data:", "blob:"))]
    assert not outside, outside
