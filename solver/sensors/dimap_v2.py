"""Airbus DIMAP v2 sensor metadata (``DIM_*.XML`` of SPOT 6/7, Pleiades 1A/1B and Pleiades Neo
primary/sensor products) read into the exact linescan model.

What is read (element paths under the root ``Dimap_Document``; Airbus' Pleiades and SPOT 6/7
user guides; checked on a real SPOT 6 product, docs/sensor-metadata.md):

- ``Metadata_Identification``: ``METADATA_FORMAT`` version 2.x and ``METADATA_PROFILE``
  (``PHR_SENSOR``, ``PNEO_SENSOR``, ``S6_SENSOR``, ``S7_SENSOR``; an ortho or projected
  product has no sensor model and is refused);
- ``Raster_Data/Raster_Dimensions``: ``NROWS``, ``NCOLS``;
- ``Geometric_Data/Refined_Model/Time``: ``Time_Range/START`` (UTC: the first line's time) and
  ``Time_Stamp/LINE_PERIOD`` (its ``unit`` attribute; without one, milliseconds for Pleiades
  1A/1B and microseconds otherwise, as the user guides state). Line L (0-based, pixel centres)
  is imaged at ``START + L LINE_PERIOD`` (on the real SPOT 6 product ``END`` is
  ``START + (NROWS - 1) LINE_PERIOD`` to 1 microsecond);
- ``.../Ephemeris/Point_List/Point``: ``LOCATION_XYZ`` (ECEF m), ``VELOCITY_XYZ`` (m/s),
  ``TIME`` (UTC); Lagrange interpolation over 8 points;
- ``.../Attitudes``: either ``Quaternion_List/Quaternion`` (``Q0`` scalar first, ``Q1..Q3``,
  ``TIME``: SPOT 6/7, Pleiades Neo) or ``Polynomial_Quaternions`` (Pleiades 1A/1B: ``OFFSET``
  seconds after 00:00 UTC of the first line's date, ``SCALE`` seconds, and ``Q0..Q3`` each with
  ``DEGREE`` and ``COEFFICIENTS``, lowest degree first, in ``(t - OFFSET) / SCALE``; sampled
  every 10 ms here and slerped). The quaternion rotates vectors of the satellite frame into
  ECEF;
- ``.../Geometric_Calibration/Instrument_Calibration``: ``Polynomial_Look_Angles``
  (``XLOS_k``, ``YLOS_k``: the tangents of the across- and along-track look angles, polynomials
  in the column; :mod:`solver.sensors.detectors`) directly (Pleiades 1A/1B) or in
  ``Band_Calibration_List/Band_Calibration`` (the panchromatic band, else the first one), with
  the ``Swath_Range/FIRST_COL`` beside them: the polynomial's column is the 0-based image column
  plus ``FIRST_COL - 1`` (as ASP found on real Pleiades products). ``Instrument_Biases`` other
  than zero are refused (no public product lets us check their rotation order);
- ``Dataset_Content/Dataset_Extent``: the corner ``Vertex`` and ``Center`` positions (``COL``,
  ``ROW`` 1-based, ``LON``, ``LAT``, ``H`` when given), for :func:`extent_check`; a ``Center``
  that is the vertices' mean (as on the real Pleiades 1A product) is left out;
- ``.../Instrument_Configuration/DETECTOR_SIZE_COL``: micrometres, or metres beside a
  ``FOCAL_LENGTH`` in metres (the real Pleiades 1A product: ``13e-06`` and ``12.9``); only its
  ratio to the focal length matters;
- the RPC component (``COMPONENT_PATH`` of the component titled ``RPC Model``): its file name,
  looked for beside the metadata file.

Corrections: off by default. The vendor's refined model has none (its corrected attitude
absorbs them): on the real SPOT 6 product the corners meet the exact model to 0.12 m without
aberration and 17 m away with it; on the real Pleiades 1A product (tests/data/vendor/pyrugged) to
0.72 px RMS without corrections, 35 px with aberration, 1.5 px with light time.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from datetime import datetime, timedelta, timezone
from pathlib import Path, PurePath

import numpy as np

from solver.geometry.rpc import RPC
from solver.schema.job import MAX_COLUMNS, MAX_LINES
from solver.sensors.detectors import DIMAP_V2_SATELLITE, LookAngles
from solver.sensors.linescan import Corrections, LinescanModel
from solver.sensors.maxar import parse_utc
from solver.sensors.screening import Screening, screen_model
from solver.sensors.timescales import UnknownLeapSeconds, leap_seconds_between
from solver.sensors.xmlsafe import Node, load

PROFILES = {"PHR_SENSOR": "Pleiades", "PNEO_SENSOR": "Pleiades Neo", "S6_SENSOR": "SPOT 6", "S7_SENSOR": "SPOT 7"}
LINE_PERIOD_UNITS = {"s": 1.0, "ms": 1e-3, "millisecond": 1e-3, "milliseconds": 1e-3,
                     "us": 1e-6, "µs": 1e-6, "microsecond": 1e-6, "microseconds": 1e-6}
QUATERNION_STEP_S = 0.01  # sampling of the Pleiades 1A/1B attitude polynomials (slerp error < 1e-8 rad)
MARGIN_S = 0.5  # polynomial attitude sampled this far beyond the first and last lines
# a Center whose longitude and latitude are the vertices' mean to this (deg) is not a projected
# point (a real Pleiades 1A product: equal to 1e-14 deg, 10 lines from the exact model's centre)
CENTRE_IS_MEAN_DEG = 1e-9
MAX_IMAGE_S = 600.0  # longest image read (a Pleiades strip lasts tens of seconds): bounds the work of a hostile file
DEFAULT_PIXEL_MM = 0.013  # Pleiades panchromatic detector pitch; only its ratio to the focal length matters


@dataclass
class DimapV2Product:
    """One DIMAP v2 sensor product: the exact model and what the job and the checks need."""

    file: str
    satellite: str
    band: str
    profile: str
    model: LinescanModel
    look: LookAngles
    line_period_s: float
    pixel_mm: float
    corners: np.ndarray  # (n, 5): line, column (0-based), lon, lat, h (NaN when not given)
    rpc_name: str | None  # the RPC component's file name
    rpc_path: Path | None  # that file beside the metadata file, when it exists
    rpc: RPC | None = None  # an RPC carried by the metadata file itself (solver.sensors.phr_dimap)
    screening: Screening = field(default_factory=Screening)


def _seconds(t: datetime, epoch: datetime) -> float:
    return (t - epoch).total_seconds()


def _line_period(stamp: Node, profile: str) -> float:
    node = stamp.child("LINE_PERIOD")
    value = stamp.number("LINE_PERIOD")
    unit = node.element.get("unit")
    if unit is None:
        scale = 1e-3 if profile == "PHR_SENSOR" else 1e-6
    elif unit.strip().lower() in LINE_PERIOD_UNITS:
        scale = LINE_PERIOD_UNITS[unit.strip().lower()]
    else:
        raise node.error(f"unit {unit[:20]!r}: s, ms or microsecond expected")
    return checked_line_period(node, value * scale)


def checked_line_period(node: Node, period: float) -> float:
    """``period`` (s) if a pushbroom sensor's line period (10 us to 10 ms), else a located error."""
    if not 1e-5 <= period <= 1e-2:
        raise node.error(f"{period:.3g} s: not the line period of a pushbroom sensor (10 us to 10 ms)")
    return period


