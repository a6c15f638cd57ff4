"""Straight-line features for the scene simulator: road segments on the terrain (seed 002).

A :class:`LineScene` is a :class:`~solver.simulate.scene.Scene` of one CBERS-like image whose
control comes in named sets chosen by region (to build the good and poor distributions of
seed 002 Figures 3-5):

- point sets (:class:`PointSet`): check points near a 3 x 3 grid without its centre (seed 002
  Figure 6), or control points spread by farthest-point sampling inside a region of the image;
- line sets (:class:`LineSet`): straight road segments. A candidate segment has a centre pixel
  drawn uniformly in the set's region, a direction (uniform, or around given directions: roads
  aligned with each other) and a ground length; the rays of its two end pixels meet the terrain
  at P1 and P2, and the feature is the straight 3D segment P1-P2. Segments are picked by
  farthest-point sampling of their centres, so the first k of a set are spread over its region.

Image points of a line: points of the true 3D segment spaced about ``point_spacing_px`` along
its image, projected exactly (:meth:`ImageGeometry.ground_to_image`: each at its own line
time, which makes the image of a straight line slightly curved and, without yaw steering,
sheared against a frame-camera image), plus Gaussian noise ``line_noise_px`` on line and column;
points leaving the image are dropped. Endpoints are written with survey noise ``gcp_sigma_m``
along east, north, up, in ``settings.crs``.

Attitude: CBERS-1/2 are three-axis stabilised; we assume, as for SPOT 1-4, that they do *not*
yaw-steer, so the CCD stays across the inertial velocity and the Earth's rotation skews the
scene by a few degrees (``yaw_steering=False`` by default). With yaw steering the image of a
line is much closer to a frame image and the pushbroom correction of the equivalent planes
model is small (see docs/experiments.md, seed002 section).
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np

from solver.geometry.geodesy import ecef_to_geodetic, enu_rotation, from_ecef
from solver.simulate.camera import cbers_camera
from solver.simulate.presets import CBERS_INCLINATION_DEG, CBERS_SITE
from solver.simulate.scene import Group, Scene, SceneSettings, SimObservation, SimPoint

FULL = (0.0, 1.0, 0.0, 1.0)  # region: line_lo, line_hi, column_lo, column_hi (fractions)
GRID = "grid"


@dataclass(frozen=True)
class PointSet:
    """``count`` points named ``<prefix>NN`` with ``role``, spread in ``region`` (or ``GRID``)."""

    prefix: str
    role: str
    count: int
    region: tuple[float, float, float, float] | str = FULL


@dataclass(frozen=True)
class LineSet:
    """``count`` road segments named ``<prefix>NN`` with ``role`` (control | check).

    ``directions_deg``: None for uniform directions, else the segments' image directions are
    drawn within ``spread_deg`` of one of these (0 = along the image lines axis, 90 = across).
    """

    prefix: str
    count: int
    region: tuple[float, float, float, float] = FULL
    role: str = "control"
    directions_deg: tuple[float, ...] | None = None
    spread_deg: float = 10.0
    length_m: tuple[float, float] = (1500.0, 6000.0)


@dataclass
class SimLine:
    id: str
    role: str
    set_prefix: str
    ecef_m: np.ndarray  # (2, 3) true endpoints
    image_points: np.ndarray  # (n, 2) noise-free (line, column)
    noise_px: np.ndarray = field(default_factory=lambda: np.zeros((0, 2)))
    survey_noise_enu_m: np.ndarray = field(default_factory=lambda: np.zeros((2, 3)))


def _farthest_order(xy: np.ndarray, k: int) -> list[int]:
    return Scene._farthest_point_order(xy, k)


def _in_region(xy: np.ndarray, region: tuple[float, float, float, float]) -> np.ndarray:
    l0, l1, c0, c1 = region
    return (xy[:, 0] >= l0) & (xy[:, 0] <= l1) & (xy[:, 1] >= c0) & (xy[:, 1] <= c1)


class LineScene(Scene):
    """One CBERS-like image with named point and line sets (see the module docstring)."""

    def __init__(
        self,
        settings: SceneSettings,
        point_sets: list[PointSet],
        line_sets: list[LineSet],
        yaw_steering: bool = False,
        point_spacing_px: float = 5.0,
        line_noise_px: float = 0.3,
    ) -> None:
        super().__init__(settings, [Group([cbers_camera()], 0, 0, 0)])
        self.point_sets = point_sets
        self.line_sets = line_sets
        self.yaw_steering = yaw_steering
        self.point_spacing_px = point_spacing_px
        self.line_noise_px = line_noise_px
        self.lines: list[SimLine] = []

    def _setup_platform(self) -> None:
        super()._setup_platform()
        att = replace(self.platform.attitude, yaw_steering=self.yaw_steering)
        self.platform = replace(self.platform, attitude=att)

    # -- points by set -----------------------------------------------------------------------
    def _select_points(self) -> None:
        group = self.groups[0]
        n = sum(s.count for s in self.point_sets)
        pts, projs, ok, xy = self._candidates(group, max(4000, 40 * n))
        used = np.zeros(len(pts), dtype=bool)
        for ps in self.point_sets:
            free = np.flatnonzero(ok & ~used)
            if ps.region == GRID:
                nodes = [(a, b) for a in (0.12, 0.5, 0.88) for b in (0.12, 0.5, 0.88) if (a, b) != (0.5, 0.5)]
                chosen = []
                for node in nodes[: ps.count]:
                    cand = free[~np.isin(free, chosen)]
                    chosen.append(int(cand[np.argmin(np.linalg.norm(xy[cand] - np.array(node), axis=1))]))
            else:
                inside = free[_in_region(xy[free], ps.region)]  # type: ignore[arg-type]
                if len(inside) < ps.count:
                    raise RuntimeError(f"point set {ps.prefix}: only {len(inside)} candidates in its region")
                chosen = [int(inside[j]) for j in _farthest_order(xy[inside], ps.count)]
            for k, idx in enumerate(chosen):
                used[idx] = True
                p_index = len(self.points)
                self.points.append(SimPoint(f"{ps.prefix}{k + 1:02d}", ps.role, 0, pts[idx]))
                pr = projs[0]
                self.observations.append(
                    SimObservation(group.images[0], p_index, float(pr.line[idx]), float(pr.column[idx]), int(pr.chip[idx]))
                )

    # -- lines -------------------------------------------------------------------------------------
    def _select_lines(self) -> None:
        im = self.images[self.groups[0].images[0]]
        cam = im.camera
        nl, nc = cam.lines - 1, cam.columns - 1
        height = float(np.linalg.norm(im.frames(np.array([im.centre_time_s]))[0][0])) - 6.371e6
        gsd = cam.pixel_mm / cam.focal_mm * height
        m = self.settings.point_margin
        for ls in self.line_sets:
            n_cand = max(400, 20 * ls.count)
            l0, l1, c0, c1 = ls.region
            centre = np.column_stack(
                [self.rng.uniform(max(l0, m), min(l1, 1 - m), n_cand), self.rng.uniform(max(c0, m), min(c1, 1 - m), n_cand)]
            )
            if ls.directions_deg is None:
                ang = self.rng.uniform(0.0, np.pi, n_cand)
            else:
                base = np.radians(np.array(ls.directions_deg))[self.rng.integers(0, len(ls.directions_deg), n_cand)]
                ang = base + np.radians(self.rng.uniform(-ls.spread_deg, ls.spread_deg, n_cand))
            half_px = 0.5 * self.rng.uniform(*ls.length_m, n_cand) / gsd
            d = np.column_stack([np.cos(ang), np.sin(ang)]) * half_px[:, None]
            c_px = centre * np.array([nl, nc])
            a_px, b_px = c_px - d, c_px + d
            lo, hi = np.array([m * nl, m * nc]), np.array([(1 - m) * nl, (1 - m) * nc])
            inside = np.all((a_px >= lo) & (a_px <= hi) & (b_px >= lo) & (b_px <= hi), axis=1)
            idx = np.flatnonzero(inside)
            if len(idx) < ls.count:
                raise RuntimeError(f"line set {ls.prefix}: only {len(idx)} candidate segments fit in the image")
            order = [int(idx[j]) for j in _farthest_order(centre[idx], ls.count)]
            ends_a = im.image_to_ground(a_px[order, 0], a_px[order, 1], terrain=self.terrain)
            ends_b = im.image_to_ground(b_px[order, 0], b_px[order, 1], terrain=self.terrain)
            for k in range(ls.count):
                p1, p2 = ends_a[k], ends_b[k]
                length_px = float(np.linalg.norm(b_px[order[k]] - a_px[order[k]]))
                n_pts = max(3, int(round(length_px / self.point_spacing_px)) + 1)
                t = np.linspace(0.0, 1.0, n_pts)
                pr = im.ground_to_image(p1[None, :] + t[:, None] * (p2 - p1)[None, :])
                keep = pr.inside
                self.lines.append(
                    SimLine(
                        f"{ls.prefix}{k + 1:02d}",
                        ls.role,
                        ls.prefix,
                        np.array([p1, p2]),
                        np.column_stack([pr.line[keep], pr.column[keep]]),
                    )
                )

    def simulate(self) -> "LineScene":
        super().simulate()
        self._select_lines()
        for ln in self.lines:
            ln.noise_px = self.rng.normal(0.0, self.line_noise_px, ln.image_points.shape)
            s = self.settings.gcp_sigma_m
            ln.survey_noise_enu_m = self.rng.normal(0.0, s, (2, 3)) if s > 0 else np.zeros((2, 3))
        return self

    # -- documents -----------------------------------------------------------------------------
    def _measured_endpoints_ecef(self, ln: SimLine) -> np.ndarray:
        llh = ecef_to_geodetic(ln.ecef_m)
        out = ln.ecef_m.copy()
        for i in range(2):
            rot = enu_rotation(np.radians(llh[i, 0]), np.radians(llh[i, 1]))
            out[i] = ln.ecef_m[i] + rot.T @ ln.survey_noise_enu_m[i]
        return out

    def job(self) -> dict[str, Any]:
        doc = super().job()
        s = self.settings
        image_id = self.images[self.groups[0].images[0]].id
        cam = self.images[0].camera
        lines = []
        for ln in self.lines:
            meas = ln.image_points + ln.noise_px
            keep = (meas[:, 0] >= -0.5) & (meas[:, 0] <= cam.lines - 0.5) & (meas[:, 1] >= -0.5) & (meas[:, 1] <= cam.columns - 0.5)
            coords = from_ecef(self._measured_endpoints_ecef(ln), s.crs)
            d: dict[str, Any] = {
                "id": ln.id,
                "role": ln.role,
                "endpoints": [[float(x) for x in coords[0]], [float(x) for x in coords[1]]],
            }
            if s.gcp_sigma_m > 0:
                d["sigma_m"] = [s.gcp_sigma_m] * 3
            d["observations"] = [
                {
                    "image": image_id,
                    "points": [{"line": float(a), "column": float(b)} for a, b in meas[keep]],
                    "sigma_px": max(self.line_noise_px, 1e-3),
                }
            ]
            lines.append(d)
        doc["lines"] = lines
        return doc

    def truth(self) -> dict[str, Any]:
        doc = super().truth()
        doc["lines"] = [
            {
                "id": ln.id,
                "role": ln.role,
                "set": ln.set_prefix,
                "ecef_m": ln.ecef_m.tolist(),
                "image_points": ln.image_points.tolist(),
                "survey_error_enu_m": ln.survey_noise_enu_m.tolist(),
            }
            for ln in self.lines
        ]
        doc["yaw_steering"] = self.yaw_steering
        return doc


def cbers_settings(settings: SceneSettings) -> SceneSettings:
    """The ``cbers-scene`` site, orbit and CRS (SAD69 / UTM 22S) applied to ``settings``."""
    return replace(
        settings,
        preset=settings.preset if settings.preset not in ("", "seed002") else "cbers-lines",
        lon_deg=CBERS_SITE[0],
        lat_deg=CBERS_SITE[1],
        inclination_deg=CBERS_INCLINATION_DEG,
        crs="EPSG:29192",
        epoch_s=48600.0 if settings.epoch_s == SceneSettings.epoch_s else settings.epoch_s,
    )


def cbers_lines(
    settings: SceneSettings,
    lines: int = 50,
    gcps: int = 23,
    checks: int = 8,
    yaw_steering: bool = False,
    line_noise_px: float = 0.3,
    check_lines: int = 0,
) -> LineScene:
    """``pba simulate cbers-lines``: a CBERS-like scene with road segments as control lines
    (``L01``...), well-spread control points (``P01``...) and check points on a grid (``K01``...)."""
    point_sets = [PointSet("K", "check", checks, GRID), PointSet("P", "gcp", gcps)] if checks else [PointSet("P", "gcp", gcps)]
    line_sets = [LineSet("L", lines)]
    if check_lines:
        line_sets.append(LineSet("X", check_lines, role="check"))
    s = cbers_settings(replace(settings, preset="cbers-lines"))
    return LineScene(s, [p for p in point_sets if p.count], line_sets, yaw_steering, line_noise_px=line_noise_px).simulate()
