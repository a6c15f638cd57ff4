"""Plots of a report (service/plots.py) and the plot endpoints (/jobs/{jobId}/plots/...):
every kind draws a valid PNG and SVG for real solved jobs (the example triplet, a mono nadir
scene, a model comparison); a plot that does not apply answers a 409 problem document, an unknown
image or model 404, a failed job 409; never a 500."""

from __future__ import annotations

import ast
import copy
import io
import xml.etree.ElementTree as ET
from pathlib import Path
from typing import Any

import httpx
import numpy as np
import pytest
from matplotlib.image import imread
from pba_service_harness import Server, execute_body, load_example

from service import plots
from service.plots import PLOT_KINDS, NoSuchSelection, PlotNotApplicable
from solver import api

CORRELATION_ABS = 1e-12  # the heat map shows the covariance normalised: the same division, values in [-1, 1]

PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"
PROBLEM = "application/problem+json"
ADJUSTMENT_KINDS = {k for k, spec in PLOT_KINDS.items() if spec.scope == "adjustment"}


def assert_png(data: bytes) -> np.ndarray:
    assert data[:8] == PNG_SIGNATURE
    pixels = imread(io.BytesIO(data), format="png")
    assert pixels.ndim == 3 and pixels.shape[0] > 200 and pixels.shape[1] > 300
    assert pixels.std() > 0.01, "a blank image"
    return pixels


def assert_svg(data: bytes) -> ET.Element:
    root = ET.fromstring(data)
    assert root.tag in ("svg", "{http://www.w3.org/2000/svg}svg"), root.tag
    assert len(list(root.iter())) > 50
    return root


# -- the plot functions on real reports ------------------------------------------------------------
@pytest.fixture(scope="module")
def triplet_report() -> dict[str, Any]:
    """The example triplet solved by the solver (intersection check points, covariance)."""
    return api.run(load_example("prism-triplet.json"))


@pytest.fixture(scope="module")
def nadir_report() -> dict[str, Any]:
    """The example nadir scene (mono check points: no height discrepancies)."""
    return api.run(load_example("prism-nadir.json"))


@pytest.fixture(scope="module")
def comparison_report() -> dict[str, Any]:
    return api.compare(load_example("prism-nadir.json"), ["K2", "P1"])


@pytest.mark.parametrize("fmt", ["png", "svg"])
def test_every_kind_draws_the_triplet(triplet_report: dict[str, Any], fmt: str) -> None:
    assert set(plots.applicable(triplet_report)) == ADJUSTMENT_KINDS
    for kind in ADJUSTMENT_KINDS:
        data = plots.plot_bytes(triplet_report, kind, fmt)
        (assert_png if fmt == "png" else assert_svg)(data)
    with pytest.raises(PlotNotApplicable, match="model comparison"):
        plots.plot(triplet_report, "model-rmse")


def test_applicable_agrees_with_drawing(
    triplet_report: dict[str, Any],
    nadir_report: dict[str, Any],
    comparison_report: dict[str, Any],
) -> None:
    no_cov = copy.deepcopy(triplet_report)
    for im in no_cov["images"]:
        im["covariance"] = None
    no_cost = copy.deepcopy(nadir_report)
    no_cost["adjustment"]["cost_history"] = []
    for report in (triplet_report, nadir_report, comparison_report, no_cov, no_cost):
        kinds = set(plots.applicable(report))
        for kind in PLOT_KINDS:
            try:
                plots.plot(report, kind)
                drawn = True
            except PlotNotApplicable:
                drawn = False
            assert drawn == (kind in kinds), (kind, report.get("job_name"))
    assert "height-discrepancies" not in plots.applicable(nadir_report)
    assert "correlations" not in plots.applicable(no_cov)
    assert "cost" not in plots.applicable(no_cost)
    assert "model-rmse" in plots.applicable(comparison_report)


def test_mono_check_points_have_no_height_plot(nadir_report: dict[str, Any]) -> None:
    with pytest.raises(PlotNotApplicable, match="mono"):
        plots.plot(nadir_report, "height-discrepancies")


def test_per_image_selection(triplet_report: dict[str, Any]) -> None:
    for kind in ("image-residuals", "residual-histograms", "correlations"):
        fig = plots.plot(triplet_report, kind, image="prism-nadir")
        text = " ".join(t.get_text() for ax in fig.axes for t in [ax.title])
        assert "prism-backward" not in text
        with pytest.raises(NoSuchSelection):
            plots.plot(triplet_report, kind, image="no-such-image")
    fig = plots.plot(triplet_report, "image-residuals")
    assert sum(ax.get_visible() for ax in fig.axes) == 3  # one panel per image


