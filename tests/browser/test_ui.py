"""The web page in real headless Chromium against a real server with real workers: submit the
example triplet and read its result (progress to 100, parameter tables, tests, plots loaded,
downloads), cancel a running job, validation errors beside the input, local mode and a model
comparison. Screenshots of the result views go to test-artifacts/browser/."""

from __future__ import annotations

import csv
import io
import json
import os
import re
from pathlib import Path
from typing import Any

import httpx
import pytest
from pba_service_harness import ROOT, Server, load_example
from playwright.sync_api import expect

pytestmark = pytest.mark.browser

# generous: a worker's first solve may compile the numba kernels (slow on a busy machine)
SOLVE_MS = 240_000
PLOTS_MS = 120_000
OK = re.compile(r"\bok\b")
BAD = re.compile(r"\bbad\b")
ADJUSTMENT_PLOTS = {
    "planimetric-discrepancies",
    "height-discrepancies",
    "image-residuals",
    "residual-histograms",
    "correlations",
    "cost",
    "error-ellipses",
}

# every plot image on the page has loaded and has pixels (naturalWidth > 0)
PLOTS_LOADED = """(n) => {
  const imgs = [...document.querySelectorAll('#plots img')];
  return imgs.length >= n && imgs.every((i) => i.complete && i.naturalWidth > 0);
}"""
LOADED_KINDS = """imgs => imgs.filter((i) => i.complete && i.naturalWidth > 0)
                              .map((i) => i.dataset.kind)"""

# records every text the progress percentage shows
RECORD_PROGRESS = """() => {
  window.__progress = [];
  const node = document.getElementById('cur-percent');
  new MutationObserver(() => window.__progress.push(node.textContent))
    .observe(node, {childList: true, characterData: true, subtree: true});
}"""


def open_ui(page: Any, server: Server, key: str | None = None) -> None:
    page.goto(f"{server.url}/ui")
    expect(page.locator("h1")).to_have_text("Pushbroom orientation server")
    if key:
        page.fill("#api-key", key)
        page.click("#key-form button[type=submit]")
        expect(page.locator("#key-status")).to_have_text("key in use (this tab)")


def set_document(page: Any, text: str) -> None:
    """Put a document in the editor as a paste would (page.fill types large texts slowly)."""
    page.evaluate(
        """(text) => {
          const ta = document.getElementById('job-text');
          ta.value = text;
          ta.dispatchEvent(new Event('input', {bubbles: true}));
        }""",
        text,
    )


def solve_document(page: Any, server: Server, job: dict) -> None:
    """Open the page, paste ``job`` as the document, wait for its validation, submit it and wait
    for the run to finish."""
    open_ui(page, server)
    set_document(page, json.dumps(job))
    expect(page.locator("#validation")).to_have_class(OK, timeout=30_000)
    page.click("#submit")
    expect(page.locator("#cur-percent")).to_have_text("100%", timeout=SOLVE_MS)


def pick_example(page: Any, name: str) -> None:
    page.select_option("#example", name)
    expect(page.locator("#validation")).to_have_class(OK, timeout=30_000)


def wait_plots(page: Any, n: int) -> list[str]:
    page.wait_for_function(PLOTS_LOADED, arg=n, timeout=PLOTS_MS)
    expect(page.locator("#plots .plot-error")).to_have_count(0)
    return page.eval_on_selector_all("#plots img", LOADED_KINDS)


# the picture of the web page on the README and the documentation's home page
FRONT_PAGE_PICTURE = "web-page.jpg"


def write_front_page_picture(page: Any, artifacts: Path) -> None:
    """The result of the example triplet as the front page shows it: a JPEG of one screen from
    the top of the result view (small enough to commit) in test-artifacts/browser/; with
    ``PBA_DOCS_SCREENSHOT=1`` also into docs/img/, the committed copy (run this test so to
    refresh it)."""
    page.evaluate("document.getElementById('result').scrollIntoView()")
    targets = [artifacts / FRONT_PAGE_PICTURE]
    if os.environ.get("PBA_DOCS_SCREENSHOT") == "1":
        targets.append(ROOT / "docs" / "img" / FRONT_PAGE_PICTURE)
    for target in targets:
        target.parent.mkdir(parents=True, exist_ok=True)
        page.screenshot(path=str(target), type="jpeg", quality=70, scale="css")


