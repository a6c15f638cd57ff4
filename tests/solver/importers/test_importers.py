"""The importers (solver/importers): files written the way QGIS, ASP and spreadsheets write
them, malformed files giving errors that name file, line and column, and round trips
(write, read back, same content).

Independent evidence: pixel conversions are checked against the conventions written out by
hand (QGIS: corner origin and negated rows; ASP: centre origin), the QGIS row matching against
pyproj's own transform of the survey into the file's CRS, ASP's ECEF sigmas against the
ENU axes at (0 E, 0 N) where east = ECEF y, north = ECEF z, up = ECEF x.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from pyproj import Transformer
from tolerances import GEODESY_M

from solver.importers.asp_gcp import read_asp_gcp, write_asp_gcp
from solver.importers.attitude_csv import read_attitude, write_attitude
from solver.importers.ephemeris_csv import read_ephemeris, read_state, write_ephemeris, write_state
from solver.importers.errors import SourceError
from solver.importers.measurements_csv import read_measurements, write_measurements
from solver.importers.points_csv import read_points, write_points
from solver.importers.qgis_points import read_qgis_points, write_qgis_points

UTM_WRITTEN_M = 1e-3  # map coordinates written by QGIS to the millimetre

EXAMPLE_PX = 1e-4  # the example's measurements, written with four decimals
SIGMA_ABS = 1e-12  # survey sigmas read from text stay the numbers written
GEO_DEG = 1e-9  # 0.1 mm: a UTM point written to ASP's GCP format and read back as lon/lat

FIXTURES = Path(__file__).parents[2] / "fixtures" / "importers"
EXAMPLE = Path(__file__).parents[3] / "examples" / "prism-triplet.json"
PX_TOL = 1e-9  # px: the +-0.5 pixel shifts of a round trip cost at most a few ulps of 1e4


@pytest.fixture(scope="module")
def triplet() -> dict[str, Any]:
    return json.loads(EXAMPLE.read_text())


def located(exc: pytest.ExceptionInfo[SourceError]) -> list[tuple[str, int, str]]:
    return [(p.file, p.line, p.column) for p in exc.value.source_problems]


# -- points ---------------------------------------------------------------------------------
def test_survey_with_lat_lon_columns_semicolons_and_roles() -> None:
    """``name;lat;lon;h;...;type``: read by name, so latitude lands in y, longitude in x."""
    pts = read_points((FIXTURES / "survey_latlon.csv").read_bytes(), "survey_latlon.csv")
    assert [p["id"] for p in pts] == ["P01", "P02", "P03", "P04"]
    assert [p["role"] for p in pts] == ["gcp", "gcp", "check", "check"]
    assert pts[0]["coordinates"] == [-51.194604705745675, -21.998144431236785, 449.7939511369914]
    assert pts[0]["sigma_m"] == [0.2, 0.2, 0.3]
    assert "sigma_m" not in pts[3]  # empty sigma fields: none


def test_points_column_map_and_default_role() -> None:
    text = "Ponto,E,N,H\nA,500000.0,7500000.0,600.5\n"
    pts = read_points(text, "s.csv", "gcp", {"Ponto": "id", "E": "x", "N": "y", "H": "z"})
    assert pts == [{"id": "A", "role": "gcp", "coordinates": [500000.0, 7500000.0, 600.5]}]


@pytest.mark.parametrize(
    ("text", "where", "words"),
    [
        ("id,x,y,z,role\nA,1,2,3,gcp\nB,1,2,x3,gcp\n", ("s.csv", 3, "z"), "not a number"),
        ("id,x,y,z,role\nA,1,2,\"3,5\",gcp\n", ("s.csv", 2, "z"), "decimal separator"),
        ("id,x,y,z,role\nA,1,2,3,gcp\nA,4,5,6,check\n", ("s.csv", 3, "id"), "already on line 2"),
        ("id,x,y,z,role\nA,1,2,3,control point\n", ("s.csv", 2, "role"), "unknown role"),
        ("id,x,y,z,sx,sy,sz,role\nA,1,2,3,0.1,-0.1,0.1,gcp\n", ("s.csv", 2, "sy"), "positive"),
        ("# comment\nid,east,north,role\nA,1,2,gcp\n", ("s.csv", 2, ""), "no column for z"),
        ("id,x,y,z,role\nA,1,2,gcp\n", ("s.csv", 2, ""), "4 fields where the header has 5"),
    ],
)
def test_malformed_points_name_file_line_column(text: str, where: tuple[str, int, str], words: str) -> None:
    with pytest.raises(SourceError) as exc:
        read_points(text, "s.csv")
    assert where in located(exc)
    assert words in str(exc.value)


def test_points_round_trip(triplet: dict[str, Any]) -> None:
    back = read_points(write_points(triplet["points"], triplet["crs"]), "back.csv")
    assert back == triplet["points"]  # repr-written floats read back bit for bit


# -- measurements CSV -----------------------------------------------------------------------
def test_measurements_csv_errors_and_image_check() -> None:
    with pytest.raises(SourceError) as exc:
        read_measurements("image,point,line,column\nN,A,1.5,2\nB,C,1,2\n", "m.csv", image="N")
    assert ("m.csv", 3, "image") in located(exc)
    with pytest.raises(SourceError) as exc:
        read_measurements("point;row;col;sigma_px\nA;10;20;0\nB;;20;0.5\n", "m.csv", image="N")
    assert located(exc) == [("m.csv", 2, "sigma_px"), ("m.csv", 3, "row")]
    obs = read_measurements("point;row;col\nA;10.25;20.5\n", "m.csv", image="N", sigma_px=0.3)
    assert obs == [{"image": "N", "point": "A", "line": 10.25, "column": 20.5, "sigma_px": 0.3}]


def test_measurements_round_trip(triplet: dict[str, Any]) -> None:
    obs = triplet["observations"]
    assert read_measurements(write_measurements(obs), "back.csv") == obs


# -- QGIS .points ---------------------------------------------------------------------------
def test_qgis_points_with_crs_line_and_negated_rows(triplet: dict[str, Any]) -> None:
    """A QGIS 3 file: #CRS WKT (UTM 22S), negated rows, a disabled row, QGIS's residuals."""
    data = (FIXTURES / "nadir_utm22s.points").read_bytes()
    obs, notes = read_qgis_points(data, "nadir.points", "prism-nadir", triplet["points"], "EPSG:4326")
    assert [o["point"] for o in obs] == ["P01", "P02", "P03"]  # P04 disabled
    assert len(notes) == 1 and "line 6" in notes[0] and "disabled" in notes[0]
    # QGIS row 1: sourceX 13949.2263, sourceY -481.7275: pixel corner origin, row negated
    assert obs[0]["column"] == pytest.approx(13949.2263 - 0.5, abs=PX_TOL)
    assert obs[0]["line"] == pytest.approx(481.7275 - 0.5, abs=PX_TOL)
    # the example's own measurement of P01 in the nadir image (these are it, to 1e-4 px)
    truth = next(o for o in triplet["observations"] if o["image"] == "prism-nadir" and o["point"] == "P01")
    assert obs[0]["line"] == pytest.approx(truth["line"], abs=EXAMPLE_PX)
    assert obs[0]["column"] == pytest.approx(truth["column"], abs=EXAMPLE_PX)


