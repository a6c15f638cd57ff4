"""Exact ground <-> image mapping of one simulated pushbroom image.

Ground to image: for each chip k, the acquisition time t of a ground point P is the root of
``x(t) = -f X(t) / Z(t) = dx_k`` with ``(X, Y, Z) = M(t) (P - S(t))`` (the point lies on the
chip's line of pixels); it is found by Newton iteration to |dt| < 1e-12 s (about 3e-9 lines
for PRISM). Then ``L = (t - first_line_time) / line_time`` and
``C = first_column + (columns - 1)/2 + (y - dy_k) / pixel`` with y = -f Y / Z. The chip is the one
to which C belongs by the solver's rule (:mod:`solver.geometry.sensor`: among the chips covering C, the
nearest centre; with unequal chip offsets a point near a hand-over may fall in none: a gap
between chips, reported as outside).

A camera with interior-orientation errors (:mod:`solver.simulate.iop`, docs/models.md section 8)
bends each chip's line of pixels and moves it in the focal plane: then the time and the scanline
coordinate y_s are solved together from both collinearity conditions ``x(t) = x_i(y_s)``,
``y(t) = y_i(y_s)`` (Newton in 2D, |dt| < 1e-12 s, |dy_s| < 1e-10 mm), with the true focal length
f + df, and ``C = first_column + (columns - 1)/2 + y_s / pixel``. Without IOP errors the
nominal path above runs unchanged.

Image to ground: the ray of (L, C) from S(t(L)) is intersected with the surface of given
ellipsoidal height (or the terrain) by Newton iteration along the ray.

Times ``t_s`` are simulator seconds from the orbit epoch.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from solver.geometry.geodesy import ecef_to_geodetic
from solver.simulate.attitude import Platform
from solver.simulate.camera import CameraSpec
from solver.simulate.terrain import Terrain

TIME_TOL_S = 1e-12
SCANLINE_TOL_MM = 1e-10  # 1.4e-8 PRISM pixels
HEIGHT_TOL_M = 1e-7


@dataclass
class ImageProjection:
    """Result of projecting ground points into an image; arrays of length n."""

    line: np.ndarray
    column: np.ndarray
    chip: np.ndarray  # chip index, -1 if the point falls in no chip
    inside: np.ndarray  # bool: a chip contains it and -0.5 <= line <= lines - 0.5
    time_s: np.ndarray


@dataclass(frozen=True)
class ImageGeometry:
    """One image: a camera on a platform, starting at ``first_line_time_s`` (simulator time)."""

    id: str
    camera: CameraSpec
    platform: Platform
    first_line_time_s: float

    def time_of_line(self, line: np.ndarray) -> np.ndarray:
        return self.first_line_time_s + np.asarray(line, dtype=float) * self.camera.line_time_s

    def line_of_time(self, t_s: np.ndarray) -> np.ndarray:
        return (np.asarray(t_s, dtype=float) - self.first_line_time_s) / self.camera.line_time_s

    @property
    def centre_time_s(self) -> float:
        return float(self.time_of_line((self.camera.lines - 1) / 2.0))

    def frames(self, t_s: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Perspective centre position, velocity (ECEF) and camera_from_ecef at times t_s."""
        return self.platform.camera_frames(t_s, self.camera.mounting_pitch_deg)

    def camera_coordinates(self, t_s: np.ndarray, points_ecef: np.ndarray) -> np.ndarray:
        """Camera-frame coordinates (n, 3) m of points (n, 3) at times (n,)."""
        r, _, m = self.frames(t_s)
        return np.einsum("nij,nj->ni", m, points_ecef - r)

    def focal_plane(self, t_s: np.ndarray, points_ecef: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Focal-plane coordinates (x_mm, y_mm) of points at times t_s (collinearity, with the
        simulated camera's true focal length)."""
        c = self.camera_coordinates(t_s, points_ecef)
        f = self.camera.focal_mm if self.camera.iop.is_zero else self.camera.true_focal_mm
        return -f * c[:, 0] / c[:, 2], -f * c[:, 1] / c[:, 2]

    def solve_time(self, points_ecef: np.ndarray, x_mm: float | np.ndarray, t0_s: np.ndarray | None = None) -> np.ndarray:
        """Times (n,) at which each point's along-track focal coordinate equals ``x_mm``."""
        p = np.atleast_2d(points_ecef)
        t = np.full(len(p), self.centre_time_s) if t0_s is None else np.array(t0_s, dtype=float)
        lo, hi = self.platform.orbit.t_min_s, self.platform.orbit.t_max_s
        h = 1e-3
        for _ in range(40):
            x = self.focal_plane(t, p)[0]
            dxdt = (self.focal_plane(t + h, p)[0] - self.focal_plane(t - h, p)[0]) / (2 * h)
            step = (x - x_mm) / dxdt
            t = np.clip(t - step, lo + h, hi - h)
            if np.max(np.abs(step)) < TIME_TOL_S:
                break
        else:
            raise RuntimeError(f"line search did not converge (max step {np.max(np.abs(step)):.3g} s)")
        return t

    def solve_time_and_scanline(
        self, points_ecef: np.ndarray, chip: int, t0_s: np.ndarray | None = None
    ) -> tuple[np.ndarray, np.ndarray]:
        """Acquisition times (n,) and scanline coordinates y_s (n,) mm at which each point lies on
        chip ``chip`` of the camera with IOP errors: Newton in 2D on both collinearity conditions
        ``x(t) = x_i(y_s)``, ``y(t) = y_i(y_s)`` (:mod:`solver.simulate.iop`)."""
        p = np.atleast_2d(points_ecef)
        cam = self.camera
        c = cam.chips[chip]
        n = len(p)
        ids = np.full(n, c.id)
        dx = np.full(n, c.dx_mm)
        dy = np.full(n, c.dy_mm)
        length = np.full(n, c.columns * cam.pixel_mm)

        def image_point(y_s: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
            return cam.iop.image_point(y_s, dx, dy, ids, length)

        # start from the nominal chip geometry
        t = self.solve_time(p, c.dx_mm, t0_s)
        y_s = self.focal_plane(t, p)[1] - c.dy_mm
        lo, hi = self.platform.orbit.t_min_s, self.platform.orbit.t_max_s
        h_t, h_y = 1e-3, 1e-3
        for _ in range(40):
            x, y = self.focal_plane(t, p)
            xi, yi = image_point(y_s)
            f1, f2 = x - xi, y - yi
            xp, yp = self.focal_plane(t + h_t, p)
            xm, ym = self.focal_plane(t - h_t, p)
            a11, a21 = (xp - xm) / (2 * h_t), (yp - ym) / (2 * h_t)
            xip, yip = image_point(y_s + h_y)
            xim, yim = image_point(y_s - h_y)
            a12, a22 = -(xip - xim) / (2 * h_y), -(yip - yim) / (2 * h_y)
            det = a11 * a22 - a12 * a21
            dt = (a22 * f1 - a12 * f2) / det
            dys = (a11 * f2 - a21 * f1) / det
            t = np.clip(t - dt, lo + h_t, hi - h_t)
            y_s = y_s - dys
            if np.max(np.abs(dt)) < TIME_TOL_S and np.max(np.abs(dys)) < SCANLINE_TOL_MM:
                break
        else:
            raise RuntimeError(f"image point search did not converge (max steps {np.max(np.abs(dt)):.3g} s, {np.max(np.abs(dys)):.3g} mm)")
        return t, y_s

    def ground_to_image(self, points_ecef: np.ndarray) -> ImageProjection:
        """Exact image coordinates of ECEF points (n, 3): line, column, chip, inside."""
        p = np.atleast_2d(np.asarray(points_ecef, dtype=float))
        cam = self.camera
        lines, cols, times, margins = [], [], [], []
        t_guess = None
        for k, c in enumerate(cam.chips):
            if cam.iop.is_zero:
                t = self.solve_time(p, c.dx_mm, t_guess)
                col = cam.column_from_y(self.focal_plane(t, p)[1], k)
            else:
                t, y_s = self.solve_time_and_scanline(p, k, t_guess)
                col = c.centre_column + y_s / cam.pixel_mm
            t_guess = t
            # margin >= 0 inside the chip's column range (pixels extend half a pixel each side)
            margins.append(np.minimum(col - (c.first_column - 0.5), (c.first_column + c.columns - 0.5) - col))
            lines.append(self.line_of_time(t))
            cols.append(col)
            times.append(t)
        # a chip images the point if the column it sees there belongs to it by the solver's rule
        # (solver.geometry.sensor); if two chips do (misregistered chips at a hand-over), the one that sees
        # it farther from its ends
        cols_a, margins_a = np.array(cols), np.array(margins)
        own = margins_a >= 0
        for k in range(len(cam.chips)):
            on = np.flatnonzero(own[k])
            own[k, on] = cam.chip_of_column(cols_a[k, on]) == k
        best = np.where(own.any(axis=0), np.argmax(np.where(own, margins_a, -np.inf), axis=0), np.argmax(margins_a, axis=0))
        idx = np.arange(len(p))
        line = np.array(lines)[best, idx]
        column = cols_a[best, idx]
        time = np.array(times)[best, idx]
        chip = np.where(own[best, idx], best, -1)
        inside = (chip >= 0) & (line >= -0.5) & (line <= cam.lines - 0.5)
        return ImageProjection(line, column, chip, inside, time)

    def rays(self, line: np.ndarray, column: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Origins (perspective centres) and unit directions (ECEF) of image points' rays."""
        t = self.time_of_line(np.atleast_1d(line))
        x, y, _ = self.camera.image_plane(np.atleast_1d(column))
        r, _, m = self.frames(t)
        f = self.camera.focal_mm if self.camera.iop.is_zero else self.camera.true_focal_mm
        d_cam = np.column_stack([x, y, np.full_like(x, -f)])
        d = np.einsum("nji,nj->ni", m, d_cam)
        return r, d / np.linalg.norm(d, axis=1, keepdims=True)

    def image_to_ground(
        self,
        line: np.ndarray,
        column: np.ndarray,
        height_m: np.ndarray | float | None = None,
        terrain: Terrain | None = None,
    ) -> np.ndarray:
        """ECEF points (n, 3) where image rays meet the surface of ellipsoidal height
        ``height_m`` or, if ``terrain`` is given, the terrain."""
        if (height_m is None) == (terrain is None):
            raise ValueError("give exactly one of height_m and terrain")
        origin, d = self.rays(line, column)
        return intersect_rays(origin, d, height_m, terrain)


def intersect_rays(
    origin: np.ndarray, direction: np.ndarray, height_m: np.ndarray | float | None, terrain: Terrain | None
) -> np.ndarray:
    """Newton iteration along rays ``origin + s direction`` for h(point) = target height."""
    s = np.full(len(origin), np.linalg.norm(origin, axis=1) - 6.371e6)  # rough first range
    s = s / np.maximum(-np.einsum("ni,ni->n", direction, origin / np.linalg.norm(origin, axis=1, keepdims=True)), 0.1)
    for _ in range(60):
        p = origin + s[:, None] * direction
        llh = ecef_to_geodetic(p)
        target = terrain.height(llh[:, 0], llh[:, 1]) if terrain is not None else np.broadcast_to(height_m, s.shape)
        f = llh[:, 2] - target
        lon, lat = np.radians(llh[:, 0]), np.radians(llh[:, 1])
        normal = np.column_stack([np.cos(lat) * np.cos(lon), np.cos(lat) * np.sin(lon), np.sin(lat)])
        s = s - f / np.einsum("ni,ni->n", direction, normal)
        if np.max(np.abs(f)) < HEIGHT_TOL_M:
            break
    else:
        raise RuntimeError("ray intersection did not converge")
    return origin + s[:, None] * direction