def test_submit_the_example_triplet_and_read_the_result(
    page: Any, keyed_server: Server, api_key: str, artifacts: Path
) -> None:
    open_ui(page, keyed_server, api_key)
    pick_example(page, "prism-triplet")
    expect(page.locator("#validation")).to_contain_text("219 degrees of freedom")
    page.evaluate(RECORD_PROGRESS)
    page.click("#submit")

    # live progress (SSE, with ?api_key=) up to 100
    expect(page.locator("#cur-percent")).to_have_text("100%", timeout=SOLVE_MS)
    expect(page.locator("#cur-status")).to_have_text("successful")
    expect(page.locator("#cur-progress")).to_have_js_property("value", 100)
    seen = [int(t.rstrip("%")) for t in page.evaluate("window.__progress") if t]
    assert seen and seen[-1] == 100 and seen == sorted(seen), seen
    job_id = page.locator("#cur-id").inner_text()

    with httpx.Client(base_url=keyed_server.url, headers={"X-API-Key": api_key}) as c:
        report = c.get(f"/jobs/{job_id}/results").json()["report"]

    # summary: sigma0, chi-square verdict, dof, iterations
    adj = report["adjustment"]
    summary = page.locator("#summary")
    expect(summary).to_contain_text(f"{adj['sigma0_aposteriori']:.4f}")
    expect(summary).to_contain_text("passed" if adj["chi2"]["passed"] else "rejected")
    expect(summary).to_contain_text(str(adj["dof"]))
    expect(summary).to_contain_text(str(adj["iterations"]))

    # one parameter table per image, a row per parameter, flags for correlations
    tables = page.locator("table.params")
    expect(tables).to_have_count(len(report["images"]))
    for im in report["images"]:
        rows = page.locator(f'table.params[data-image="{im["id"]}"] tbody tr')
        expect(rows).to_have_count(len(im["parameters"]))
        expect(rows.first).to_contain_text(im["parameters"][0]["name"])
    if report["correlations"]["pairs"]:
        assert page.locator("table.params .flag.corr").count() > 0

    # check-point statistics with the t-test and Shapiro-Wilk verdicts
    stats = page.locator("#checkpoint-stats")
    expect(stats).to_contain_text("t-test")
    expect(stats).to_contain_text("Shapiro-Wilk")
    t_e = report["checkpoints"]["t_test"]["e"]
    expect(stats.locator("tr", has_text="t-test")).to_contain_text(
        "no bias" if t_e["passed"] else "biased"
    )
    expect(stats.locator("tr", has_text="Shapiro-Wilk")).to_contain_text("normal")

    # plots: every kind that applies to the triplet, loaded as images
    kinds = wait_plots(page, len(ADJUSTMENT_PLOTS))
    assert set(kinds) == ADJUSTMENT_PLOTS, kinds
    widths = page.eval_on_selector_all(
        "#plots img", "imgs => imgs.map((i) => [i.dataset.kind, i.naturalWidth])"
    )
    assert all(w > 300 for _, w in widths), widths

    # one image of the per-image plots
    page.select_option("#plot-image", "prism-nadir")
    wait_plots(page, len(ADJUSTMENT_PLOTS))

    # downloads (fetched with the key)
    with page.expect_download() as dl:
        page.locator("button.download", has_text="parameters CSV").click()
    rows = list(csv.DictReader(io.StringIO(Path(dl.value.path()).read_text())))
    assert len(rows) == sum(len(im["parameters"]) for im in report["images"])
    with page.expect_download() as dl:
        page.locator("figure[data-kind='cost'] button.download", has_text="SVG").click()
    assert "<svg" in Path(dl.value.path()).read_text()[:2000]

    # the job list shows it
    expect(page.locator(f'#jobs-table tr[data-job="{job_id}"] .badge')).to_have_text("successful")

    page.select_option("#plot-image", "")
    wait_plots(page, len(ADJUSTMENT_PLOTS))
    page.screenshot(path=str(artifacts / "triplet-page.png"), full_page=True)
    page.locator("#result").screenshot(path=str(artifacts / "triplet-result.png"))
    page.locator("#adjustment").screenshot(path=str(artifacts / "triplet-tables.png"))
    write_front_page_picture(page, artifacts)