def test_qgis_rows_match_the_survey_point_pyproj_puts_there(triplet: dict[str, Any]) -> None:
    """Each row is matched to the point whose UTM position (by pyproj directly) is its mapX/Y."""
    to_utm = Transformer.from_crs("EPSG:4326", "EPSG:32722", always_xy=True)
    rows = [r.split(",") for r in (FIXTURES / "nadir_utm22s.points").read_text().splitlines()[2:5]]
    pts = {p["id"]: p for p in triplet["points"]}
    data = (FIXTURES / "nadir_utm22s.points").read_bytes()
    obs, _ = read_qgis_points(data, "nadir.points", "N", triplet["points"], "EPSG:4326")
    for row, o in zip(rows, obs, strict=True):
        e, n = to_utm.transform(*pts[o["point"]]["coordinates"][:2])
        assert abs(e - float(row[0])) < UTM_WRITTEN_M and abs(n - float(row[1])) < UTM_WRITTEN_M


def test_qgis_2x_file_needs_its_crs() -> None:
    data = (FIXTURES / "qgis_2x.points").read_bytes()
    pts = read_points((FIXTURES / "survey_latlon.csv").read_bytes(), "survey.csv")
    with pytest.raises(SourceError) as exc:
        read_qgis_points(data, "old.points", "N", pts, "EPSG:4326")
    assert located(exc) == [("old.points", 1, "")]
    obs, _ = read_qgis_points(data, "old.points", "N", pts, "EPSG:4326", map_crs="EPSG:4326")
    assert [o["point"] for o in obs] == ["P01", "P02"]
    assert obs[1]["line"] == pytest.approx(15091.9654 - 0.5, abs=PX_TOL)


