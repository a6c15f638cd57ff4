"""The exact pushbroom (linescan) model of a vendor's metadata: image-to-ground and
ground-to-image in numpy, built from the metadata alone.

Frames and units. Positions ECEF metres (WGS 84 / ITRF as the vendor gives them), times seconds
from the model's ``epoch`` (an ISO UTC instant: every time of one file is on one scale, UTC for
Maxar; an interval crossing a leap second is refused by the readers), angles radians.
Image coordinates: ``line`` and ``column`` with the centre of the top-left pixel at (0, 0)
(RPC00B's convention and the solver's).

The model, for one image position (line L, column C):

1. time ``t = line_time(L)``: piecewise linear through the (line, time) table (Maxar's TLC
   list; first-line time and rate for a constant rate), extrapolated with the end slopes;
2. perspective centre ``S(t)``: Lagrange interpolation (8 nodes) of the ECEF positions, plus the
   camera's offset from the body origin rotated by the attitude;
3. attitude ``R(t)`` (body to ECEF): spherical linear interpolation (slerp) of the quaternions
   between the two neighbouring samples;
4. look vector ``d = R(t) look_body(C)``: the detector's direction in the body frame (the
   reader's focal-plane geometry and camera-to-body mounting);
5. velocity aberration (switchable): the camera sees the apparent direction; the ray in the
   Earth-centred non-rotating frame is ``normalize(d - v/c)`` with ``v`` the inertial velocity
   ``v_ecef + omega x S`` (first order; 7.5 km/s gives ~25 microradians, tens of pixels at
   WorldView-2's 1.65e6 px focal length);
6. intersection with the ellipsoid raised by ``h`` (a + h, b + h; then refined so that the
   geodetic height is exactly ``h``);
7. light-travel time (switchable): the light left the ground ``tau = |P - S| / c`` before it
   arrived; in the frame fixed to the Earth at the arrival the ground point was rotated by
   ``-omega tau`` about z, so the ECEF point is ``Rz(omega tau) P`` (~1 m at the equator for
   700 km).

8. atmospheric refraction (switchable): in flat layers of an exponential atmosphere
   (``n - 1 = N0 exp(-h/H)``), Snell's law moves the true ground point towards the nadir by
   ``N0 exp(-h/H) H tan z / cos^2 z`` (z the zenith angle of the line of sight at the ground;
   0.78 m at 17.6 degrees, 2.7 m at 30 degrees) from where the straight ray meets the ground.

Ground-to-image inverts image-to-ground by Gauss-Newton in image space (finite-difference
Jacobian, one pixel step), from the nearest node of a 33 x 33 image grid, to 1e-6 px (1e-3 px
accepted where the slerp's interval changes); points
where it does not converge (far outside the image) get NaN.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field, replace

import numpy as np

from solver.geometry.geodesy import A_WGS84_M, F_WGS84, ecef_to_geodetic, geodetic_to_ecef

C_M_S = 299_792_458.0  # speed of light
# Exponential model of the air's refractivity n - 1 = N0 exp(-h / H) (visible light, standard
# atmosphere near the ground: N0 ~ 2.8e-4, scale height ~ 8 km).
REFRACTIVITY_SEA_LEVEL = 2.77e-4
REFRACTIVITY_SCALE_HEIGHT_M = 8000.0
OMEGA_EARTH_RAD_S = 7.2921151467e-5  # WGS 84 Earth rotation rate
LAGRANGE_NODES = 8
ACCEPT_PX = 1e-3  # ground-to-image: a last step larger than this marks the point as not converged


@dataclass(frozen=True)
class Corrections:
    """Switchable corrections of the exact model (all on by default)."""

    aberration: bool = True
    light_time: bool = True
    refraction: bool = True


def quaternion_matrices(q_wxyz: np.ndarray) -> np.ndarray:
    """(n, 3, 3) rotation matrices of unit quaternions (n, 4) scalar first (Hamilton, active:
    ``v' = q v q*``)."""
    q = np.asarray(q_wxyz, float)
    q = q / np.linalg.norm(q, axis=-1, keepdims=True)
    w, x, y, z = q[..., 0], q[..., 1], q[..., 2], q[..., 3]
    return np.stack([
        np.stack([1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)], -1),
        np.stack([2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)], -1),
        np.stack([2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)], -1),
    ], -2)