def test_cancel_a_running_job(
    page: Any, keyed_server: Server, api_key: str, big_job_file: Path, artifacts: Path
) -> None:
    open_ui(page, keyed_server, api_key)
    page.set_input_files("#file", str(big_job_file))
    expect(page.locator("#doc-info")).to_contain_text(big_job_file.name)
    expect(page.locator("#validation")).to_have_class(OK, timeout=60_000)
    page.click("#submit")
    expect(page.locator("#cur-status")).to_have_text("running", timeout=SOLVE_MS)
    expect(page.locator("#cancel")).to_be_enabled()
    page.click("#cancel")
    expect(page.locator("#cur-status")).to_have_text("dismissed", timeout=30_000)
    expect(page.locator("#cur-message")).to_contain_text("cancel")
    expect(page.locator("#cancel")).to_be_disabled()
    expect(page.locator("#result")).to_be_hidden()
    job_id = page.locator("#cur-id").inner_text()
    with httpx.Client(base_url=keyed_server.url, headers={"X-API-Key": api_key}) as c:
        st = c.get(f"/jobs/{job_id}").json()
    assert st["status"] == "dismissed" and st["progress"] < 100, st
    expect(page.locator(f'#jobs-table tr[data-job="{job_id}"] .badge')).to_have_text("dismissed")
    page.screenshot(path=str(artifacts / "cancelled.png"))


def test_validation_errors_beside_the_input(
    page: Any, keyed_server: Server, api_key: str, artifacts: Path
) -> None:
    open_ui(page, keyed_server, api_key)
    pick_example(page, "prism-triplet")
    broken = load_example("prism-triplet.json")
    broken["observations"][3]["image"] = "no-such-image"
    set_document(page, json.dumps(broken, indent=2))
    box = page.locator("#validation")
    expect(box).to_have_class(BAD, timeout=30_000)
    expect(box).to_contain_text("/inputs/job/observations/3/image")
    expect(box).to_contain_text("unknown image 'no-such-image'")
    page.locator("#new-job").screenshot(path=str(artifacts / "validation-error.png"))

    # submitting it is refused the same way; no job is created
    with httpx.Client(base_url=keyed_server.url, headers={"X-API-Key": api_key}) as c:
        before = c.get("/jobs").json()["numberMatched"]
        page.click("#submit")
        expect(box).to_contain_text("Not submitted")
        expect(box).to_contain_text("/inputs/job/observations/3/image")
        assert c.get("/jobs").json()["numberMatched"] == before

    # a schema error points at its field; broken JSON says where
    broken = load_example("prism-triplet.json")
    broken["points"][0]["role"] = "landmark"
    set_document(page, json.dumps(broken))
    expect(box).to_contain_text("/inputs/job/points/0/role", timeout=30_000)
    page.fill("#job-text", '{\n  "name": "x",\n  "cameras": [\n}')
    expect(box).to_contain_text("Not valid JSON")
    expect(box).to_contain_text("line 4, column 1")


def test_local_mode_model_comparison(page: Any, local_server: Server, artifacts: Path) -> None:
    open_ui(page, local_server)
    expect(page.locator("#key-status")).to_have_text("no key: local mode")
    expect(page.locator("#jobs-table")).to_contain_text("No jobs yet.")
    # the page reads the model names from /processes/model-comparison first
    expect(page.locator("#models")).to_have_attribute("title", re.compile("available: .*K2"))
    page.select_option("#process", "model-comparison")
    page.fill("#models", "K2, P1")
    pick_example(page, "prism-nadir")
    page.click("#submit")
    expect(page.locator("#cur-percent")).to_have_text("100%", timeout=SOLVE_MS)
    table = page.locator("#comparison-table")
    expect(table.locator("tbody tr")).to_have_count(2)
    expect(table).to_contain_text("K2")
    expect(table).to_contain_text("P1")
    # mono check points: no height plot; the per-model RMSE bars are there
    kinds = wait_plots(page, 5)
    assert {"model-rmse", "planimetric-discrepancies", "image-residuals"} <= set(kinds), kinds
    assert "height-discrepancies" not in kinds
    expect(page.locator(".param-card .meta").first).to_contain_text("K2")
    page.screenshot(path=str(artifacts / "comparison-page.png"), full_page=True)
    page.select_option("#model-select", "P1")
    expect(page.locator(".param-card .meta").first).to_contain_text("P1")
    wait_plots(page, 5)
    page.locator("#result").screenshot(path=str(artifacts / "comparison-result.png"))