EPHEMERIS_TAGS = ("LOCATION_XYZ", "VELOCITY_XYZ", "TIME")  # position, velocity, time of a Point


def _ephemeris(lst: Node, epoch: datetime, tags: tuple[str, str, str] = EPHEMERIS_TAGS) -> tuple[np.ndarray, np.ndarray, np.ndarray, datetime]:
    """The ``Point`` children of ``lst``: times (s after ``epoch``), ECEF positions, velocities."""
    points = lst.children("Point")
    if len(points) < 4:
        raise lst.error(f"4 points at least, {len(points)} found", "Point")
    times = [parse_utc(p, tags[2]) for p in points]
    pos = np.array([p.numbers(tags[0], 3) for p in points])
    vel = np.array([p.numbers(tags[1], 3) for p in points])
    t = np.array([_seconds(x, epoch) for x in times])
    if np.any(np.diff(t) <= 0):
        raise lst.error("point times must increase (duplicated or unordered points)", "Point")
    r = np.linalg.norm(pos, axis=1)
    if np.any((r < 6.4e6) | (r > 5e7)):
        raise lst.error("positions are not ECEF metres of an orbit", f"Point/{tags[0]}")
    return t, pos, vel, times[0]


def _quaternion_list(att: Node, epoch: datetime) -> tuple[np.ndarray, np.ndarray]:
    lst = att.child("Quaternion_List")
    rows = lst.children("Quaternion")
    if len(rows) < 2:
        raise lst.error(f"2 quaternions at least, {len(rows)} found", "Quaternion")
    t = np.array([_seconds(parse_utc(q, "TIME"), epoch) for q in rows])
    q = np.array([[r.number(k) for k in ("Q0", "Q1", "Q2", "Q3")] for r in rows])
    if np.any(np.diff(t) <= 0):
        raise lst.error("quaternion times must increase", "Quaternion")
    norm = np.linalg.norm(q, axis=1)
    if np.any(np.abs(norm - 1.0) > 1e-3):
        k = int(np.argmax(np.abs(norm - 1.0)))
        raise lst.error(f"quaternion {k + 1} has norm {norm[k]:.6f}: unit quaternions expected", "Quaternion")
    return t, q / norm[:, None]