def matrix_to_quaternion(r: np.ndarray) -> np.ndarray:
    """Scalar-first unit quaternions (n, 4) of rotation matrices (n, 3, 3) (Shepperd's method
    through the largest diagonal term)."""
    out = np.empty((r.shape[0], 4))
    for k, m in enumerate(r):
        tr = np.trace(m)
        cands = np.array([tr, m[0, 0], m[1, 1], m[2, 2]])
        i = int(np.argmax(cands))
        if i == 0:
            s = 2 * np.sqrt(1 + tr)
            q = [s / 4, (m[2, 1] - m[1, 2]) / s, (m[0, 2] - m[2, 0]) / s, (m[1, 0] - m[0, 1]) / s]
        elif i == 1:
            s = 2 * np.sqrt(1 + m[0, 0] - m[1, 1] - m[2, 2])
            q = [(m[2, 1] - m[1, 2]) / s, s / 4, (m[0, 1] + m[1, 0]) / s, (m[0, 2] + m[2, 0]) / s]
        elif i == 2:
            s = 2 * np.sqrt(1 + m[1, 1] - m[0, 0] - m[2, 2])
            q = [(m[0, 2] - m[2, 0]) / s, (m[0, 1] + m[1, 0]) / s, s / 4, (m[1, 2] + m[2, 1]) / s]
        else:
            s = 2 * np.sqrt(1 + m[2, 2] - m[0, 0] - m[1, 1])
            q = [(m[1, 0] - m[0, 1]) / s, (m[0, 2] + m[2, 0]) / s, (m[1, 2] + m[2, 1]) / s, s / 4]
        q = np.array(q)
        out[k] = q if q[0] >= 0 else -q
    return out