def test_malformed_qgis_files(triplet: dict[str, Any]) -> None:
    head = "#CRS: EPSG:4326\nmapX,mapY,sourceX,sourceY,enable,dX,dY,residual\n"
    p01 = "-51.194604705745675,-21.998144431236785"
    pts = triplet["points"]
    with pytest.raises(SourceError) as exc:  # rows not negated: not what QGIS writes
        read_qgis_points(head + f"{p01},13949.2,481.7,1,0,0,0\n", "a.points", "N", pts, "EPSG:4326")
    assert located(exc) == [("a.points", 3, "sourceY")]
    with pytest.raises(SourceError) as exc:  # far from every survey point; lon/lat swapped
        read_qgis_points(head + "-21.998144431236785,-51.194604705745675,1,-1,1,0,0,0\n", "b.points", "N", pts, "EPSG:4326")
    assert located(exc) == [("b.points", 3, "mapX")]
    assert exc.value.source_problems[0].code == "unmatched_point" and "swapped" in str(exc.value)
    with pytest.raises(SourceError) as exc:
        read_qgis_points(head + f"{p01},13949.2,-481.7,1,0,0,0\n{p01},1.0,-x,1,0,0,0\n", "c.points", "N", pts, "EPSG:4326")
    assert located(exc) == [("c.points", 4, "sourceY")]
    with pytest.raises(SourceError) as exc:
        read_qgis_points("#CRS: EPSG:999999\n" + head[16:], "d.points", "N", pts, "EPSG:4326")
    assert located(exc) == [("d.points", 1, "#CRS")]


def test_qgis_round_trip(triplet: dict[str, Any]) -> None:
    obs = [o for o in triplet["observations"] if o["image"] == "prism-nadir"]
    text, notes = write_qgis_points(obs, triplet["points"], "EPSG:4326", map_crs="EPSG:32722")
    assert text.startswith("#CRS: PROJCRS[") and len(notes) == 40  # 40 tie points: no room
    back, _ = read_qgis_points(text, "n.points", "prism-nadir", triplet["points"], "EPSG:4326")
    surveyed = [o for o in obs if not o["point"].startswith("T")]
    assert [o["point"] for o in back] == [o["point"] for o in surveyed]
    for a, b in zip(back, surveyed, strict=True):
        assert abs(a["line"] - b["line"]) < PX_TOL and abs(a["column"] - b["column"]) < PX_TOL


# -- ASP GCP --------------------------------------------------------------------------------
def test_asp_gcp_file() -> None:
    """Blanks and commas, # comments, latitude first, two images on a line, ECEF sigmas."""
    pts, obs, notes = read_asp_gcp((FIXTURES / "forward.gcp").read_bytes(), "forward.gcp")
    assert [p["id"] for p in pts] == ["1", "2"]
    assert pts[0]["coordinates"] == [-51.194604705745675, -21.998144431236785, 449.7939511369914]
    assert pts[0]["sigma_m"] == pytest.approx([0.2, 0.2, 0.2], abs=SIGMA_ABS)  # equal sigmas stay equal
    assert [(o["image"], o["point"]) for o in obs] == [("prism-forward", "1"), ("prism-nadir", "1"), ("prism-forward", "2")]
    assert (obs[0]["line"], obs[0]["column"]) == (477.2163, 13394.6983)  # ASP: centre origin, as ours
    assert obs[2]["sigma_px"] == 0.8 and len(notes) == 1  # 0.5 / 0.8 px: the larger, noted


def test_asp_ecef_sigmas_rotate_into_east_north_up() -> None:
    """At (0 E, 0 N): east = ECEF y, north = ECEF z, up = ECEF x."""
    pts, _, _ = read_asp_gcp("1 0 0 10 1 2 3 a.tif 1 2 0.5 0.5\n", "z.gcp")
    assert pts[0]["sigma_m"] == pytest.approx([2.0, 3.0, 1.0], abs=SIGMA_ABS)
    pts, _, _ = read_asp_gcp("1 0 0 10 1 2 3 a.tif 1 2 0.5 0.5\n", "z.gcp", sigma_frame="lon-lat-height")
    assert pts[0]["sigma_m"] == [2.0, 1.0, 3.0]  # (lat, lon, h) -> (east, north, up)


@pytest.mark.parametrize(
    ("line", "column", "words"),
    [
        ("1 -21.9 -51.1 400 0.2 0.2 0.2 a.tif 10 20 0.5\n", "", "a GCP line has"),
        ("1 139.7 35.6 40 0.2 0.2 0.2 a.tif 10 20 0.5 0.5\n", "2 (latitude)", "latitude first"),
        ("1 -21.9 -51.1 400 0.2 0 0.2 a.tif 10 20 0.5 0.5\n", "6 (sigma_y)", "positive"),
        ("1 -21.9 -51.1 400 0.2 0.2 0.2 a.tif 10 2O 0.5 0.5\n", "10 (row)", "not a number"),
    ],
)
def test_malformed_asp_lines(line: str, column: str, words: str) -> None:
    with pytest.raises(SourceError) as exc:
        read_asp_gcp("# header\n\n" + line, "bad.gcp")
    assert located(exc) == [("bad.gcp", 3, column)]
    assert words in str(exc.value)