def polynomial_coefficients(node: Node, tag: str) -> np.ndarray:
    """The ``COEFFICIENTS`` (lowest degree first) of the child ``tag`` with its ``DEGREE``."""
    p = node.child(tag)
    degree = p.integer("DEGREE")
    if not 0 <= degree <= 10:
        raise p.error(f"{degree}: a degree of 0 to 10 expected", "DEGREE")
    return np.array(p.numbers("COEFFICIENTS", degree + 1))


def polynomial_quaternions(poly: Node, scaling: Node, epoch: datetime, first_line: datetime,
                            span: tuple[float, float]) -> tuple[np.ndarray, np.ndarray]:
    """Quaternions sampled from the polynomials ``Q0..Q3`` of ``poly`` in ``(t - OFFSET) / SCALE``
    (both in ``scaling``; t in s after 00:00 UTC of the first line's date)."""
    offset, scale = scaling.number("OFFSET"), scaling.number("SCALE")
    if scale <= 0:
        raise scaling.error("must be positive", "SCALE")
    coeffs = [polynomial_coefficients(poly, k) for k in ("Q0", "Q1", "Q2", "Q3")]
    midnight = datetime(first_line.year, first_line.month, first_line.day, tzinfo=timezone.utc)
    t = np.arange(span[0] - MARGIN_S, span[1] + MARGIN_S + QUATERNION_STEP_S, QUATERNION_STEP_S)
    u = (t + _seconds(epoch, midnight) - offset) / scale
    q = np.column_stack([np.polynomial.polynomial.polyval(u, c) for c in coeffs])
    norm = np.linalg.norm(q, axis=1)
    if np.any(np.abs(norm - 1.0) > 1e-2):
        raise poly.error(f"the polynomials give quaternions of norm {norm.min():.4f} to {norm.max():.4f} over the "
                         "image's lines: OFFSET (seconds after 00:00 UTC) or the coefficients do not fit it")
    return t, q / norm[:, None]


