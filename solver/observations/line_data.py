"""The lines of a problem as data (seed 002): the object lines in the LGS, each image of a line
with its measurements, and the set's model state; the job's lines converted at assembly
(:func:`build_lines`, :func:`lines_ecef`). The equations, terms, validation and report of the
straight-line family are :mod:`solver.observations.lines`.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from solver.geometry.geodesy import UnknownCRSError, to_ecef
from solver.geometry.sensor import camera_chip
from solver.kernels.layout import FORM_X, FORM_Y, N_OBS_CONST

FORM_NAMES = ("y=ax+b", "x=a'y+b'")


@dataclass
class GroundLineState:
    """An object line in the LGS (metres)."""

    id: str
    index: int  # in job.lines
    role: str  # control | check
    p1: np.ndarray
    p2: np.ndarray
    sigma_m: np.ndarray | None  # (3,) east, north, up of each endpoint


@dataclass
class LineImage:
    """One image of one object line (``job.lines[line].observations[k]``) and its model state."""

    line: int  # index in LineSet.lines
    k: int  # index in the job line's observations
    image: int  # image index
    points: np.ndarray  # (n, 2) measured (line, column) px; (0, 2) for fitted input
    sigma_px: float
    ocs: np.ndarray  # (n, 9) observation constants of the measured points
    fitted: tuple[int, np.ndarray, np.ndarray] | None  # (form, ab, cov) in pixels
    # fixed at start from the initial orientation
    ref_line: float = 0.0
    ref_oc: np.ndarray = field(default_factory=lambda: np.zeros(N_OBS_CONST))  # chip of the reference
    end_ocs: np.ndarray = field(default_factory=lambda: np.zeros((2, N_OBS_CONST)))  # projections of P1, P2
    form: int = FORM_Y  # equivalent planes form in the pseudo-frame
    ab_obs: np.ndarray = field(default_factory=lambda: np.zeros(2))  # pseudo-frame (a, b)
    ab_cov: np.ndarray = field(default_factory=lambda: np.eye(2))
    # refreshed
    correction: np.ndarray = field(default_factory=lambda: np.zeros(2))
    s: np.ndarray = field(default_factory=lambda: np.zeros(0))
    whiten: np.ndarray = field(default_factory=lambda: np.eye(0))

    @property
    def n_points(self) -> int:
        return int(self.points.shape[0])


@dataclass
class LineSet:
    """All lines of a problem, the model used and its refresh state."""

    lines: list[GroundLineState]
    images: list[LineImage]
    model: str  # rigorous | equivalent_planes
    correction: str  # iterated | initial | none
    started: bool = False
    refresh_changes: list[float] = field(default_factory=list)  # largest residual change per refresh
    anderson: list[tuple[np.ndarray, np.ndarray]] = field(default_factory=list)  # (used, computed)
    k_mm: dict[int, float] = field(default_factory=dict)  # per image

    def active(self) -> list[LineImage]:
        """Observations of control lines (those that enter the adjustment)."""
        return [li for li in self.images if self.lines[li.line].role == "control"]


def lines_ecef(job) -> dict[str, np.ndarray]:
    """ECEF endpoints (2, 3) of every line whose CRS is understood, by line id (one
    transformation per CRS: building a PROJ transformer is the expensive part)."""
    by_crs: dict[str, list] = {}
    for gl in job.lines:
        by_crs.setdefault(gl.crs or job.crs, []).append(gl)
    out: dict[str, np.ndarray] = {}
    for crs, group in by_crs.items():
        try:
            xyz = to_ecef(np.array([gl.endpoints for gl in group], dtype=float).reshape(-1, 3), crs)
        except (UnknownCRSError, ValueError):
            continue
        for k, gl in enumerate(group):
            out[gl.id] = xyz[2 * k : 2 * k + 2]
    return out


def control_line_points_ecef(job, ecef: dict[str, np.ndarray]) -> np.ndarray:
    """Endpoints of the control lines (m, 3) (for the LGS when a job has no control points)."""
    pts = [ecef[gl.id] for gl in job.lines if gl.role == "control" and gl.id in ecef]
    return np.concatenate(pts) if pts else np.zeros((0, 3))


def on_a_chip(camera, column: float) -> bool:
    """True if ``column`` is in the delivered image and on a CCD chip (:mod:`solver.geometry.sensor`)."""

    try:
        camera_chip(camera, column)
    except KeyError:
        return False
    return True


def _chip_constants(camera, column: float) -> tuple[float, float, float]:
    """(xo, yo, centre column) of the chip of ``column`` (clamped into the image) by the rule of
    :mod:`solver.geometry.sensor` (line points do not name their chip)."""

    ncols = camera.columns or 1
    col = min(max(column, 0.0), ncols - 1.0)
    _chip, dx, dy, centre = camera_chip(camera, col)
    x0, y0 = camera.principal_point_mm
    return dx - x0, dy - y0, centre


def line_point_constants(img, line: float, column: float, sigma: float = 1.0) -> np.ndarray:
    """The observation constants (:data:`solver.kernels.N_OBS_CONST`) of an image point of a
    line in image state ``img``: its chip by the column (line points do not name their chip)."""
    cam = img.camera
    xo, yo, centre = _chip_constants(cam, column)
    return np.array([line, column, sigma, cam.focal_mm, cam.pixel_mm, xo, yo, centre, img.tau_per_line])


def build_lines(job, frame, images, ecef: dict[str, np.ndarray]) -> LineSet:
    """Convert the job's lines (validated) into the LGS; the model state is set by :func:`start`."""
    lines: list[GroundLineState] = []
    obs: list[LineImage] = []
    img_index = {im.id: im.index for im in images}
    for j, gl in enumerate(job.lines):
        p = frame.to_lgs(ecef[gl.id])
        sig = np.array(gl.sigma_m, dtype=float) if gl.sigma_m is not None else None
        lines.append(GroundLineState(gl.id, j, gl.role, np.ascontiguousarray(p[0]), np.ascontiguousarray(p[1]), sig))
        for k, o in enumerate(gl.observations):
            img = images[img_index[o.image]]
            pts = np.array([[q.line, q.column] for q in o.points], dtype=float).reshape(-1, 2)
            ocs = np.ascontiguousarray([line_point_constants(img, q[0], q[1], o.sigma_px) for q in pts]).reshape(-1, N_OBS_CONST)
            fitted = None
            if o.fitted is not None:
                ft = o.fitted
                form = FORM_Y if ft.form == FORM_NAMES[0] else FORM_X
                cov = np.array(
                    [
                        [ft.sigma_a**2, ft.correlation * ft.sigma_a * ft.sigma_b],
                        [ft.correlation * ft.sigma_a * ft.sigma_b, ft.sigma_b**2],
                    ]
                )
                fitted = (form, np.array([ft.a, ft.b]), cov)
            obs.append(LineImage(len(lines) - 1, k, img.index, pts, o.sigma_px, ocs, fitted))
    opts = job.options
    return LineSet(lines, obs, opts.line_model, opts.line_correction)


# ---- start: reference epochs, pseudo-frame observations -------------------------------------
