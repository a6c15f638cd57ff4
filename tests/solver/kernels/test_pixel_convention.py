"""The pixel and time conventions, pinned by projections computed by hand.

docs/models.md and solver/schema/job.py (Chip): column C of a chip sits at the focal-plane position
``x = dx_mm``, ``y = dy_mm + (C - first_column - (columns - 1)/2) pixel_mm`` (pixel centres,
column 0 is the centre of the first pixel); a camera without chips is one chip centred on the
principal point; image coordinates are taken from the principal point (x0, y0); line L is
exposed at tau = L * tau_per_line after line 0 (orbital models: t = L line_time_s).

A half-pixel error in these conventions is absorbed by X0 and omega in an adjustment, so
recovery tests cannot see it; here the platform is fixed by hand (angles zero: camera axes =
LGS axes, x along track = east, y = north, z up) and the solver's projection must land on
the hand-computed line and column.
"""

from __future__ import annotations

import numpy as np
import pytest

from solver.engine.assemble import build_problem
from solver.kernels import project
from solver.platforms import get_model
from solver.schema.job import load_job

TIME_SCALE_REL = 1e-15  # tau per line is a copy of the line time or a division by 1000: one ulp

F_MM = 2000.0
PX_MM = 0.01
LINES, COLUMNS = 2000, 1000
LINE_TIME_S = 0.0005
H_M = 700_000.0  # platform height above the points
X0_M, V_M_PER_TAU = -5000.0, 3500.0  # along-track position at line 0 and its rate (per tau)
Y0_M = 120.0
TOL_PX = 1e-6  # Newton stops at a 1e-8 line step; both sides are closed forms in double precision

CAMERAS = {
    "no chips": {"principal_point_mm": (0.0, 0.0), "chips": []},
    "no chips, principal point off centre": {"principal_point_mm": (0.012, -0.034), "chips": []},
    "two chips with offsets": {
        "principal_point_mm": (0.003, 0.005),
        "chips": [
            {"id": "a", "first_column": 0, "columns": 400, "dx_mm": 0.0142, "dy_mm": -3.0},
            {"id": "b", "first_column": 400, "columns": 600, "dx_mm": -0.0071, "dy_mm": 2.1},
        ],
    },
}


def _chips(camera: dict) -> list[dict]:
    """The chips of a camera; none means one chip of every column on the principal point."""
    return camera["chips"] or [{"id": "1", "first_column": 0, "columns": COLUMNS, "dx_mm": 0.0, "dy_mm": 0.0}]


def _hand_ground_point(camera: dict, chip: dict, line: float, column: float) -> np.ndarray:
    """The LGS point (m) imaged at (line, column) by the platform below, by hand.

    Angles zero: d = P - S, image coordinates (from the principal point) x = -f d_x/d_z,
    y = -f d_y/d_z with d_z = -H. Column C of the chip is at x = dx - x0,
    y = dy - y0 + (C - first_column - (columns - 1)/2) pixel.
    """
    x0, y0 = camera["principal_point_mm"]
    x_mm = chip["dx_mm"] - x0
    y_mm = chip["dy_mm"] - y0 + (column - chip["first_column"] - (chip["columns"] - 1) / 2.0) * PX_MM
    tau = line / 1000.0  # polynomial models: tau = L / 1000
    s = np.array([X0_M + V_M_PER_TAU * tau, Y0_M, H_M])
    return s + np.array([x_mm * H_M / F_MM, y_mm * H_M / F_MM, -H_M])


def _targets(chip: dict) -> list[tuple[float, float]]:
    """(line, column): the chip's first, centre and last pixel on the first, middle and last line."""
    first, n = chip["first_column"], chip["columns"]
    return [(ln, c) for ln in (0.0, (LINES - 1) / 2.0, LINES - 1.0) for c in (first, first + (n - 1) / 2.0, first + n - 1)]


def _problem(camera: dict, targets: list[tuple[float, float]]):
    """The solver's problem for one P1 image observing one point per target. The points' job
    coordinates only place the LGS; the projections below use the hand-made LGS points."""
    job = {
        "name": "pixel convention",
        "crs": "EPSG:4326",
        "cameras": [
            {"id": "cam", "focal_mm": F_MM, "pixel_mm": PX_MM, "line_time_s": LINE_TIME_S, "lines": LINES, "columns": COLUMNS, **camera}
        ],
        "images": [{"id": "img", "camera": "cam", "model": {"name": "P1"}}],
        "points": [
            {"id": f"p{i}", "role": "gcp", "coordinates": [-51.4 + 0.001 * (i % 5), -22.1 + 0.001 * (i // 5), 400.0]}
            for i in range(len(targets))
        ],
        "observations": [
            {"image": "img", "point": f"p{i}", "line": ln, "column": c, "sigma_px": 0.5} for i, (ln, c) in enumerate(targets)
        ],
    }
    return build_problem(load_job(job))


@pytest.mark.parametrize("name", list(CAMERAS))
def test_projection_of_chip_centres_edges_and_first_and_last_lines(name: str) -> None:
    camera = CAMERAS[name]
    targets, points = [], []
    for chip in _chips(camera):
        for line, column in _targets(chip):
            targets.append((line, column))
            points.append(_hand_ground_point(camera, chip, line, column))
    problem = _problem(camera, targets)
    img = problem.images[0]
    coef = np.zeros(24)
    coef[0], coef[1], coef[4], coef[8] = X0_M, V_M_PER_TAU, Y0_M, H_M  # X0, X1, Y0, Z0; angles 0
    for k, (line, column) in enumerate(targets):
        ok, got_line, got_col, *_ = project(img.kind, coef, img.kc, points[k], problem.obs.oc[k], False)
        assert ok
        assert abs(got_line - line) < TOL_PX and abs(got_col - column) < TOL_PX, (name, line, column, got_line, got_col)


def test_principal_point_images_the_point_below_the_platform() -> None:
    """Without chips, the ray along the camera axis (the point straight below the perspective
    centre) is imaged at the principal point: column (columns - 1)/2 + y0/pixel, and on the
    line of that instant when x0 = 0."""
    camera = {"principal_point_mm": (0.0, 0.025), "chips": []}
    line = 700.0
    below = np.array([X0_M + V_M_PER_TAU * line / 1000.0, Y0_M, 0.0])
    column = (COLUMNS - 1) / 2.0 + 0.025 / PX_MM
    problem = _problem(camera, [(line, column)])
    img = problem.images[0]
    coef = np.zeros(24)
    coef[0], coef[1], coef[4], coef[8] = X0_M, V_M_PER_TAU, Y0_M, H_M
    ok, got_line, got_col, *_ = project(img.kind, coef, img.kc, below, problem.obs.oc[0], False)
    assert ok and abs(got_line - line) < TOL_PX and abs(got_col - column) < TOL_PX, (got_line, got_col)


@pytest.mark.parametrize("model", ["P1", "K2", "OA-J2", "PASS-J2"])
def test_line_time_convention(model: str) -> None:
    """Line L is exposed at tau = L tau_per_line after line 0: L/1000 for polynomial models,
    L line_time_s (seconds since first_line_time_s) for orbital ones (docs/models.md)."""
    m = get_model(model)
    expected = LINE_TIME_S if m.kind.earth_fixed else 1.0 / 1000.0
    assert m.tau_per_line(LINE_TIME_S) == pytest.approx(expected, rel=TIME_SCALE_REL)
    assert ("line_time" in m.time_variable) is m.kind.earth_fixed