def _look_angles(calib: Node) -> tuple[LookAngles, str]:
    """The look-angle polynomials (module docstring) and the band they belong to."""
    holder, band = calib, ""
    if calib.find("Polynomial_Look_Angles") is None:
        bands = calib.child("Band_Calibration_List").children("Band_Calibration")
        if not bands:
            raise calib.error("missing", "Band_Calibration_List/Band_Calibration")
        ids = [b.text("BAND_ID") if b.find("BAND_ID") is not None else "" for b in bands]
        pick = next((k for k, b in enumerate(ids) if b.upper() in ("P", "PAN", "PA")), 0)
        holder, band = bands[pick], ids[pick]
    look = holder.child("Polynomial_Look_Angles")
    xs, ys = [], []
    for name, out in (("XLOS", xs), ("YLOS", ys)):
        while look.find(f"{name}_{len(out)}") is not None:
            out.append(look.number(f"{name}_{len(out)}"))
        if not out:
            raise look.error("missing", f"{name}_0")
    swath = holder.find("Swath_Range") or calib.find("Swath_Range")
    first_col = swath.number("FIRST_COL") if swath is not None else 1.0
    return LookAngles.polynomials(ys, xs, first_col - 1.0, DIMAP_V2_SATELLITE), band


def _biases(calib: Node) -> None:
    b = calib.find("Instrument_Biases")
    if b is None:
        return
    for tag in ("YAW", "PITCH", "ROLL"):
        if b.find(tag) is not None and b.number(tag) != 0.0:
            raise b.error("non-zero instrument biases are not read (their rotation order is not checked on a real "
                          "product)", tag)
    q = [b.number(t) for t in ("Q0", "Q1", "Q2", "Q3")] if b.find("Q0") is not None else [1.0, 0, 0, 0]
    if abs(abs(q[0]) - 1.0) > 1e-12:
        raise b.error("a bias quaternion other than the identity is not read", "Q0")


def _corners(root: Node) -> np.ndarray:
    content = root.find("Dataset_Content")
    extent = content.find("Dataset_Extent") if content is not None else None
    if extent is None:
        return np.zeros((0, 5))
    return extent_rows(extent)


def extent_rows(extent: Node) -> np.ndarray:
    """(n, 5) line, column (0-based), lon, lat, h (NaN when not given) of the ``Vertex`` and
    ``Center`` children of ``extent``; a centre that is the vertices' mean is left out."""

    def rows_of(nodes: list[Node]) -> np.ndarray:
        rows = []
        for v in nodes:
            if all(v.find(t) is not None for t in ("COL", "ROW", "LON", "LAT")):
                h = v.number("H") if v.find("H") is not None else np.nan
                rows.append([v.number("ROW") - 1, v.number("COL") - 1, v.number("LON"), v.number("LAT"), h])
        return np.array(rows).reshape(-1, 5)

    vertices, centre = rows_of(extent.children("Vertex")), rows_of(extent.children("Center"))
    if len(vertices) and len(centre) and np.allclose(centre[:, 2:4], vertices[:, 2:4].mean(axis=0), rtol=0.0, atol=CENTRE_IS_MEAN_DEG):
        centre = centre[:0]  # the vertices' mean, not a located point: no evidence about the model
    return np.vstack([vertices, centre])


def rpc_component(root: Node) -> str | None:
    """The file name (no directory) of the RPC component a DIMAP v2 document names, if any."""
    for section in ("Dataset_Content/Dataset_Components", "Geoposition/Geoposition_Models/Rational_Function_Model"):
        holder = root.element.find(section)
        if holder is None:
            continue
        for comp in holder.findall("Component"):
            title = (comp.findtext("COMPONENT_TITLE") or "").strip().lower()
            path = comp.find("COMPONENT_PATH")
            if "rpc" in title and path is not None and path.get("href"):
                return PurePath(path.get("href", "").replace("\\", "/")).name or None
    return None