def lagrange(t: np.ndarray, times: np.ndarray, values: np.ndarray, nodes: int = LAGRANGE_NODES) -> np.ndarray:
    """Lagrange interpolation of ``values`` (m, k) sampled at increasing ``times`` (m,) at ``t``
    (n,), with ``nodes`` samples around each ``t`` (fewer near the ends of the table)."""
    t = np.atleast_1d(np.asarray(t, float))
    m = times.size
    nodes = min(nodes, m)
    i = np.clip(np.searchsorted(times, t) - nodes // 2, 0, m - nodes)
    idx = i[:, None] + np.arange(nodes)[None, :]
    tn = times[idx]  # (n, nodes)
    w = np.ones_like(tn)
    for j in range(nodes):
        for k in range(nodes):
            if j != k:
                w[:, j] *= (t - tn[:, k]) / (tn[:, j] - tn[:, k])
    return np.einsum("nj,njk->nk", w, values[idx])


def slerp(t: np.ndarray, times: np.ndarray, q_wxyz: np.ndarray) -> np.ndarray:
    """Unit quaternions (n, 4) at ``t`` by slerp between the two neighbouring samples."""
    t = np.atleast_1d(np.asarray(t, float))
    i = np.clip(np.searchsorted(times, t) - 1, 0, times.size - 2)
    q0, q1 = q_wxyz[i], q_wxyz[i + 1].copy()
    dot = np.sum(q0 * q1, axis=1)
    q1[dot < 0] *= -1
    dot = np.abs(dot)
    u = ((t - times[i]) / (times[i + 1] - times[i]))[:, None]
    theta = np.arccos(np.clip(dot, -1.0, 1.0))[:, None]
    small = theta < 1e-9
    s = np.where(small, 1.0, np.sin(theta))
    a = np.where(small, 1.0 - u, np.sin((1.0 - u) * theta) / s)
    b = np.where(small, u, np.sin(u * theta) / s)
    q = a * q0 + b * q1
    return q / np.linalg.norm(q, axis=1, keepdims=True)


def orbital_rows(position: np.ndarray, velocity: np.ndarray) -> np.ndarray:
    """(n, 3, 3) ``R_orbit``: rows along track (velocity without its radial part), cross track
    (``z x x``), radial up (docs/models.md section 10)."""
    z = position / np.linalg.norm(position, axis=1, keepdims=True)
    x = velocity - np.sum(velocity * z, axis=1, keepdims=True) * z
    x /= np.linalg.norm(x, axis=1, keepdims=True)
    y = np.cross(z, x)
    return np.stack([x, y, z], axis=1)


def _rotate_z(p: np.ndarray, angle: np.ndarray) -> np.ndarray:
    c, s = np.cos(angle), np.sin(angle)
    return np.column_stack([c * p[:, 0] - s * p[:, 1], s * p[:, 0] + c * p[:, 1], p[:, 2]])


def intersect_ellipsoid(origin: np.ndarray, direction: np.ndarray, h: np.ndarray) -> np.ndarray:
    """First intersection (n, 3) of rays with the WGS 84 ellipsoid raised to geodetic height ``h``
    (metres): the ellipsoid (a + h, b + h), then refined along the ray until the geodetic height
    is ``h`` to 1 mm. NaN where a ray misses."""
    a = A_WGS84_M
    b = a * (1.0 - F_WGS84)
    h = np.broadcast_to(np.asarray(h, float), (origin.shape[0],)).copy()
    d = direction / np.linalg.norm(direction, axis=1, keepdims=True)
    target = h.copy()
    for _ in range(6):
        ah, bh = a + target, b + target
        scale = np.column_stack([1 / ah, 1 / ah, 1 / bh])
        o, v = origin * scale, d * scale
        qa = np.sum(v * v, 1)
        qb = 2 * np.sum(o * v, 1)
        qc = np.sum(o * o, 1) - 1
        disc = qb * qb - 4 * qa * qc
        s = (-qb - np.sqrt(np.where(disc >= 0, disc, np.nan))) / (2 * qa)
        p = origin + s[:, None] * d
        err = ecef_to_geodetic(p)[:, 2] - h
        if np.nanmax(np.abs(err), initial=0.0) < 1e-3:
            break
        target = target - err
    return p


def refraction_shift(ground: np.ndarray, satellite: np.ndarray, h: np.ndarray) -> np.ndarray:
    """ECEF shift (n, 3) from the straight ray's ground point to the refracted one: horizontal,
    towards the satellite, ``N0 exp(-h/H) H tan z / cos^2 z`` metres (module docstring, step 8)."""
    lon_lat = ecef_to_geodetic(ground)
    lon, lat = np.radians(lon_lat[:, 0]), np.radians(lon_lat[:, 1])
    up = np.column_stack([np.cos(lat) * np.cos(lon), np.cos(lat) * np.sin(lon), np.sin(lat)])
    los = satellite - ground
    los /= np.linalg.norm(los, axis=1, keepdims=True)
    cos_z = np.sum(los * up, axis=1)
    horizontal = los - cos_z[:, None] * up
    sin_z = np.linalg.norm(horizontal, axis=1)
    size = REFRACTIVITY_SEA_LEVEL * np.exp(-h / REFRACTIVITY_SCALE_HEIGHT_M) * REFRACTIVITY_SCALE_HEIGHT_M * sin_z / cos_z**3
    return horizontal / np.maximum(sin_z, 1e-12)[:, None] * size[:, None]


@dataclass
class LinescanModel:
    """An exact pushbroom model (module docstring). ``look_body(columns)`` gives the (n, 3)
    directions of detectors in the body frame; ``attitude_wxyz`` rotates body vectors into ECEF."""

    lines: int
    columns: int
    epoch_utc: str
    tlc_lines: np.ndarray  # (k,) image lines of the (line, time) table
    tlc_times_s: np.ndarray  # (k,) their times, seconds from the epoch
    ephemeris_times_s: np.ndarray
    positions_ecef_m: np.ndarray
    velocities_ecef_m_s: np.ndarray
    attitude_times_s: np.ndarray
    attitude_wxyz: np.ndarray
    look_body: Callable[[np.ndarray], np.ndarray]
    camera_offset_body_m: np.ndarray = field(default_factory=lambda: np.zeros(3))
    corrections: Corrections = field(default_factory=Corrections)

    def with_corrections(self, **flags: bool) -> "LinescanModel":
        return replace(self, corrections=replace(self.corrections, **flags))

    def line_time(self, line: np.ndarray) -> np.ndarray:
        """Seconds from the epoch of image lines (pixel centres), linear in each TLC interval."""
        line = np.asarray(line, float)
        tl, tt = self.tlc_lines, self.tlc_times_s
        i = np.clip(np.searchsorted(tl, line) - 1, 0, tl.size - 2)
        return tt[i] + (line - tl[i]) * (tt[i + 1] - tt[i]) / (tl[i + 1] - tl[i])

    def position(self, t: np.ndarray) -> np.ndarray:
        return lagrange(t, self.ephemeris_times_s, self.positions_ecef_m)

    def velocity(self, t: np.ndarray) -> np.ndarray:
        return lagrange(t, self.ephemeris_times_s, self.velocities_ecef_m_s)

    def rotation(self, t: np.ndarray) -> np.ndarray:
        """(n, 3, 3) body-to-ECEF rotations at ``t``."""
        return quaternion_matrices(slerp(t, self.attitude_times_s, self.attitude_wxyz))

    def ray(self, line: np.ndarray, column: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(origin ECEF (n, 3), unit direction ECEF (n, 3), time (n,)) of image positions, with
        velocity aberration removed when switched on."""
        line, column = np.broadcast_arrays(np.atleast_1d(np.asarray(line, float)), np.atleast_1d(np.asarray(column, float)))
        t = self.line_time(line)
        r = self.rotation(t)
        s = self.position(t) + r @ self.camera_offset_body_m
        d = np.einsum("nij,nj->ni", r, self.look_body(column))
        d /= np.linalg.norm(d, axis=1, keepdims=True)
        if self.corrections.aberration:
            v = self.velocity(t) + np.cross([0.0, 0.0, OMEGA_EARTH_RAD_S], s)
            d = d - v / C_M_S
            d /= np.linalg.norm(d, axis=1, keepdims=True)
        return s, d, t

    def image_to_ecef(self, line: np.ndarray, column: np.ndarray, h: np.ndarray) -> np.ndarray:
        """ECEF metres (n, 3) of image positions at geodetic height ``h`` metres."""
        s, d, _ = self.ray(line, column)
        p = intersect_ellipsoid(s, d, h)
        if self.corrections.refraction:
            p = p + refraction_shift(p, s, np.broadcast_to(np.asarray(h, float), (p.shape[0],)))
        if self.corrections.light_time:
            tau = np.linalg.norm(p - s, axis=1) / C_M_S
            p = _rotate_z(p, OMEGA_EARTH_RAD_S * tau)
        return p

    def image_to_ground(self, line: np.ndarray, column: np.ndarray, h: np.ndarray) -> np.ndarray:
        """(lon_deg, lat_deg, h_m) (n, 3) of image positions at geodetic height ``h`` metres."""
        return ecef_to_geodetic(self.image_to_ecef(line, column, h))

    def ground_to_image(self, lon_lat_h: np.ndarray, tol_px: float = 1e-6, max_iterations: int = 30) -> np.ndarray:
        """(line, column) (n, 2) of geodetic points (lon_deg, lat_deg, h_m) (n, 3); NaN where the
        iteration does not converge (a point far outside the image's swath)."""
        g = np.atleast_2d(np.asarray(lon_lat_h, float))
        x = geodetic_to_ecef(g)
        h = g[:, 2]
        n = g.shape[0]
        lc = self._coarse_start(x, h)
        step = 1.0
        delta = np.full((n, 2), np.inf)
        for _ in range(max_iterations):
            p = self.image_to_ecef(lc[:, 0], lc[:, 1], h)
            pl = self.image_to_ecef(lc[:, 0] + step, lc[:, 1], h)
            pc = self.image_to_ecef(lc[:, 0], lc[:, 1] + step, h)
            j = np.stack([(pl - p) / step, (pc - p) / step], axis=2)  # (n, 3, 2)
            jt = np.transpose(j, (0, 2, 1))
            normal = jt @ j
            ok = np.all(np.isfinite(normal), axis=(1, 2)) & (np.abs(np.linalg.det(np.where(np.isfinite(normal), normal, 1.0))) > 0)
            delta = np.full((n, 2), np.nan)
            if np.any(ok):
                delta[ok] = np.linalg.solve(normal[ok], (jt[ok] @ (x[ok] - p[ok])[:, :, None]))[:, :, 0]
            lc = lc + delta
            if np.all(np.abs(delta) < tol_px):
                break
        # the last step may hover at 1e-5 px where the attitude's slerp changes interval (its
        # derivative jumps there): accepted up to ACCEPT_PX
        bad = ~np.all(np.abs(delta) < max(tol_px, ACCEPT_PX), axis=1)
        lc[bad] = np.nan
        return lc

    def _coarse_start(self, x: np.ndarray, h: np.ndarray, k: int = 33) -> np.ndarray:
        """Start of the ground-to-image iteration: the nearest node of a k x k image grid (at
        each point's height) for each point, so that long strips converge too."""
        lines = np.linspace(0, self.lines - 1, k)
        cols = np.linspace(0, self.columns - 1, k)
        gl, gc = (a.ravel() for a in np.meshgrid(lines, cols, indexing="ij"))
        h0 = float(np.mean(h))
        nodes = self.image_to_ecef(gl, gc, np.full(gl.size, h0))
        d = np.linalg.norm(x[:, None, :] - nodes[None, :, :], axis=2)
        best = np.nanargmin(np.where(np.isfinite(d), d, np.inf), axis=1)
        return np.column_stack([gl[best], gc[best]])