def test_asp_round_trip(triplet: dict[str, Any]) -> None:
    surveyed = [p for p in triplet["points"] if p["role"] != "tie"]
    obs = [o for o in triplet["observations"] if o["point"] in {p["id"] for p in surveyed}]
    text, _ = write_asp_gcp(surveyed, obs, "EPSG:4326")
    pts, back, _ = read_asp_gcp(text, "all.gcp")
    assert [p["coordinates"] for p in pts] == [p["coordinates"] for p in surveyed]
    # survey sigmas kept; points without (fixed) get the writer's 1 m: ASP needs three sigmas
    assert [p["sigma_m"] for p in pts] == [p.get("sigma_m", [1.0, 1.0, 1.0]) for p in surveyed]
    key = {(o["image"], o["point"]): o for o in obs}
    assert len(back) == len(obs)
    for o in back:
        t = key[(o["image"], o["point"])]
        assert (o["line"], o["column"], o["sigma_px"]) == (t["line"], t["column"], t["sigma_px"])


def test_asp_export_of_projected_points_goes_through_wgs84() -> None:
    """A UTM 22S point is written as the latitude/longitude pyproj gives."""
    to_geo = Transformer.from_crs("EPSG:32722", "EPSG:4326", always_xy=True)
    p = {"id": "A", "role": "gcp", "coordinates": [479912.4486, 7567365.6496, 449.79]}
    o = {"image": "N", "point": "A", "line": 1.0, "column": 2.0, "sigma_px": 0.5}
    text, _ = write_asp_gcp([p], [o], "EPSG:32722")
    pts, _, _ = read_asp_gcp(text, "u.gcp")
    lon, lat = to_geo.transform(479912.4486, 7567365.6496)
    assert np.allclose(pts[0]["coordinates"][:2], [lon, lat], atol=GEO_DEG)
    assert pts[0]["coordinates"][2] == pytest.approx(449.79, abs=GEODESY_M)


# -- ephemeris, state, attitude --------------------------------------------------------------
def test_time_tables_round_trip_and_time_scale(triplet: dict[str, Any]) -> None:
    im = triplet["images"][0]
    eph, scale = read_ephemeris(write_ephemeris(im["ephemeris"], "GPS"), "e.csv")
    assert eph == im["ephemeris"] and scale == "GPS"
    att, scale = read_attitude(write_attitude(im["attitude"], "gps"), "a.csv")
    assert att == im["attitude"] and scale == "GPS"
    state = {k: im["approx_state"][k] for k in ("position_ecef_m", "velocity_ecef_m_s")}
    t, back, _ = read_state(write_state(im["first_line_time_s"], state, "GPS"), "s.csv")
    assert t == im["first_line_time_s"] and back == state


def test_time_tables_errors() -> None:
    body = "time_s,x,y,z,vx,vy,vz\n10,7e6,0,0,0,7500,0\n"
    with pytest.raises(SourceError) as exc:  # no time scale stated
        read_ephemeris(body, "e.csv")
    assert exc.value.source_problems[0].code == "time_scale_missing"
    with pytest.raises(SourceError) as exc:
        read_ephemeris("# time_scale: UTC\n" + body, "e.csv", time_scale="GPS")
    assert exc.value.source_problems[0].code == "time_scale_mismatch"
    with pytest.raises(SourceError) as exc:
        read_ephemeris(body + "5,7e6,0,0,0,7500,0\n", "e.csv", time_scale="GPS")
    assert located(exc) == [("e.csv", 3, "time_s")]
    with pytest.raises(SourceError) as exc:
        read_attitude("t,roll_rad,pitch_rad,yaw_rad\n1,0,0,0\n", "a.csv", "GPS")
    assert located(exc) == [("a.csv", 1, "roll_rad")]
    with pytest.raises(SourceError) as exc:
        read_attitude("t,roll,pitch,yaw\n1,0,400,0\n", "a.csv", "GPS")
    assert located(exc) == [("a.csv", 2, "pitch_deg")]
    with pytest.raises(SourceError) as exc:
        read_state(body + "20,7e6,0,0,0,7500,0\n", "s.csv", "GPS")
    assert "one row" in str(exc.value)


def test_not_utf8_is_located() -> None:
    with pytest.raises(SourceError) as exc:
        read_points(b"id,x,y,z,role\nS\xe3o,1,2,3,gcp\n", "latin1.csv")
    assert located(exc) == [("latin1.csv", 2, "")]