def test_pass_propagated_model_shows_the_shared_orbit(page: Any, local_server: Server, artifacts: Path) -> None:
    """Comparison of OA-J2 and PASS-J2 on the triplet: the pass model's result has one card for
    the shared orbit state (six rows) besides the three attitude cards."""
    open_ui(page, local_server)
    page.select_option("#process", "model-comparison")
    page.fill("#models", "OA-J2, PASS-J2")
    pick_example(page, "prism-triplet")
    page.click("#submit")
    expect(page.locator("#cur-percent")).to_have_text("100%", timeout=SOLVE_MS)
    expect(page.locator("#comparison-table tbody tr")).to_have_count(2)
    page.select_option("#model-select", "PASS-J2")
    card = page.locator('table.params[data-pass="1"] tbody tr')
    expect(card).to_have_count(6)
    expect(card.first).to_contain_text("X")
    expect(page.locator("table.params[data-image]")).to_have_count(3)
    page.locator("#result").screenshot(path=str(artifacts / "pass-model-result.png"))


def test_direct_georeferencing_example_shows_the_measured_attitude(
    page: Any, local_server: Server, artifacts: Path
) -> None:
    """examples/prism-triplet-direct.json (no control: ephemeris and attitude weighted): the
    result has the measured-attitude table, one row per camera with the residual RMS of roll,
    pitch and yaw at the level of their 0.002-deg sigma, and the check points."""
    open_ui(page, local_server)
    pick_example(page, "prism-triplet-direct")
    page.click("#submit")
    expect(page.locator("#cur-percent")).to_have_text("100%", timeout=SOLVE_MS)
    rows = page.locator('table[data-attitude="1"] tbody tr')
    expect(rows).to_have_count(3)
    for k in range(3):
        cells = rows.nth(k).locator("td")
        expect(cells.nth(1)).to_have_text(re.compile(r"^[56]$"))  # 1-Hz samples over a ~6-s image
        rms, _max, sigma = (float(x) for x in cells.nth(2).inner_text().split(" / "))
        assert sigma == 0.002 and 0.0005 < rms < 0.005, (rms, sigma)
    expect(page.locator("#result")).to_contain_text("Check points")
    page.locator("#result").screenshot(path=str(artifacts / "direct-georeferencing-result.png"))


def test_blunder_detection_table(page: Any, local_server: Server, artifacts: Path) -> None:
    """A job with two image blunders and options.blunder_detection: the result lists the rejected
    column error and the non-identifiable group of the along-track error (three rays of one tie
    point) with w above the critical value, and offers rejected.csv."""
    from utils.scenes import block_job

    job, _truth = block_job(model="P1", n_tie=30, n_gcp=14, n_check=6, seed=3, gcp_sigma_m=0.5)
    ties = [i for i, o in enumerate(job["observations"]) if "-T" in o["point"]]
    job["observations"][ties[0]]["line"] += 20.0
    job["observations"][ties[5]]["column"] += 12.0
    job["options"] = {"blunder_detection": {}}
    solve_document(page, local_server, job)
    rows = page.locator("#snooping-table tbody tr")
    expect(rows).to_have_count(4)
    expect(rows.first).to_contain_text(job["observations"][ties[5]]["point"])
    expect(page.locator("#snooping-table")).to_contain_text("not identifiable #1")
    for k in range(4):
        cells = rows.nth(k).locator("td")
        assert float(cells.nth(3).inner_text()) > float(cells.nth(4).inner_text())
    button = page.locator("button.download", has_text="rejected CSV")
    expect(button).to_have_count(1)
    assert button.get_attribute("data-href").endswith("/results/rejected.csv")
    page.locator("#result").screenshot(path=str(artifacts / "blunder-detection-result.png"))