def test_correlation_heat_map_is_the_covariance_normalised(triplet_report: dict[str, Any]) -> None:
    im = triplet_report["images"][1]
    fig = plots.plot(triplet_report, "correlations", image=im["id"])
    shown = np.asarray(fig.axes[0].images[0].get_array())
    c = np.array(im["covariance"]["matrix"])
    s = np.sqrt(np.diag(c))
    np.testing.assert_allclose(shown, c / np.outer(s, s), atol=CORRELATION_ABS)
    assert np.allclose(np.diag(shown), 1.0)


def test_comparison_model_rmse_and_model_selection(comparison_report: dict[str, Any]) -> None:
    fig = plots.plot(comparison_report, "model-rmse")
    ax = fig.axes[0]
    assert [t.get_text() for t in ax.get_xticklabels()] == ["K2", "P1"]
    bars = {
        label: [p.get_height() for p in container]
        for container, label in zip(ax.containers, ["E", "N", "planimetric"], strict=False)
    }
    table = {row["model"]: row for row in comparison_report["table"]}
    assert bars["E"] == pytest.approx(
        [table["K2"]["check_rmse_e_m"], table["P1"]["check_rmse_e_m"]]
    )
    assert_png(plots.plot_bytes(comparison_report, "model-rmse", "png"))
    # the single-adjustment kinds draw one model's report
    fig = plots.plot(comparison_report, "image-residuals", model="P1")
    assert "(P1)" in fig.axes[0].get_title()
    with pytest.raises(NoSuchSelection):
        plots.plot(comparison_report, "cost", model="J2-2")
    failed = copy.deepcopy(comparison_report)
    failed["reports"]["P1"] = {"error": {"detail": "rank deficient"}}
    with pytest.raises(PlotNotApplicable, match="rank deficient"):
        plots.plot(failed, "cost", model="P1")


def test_reports_with_nulls_do_not_break_the_plots(triplet_report: dict[str, Any]) -> None:
    """The stored report writes NaN as null: plots skip such values."""
    report = copy.deepcopy(triplet_report)
    report["checkpoints"]["points"][0]["discrepancy_m"] = {"e": None, "n": None, "u": None}
    report["checkpoints"]["gsd_m"] = None
    report["observations"][0]["residual_line_px"] = None
    report["observations"][1]["standardized_line"] = None
    report["images"][0]["covariance"]["matrix"][0][0] = None
    report["adjustment"]["cost_history"][0]["cost"] = None
    for kind in ADJUSTMENT_KINDS:
        assert_png(plots.plot_bytes(report, kind, "png"))


def test_plots_do_no_solver_mathematics() -> None:
    """service/plots.py draws the report: it imports neither the solver nor the service."""
    source = Path(plots.__file__).read_text()
    imported = {
        (node.module or "") if isinstance(node, ast.ImportFrom) else alias.name
        for node in ast.walk(ast.parse(source))
        if isinstance(node, (ast.Import, ast.ImportFrom))
        for alias in node.names
    }
    assert not {m for m in imported if m.split(".")[0] in ("solver", "service", "pyceres")}


# -- the endpoints on a real server ---------------------------------------------------------------
@pytest.fixture(scope="module")
def solved(server: Server, keys: dict[str, str]) -> dict[str, str]:
    """alice's solved jobs on the shared server: the triplet, the nadir scene, a comparison,
    and one the solver rejects (failed)."""
    ids = {}
    with server.client(keys["alice"]) as c:
        for name, process, body in (
            ("triplet", "bundle-adjustment", execute_body(load_example("prism-triplet.json"))),
            ("nadir", "bundle-adjustment", execute_body(load_example("prism-nadir.json"))),
            (
                "comparison",
                "model-comparison",
                execute_body(load_example("prism-nadir.json"), models=["K2", "P1"]),
            ),
        ):
            r = c.post(f"/processes/{process}/execution", json=body)
            assert r.status_code == 200, r.text[:500]
            ids[name] = r.headers["location"].rsplit("/", 1)[1]
        job = load_example("prism-triplet.json")
        for p in [p for p in job["points"] if p["role"] == "gcp"][1:]:
            p["role"] = "tie"  # one control point: the solver rejects it
        r = c.post("/processes/bundle-adjustment/execution", json=execute_body(job))
        assert r.status_code == 422, r.text[:300]
        ids["failed"] = r.headers["location"].rsplit("/", 1)[1]
    return ids


def assert_problem(r: httpx.Response, status: int) -> dict[str, Any]:
    assert r.status_code == status, r.text[:500]
    assert r.headers["content-type"].startswith(PROBLEM)
    doc = r.json()
    assert doc["status"] == status and doc["title"] and doc["type"] and doc["detail"]
    return doc


