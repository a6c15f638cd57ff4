"""A vendor product as a fragment of our job: a camera, an image with ephemeris, attitude samples
and line times, a default model and the options that weight them, plus how far that job form
is from the vendor's exact model (pixels).

Mapping (docs/models.md sections 1, 9, 10):

- Camera frame. Ours has ``x`` along track, ``z`` away from the scene; a detector sits at
  ``(x_c, y_c)`` and looks along ``(x_c, y_c, -f)``. Maxar's camera frame has ``z`` towards the
  ground and the detector array along ``-y``; the two differ by a half turn about ``x``
  (``P = diag(1, -1, -1)``; when the Maxar ``x`` points against the flight direction, a half
  turn about ``y`` is used instead, ``diag(-1, 1, -1)``). A straight array with
  ``DETROTANGLE = 0`` is one chip of ours: ``dx_mm = DETORIGINX``, pixel pitch, and
  ``dy_mm`` so that column C sits at ``C p - DETORIGINY``; a rotated array is approximated
  (its along-track offset ``C p sin(rot)`` is left out and counted in the difference).
- Attitude. The job's samples are roll, pitch, yaw of ``A = M R_orbit^T`` (``M`` object to
  camera, ``R_orbit`` rows: along-track, cross-track, radial), ``A = Rx(roll) Ry(pitch)
  Rz(yaw)``, mounting 0. The adjustment models neither velocity aberration nor light-travel
  time nor refraction, so each sample's rotation is the *effective* one: the rotation (Kabsch
  fit over 9 detectors across the array) that makes straight rays from the perspective centre
  meet the ground where the exact model, with every correction, puts them at the product's
  mean height. What this cannot absorb (their change across the swath and with height) is in
  ``difference_px``.
- Line times: a constant ``line_time_s = 1 / AVGLINERATE`` from the first line's time; a
  TLC table that departs from it is counted in the difference.
- Times: seconds since 00:00 UTC of the product's first ephemeris date (``time_origin_utc``),
  shared by every product of one import so that the images of a pass share one scale.
"""

from __future__ import annotations

from datetime import datetime, timezone
from typing import Any

import numpy as np

from solver.sensors.linescan import LinescanModel, quaternion_matrices
from solver.sensors.maxar import MaxarProduct

KABSCH_DETECTORS = 9
DEFAULT_MODEL = "OA-J2"


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


def orbital_rows(position: np.ndarray, velocity: np.ndarray) -> np.ndarray:
    """(n, 3, 3) ``R_orbit``: rows along track (velocity without its radial part), cross track
    (``z x x``), radial up (docs/models.md section 10)."""
    z = position / np.linalg.norm(position, axis=1, keepdims=True)
    x = velocity - np.sum(velocity * z, axis=1, keepdims=True) * z
    x /= np.linalg.norm(x, axis=1, keepdims=True)
    y = np.cross(z, x)
    return np.stack([x, y, z], axis=1)


def angles_xyz(a: np.ndarray) -> np.ndarray:
    """(roll, pitch, yaw) radians (n, 3) with ``a = Rx(roll) Ry(pitch) Rz(yaw)`` (active)."""
    pitch = np.arcsin(np.clip(a[:, 0, 2], -1, 1))
    roll = np.arctan2(-a[:, 1, 2], a[:, 2, 2])
    yaw = np.arctan2(-a[:, 0, 1], a[:, 0, 0])
    return np.column_stack([roll, pitch, yaw])


def rotation_xyz(angles: np.ndarray) -> np.ndarray:
    """(n, 3, 3) ``Rx(roll) Ry(pitch) Rz(yaw)`` (active elementary rotations)."""
    r, p, y = angles[:, 0], angles[:, 1], angles[:, 2]
    o, z = np.ones_like(r), np.zeros_like(r)
    rx = np.stack([np.stack([o, z, z], -1), np.stack([z, np.cos(r), -np.sin(r)], -1), np.stack([z, np.sin(r), np.cos(r)], -1)], -2)
    ry = np.stack([np.stack([np.cos(p), z, np.sin(p)], -1), np.stack([z, o, z], -1), np.stack([-np.sin(p), z, np.cos(p)], -1)], -2)
    rz = np.stack([np.stack([np.cos(y), -np.sin(y), z], -1), np.stack([np.sin(y), np.cos(y), z], -1), np.stack([z, z, o], -1)], -2)
    return rx @ ry @ rz


def _kabsch(body: np.ndarray, ecef: np.ndarray) -> np.ndarray:
    """The rotation R (3, 3) minimising sum |R body_i - ecef_i|^2 (unit vectors, rows)."""
    u, _, vt = np.linalg.svd(ecef.T @ body)
    d = np.sign(np.linalg.det(u @ vt))
    return u @ np.diag([1.0, 1.0, d]) @ vt