def test_blunder_detection_shows_reinstated_and_lost_control(page: Any, local_server: Server, artifacts: Path) -> None:
    """One image with four image blunders on control points and a moved control point
    (prism-single seed 4): every blunder of a single image's control point is a
    non-identifiable {image point, survey} group whose removal costs the control point; a
    clean group removed on the way is put back. The page lists the reinstated members with
    their predicted test and names the lost control points with the predicted check RMSE."""
    from utils.blunder_scenes import prism_single_with_blunders

    import solver.api

    job, _injected = prism_single_with_blunders(seed=4)
    job["options"] = {"blunder_detection": {"max_rejections": 50}}
    q = solver.api.run(json.loads(json.dumps(job)))["quality"]
    assert q["reinstated"] and q["lost_control"]["points"], "the scene reinstates and loses control (measured)"
    solve_document(page, local_server, job)
    back = page.locator("#snooping-table tbody tr.reinstated")
    expect(back).to_have_count(len(q["reinstated"]))
    expect(back.first).to_contain_text("reinstated (predicted w")
    lost = page.locator("#lost-control")
    for pid in q["lost_control"]["points"]:
        expect(lost).to_contain_text(pid)
    expect(lost).to_contain_text("predicted check-point RMSE")
    page.locator("#result").screenshot(path=str(artifacts / "blunder-detection-reinstated.png"))


def test_preanalysis_of_a_planned_layout(page: Any, local_server: Server, artifacts: Path) -> None:
    """The example triplet as planned (no observations, tie points at their simulated places),
    run as the preanalysis process: the page shows the predicted precision of every planned
    point and the map of error ellipses."""
    job = load_example("prism-triplet.json")
    truth = json.loads((Path(__file__).resolve().parents[2] / "examples" / "prism-triplet.truth.json").read_text())
    where = {p["id"]: p for p in truth["points"]}
    job["observations"] = []
    for p in job["points"]:
        if p["role"] == "tie":
            q = where[p["id"]]
            p["coordinates"] = [q["lon_deg"], q["lat_deg"], q["height_m"]]
    open_ui(page, local_server)
    page.select_option("#process", "preanalysis")
    set_document(page, json.dumps(job))
    expect(page.locator("#validation")).to_contain_text("planned points", timeout=30_000)
    page.click("#submit")
    expect(page.locator("#cur-percent")).to_have_text("100%", timeout=SOLVE_MS)
    expect(page.locator("#preanalysis-points tbody tr")).to_have_count(len(job["points"]))
    expect(page.locator("#preanalysis-rmse")).to_contain_text("predicted check RMSE")
    kinds = wait_plots(page, 1)
    assert kinds == ["error-ellipses"], kinds
    page.locator("#result").screenshot(path=str(artifacts / "preanalysis-result.png"))


def test_the_page_says_when_the_workers_are_not_ready(page: Any, local_server: Server) -> None:
    """The page reads /readyz: a ready server shows no notice; while /readyz answers 503 (the
    workers loading the solver and compiling its kernels; here the answer is held by the test,
    with the body the server writes) the page says so and why, and the notice goes once the
    server is ready."""
    ready = httpx.get(f"{local_server.url}/readyz", timeout=10)
    assert ready.status_code == 200, ready.text
    open_ui(page, local_server)
    expect(page.locator("#readiness")).to_be_hidden()
    starting = {"status": "unavailable", "checks": {
        "store": "ok", "queue": "1 of 1 workers alive, 0 ready (1 starting: loading the solver, compiling its kernels)",
        "evaluation": "compiled"}}
    page.route("**/readyz", lambda route: route.fulfill(status=503, content_type="application/json", body=json.dumps(starting)))
    open_ui(page, local_server)
    notice = page.locator("#readiness")
    expect(notice).to_be_visible()
    expect(notice).to_contain_text("not ready yet")
    expect(notice).to_contain_text("0 ready (1 starting: loading the solver, compiling its kernels)")
    page.unroute("**/readyz")  # the real server, ready: the page notices at its next poll
    expect(notice).to_be_hidden(timeout=20_000)
