"""INPE product XML of CBERS-4, CBERS-4A and Amazonia-1 (root ``prdf``, namespace
``http://www.gisplan.com.br/xmlsat``: the ``*_BANDn.xml`` beside each L2/L4 product) read into a
linescan model.

INPE publishes no description of this format; what follows was read from ten public records
(tests/data/vendor/README.md) and checked on their corner coordinates.

- A record holds one camera (``prdf/image``) or two (``prdf/leftCamera/image`` and
  ``prdf/rightCamera/image``: the WFI of CBERS-4A and Amazonia-1); one is read per call.
- ``image/ephemerides/ephemeris``: ``time`` (ISO 8601 without zone), ``x y z`` (ECEF m),
  ``vx vy vz`` (m/s), 1 s apart, ``description="PACDB_GPS"`` (on-board GPS). The record states
  no time scale; the geometry cannot tell one (image times and states share it), so times are
  read as UTC (GPS time would move every instant by the 17-18 s of :mod:`solver.sensors.timescales`,
  which matters only when the product is combined with another source). The states are screened
  (:mod:`solver.sensors.ephemeris_check`): duplicated samples and states whose positions
  disagree with the velocities (the CBERS-4A WFI record of 2020-08-01, from its 68th state on)
  are named in :attr:`CbersProduct.warnings` and not used; states the image needs in their place
  are propagated from the last good one (named in the warning too).
- ``image/timeStamp``: ``begin`` and ``end`` (UTC) of the first and last line of the corners
  (``image/imageData``: ``UL UR LR LL CT``, each ``line``, ``column`` of the raw image,
  ``latitude``, ``longitude``, degrees WGS 84, on the ellipsoid): line L is at
  ``begin + (L - L_first) (end - begin) / (L_last - L_first)``; the model's lines run from 0 to
  ``L_last``, its columns from 0 to the corners' last column.
- ``image/attitudes/attitude``: ``roll pitch yaw`` (rad) and ``deltaRoll ...`` at 1 Hz, and
  ``image/boresightMatrix`` (3 x 3, ``value row= col=``): read and kept, but *not* used: no
  convention we tried (the angles turning the orbital frame, in either order, with the boresight
  matrix or its transpose) meets the corners. CBERS-4 records carry constant angles
  (-0.4, -1.7, -1.6 degrees in every sample of four records, ``ephemerisMode`` AUTO) and
  CBERS-4A yaws of 204-218 degrees that turn by 0.1 degree a second.
- ``image/focalDistance`` (micrometres; 4A and Amazonia-1 only): reported. No detector pitch is
  given.

The pointing is therefore taken from the corners: the orbital frame (x along the velocity
without its radial part, z up; CBERS-4A's arrays lie across the Earth-fixed ground track, so
its velocity is the ECEF one; CBERS-4 and Amazonia-1 are not yaw-steered, so theirs is the
inertial one ``v + omega x r``) turned by a constant rotation ``Rx(roll) Ry(pitch) Rz(yaw)``, and
column C looking along ``(0, (C - c0) ifov, -1)`` in the turned frame, ``c0`` the middle
column: four numbers (roll, pitch, yaw, ifov) fitted to the four corners UL, UR, LR, LL (eight
coordinates; their residuals and a leave-one-corner-out prediction are reported by
:func:`corner_check`). The centre point CT is not used: in every
record it lies 0.9-1.2 degrees along track from where the four corners put the image's centre
(about 12-16 km), so it is not the centre of the same image. Velocity aberration, light-travel
time and refraction are off: constant parts are in the fitted rotation.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from datetime import datetime, timezone
from pathlib import Path

import numpy as np
from scipy.optimize import least_squares

from solver.geometry.geodesy import geodetic_to_ecef
from solver.sensors.ephemeris_check import EphemerisScreen, label, propagate, screen
from solver.sensors.linescan import (
    OMEGA_EARTH_RAD_S,
    Corrections,
    LinescanModel,
    lagrange,
    matrix_to_quaternion,
    orbital_rows,
)
from solver.sensors.screening import Screening
from solver.sensors.xmlsafe import Node, load

NAMESPACE = "{http://www.gisplan.com.br/xmlsat}"
CORNERS = ("UL", "UR", "LR", "LL")
YAW_STEERED = ("CBERS 4A",)  # arrays across the Earth-fixed ground track (module docstring)
# timeStamp begin and end are this many lines closer together than the corners' first and last
# lines in every record with an integrationTime (the CBERS-4A WPM record has none, and no lag):
# measured, the four corners then agree to 0.01-0.07 px on 8 records, 8-16 px without
TIMESTAMP_LAG_LINES = 16
STATE_MARGIN_S = 4.0  # ephemeris needed beyond the image's first and last line (8-node Lagrange, 1-s states)


@dataclass
class CbersProduct:
    file: str
    satellite: str  # "CBERS 4A"
    instrument: str  # "WFI"
    camera: str  # "left", "right" or "" (one camera)
    cameras: list[str]
    model: LinescanModel
    corners: np.ndarray  # (4, 5): line, column, lon_deg, lat_deg, h_m of UL, UR, LR, LL
    centre: np.ndarray  # (5,): CT, reported only
    line_period_s: float
    focal_mm: float | None
    ifov_rad: float
    centre_column: float
    pointing_rad: np.ndarray  # fitted roll, pitch, yaw of the camera in the orbital frame
    boresight: np.ndarray  # (3, 3) as read
    attitude_times_s: np.ndarray  # the record's attitude samples, seconds from the model's epoch
    attitude_rpy_rad: np.ndarray  # (n, 3) roll, pitch, yaw as read (not used)
    ephemeris: EphemerisScreen
    corners_used: np.ndarray  # (4,) bool: corners the pointing was fitted to
    warnings: list[str] = field(default_factory=list)  # the screening's notes and warnings, and the reader's
    screening: Screening = field(default_factory=Screening)
    level: str = ""  # image/level: 2 (system corrected) or 4 (orthorectified)
    projection: str = ""  # image/projectionName: the delivered raster's map grid ("" for a raw image)
    pixel_m: float | None = None  # image/verticalPixelSize: the raster's grid spacing
    raw_geometry: bool = False  # the measurements are in the raw image the record describes (FILE#raw)


def _strip_namespace(root: Node) -> None:
    for e in root.element.iter():
        if isinstance(e.tag, str) and e.tag.startswith(NAMESPACE):
            e.tag = e.tag[len(NAMESPACE):]
    root.path = root.element.tag


def _utc(node: Node, tag: str) -> datetime:
    text = node.text(tag)
    try:
        t = datetime.fromisoformat(text.replace("Z", "+00:00"))
    except ValueError:
        raise node.error(f"not an ISO 8601 time: {text[:40]!r}", tag) from None
    return t if t.tzinfo else t.replace(tzinfo=timezone.utc)


def _rotation(rpy: np.ndarray) -> np.ndarray:
    r, p, y = rpy
    rx = np.array([[1, 0, 0], [0, np.cos(r), -np.sin(r)], [0, np.sin(r), np.cos(r)]])
    ry = np.array([[np.cos(p), 0, np.sin(p)], [0, 1, 0], [-np.sin(p), 0, np.cos(p)]])
    rz = np.array([[np.cos(y), -np.sin(y), 0], [np.sin(y), np.cos(y), 0], [0, 0, 1]])
    return rx @ ry @ rz


def _frames(model_pos: np.ndarray, model_vel: np.ndarray, inertial: bool) -> np.ndarray:
    """(n, 3, 3) orbital-frame-to-ECEF matrices (columns x, y, z of the module docstring)."""
    v = model_vel + np.cross([0.0, 0.0, OMEGA_EARTH_RAD_S], model_pos) if inertial else model_vel
    return np.transpose(orbital_rows(model_pos, v), (0, 2, 1))


def fit_pointing(corners: np.ndarray, c0: float, line_time, position, velocity, inertial: bool,
                 fit_yaw: bool = True) -> tuple[np.ndarray, np.ndarray]:
    """(roll, pitch, yaw, ifov) fitted to ``corners`` (k, 5) with the principal column ``c0``
    held (a roll moves the swath as c0 would), and the residuals (k, 2) as angles (rad: along,
    across track) of the fitted look against the corner's direction; yaw held at 0 when
    ``fit_yaw`` is false."""
    t = line_time(corners[:, 0])
    s, v = position(t), velocity(t)
    d = geodetic_to_ecef(corners[:, 2:5]) - s
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    local = np.einsum("nji,nj->ni", _frames(s, v, inertial), d)  # ECEF -> orbital frame

    def full(x: np.ndarray) -> np.ndarray:
        return x if fit_yaw else np.array([x[0], x[1], 0.0, x[2]])

    def residual(x: np.ndarray) -> np.ndarray:
        x = full(x)
        cam = local @ _rotation(x[:3])  # rows: R^T d
        return np.column_stack([cam[:, 0] / -cam[:, 2], cam[:, 1] / -cam[:, 2] - (corners[:, 1] - c0) * x[3]]).ravel()

    c = corners[:, 1]
    angle = local[:, 1] / -local[:, 2]
    ifov0 = float((angle[np.argmax(c)] - angle[np.argmin(c)]) / max(float(c.max() - c.min()), 1.0)) or 1e-5
    x0 = np.array([0.0, 0.0, 0.0, ifov0])
    scale = np.array([1e-3, 1e-3, 1e-2, abs(ifov0)])
    keep = [0, 1, 2, 3] if fit_yaw else [0, 1, 3]
    sol = least_squares(residual, x0[keep], x_scale=scale[keep], xtol=1e-15, ftol=1e-15)
    return full(sol.x), sol.fun.reshape(-1, 2)


def read_cbers(path: str | Path, shown: str | None = None, data: bytes | None = None, camera: str | None = None,
               raw_geometry: bool = False) -> CbersProduct:
    """The model of one camera of an INPE product XML (module docstring); ``camera`` "left" or
    "right" in two-camera records (default: the left one), ``data`` as for
    :func:`solver.sensors.maxar.read_maxar`; ``raw_geometry``: the measurements are in the raw
    image the record describes (not in the map-projected raster: see :func:`map_grid`)."""
    path = Path(path)
    shown = str(path) if shown is None else shown
    root = load(path, shown, data)
    _strip_namespace(root)
    if root.element.tag != "prdf":
        raise root.error("not an INPE product XML (root element prdf expected)")
    cams = [c for c in ("leftCamera", "rightCamera") if root.find(c) is not None]
    names = [c[:-6] for c in cams]
    if cams:
        if camera is not None and camera not in names:
            raise root.error(f"no {camera} camera in this record (it has: {', '.join(names)})")
        chosen = camera or names[0]
        node = root.child(f"{chosen}Camera")
    else:
        if camera not in (None, ""):
            raise root.error(f"a one-camera record: no {camera} camera")
        chosen, node = "", root
    sat = node.child("satellite")
    satellite = f"{sat.text('name')} {sat.text('number')}"
    instrument = sat.text("instrument")
    image = node.child("image")

    states = image.child("ephemerides").children("ephemeris")
    if len(states) < 8:
        raise image.error(f"8 ephemeris states at least, {len(states)} found", "ephemerides")
    times = [_utc(s, "time") for s in states]
    epoch = min(times)

    def seconds(t: datetime) -> float:
        return (t - epoch).total_seconds()

    eph_t = np.array([seconds(t) for t in times])
    if np.any(np.diff(eph_t) < 0):
        k = int(np.flatnonzero(np.diff(eph_t) < 0)[0])
        raise states[k + 1].error(f"state {k + 2}: its time goes back from the previous one's (states must be in time order)")
    pos = np.array([[s.number(a) for a in ("x", "y", "z")] for s in states])
    vel = np.array([[s.number(a) for a in ("vx", "vy", "vz")] for s in states])
    r = np.linalg.norm(pos, axis=1)
    if np.any((r < 6.4e6) | (r > 5e7)):
        k = int(np.flatnonzero((r < 6.4e6) | (r > 5e7))[0])
        raise states[k].error(f"state {k + 1}: not ECEF metres of an orbit (6400 km to 50000 km from the centre)")
    checked = screen(eph_t, pos, vel, epoch, f"{image.path}/ephemerides")
    vel = checked.velocities_m_s
    warnings = list(checked.notes) + list(checked.warnings)
    kept = checked.kept.copy()
    if kept.sum() < 8:
        raise image.error(f"only {int(kept.sum())} consistent ephemeris states: " + "; ".join(warnings), "ephemerides")

    stamp = image.child("timeStamp")
    t_begin, t_end = seconds(_utc(stamp, "begin")), seconds(_utc(stamp, "end"))
    data_node = image.child("imageData")

    def corner(tag: str) -> list[float]:
        c = data_node.child(tag)
        lat, lon = c.number("latitude"), c.number("longitude")
        if not (-90 <= lat <= 90 and -180 <= lon <= 360):
            raise c.error(f"latitude {lat}, longitude {lon}: not degrees")
        return [c.number("line"), c.number("column"), lon, lat, 0.0]

    corners = np.array([corner(t) for t in CORNERS])
    centre = np.array(corner("CT"))
    l_first, l_last = corners[:, 0].min(), corners[:, 0].max()
    if l_last <= l_first or t_end <= t_begin:
        raise data_node.error("the corners' first and last lines, and timeStamp begin and end, must differ and increase")
    if corners[:, 1].max() <= corners[:, 1].min():
        raise data_node.error("the corners' columns must differ")
    lag = TIMESTAMP_LAG_LINES if image.find("integrationTime") is not None else 0
    if l_last - l_first <= lag:
        raise data_node.error(f"the corners' first and last lines must be more than {lag} lines apart")
    period = (t_end - t_begin) / (l_last - l_first - lag)
    lines, columns = int(l_last) + 1, int(corners[:, 1].max()) + 1
    t_first = t_begin - (l_first + lag / 2) * period
    t_last = t_first + (lines - 1) * period
    consistent = (eph_t[kept].min() - 0.5, eph_t[kept].max() + 0.5)

    # states the image needs but the file cannot give: propagated from the nearest kept one
    need = (eph_t >= t_first - STATE_MARGIN_S) & (eph_t <= t_last + STATE_MARGIN_S)
    lost = need & np.isin(np.arange(eph_t.size), checked.dropped_inconsistent)
    if np.any(lost):
        p_new, v_new = propagate(eph_t[kept], pos[kept], vel[kept], eph_t[lost])
        pos, vel = pos.copy(), vel.copy()
        pos[lost], vel[lost] = p_new, v_new
        kept = kept | lost
        first_line = max(0, int((eph_t[lost].min() - STATE_MARGIN_S - t_first) / period))
        warnings.append(f"{image.path}/ephemerides: {int(lost.sum())} states the image needs "
                        f"({label(epoch, eph_t[lost].min())} to {label(epoch, eph_t[lost].max())}) replaced by the "
                        f"orbit propagated from the nearest consistent state (zonal gravity J2-J4): the model of "
                        f"lines from about {first_line} on rests on them")
    eph_t, pos, vel = eph_t[kept], pos[kept], vel[kept]
    if t_first < eph_t[0] - 1.0 or t_last > eph_t[-1] + 1.0:
        raise image.error("the ephemeris does not cover the image's lines (timeStamp)", "ephemerides")

    inertial = satellite not in YAW_STEERED

    def line_time(line: np.ndarray) -> np.ndarray:
        return t_first + np.asarray(line, float) * period

    def position(t: np.ndarray) -> np.ndarray:
        return lagrange(t, eph_t, pos)

    def velocity(t: np.ndarray) -> np.ndarray:
        return lagrange(t, eph_t, vel)

    t_corner = line_time(corners[:, 0])
    used = (t_corner >= consistent[0]) & (t_corner <= consistent[1])
    if used.sum() < 2:
        raise data_node.error("fewer than two corners lie where the ephemeris is consistent: the pointing cannot be fitted")
    if not used.all():
        warnings.append(f"{data_node.path}: corners {', '.join(np.array(CORNERS)[~used])} lie where the record's states are "
                        "inconsistent (the vendor computed them with those states): not used for the pointing"
                        + ("" if used.sum() >= 3 else "; with two corners the yaw is held at 0"))
    c0 = (columns - 1) / 2.0
    x, _ = fit_pointing(corners[used], c0, line_time, position, velocity, inertial, fit_yaw=bool(used.sum() >= 3))
    rot = _rotation(x[:3])
    ifov = float(x[3])
    frames = _frames(pos, vel, inertial)

    def look_body(column: np.ndarray) -> np.ndarray:
        c = np.atleast_1d(np.asarray(column, float))
        return np.column_stack([np.zeros_like(c), (c - c0) * ifov, -np.ones_like(c)]) @ rot.T

    model = LinescanModel(
        lines=lines, columns=columns, epoch_utc=epoch.isoformat().replace("+00:00", "Z"),
        tlc_lines=np.array([0.0, 1.0]), tlc_times_s=np.array([t_first, t_first + period]),
        ephemeris_times_s=eph_t, positions_ecef_m=pos, velocities_ecef_m_s=vel,
        attitude_times_s=eph_t, attitude_wxyz=matrix_to_quaternion(frames), look_body=look_body,
        corrections=Corrections(aberration=False, light_time=False, refraction=False),
    )
    bm = np.full((3, 3), np.nan)
    b_node = image.find("boresightMatrix")
    for v in b_node.children("value") if b_node is not None else []:
        i, j = v.element.get("row", ""), v.element.get("col", "")
        if i in ("0", "1", "2") and j in ("0", "1", "2"):
            bm[int(i), int(j)] = v.numbers(None, 1)[0]
    att = image.find("attitudes")
    samples = att.children("attitude") if att is not None else []
    att_t = np.array([seconds(_utc(s, "time")) for s in samples])
    rpy = np.array([[s.number(a) for a in ("roll", "pitch", "yaw")] for s in samples]).reshape(-1, 3)
    focal = None
    for f_node in image.children("focalDistance"):
        name = f_node.element.get("name", "")
        if not cams or name.lower().startswith(chosen):
            focal = f_node.numbers(None, 1)[0] / 1000.0
            break
    screened = Screening(list(checked.notes), list(checked.warnings), checked.velocity_frame, checked.velocity_rms_m_s,
                         sorted(checked.dropped_duplicates + checked.dropped_inconsistent))
    level = image.text("level") if image.find("level") is not None and (image.child("level").element.text or "").strip() else ""
    projection = image.text("projectionName") if image.find("projectionName") is not None and \
        (image.child("projectionName").element.text or "").strip() else ""
    pixel = image.number("verticalPixelSize") if image.find("verticalPixelSize") is not None else None
    return CbersProduct(shown, satellite, instrument, chosen, names, model, corners, centre, period, focal, ifov, c0,
                        x[:3].copy(), bm, att_t, rpy, checked, used, warnings, screened, level, projection, pixel, raw_geometry)


def map_grid(p: CbersProduct) -> str | None:
    """Why the product's raster is no pushbroom image (None when it is, or when the measurements
    are declared raw): INPE delivers level 2 (system corrected) and level 4 (orthorectified)
    products as rasters on a map grid (``projectionName``, ``verticalPixelSize``), resampled
    from the raw acquisition; the record's lines, columns, times, states and corners are those of
    the raw image, which the raster no longer has."""
    if p.raw_geometry or not p.projection:
        return None
    kind = {"2": "system corrected", "4": "orthorectified"}.get(p.level, f"level {p.level or 'unknown'}")
    size = f", {p.pixel_m:g} m" if p.pixel_m else ""
    return (f"level {p.level or '?'} ({kind}): the delivered raster is a {p.projection} map grid{size} resampled from the raw "
            "acquisition, while the record's lines, columns, times and corners are those of the raw image: measurements in "
            "the raster are map positions, not pushbroom lines and columns")


def pointing_rotation(p: CbersProduct) -> np.ndarray:
    """(3, 3) the fitted camera-to-orbital-frame rotation ``Rx(roll) Ry(pitch) Rz(yaw)``."""
    return _rotation(p.pointing_rad)


def corner_check(p: CbersProduct) -> dict[str, object]:
    """The model against the record's corners: residuals (px) of the fit to the corners used
    and, when four were used, for each corner how far the model fitted to the other three puts
    it (px, and metres across the ray at the corner's distance)."""
    m = p.model
    inertial = p.satellite not in YAW_STEERED
    corners = p.corners[p.corners_used]
    names = [n for n, u in zip(CORNERS, p.corners_used) if u]
    c0 = p.centre_column
    _, res = fit_pointing(corners, c0, m.line_time, m.position, m.velocity, inertial, fit_yaw=len(names) >= 3)
    fit_px = np.hypot(res[:, 0], res[:, 1]) / p.ifov_rad
    held = []
    for k in range(corners.shape[0] if len(names) == 4 else 0):
        x, _ = fit_pointing(np.delete(corners, k, axis=0), c0, m.line_time, m.position, m.velocity, inertial)
        t = m.line_time(corners[k:k + 1, 0])
        s, v = m.position(t), m.velocity(t)
        look = np.array([[0.0, (corners[k, 1] - c0) * x[3], -1.0]]) @ _rotation(x[:3]).T
        d = np.einsum("nij,nj->ni", _frames(s, v, inertial), look)[0]
        to_g = (geodetic_to_ecef(corners[k:k + 1, 2:5]) - s)[0]
        dist = float(np.linalg.norm(to_g))
        miss = float(np.linalg.norm(np.cross(d / np.linalg.norm(d), to_g / dist)))
        held.append({"corner": names[k], "px": miss / x[3], "m": miss * dist})
    return {"corners": names, "fit_rms_px": float(np.sqrt(np.mean(fit_px**2))), "fit_max_px": float(fit_px.max()),
            "held_out": held}
