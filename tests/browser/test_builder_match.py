"""The job builder's "find tie points" step: two real Pleiades images (tests/data/matching:
their RPC sidecars make the job, their rasters go to the match process) get tie points, which
join the composed job as one measurement file per image; a raster named in the user's folder
on the server (PBA_IMAGE_ROOT) works the same way, and a path leaving the folder is refused
with the server's message."""

from __future__ import annotations

import json
import re
import shutil
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest
from pba_service_harness import ROOT, Server
from playwright.sync_api import expect

pytestmark = pytest.mark.browser

DATA = ROOT / "tests" / "data" / "matching"
LEFT, RIGHT = "ventoux_left", "ventoux_right"
MATCH_MS = 300_000
MIN_TIE_POINTS = 20  # the grid of 16 cells finds ~90 on this pair (tests/solver/matching/test_matching_real.py)


@pytest.fixture(scope="module")
def match_server(tmp_path_factory: pytest.TempPathFactory) -> Iterator[tuple[Server, Path]]:
    """A local single-user server (user ``local``) with an image root holding the right image."""
    base = tmp_path_factory.mktemp("builder-match")
    root = base / "images"
    (root / "local" / "pleiades").mkdir(parents=True)
    shutil.copyfile(DATA / f"{RIGHT}.tif", root / "local" / "pleiades" / f"{RIGHT}.tif")
    with Server(base / "data", workers=1, require_api_keys="false", image_root=str(root)) as srv:
        yield srv, root


def _ties(page: Any) -> dict[str, int]:
    job = json.loads(page.locator("#builder-json").input_value())
    counts: dict[str, int] = {}
    for o in job["observations"]:
        counts[o["image"]] = counts.get(o["image"], 0) + 1
    return counts


def test_find_tie_points_from_uploaded_and_server_rasters(page: Any, match_server: tuple[Server, Path]) -> None:
    srv, _root = match_server
    page.goto(f"{srv.url}/ui")
    page.set_input_files("#builder-input", [str(DATA / f"{LEFT}_RPC.TXT"), str(DATA / f"{RIGHT}_RPC.TXT"),
                                            str(DATA / f"{LEFT}.tif"), str(DATA / f"{RIGHT}.tif")])
    expect(page.locator(f'select.b-kind[data-file="{LEFT}.tif"]')).to_have_value("raster")
    expect(page.locator(f'select.b-kind[data-file="{LEFT}_RPC.TXT"]')).to_have_value("rpc")
    expect(page.locator("#builder-json")).to_have_value(re.compile('"rpc"'), timeout=60_000)
    page.fill("#b-heights", "400,700")
    expect(page.locator("#builder-match")).to_be_enabled()
    page.click("#builder-match")
    expect(page.locator("#builder-match-status")).to_contain_text("tie points", timeout=MATCH_MS)
    expect(page.locator("#builder-match-pairs")).to_contain_text(f"{LEFT}-{RIGHT}")
    expect(page.locator(f'select.b-kind[data-file="{LEFT}-matched-ties.csv"]')).to_have_value("measurements")
    expect(page.locator("#builder-messages")).to_contain_text(re.compile(rf"{LEFT}: 0 gcp, 0 check, [1-9]\d* tie measured"), timeout=60_000)
    # the first composition (RPCs alone) already lists both images with 0 tie points measured:
    # waiting for a non-zero count waits for the composition that holds the matched files
    counts = _ties(page)
    assert counts.get(LEFT, 0) >= MIN_TIE_POINTS and counts.get(LEFT) == counts.get(RIGHT), counts

    # the right image from the server instead of the upload; then a path leaving the folder
    page.fill("#b-raster-paths", f"{RIGHT}=pleiades/{RIGHT}.tif")
    page.click("#builder-match")
    expect(page.locator("#builder-match-status")).to_contain_text("tie points", timeout=MATCH_MS)
    page.fill("#b-raster-paths", f"{RIGHT}=../{RIGHT}.tif")
    page.click("#builder-match")
    expect(page.locator("#builder-match-status")).to_contain_text("refused", timeout=60_000)
    expect(page.locator("#builder-match-status")).to_contain_text("/inputs/images")