def read_dimap_v2_root(root: Node, path: Path, shown: str) -> DimapV2Product:
    """The product of a parsed DIMAP v2 document (module docstring)."""
    ident = root.child("Metadata_Identification")
    profile = ident.text("METADATA_PROFILE")
    if profile not in PROFILES:
        raise ident.error(f"{profile[:40]}: a sensor product ({', '.join(PROFILES)}) expected; an ortho or projected "
                          "product has no sensor model", "METADATA_PROFILE")
    dims = root.child("Raster_Data").child("Raster_Dimensions")
    lines, columns = dims.integer("NROWS"), dims.integer("NCOLS")
    if not (2 <= lines <= MAX_LINES and 1 <= columns <= MAX_COLUMNS):
        raise dims.error(f"NROWS {lines}, NCOLS {columns}: 2 to {MAX_LINES} rows and 1 to {MAX_COLUMNS} columns expected")
    model_node = root.child("Geometric_Data").child("Refined_Model")
    time = model_node.child("Time")
    first_line = parse_utc(time.child("Time_Range"), "START")
    period = _line_period(time.child("Time_Stamp"), profile)
    att = model_node.child("Attitudes")

    def attitude(epoch: datetime, span: tuple[float, float]) -> tuple[np.ndarray, np.ndarray]:
        if att.find("Quaternion_List") is not None:
            return _quaternion_list(att, epoch)
        poly = att.child("Polynomial_Quaternions")
        return polynomial_quaternions(poly, poly, epoch, first_line, span)

    calib = model_node.child("Geometric_Calibration").child("Instrument_Calibration")
    look, band = _look_angles(calib)
    _biases(calib)
    config = model_node.find("Instrument_Configuration")
    pixel_mm = DEFAULT_PIXEL_MM
    if config is not None and config.find("DETECTOR_SIZE_COL") is not None:
        size = config.number("DETECTOR_SIZE_COL")
        if 0.5 < size < 100:  # micrometres (SPOT 6/7 user guide)
            pixel_mm = size * 1e-3
        elif 1e-7 < size < 1e-4:  # metres, beside a FOCAL_LENGTH in metres (a real Pleiades 1A product)
            pixel_mm = size * 1e3
        else:
            raise config.error(f"{size}: a detector size in micrometres (0.5-100) or metres (1e-7 to 1e-4) expected",
                               "DETECTOR_SIZE_COL")
    model, screening = linescan_model(model_node.child("Ephemeris").child("Point_List"), EPHEMERIS_TAGS, att, attitude, time,
                                      first_line, period, lines, columns, look)
    rpc_name = rpc_component(root)
    rpc_path = path.parent / rpc_name if rpc_name and path.name else None  # only beside a file read from disk
    if rpc_path is not None and not rpc_path.is_file():
        rpc_path = None
    satellite = PROFILES[profile]
    return DimapV2Product(shown, satellite, band or "P", profile, model, look, period, pixel_mm, _corners(root),
                          rpc_name, rpc_path, screening=screening)