def effective_rotations(model: LinescanModel, times: np.ndarray, height_m: float) -> np.ndarray:
    """(n, 3, 3) body-to-ECEF rotations at ``times`` that absorb every correction at ``height_m``
    (module docstring)."""
    cols = np.linspace(0, model.columns - 1, KABSCH_DETECTORS)
    tl, tt = model.tlc_lines, model.tlc_times_s
    rate = (tl[-1] - tl[0]) / (tt[-1] - tt[0])
    out = np.empty((times.size, 3, 3))
    body = model.look_body(cols)
    body /= np.linalg.norm(body, axis=1, keepdims=True)
    for k, t in enumerate(times):
        line = np.full(cols.size, tl[0] + (t - tt[0]) * rate)
        ground = model.image_to_ecef(line, cols, np.full(cols.size, height_m))
        s = model.position(np.array([t]))[0] + model.rotation(np.array([t]))[0] @ model.camera_offset_body_m
        d = ground - s
        out[k] = _kabsch(body, d / np.linalg.norm(d, axis=1, keepdims=True))
    return out


def _axes_to_ours(product: MaxarProduct) -> np.ndarray:
    """``P``: Maxar camera components to ours (module docstring), chosen by the flight direction."""
    m = product.model
    t = np.array([m.line_time(np.array([m.lines / 2.0]))[0]])
    x_cam_ecef = m.rotation(t)[0] @ quaternion_matrices(product.camera_to_body_wxyz[None, :])[0] @ np.array([1.0, 0, 0])
    forward = float(np.dot(x_cam_ecef, m.velocity(t)[0])) > 0
    return np.diag([1.0, -1.0, -1.0]) if forward else np.diag([-1.0, 1.0, -1.0])


def _time_origin(products: list[MaxarProduct]) -> datetime:
    first = min(datetime.fromisoformat(p.model.epoch_utc.replace("Z", "+00:00")) for p in products)
    return datetime(first.year, first.month, first.day, tzinfo=timezone.utc)


def fragment(products: list[MaxarProduct], image_ids: list[str]) -> dict[str, Any]:
    """The job fragment of one or more products (``cameras``, ``images``, ``options``) and a
    ``sensor_metadata`` block per image (what was read, the RPC agreement is not computed here)."""
    origin = _time_origin(products)
    cameras, images, notes = [], [], []
    sig_p, sig_a = [], []
    for p, image_id in zip(products, image_ids):
        m = p.model
        shift = (datetime.fromisoformat(m.epoch_utc.replace("Z", "+00:00")) - origin).total_seconds()
        axes = _axes_to_ours(p)
        ox, oy = p.detector_origin_mm
        along = axes[0, 0]  # +1: our x is Maxar's x
        camera = {
            "id": image_id, "focal_mm": p.principal_distance_mm, "pixel_mm": p.pixel_mm,
            "line_time_s": 1.0 / p.avg_line_rate_hz, "lines": m.lines, "columns": m.columns,
            "chips": [{"id": "1", "first_column": 0, "columns": m.columns, "dx_mm": along * ox,
                       "dy_mm": -axes[1, 1] * ((m.columns - 1) / 2.0 * p.pixel_mm) + axes[1, 1] * oy}],
        }
        t0 = float(m.line_time(np.array([0.0]))[0])
        t1 = float(m.line_time(np.array([m.lines - 1.0]))[0])
        lo, hi = min(t0, t1), max(t0, t1)
        ke = (m.ephemeris_times_s >= lo - 0.2) & (m.ephemeris_times_s <= hi + 0.2)
        ka = (m.attitude_times_s >= lo - 0.1) & (m.attitude_times_s <= hi + 0.1)
        at = m.attitude_times_s[ka]
        height = p.rpc.height_off if p.rpc is not None else 0.0
        rot = effective_rotations(m, at, height)  # body to ECEF
        cam_to_body = quaternion_matrices(p.camera_to_body_wxyz[None, :])[0]
        ecef_to_cam = np.einsum("ij,njk->nik", axes @ cam_to_body.T, np.transpose(rot, (0, 2, 1)))
        a = ecef_to_cam @ np.transpose(orbital_rows(m.position(at), m.velocity(at)), (0, 2, 1))
        ang = np.degrees(angles_xyz(a))
        image = {
            "id": image_id, "camera": image_id, "model": {"name": DEFAULT_MODEL},
            "first_line_time_s": t0 + shift,
            "ephemeris": [{"time_s": float(t + shift), "position_ecef_m": [float(v) for v in pos],
                           "velocity_ecef_m_s": [float(v) for v in vel]}
                          for t, pos, vel in zip(m.ephemeris_times_s[ke], m.positions_ecef_m[ke], m.velocities_ecef_m_s[ke])],
            "attitude": [{"time_s": float(t + shift), "roll_deg": float(r[0]), "pitch_deg": float(r[1]), "yaw_deg": float(r[2])}
                         for t, r in zip(at, ang)],
        }
        cameras.append(camera)
        images.append(image)
        cov = p.position_covariance_m2
        if cov.shape[1] == 6:
            sig_p.append(float(np.sqrt(np.mean(cov[ke][:, [0, 3, 5]].sum(axis=1) / 3.0))))
        sig_a.append(p.attitude_sigma_rad)
        notes.append({"image": image_id, "file": p.file, "satellite": p.satellite, "band": p.band,
                      "first_line_utc": _utc(origin, t0 + shift), "time_origin_utc": origin.isoformat().replace("+00:00", "Z"),
                      "difference_px": job_form_difference(p, camera, image, shift, axes)})
    options: dict[str, Any] = {"ephemeris": {"sigma_position_m": max(max(sig_p), 0.01) if sig_p else 5.0}}
    sa = [s for s in sig_a if s is not None]
    sigma_deg = max(float(np.degrees(max(sa))), 1e-5) if sa else 0.002
    options["attitude"] = {"sigma_deg": [sigma_deg] * 3}
    return {"cameras": cameras, "images": images, "options": options, "sensor_metadata": notes}


