"""Airbus/CNES DIMAP v1 (SPOT 1-5 level 1A/1B scene or segment metadata, ``METADATA.DIM``: SPOT 5
HRG/HRS, SPOT 1-4 HRV/HRVIR) read into the exact linescan model.

What is read, and the conventions (SPOT 1-5 Geometry Handbook, GAEL-P135-DOC-001; the public
SPOT 5 HRS segment of tests/data/vendor/stereopipeline):

- ``Raster_Dimensions``: ``NCOLS``, ``NROWS``.
- ``Data_Strip/Ephemeris/Points/Point``: ``Location`` and ``Velocity`` (``X Y Z``, ECEF m and
  m/s; SPOT 5: DORIS-determined, 30 s apart; SPOT 1-4: 60 s apart) and ``TIME`` (UTC, ISO 8601
  without zone). The velocities of SPOT 1-4 files are *inertial* velocities in Earth-fixed axes
  (``V = v_ecef + omega x P``): the screening (:mod:`solver.sensors.screening`) finds it from the
  data (as Earth-fixed velocities they miss their positions by 20-27 km per 60-s interval on
  seven public scenes, as ``V - omega x P`` by 0.5-10 m) and converts them, saying so. The
  orbital frame of the attitude (below) is built from the velocities as the file gives them, as
  the vendor's location model does (its tie points are met to metres with them).
- SPOT 5: ``Data_Strip/Satellite_Attitudes/Corrected_Attitudes/Corrected_Attitude/Angles``: ``TIME``,
  ``YAW``, ``PITCH``, ``ROLL`` (rad; star-tracker corrected, 8 Hz), samples flagged
  ``OUT_OF_RANGE`` Y are refused. The angles turn the navigation frame O1 into the local
  orbital frame O2: ``M = [[cr cy, -cr sy, -sr], [cp sy + sp sr cy, cp cy - sp sr sy, sp cr],
  [-sp sy + cp sr cy, -sp cy - cp sr sy, cp cr]]`` (handbook eq. 11), and O2 into ECEF by the
  columns ``X2 = normalize(V x Z2)``, ``Y2 = Z2 x X2``, ``Z2 = P / |P|`` (eq. 7); the attitude
  turned into body-to-ECEF quaternions at the samples and slerped between them (the handbook
  interpolates the angles linearly; at 8 Hz the two differ by far less than a pixel). Real
  segments start and end a fraction of a second beyond the attitude samples: extrapolation by
  up to two sample intervals is accepted.
- SPOT 1-4 (no corrected attitude): ``.../Raw_Attitudes/Aocs_Attitude/Angular_Speeds_List``:
  the gyros' yaw, pitch and roll speeds (rad/s, about 8 Hz), integrated (trapezoids) into the
  same three angles; the integration constant is the first absolute angle of ``Angles_List``
  (at its time) when given, else zero at the scene centre time. On three real SPOT 2/3 scenes
  the integrated speeds reproduce the second absolute angle, 9 s later, to 1.6e-6 rad at most.
- ``Data_Strip/Sensor_Configuration/Time_Stamp``: ``LINE_PERIOD`` (s), ``SCENE_CENTER_TIME``
  (UTC), ``SCENE_CENTER_LINE`` (1-based): line L (0-based, pixel centres) is at
  ``SCENE_CENTER_TIME + (L + 1 - SCENE_CENTER_LINE) LINE_PERIOD``.
- ``.../Instrument_Look_Angles/Look_Angles_List/Look_Angles``: ``DETECTOR_ID`` (1-based;
  column C is detector C + 1), ``PSI_X`` (along track) and ``PSI_Y`` (across track), rad:
  the detector looks along ``(-tan PSI_Y, tan PSI_X, -1)`` in O1 (z away from the ground;
  :mod:`solver.sensors.detectors`). SPOT 5 gives one per column, SPOT 1-4 the first and last
  detector's: the *angles* are linear in the column between the given detectors (the tangents
  linear instead miss the scene centre the file states by 65-722 m; docs/sensor-metadata.md).

The file's corner tie points (``Geoposition/Geoposition_Points/Tie_Point``: ``TIE_POINT_CRS_X``
longitude, ``_Y`` latitude, ``_Z`` height at ``TIE_POINT_DATA_X`` column, ``_Y`` line, 1-based)
and the scene centre (``Dataset_Frame/Scene_Center``: ``FRAME_ROW``, ``FRAME_COL``, 1-based,
``FRAME_LON``, ``FRAME_LAT``, at the tie points' height) are kept for the checks
(:func:`tie_point_check`, :mod:`solver.sensors.self_check`); DIMAP v1 carries no RPC. The corrections of
:mod:`solver.sensors.linescan` are all switched off by default for SPOT 5: the vendor's location
model has none (its tie points agree with the uncorrected model to centimetres, and the
corrected attitude, estimated with that model, absorbs them); switch them on to see their size.

The tie points and centres of SPOT 1-4 products are the vendor's systematic location, made
without the attitude: on seven public scenes the exact model with zero angles meets all four
corners of a scene to one common 0.4-2.7 m and its centre to 0.4-2.5 m, with the measured
attitude (1-7 arcseconds) they are 1.5-24 m away (docs/sensor-metadata.md);
:attr:`Spot5Product.systematic` is that attitude-free model, for the self-check. DIMAP v2 (SPOT 6/7, Pleiades) is
:mod:`solver.sensors.dimap_v2`.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field, replace
from datetime import datetime, timezone
from pathlib import Path

import numpy as np

from solver.schema.job import MAX_COLUMNS, MAX_LINES
from solver.sensors.detectors import SPOT_NAVIGATION, LookAngles
from solver.sensors.linescan import Corrections, LinescanModel, lagrange, matrix_to_quaternion
from solver.sensors.screening import Screening, screen_model
from solver.sensors.xmlsafe import Node, load


@dataclass
class Spot5Product:
    file: str
    mission: str
    instrument: str
    model: LinescanModel
    corners: np.ndarray  # (k, 5): tie points: line, column (0-based), lon_deg, lat_deg, h_m
    line_period_s: float
    look: LookAngles
    centre: np.ndarray = field(default_factory=lambda: np.zeros((0, 5)))  # (0 or 1, 5): Dataset_Frame/Scene_Center
    screening: Screening = field(default_factory=Screening)
    incidence_deg: float | None = None  # Scene_Source/INCIDENCE_ANGLE, as stated
    # SPOT 1-4 (gyro attitude): the model without the attitude angles, in which the vendor
    # located the tie points and the scene centre (module docstring); None for SPOT 5
    systematic: LinescanModel | None = None


def _utc(node: Node, tag: str) -> datetime:
    text = node.text(tag)
    try:
        t = datetime.fromisoformat(text.replace("Z", "+00:00"))
    except ValueError:
        raise node.error(f"not an ISO 8601 time: {text[:40]!r}", tag) from None
    return t if t.tzinfo else t.replace(tzinfo=timezone.utc)


def _corrected_angles(attitudes: Node, seconds: Callable[[datetime], float]) -> tuple[Node, np.ndarray, np.ndarray]:
    """SPOT 5: the star-tracker corrected yaw, pitch, roll samples (rad)."""
    att = attitudes.child("Corrected_Attitudes").child("Corrected_Attitude")
    samples = att.children("Angles")
    if len(samples) < 2:
        raise att.error(f"2 attitude samples at least, {len(samples)} found", "Angles")
    for s in samples:
        if s.find("OUT_OF_RANGE") is not None and s.text("OUT_OF_RANGE").upper() == "Y":
            raise s.error("a sample flagged OUT_OF_RANGE", "OUT_OF_RANGE")
    att_t = np.array([seconds(_utc(s, "TIME")) for s in samples])
    if np.any(np.diff(att_t) <= 0):
        raise att.error("attitude times must increase", "Angles")
    return att, att_t, np.array([[s.number("YAW"), s.number("PITCH"), s.number("ROLL")] for s in samples])


def _integrated_speeds(attitudes: Node, seconds: Callable[[datetime], float], t_center: float) -> tuple[Node, np.ndarray, np.ndarray]:
    """SPOT 1-4: yaw, pitch, roll (rad) integrated from the gyros' angular speeds (rad/s, linear
    between samples: trapezoids). The integration constant is the first absolute AOCS angle
    (``Aocs_Attitude/Angles_List/Angles``) at its time when the file has one (the first speed
    held constant back to it), else zero at the scene centre time."""
    raw = attitudes.child("Raw_Attitudes")
    aocs = raw.find("Aocs_Attitude") or raw
    lst = aocs.child("Angular_Speeds_List")
    samples = lst.children("Angular_Speeds")
    if len(samples) < 2:
        raise lst.error(f"2 angular speed samples at least, {len(samples)} found", "Angular_Speeds")
    for s in samples:
        if s.find("OUT_OF_RANGE") is not None and s.text("OUT_OF_RANGE").upper() == "Y":
            raise s.error("a sample flagged OUT_OF_RANGE", "OUT_OF_RANGE")
    t = np.array([seconds(_utc(s, "TIME")) for s in samples])
    rates = np.array([[s.number("YAW"), s.number("PITCH"), s.number("ROLL")] for s in samples])
    if np.any(np.abs(rates) > 0.1):
        raise lst.error("angular speeds above 0.1 rad/s: rad/s of a pointing platform expected", "Angular_Speeds")
    absolute = aocs.find("Angles_List")
    first = absolute.children("Angles")[0] if absolute is not None and absolute.children("Angles") else None
    if first is not None and not (first.find("OUT_OF_RANGE") is not None and first.text("OUT_OF_RANGE").upper() == "Y"):
        t_first = seconds(_utc(first, "TIME"))
        if t_first < t[0]:  # the first speed held back to the absolute angle's time
            t, rates = np.concatenate([[t_first], t]), np.vstack([rates[:1], rates])
        origin_t, origin = t_first, np.array([first.number("YAW"), first.number("PITCH"), first.number("ROLL")])
    else:
        origin_t, origin = t_center, np.zeros(3)
    if np.any(np.diff(t) <= 0):
        raise lst.error("angular speed times must increase", "Angular_Speeds")
    if not t[0] <= origin_t <= t[-1]:
        raise lst.error("the samples do not contain the time they are integrated from", "Angular_Speeds")
    steps = 0.5 * (rates[1:] + rates[:-1]) * np.diff(t)[:, None]
    angles = np.vstack([np.zeros(3), np.cumsum(steps, axis=0)])
    # the integral of speeds linear between samples is quadratic there: its value at the origin
    i = int(np.clip(np.searchsorted(t, origin_t) - 1, 0, t.size - 2))
    u = origin_t - t[i]
    slope = (rates[i + 1] - rates[i]) / (t[i + 1] - t[i])
    at_origin = angles[i] + rates[i] * u + 0.5 * slope * u * u
    return lst, t, angles - at_origin + origin


def _look_angles(cfg: Node, columns: int) -> LookAngles:
    """The look angles of the first band's detectors: one per column (SPOT 5) or a few detectors
    (SPOT 1-4: the first and the last), linear in their tangents between detectors."""
    looks = cfg.child("Instrument_Look_Angles_List").child("Instrument_Look_Angles").child("Look_Angles_List")
    cells = looks.children("Look_Angles")
    table = np.array([[c.number("DETECTOR_ID"), c.number("PSI_X"), c.number("PSI_Y")] for c in cells]) if cells else np.zeros((0, 3))
    ids = table[:, 0]
    if (table.shape[0] < min(2, columns) or np.any(np.diff(ids) <= 0) or ids[0] != 1 or ids[-1] != columns
            or np.any(np.abs(table[:, 1:]) >= 1.0)):
        raise looks.error(f"look angles (rad) of detectors 1 to {columns} expected in increasing order (every column, or "
                          f"the first and last), {table.shape[0]} found")
    return LookAngles.table(np.tan(table[:, 1]), np.tan(table[:, 2]), SPOT_NAVIGATION, ids - 1.0)


def look_rotation(yaw: np.ndarray, pitch: np.ndarray, roll: np.ndarray) -> np.ndarray:
    """(n, 3, 3) navigation (O1) to local orbital frame (O2), SPOT handbook eq. 11."""
    cp, sp, cr, sr, cy, sy = np.cos(pitch), np.sin(pitch), np.cos(roll), np.sin(roll), np.cos(yaw), np.sin(yaw)
    return np.stack([
        np.stack([cr * cy, -cr * sy, -sr], -1),
        np.stack([cp * sy + sp * sr * cy, cp * cy - sp * sr * sy, sp * cr], -1),
        np.stack([-sp * sy + cp * sr * cy, -sp * cy - cp * sr * sy, cp * cr], -1),
    ], -2)


def orbital_to_ecef(position: np.ndarray, velocity: np.ndarray) -> np.ndarray:
    """(n, 3, 3) with columns X2, Y2, Z2 (SPOT handbook eq. 7)."""
    z = position / np.linalg.norm(position, axis=1, keepdims=True)
    x = np.cross(velocity, z)
    x /= np.linalg.norm(x, axis=1, keepdims=True)
    y = np.cross(z, x)
    return np.stack([x, y, z], axis=2)


def dimap_version(root: Node) -> str:
    """The DIMAP version of a parsed ``Dimap_Document`` (``METADATA_FORMAT``'s ``version``: in
    ``Metadata_Id`` for v1, ``Metadata_Identification`` for v2), "" when it has none."""
    if root.element.tag != "Dimap_Document":
        raise root.error("not a DIMAP document (root element Dimap_Document expected)")
    for section in ("Metadata_Id", "Metadata_Identification"):
        fmt = root.element.find(f"{section}/METADATA_FORMAT")
        if fmt is not None:
            return fmt.get("version", "").strip()
    return ""


def read_spot5(path: str | Path, shown: str | None = None, data: bytes | None = None) -> Spot5Product:
    """The exact model of a SPOT 1-5 DIMAP v1 metadata file (module docstring); ``data`` as for
    :func:`solver.sensors.maxar.read_maxar`."""
    path = Path(path)
    shown = str(path) if shown is None else shown
    root = load(path, shown, data)
    version = dimap_version(root)
    if not version.startswith("1."):
        raise root.error(f"DIMAP version {version or 'unknown'}: DIMAP v1 (SPOT 1-5) expected here")
    return read_dimap_v1_root(root, shown)


def read_dimap_v1_root(root: Node, shown: str) -> Spot5Product:
    """The product of a parsed DIMAP v1 document (module docstring)."""
    dims = root.child("Raster_Dimensions")
    columns, lines = dims.integer("NCOLS"), dims.integer("NROWS")
    if not (1 <= lines <= MAX_LINES and 1 <= columns <= MAX_COLUMNS):
        raise dims.error(f"NROWS {lines}, NCOLS {columns}: 1 to {MAX_LINES} rows and 1 to {MAX_COLUMNS} columns expected")
    strip = root.child("Data_Strip")
    points = strip.child("Ephemeris").child("Points").children("Point")
    if len(points) < 4:
        raise strip.error(f"4 ephemeris points at least, {len(points)} found", "Ephemeris/Points")
    times = [_utc(p, "TIME") for p in points]
    epoch = times[0]

    def seconds(t: datetime) -> float:
        return (t - epoch).total_seconds()

    eph_t = np.array([seconds(t) for t in times])
    if np.any(np.diff(eph_t) <= 0):
        raise strip.error("ephemeris times must increase (duplicated or unordered points)", "Ephemeris/Points")
    pos = np.array([[p.child("Location").number(a) for a in "XYZ"] for p in points])
    vel = np.array([[p.child("Velocity").number(a) for a in "XYZ"] for p in points])
    r = np.linalg.norm(pos, axis=1)
    if np.any((r < 6.4e6) | (r > 5e7)):
        raise strip.error("positions are not ECEF metres of an orbit", "Ephemeris/Points")

    cfg = strip.child("Sensor_Configuration")
    stamp = cfg.child("Time_Stamp")
    period = stamp.number("LINE_PERIOD")
    if not 0 < period < 1:
        raise stamp.error(f"{period}: a line period in seconds expected", "LINE_PERIOD")
    t_center = seconds(_utc(stamp, "SCENE_CENTER_TIME"))
    center_line = stamp.number("SCENE_CENTER_LINE")

    attitudes = strip.child("Satellite_Attitudes")
    if attitudes.find("Corrected_Attitudes") is not None:
        att, att_t, ypr = _corrected_angles(attitudes, seconds)
    else:
        att, att_t, ypr = _integrated_speeds(attitudes, seconds, t_center)
    look = _look_angles(cfg, columns)

    t0 = t_center + (0 + 1 - center_line) * period
    t_end = t0 + (lines - 1) * period
    for node, t in ((strip, eph_t), (att, att_t)):
        margin = 2.0 * float(np.median(np.diff(t)))  # extrapolation by two sample intervals at most
        if t0 < t[0] - margin or t_end > t[-1] + margin:
            raise node.error("the samples do not cover the image's line times")
    # the orbital frame from the velocities as the file gives them (inertial ones for SPOT 1-4, as
    # the vendor's location model: its tie points are met to metres); the model's velocities are
    # then screened and, where inertial, converted to Earth-fixed (solver.sensors.screening)
    frame = orbital_to_ecef(lagrange(att_t, eph_t, pos), lagrange(att_t, eph_t, vel))
    rot = frame @ look_rotation(ypr[:, 0], ypr[:, 1], ypr[:, 2])
    model = LinescanModel(
        lines=lines, columns=columns, epoch_utc=epoch.isoformat().replace("+00:00", "Z"),
        tlc_lines=np.array([0.0, 1.0]), tlc_times_s=np.array([t0, t0 + period]),
        ephemeris_times_s=eph_t, positions_ecef_m=pos, velocities_ecef_m_s=vel,
        attitude_times_s=att_t, attitude_wxyz=matrix_to_quaternion(rot), look_body=look.body,
        corrections=Corrections(aberration=False, light_time=False, refraction=False),
    )
    raw_attitude = attitudes.find("Corrected_Attitudes") is None
    model, screening = screen_model(model, strip.child("Ephemeris").child("Points"), att)
    # SPOT 1-4 locate their tie points and scene centre without the attitude (the orbital frame
    # alone): the model of those points, for the self-check
    systematic = replace(model, attitude_times_s=att_t, attitude_wxyz=matrix_to_quaternion(frame)) if raw_attitude else None
    corners = []
    geo = root.find("Geoposition")
    tie = geo.find("Geoposition_Points") if geo is not None else None
    for v in tie.children("Tie_Point") if tie is not None else []:
        corners.append([v.number("TIE_POINT_DATA_Y") - 1, v.number("TIE_POINT_DATA_X") - 1,
                        v.number("TIE_POINT_CRS_X"), v.number("TIE_POINT_CRS_Y"), v.number("TIE_POINT_CRS_Z")])
    corners_array = np.array(corners).reshape(-1, 5)
    src = root.find("Dataset_Sources")
    scene = src.find("Source_Information") if src is not None else None
    scene = scene.find("Scene_Source") if scene is not None else None
    mission = f"{scene.text('MISSION')} {scene.text('MISSION_INDEX')}" if scene is not None and scene.find("MISSION") is not None else ""
    if mission and mission not in ("SPOT 1", "SPOT 2", "SPOT 3", "SPOT 4", "SPOT 5"):
        raise scene.error(f"{mission}: a DIMAP v1 product of SPOT 1 to 5 expected", "MISSION_INDEX")
    instrument = scene.text("INSTRUMENT") if scene is not None and scene.find("INSTRUMENT") is not None else ""
    incidence = scene.number("INCIDENCE_ANGLE") if scene is not None and scene.find("INCIDENCE_ANGLE") is not None else None
    return Spot5Product(shown, mission, instrument, model, corners_array, period, look,
                        _scene_centre(root, corners_array), screening, incidence, systematic)


def _scene_centre(root: Node, tie_points: np.ndarray) -> np.ndarray:
    """(0 or 1, 5) the ``Dataset_Frame/Scene_Center`` (line, column 0-based, lon, lat, height of
    the tie points: the frame states none) when the frame's vertices are the tie points (a frame
    rewritten apart from them, as in the public SPOT 5 segment cut to 300 columns, is not used)."""
    frame = root.find("Dataset_Frame")
    if frame is None or frame.find("Scene_Center") is None or tie_points.shape[0] == 0:
        return np.zeros((0, 5))
    vertices = np.array([[v.number("FRAME_ROW") - 1, v.number("FRAME_COL") - 1, v.number("FRAME_LON"), v.number("FRAME_LAT")]
                         for v in frame.children("Vertex")]).reshape(-1, 4)
    if vertices.shape[0] != tie_points.shape[0] or not np.allclose(vertices, tie_points[:, :4], rtol=0.0, atol=1e-6):
        return np.zeros((0, 5))
    c = frame.child("Scene_Center")
    height = float(np.mean(tie_points[:, 4]))
    return np.array([[c.number("FRAME_ROW") - 1, c.number("FRAME_COL") - 1, c.number("FRAME_LON"), c.number("FRAME_LAT"), height]])


def tie_point_check(p: Spot5Product) -> dict[str, object]:
    """Distances (m) between the vendor's tie points and the exact model's ground points at the
    same image positions and heights, for the tie points whose column has a look angle."""
    from solver.geometry.geodesy import geodetic_to_ecef

    c = p.corners
    inside = (c[:, 1] >= 0) & (c[:, 1] <= p.model.columns - 1) & (c[:, 0] >= 0) & (c[:, 0] <= p.model.lines - 1)
    c = c[inside]
    if c.shape[0] == 0:
        return {"points": 0, "distances_m": []}
    g = p.model.image_to_ecef(c[:, 0], c[:, 1], c[:, 4])
    d = np.linalg.norm(g - geodetic_to_ecef(c[:, 2:5]), axis=1)
    return {"points": int(c.shape[0]), "distances_m": [float(x) for x in d], "outside_columns": int((~inside).sum())}