def test_every_plot_endpoint_answers_png_and_svg(
    server: Server, keys: dict[str, str], solved: dict[str, str]
) -> None:
    with server.client(keys["alice"]) as c:
        index = c.get(f"/jobs/{solved['triplet']}/plots").json()
        assert {p["kind"] for p in index["plots"]} == ADJUSTMENT_KINDS
        assert index["images"] == ["prism-backward", "prism-nadir", "prism-forward"]
        for p in index["plots"]:
            for link in p["links"]:
                r = c.get(link["href"])
                assert r.status_code == 200, (link["href"], r.text[:300])
                assert r.headers["content-type"] == link["type"]
                if link["type"] == "image/png":
                    assert_png(r.content)
                else:
                    assert link["type"] == "image/svg+xml"
                    assert_svg(r.content)
        for kind in ("image-residuals", "residual-histograms", "correlations"):
            r = c.get(
                f"/jobs/{solved['triplet']}/plots/{kind}.png", params={"image": "prism-nadir"}
            )
            assert_png(r.content)
        cmp_index = c.get(f"/jobs/{solved['comparison']}/plots").json()
        assert cmp_index["kind"] == "comparison" and cmp_index["models"] == ["K2", "P1"]
        assert "model-rmse" in {p["kind"] for p in cmp_index["plots"]}
        for fmt, check in (("png", assert_png), ("svg", assert_svg)):
            r = c.get(f"/jobs/{solved['comparison']}/plots/model-rmse.{fmt}")
            assert r.status_code == 200
            check(r.content)
        r = c.get(f"/jobs/{solved['comparison']}/plots/cost.svg", params={"model": "P1"})
        assert_svg(r.content)


def test_plots_that_do_not_apply_are_problems_not_errors(
    server: Server, keys: dict[str, str], solved: dict[str, str]
) -> None:
    with server.client(keys["alice"]) as c:
        doc = assert_problem(c.get(f"/jobs/{solved['nadir']}/plots/height-discrepancies.png"), 409)
        assert "mono" in doc["detail"]
        assert_problem(c.get(f"/jobs/{solved['triplet']}/plots/model-rmse.svg"), 409)
        assert_problem(c.get(f"/jobs/{solved['failed']}/plots/cost.png"), 409)
        assert_problem(c.get(f"/jobs/{solved['failed']}/plots"), 409)
        assert_problem(
            c.get(f"/jobs/{solved['triplet']}/plots/image-residuals.png?image=nope"), 404
        )
        assert_problem(c.get(f"/jobs/{solved['comparison']}/plots/cost.png?model=J2-2"), 404)
        assert_problem(c.get(f"/jobs/{solved['triplet']}/plots/no-such-kind.png"), 400)
        assert_problem(c.get(f"/jobs/{solved['triplet']}/plots/cost.gif"), 400)
        assert_problem(c.get("/jobs/no-such-job/plots/cost.png"), 404)
    with server.client(keys["bob"]) as c:  # another user's job does not exist for bob
        assert_problem(c.get(f"/jobs/{solved['triplet']}/plots/cost.png"), 404)
        assert_problem(c.get(f"/jobs/{solved['triplet']}/plots"), 404)
    with server.client() as c:
        assert_problem(c.get(f"/jobs/{solved['triplet']}/plots/cost.png"), 401)


def test_the_page_and_its_examples_are_served(server: Server) -> None:
    with server.client() as c:  # no key needed for the page itself
        r = c.get("/ui")
        assert r.status_code == 200 and r.headers["content-type"].startswith("text/html")
        assert f'<base href="{server.url}/">' in r.text
        assert "Content-Security-Policy" in r.headers
        for asset in ("app.js", "style.css"):
            assert c.get(f"/ui/assets/{asset}").status_code == 200
        assert_problem(c.get("/ui/assets/index.html"), 404)
        assert_problem(c.get("/ui/assets/..%2F..%2Fplots.py"), 404)
        examples = c.get("/ui/examples").json()["examples"]
        names = {e["name"] for e in examples}
        assert {"prism-triplet", "prism-nadir"} <= names
        assert not any(n.endswith(".truth") for n in names)
        doc = c.get("/ui/examples/prism-triplet").json()
        assert doc == load_example("prism-triplet.json")
        assert_problem(c.get("/ui/examples/prism-triplet.truth"), 404)


def test_route_kinds_are_the_plot_kinds() -> None:
    from typing import get_args

    from service.routes.plots import PlotKindName

    assert list(get_args(PlotKindName)) == list(PLOT_KINDS)