def _utc(origin: datetime, seconds: float) -> str:
    return datetime.fromtimestamp(origin.timestamp() + seconds, timezone.utc).isoformat().replace("+00:00", "Z")


def job_form_difference(p: MaxarProduct, camera: dict[str, Any], image: dict[str, Any], shift: float, axes: np.ndarray,
                        n: int = 7, k: int = 3) -> dict[str, float]:
    """How far the job form (our one-chip camera, constant line rate, the effective attitude
    samples slerped, straight rays, no corrections) is from the exact model with every
    correction: RMS and maximum px over ``n`` x ``n`` image positions times ``k`` heights (the
    RPC's height range, else 0 +- 500 m)."""
    m = p.model
    chip = camera["chips"][0]
    f, pix, dx, dy, cols = camera["focal_mm"], camera["pixel_mm"], chip["dx_mm"], chip["dy_mm"], camera["columns"]
    cam_to_body = quaternion_matrices(p.camera_to_body_wxyz[None, :])[0]
    ours_to_body = cam_to_body @ axes.T

    def look_body(c: np.ndarray) -> np.ndarray:
        c = np.asarray(c, float)
        v = np.column_stack([np.full(c.shape, dx), (c - (cols - 1) / 2.0) * pix + dy, np.full(c.shape, -f)])
        return v @ ours_to_body.T

    at = np.array([s["time_s"] - shift for s in image["attitude"]])
    ang = np.radians([[s["roll_deg"], s["pitch_deg"], s["yaw_deg"]] for s in image["attitude"]])
    r_orbit = orbital_rows(m.position(at), m.velocity(at))
    ecef_to_ours = rotation_xyz(ang) @ r_orbit
    body_to_ecef = np.transpose(ecef_to_ours, (0, 2, 1)) @ ours_to_body
    t0 = image["first_line_time_s"] - shift
    job = LinescanModel(
        lines=m.lines, columns=m.columns, epoch_utc=m.epoch_utc,
        tlc_lines=np.array([0.0, 1.0]), tlc_times_s=np.array([t0, t0 + camera["line_time_s"]]),
        ephemeris_times_s=m.ephemeris_times_s, positions_ecef_m=m.positions_ecef_m, velocities_ecef_m_s=m.velocities_ecef_m_s,
        attitude_times_s=at, attitude_wxyz=matrix_to_quaternion(body_to_ecef), look_body=look_body,
        camera_offset_body_m=m.camera_offset_body_m,
    ).with_corrections(aberration=False, light_time=False, refraction=False)
    if p.rpc is not None:
        heights = p.rpc.height_off + p.rpc.height_scale * np.linspace(-1, 1, k)
    else:
        heights = np.linspace(-500, 500, k)
    L, C, H = (a.ravel() for a in np.meshgrid(np.linspace(0, m.lines - 1, n), np.linspace(0, m.columns - 1, n), heights, indexing="ij"))
    g = job.image_to_ground(L, C, H)
    d = m.ground_to_image(g) - np.column_stack([L, C])
    dist = np.hypot(d[:, 0], d[:, 1])
    return {"rms": float(np.sqrt(np.nanmean(dist**2))), "max": float(np.nanmax(dist))}