def linescan_model(points: Node, tags: tuple[str, str, str], att: Node, attitude, time: Node, first_line: datetime,  # noqa: ANN001
                   period: float, lines: int, columns: int, look: LookAngles) -> tuple[LinescanModel, Screening]:
    """The exact model from a product's ephemeris ``points`` (``Point`` children with ``tags``),
    its attitude (``attitude(epoch, (t_first, t_last))`` -> sample times and quaternions, read from
    ``att``), first-line time and line period, with the checks every Airbus format shares: the
    samples cover the image's lines, no leap second inside, an image of at most MAX_IMAGE_S; and
    the screening of :mod:`solver.sensors.screening` (what it did: the second value)."""
    probe = points.children("Point")
    epoch = min(first_line, parse_utc(probe[0], tags[2])) if probe else first_line
    eph_t, pos, vel, _ = _ephemeris(points, epoch, tags)
    t0 = _seconds(first_line, epoch)
    t_end = t0 + (lines - 1) * period
    if t_end - t0 > MAX_IMAGE_S:
        raise time.error(f"NROWS x LINE_PERIOD is {t_end - t0:.0f} s: an image of {MAX_IMAGE_S:.0f} s at most is read")
    margin = 2.0 * float(np.median(np.diff(eph_t)))  # extrapolation by two sample intervals at most
    if t0 < eph_t[0] - margin or t_end > eph_t[-1] + margin:
        raise points.error(
            f"the samples ({eph_t[0] - t0:+.3f} to {eph_t[-1] - t0:+.3f} s from the first line) do not cover the image's lines "
            f"(0 to {t_end - t0:.3f} s)")
    try:
        leaps = leap_seconds_between(epoch, epoch + timedelta(seconds=float(max(eph_t[-1], t_end))))
    except UnknownLeapSeconds as exc:
        raise time.error(f"{exc}: not read") from None
    if leaps:
        raise time.error(f"the samples span the leap second before {leaps[0].isoformat()}: not read")
    att_t, att_q = attitude(epoch, (t0, t_end))
    margin = 2.0 * float(np.median(np.diff(att_t)))
    if t0 < att_t[0] - margin or t_end > att_t[-1] + margin:
        raise att.error(f"the samples ({att_t[0] - t0:+.3f} to {att_t[-1] - t0:+.3f} s from the first line) do not cover "
                        f"the image's lines (0 to {t_end - t0:.3f} s)")
    model = LinescanModel(
        lines=lines, columns=columns, epoch_utc=epoch.isoformat().replace("+00:00", "Z"),
        tlc_lines=np.array([0.0, 1.0]), tlc_times_s=np.array([t0, t0 + period]),
        ephemeris_times_s=eph_t, positions_ecef_m=pos, velocities_ecef_m_s=vel,
        attitude_times_s=att_t, attitude_wxyz=att_q, look_body=look.body,
        corrections=Corrections(aberration=False, light_time=False, refraction=False),
    )
    return screen_model(model, points, att)


def read_dimap_v2(path: str | Path, shown: str | None = None, data: bytes | None = None) -> DimapV2Product:
    """The exact model of a DIMAP v2 ``DIM_*.XML`` (module docstring); ``data`` as for
    :func:`solver.sensors.maxar.read_maxar`."""
    path = Path(path)
    shown = str(path) if shown is None else shown
    return read_dimap_v2_root(load(path, shown, data), path, shown)


EXTENT_HEIGHTS_M = (-500.0, 9000.0)  # search range of the common height of corners given without one


def extent_check(p: DimapV2Product) -> dict[str, object]:
    """Distances (m) between the product's extent corners and the exact model's ground points at
    the same image positions: at the corners' own heights when given, else at the one height
    (metres, fitted here) that brings them closest; a real product's corners are computed at one
    height, so the distances measure the model's agreement with the vendor's."""
    from solver.geometry.geodesy import geodetic_to_ecef

    c = p.corners
    if c.shape[0] == 0:
        return {"points": 0, "distances_m": [], "height_m": None}

    def distances(h: np.ndarray) -> np.ndarray:
        g = p.model.image_to_ecef(c[:, 0], c[:, 1], h)
        return np.linalg.norm(g - geodetic_to_ecef(np.column_stack([c[:, 2], c[:, 3], h])), axis=1)

    if np.all(np.isfinite(c[:, 4])):
        return {"points": int(c.shape[0]), "distances_m": [float(x) for x in distances(c[:, 4])], "height_m": None}
    lo, hi = EXTENT_HEIGHTS_M
    for _ in range(3):  # coarse to fine grid of the common height
        hs = np.linspace(lo, hi, 41)
        cost = [float(np.sum(distances(np.full(c.shape[0], h)) ** 2)) for h in hs]
        k = int(np.argmin(cost))
        step = hs[1] - hs[0]
        lo, hi = hs[k] - step, hs[k] + step
    h = float(hs[k])
    return {"points": int(c.shape[0]), "distances_m": [float(x) for x in distances(np.full(c.shape[0], h))], "height_m": h}
