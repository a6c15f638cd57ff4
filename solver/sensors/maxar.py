"""Maxar/DigitalGlobe support data (WorldView, QuickBird, GeoEye Basic/Stereo 1B): the single
XML (root ``isd`` with ``IMD``, ``EPH``, ``ATT``, ``GEO`` and ``RPB``) read into the exact
linescan model and the vendor's RPC.

What is read, and the conventions (DigitalGlobe Imagery Support Data documentation, and the
public WorldView-2 files of tests/data/vendor/stereopipeline, whose RPB they reproduce):

- ``IMD/IMAGE``: ``FIRSTLINETIME`` (UTC, ISO 8601 with ``Z``), ``AVGLINERATE`` (lines/s), the
  ``TLCLISTList`` of (line, seconds after ``TLCTIME``) pairs (line times between them are
  linear; one pair: the average rate from it), ``SCANDIRECTION``; ``IMD/NUMROWS``,
  ``IMD/NUMCOLUMNS``. Line 0 is the centre of the first image line.
- ``EPH``: ``STARTTIME`` (UTC), ``TIMEINTERVAL`` (s), ``EPHEMLISTList``: per row the 1-based
  point number, ECEF position (m), ECEF velocity (m/s) and the 6 upper-triangle terms of the
  position covariance (m^2). The time of point k is ``STARTTIME + (k - 1) TIMEINTERVAL``.
- ``ATT``: the same times; ``ATTLISTList`` rows: point number, ``q1 q2 q3 q4`` (scalar last)
  rotating vectors of the spacecraft body frame into ECEF, then 10 covariance terms.
- ``GEO``: ``PRINCIPAL_DISTANCE/PD`` (mm), ``PERSPECTIVE_CENTER`` (``CX CY CZ``, m, camera
  offset in the body frame), ``CAMERA_ATTITUDE`` (``QCS1..QCS4``, scalar last: camera frame to
  body frame), ``DETECTOR_MOUNTING/BAND_x/DETECTOR_ARRAY``: ``DETORIGINX``, ``DETORIGINY`` (mm:
  the first detector, column 0, in the camera frame), ``DETROTANGLE`` (rad: the array's
  rotation from the camera's -y axis) and ``DETPITCH`` (mm). Column C's detector is at
  ``(DETORIGINX + C p sin(rot), DETORIGINY - C p cos(rot))`` in the focal plane and its look
  vector in the camera frame ``(x, y, PD)`` (z towards the ground). ``OPTICAL_DISTORTION`` with
  ``POLYORDER`` > 0 is refused (every 1B product we know has -1, none).
- ``RPB/IMAGE``: the vendor's RPC00B (pixel centres, the RPC's usual convention).

Times: every time of the file is UTC; the model's epoch is the first ephemeris time, and an
interval containing a leap second of the table (:mod:`solver.sensors.timescales`; or the end
of a June or December beyond the table) is refused rather than silently one second off.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from datetime import datetime, timezone
from pathlib import Path
from typing import Any

import numpy as np

from solver.geometry.rpc import RPC
from solver.sensors.linescan import LinescanModel, quaternion_matrices
from solver.sensors.screening import Screening, screen_model
from solver.sensors.timescales import UnknownLeapSeconds, leap_seconds_between
from solver.sensors.xmlsafe import Node, load


@dataclass
class MaxarProduct:
    """One Maxar image's metadata: the exact model, the vendor's RPC and what the job needs."""

    file: str
    satellite: str
    band: str
    model: LinescanModel
    rpc: RPC | None
    pixel_mm: float
    principal_distance_mm: float
    detector_origin_mm: tuple[float, float]
    detector_rotation_rad: float
    camera_to_body_wxyz: np.ndarray
    avg_line_rate_hz: float
    first_line_time_s: float  # seconds from model.epoch_utc
    position_covariance_m2: np.ndarray  # (n, 6) upper triangles per ephemeris point
    attitude_sigma_rad: float | None  # from the quaternion covariance: 2 sqrt(mean variance of q1..q3)
    image_descriptor: str
    screening: Screening = field(default_factory=Screening)
    corners: np.ndarray = field(default_factory=lambda: np.zeros((0, 5)))  # (k, 5) IMD/BAND_x corners: line, column, lon, lat, HAE


def parse_utc(node: Node, tag: str) -> datetime:
    """An ISO 8601 UTC instant (``2013-05-08T00:03:30.536775Z``)."""
    text = node.text(tag)
    try:
        t = datetime.fromisoformat(text.replace("Z", "+00:00"))
    except ValueError:
        raise node.error(f"not an ISO 8601 time: {text[:40]!r}", tag) from None
    if t.tzinfo is None:
        t = t.replace(tzinfo=timezone.utc)
    return t


def _table(node: Node, list_tag: str, row_tag: str, width: int, min_rows: int) -> np.ndarray:
    lst = node.child(list_tag)
    rows = lst.children(row_tag)
    if len(rows) < min_rows:
        raise lst.error(f"{min_rows} <{row_tag}> rows at least, {len(rows)} found")
    out = np.array([r.numbers(None) for r in rows[:1]][0])
    table = np.empty((len(rows), out.size))
    for k, r in enumerate(rows):
        vals = r.numbers(None)
        if len(vals) < width or len(vals) != out.size:
            raise r.error(f"row {k + 1}: {max(width, out.size)} numbers expected, {len(vals)} found")
        table[k] = vals
    return table


def _check_numbering(node: Node, table: np.ndarray, count: int, list_tag: str) -> None:
    if table.shape[0] != count:
        raise node.error(f"NUMPOINTS says {count}, the list has {table.shape[0]} rows", list_tag)
    if not np.allclose(table[:, 0], np.arange(1, count + 1), atol=1e-9):
        raise node.error("point numbers are not 1, 2, 3, ... (duplicated or missing samples)", list_tag)


def read_rpb(rpb: Node) -> RPC:
    """The vendor's RPC00B of an ``RPB`` element (``RPB/IMAGE``)."""
    img = rpb.child("IMAGE")

    def coeffs(tag: str) -> np.ndarray:
        lst = img.child(tag + "List")
        rows = lst.children(tag)
        vals = [v for r in rows for v in r.numbers(None)]
        if len(vals) != 20:
            raise lst.error(f"20 coefficients expected, {len(vals)} found")
        return np.array(vals)

    scale = {t: img.number(t) for t in ("LINESCALE", "SAMPSCALE", "LATSCALE", "LONGSCALE", "HEIGHTSCALE")}
    for t, v in scale.items():
        if v == 0:
            raise img.error("a scale of 0", t)
    err_bias = img.number("ERRBIAS") if img.find("ERRBIAS") is not None else -1.0
    err_rand = img.number("ERRRAND") if img.find("ERRRAND") is not None else -1.0
    return RPC(
        img.number("LINEOFFSET"), img.number("SAMPOFFSET"), img.number("LATOFFSET"), img.number("LONGOFFSET"),
        img.number("HEIGHTOFFSET"), scale["LINESCALE"], scale["SAMPSCALE"], scale["LATSCALE"], scale["LONGSCALE"],
        scale["HEIGHTSCALE"], coeffs("LINENUMCOEF"), coeffs("LINEDENCOEF"), coeffs("SAMPNUMCOEF"), coeffs("SAMPDENCOEF"),
        err_bias, err_rand,
    )


def is_maxar_xml(path: Path) -> bool:
    """Whether a file looks like a Maxar support-data XML (its first kilobytes hold ``<isd>``)."""
    try:
        with path.open("rb") as f:
            head = f.read(4096)
    except OSError:
        return False
    return b"<isd>" in head or b"<isd " in head


def read_maxar_rpc(path: str | Path, shown: str | None = None) -> RPC:
    """The vendor's RPC of a Maxar XML (its ``RPB`` element), without the exact model."""
    path = Path(path)
    root = load(path, str(path) if shown is None else shown)
    if root.element.tag != "isd":
        raise root.error("not a Maxar support-data XML (root element isd expected)")
    root.check_counts()
    return read_rpb(root.child("RPB"))


def read_maxar(path: str | Path, shown: str | None = None, data: bytes | None = None) -> MaxarProduct:
    """The exact model and RPC of a Maxar support-data XML (module docstring); ``data``: the
    file's bytes when they are at hand (an upload), else the file at ``path`` is read."""
    path = Path(path)
    shown = str(path) if shown is None else shown
    root = load(path, shown, data)
    if root.element.tag != "isd":
        raise root.error("not a Maxar support-data XML (root element isd expected)")
    root.check_counts()
    missing = [t for t in ("EPH", "ATT") if root.find(t) is None]
    if missing and root.find("RPB") is not None:  # an ortho-ready or RPC-only product: no sensor model
        raise root.error(f"no {', '.join(missing)}: no ephemeris and attitude, an RPC product (ortho-ready, or support "
                         "data without the sensor model); its RPB goes through pba import-rpc")
    imd, eph, att, geo = (root.child(t) for t in ("IMD", "EPH", "ATT", "GEO"))
    image = imd.child("IMAGE")
    lines, columns = imd.integer("NUMROWS"), imd.integer("NUMCOLUMNS")
    if lines < 1 or columns < 1:
        raise imd.error("NUMROWS and NUMCOLUMNS must be positive")

    epoch = parse_utc(eph, "STARTTIME")
    if parse_utc(att, "STARTTIME") != epoch:
        raise att.error("ATT and EPH start at different times (not supported)", "STARTTIME")

    def seconds(t: datetime) -> float:
        return (t - epoch).total_seconds()

    eph_dt, att_dt = eph.number("TIMEINTERVAL"), att.number("TIMEINTERVAL")
    for node, dt in ((eph, eph_dt), (att, att_dt)):
        if not 0 < dt <= 60:
            raise node.error(f"{dt} s: a sample interval in (0, 60] s expected", "TIMEINTERVAL")
    et = _table(eph, "EPHEMLISTList", "EPHEMLIST", 7, 4)
    _check_numbering(eph, et, eph.integer("NUMPOINTS"), "EPHEMLISTList")
    at = _table(att, "ATTLISTList", "ATTLIST", 5, 2)
    _check_numbering(att, at, att.integer("NUMPOINTS"), "ATTLISTList")
    qn = np.linalg.norm(at[:, 1:5], axis=1)
    if np.any(np.abs(qn - 1.0) > 1e-3):
        k = int(np.argmax(np.abs(qn - 1.0)))
        raise att.error(f"row {k + 1}: quaternion norm {qn[k]:.6f}, a unit quaternion expected", "ATTLISTList")
    r = np.linalg.norm(et[:, 1:4], axis=1)
    if np.any((r < 6.4e6) | (r > 5e7)):
        raise eph.error("positions are not ECEF metres of an orbit (6400 km to 50000 km from the centre)", "EPHEMLISTList")
    eph_t = (et[:, 0] - 1.0) * eph_dt
    att_t = (at[:, 0] - 1.0) * att_dt

    first = parse_utc(image, "FIRSTLINETIME")
    rate = image.number("AVGLINERATE")
    if not 0 < rate < 1e6:
        raise image.error(f"{rate}: a line rate in lines per second expected", "AVGLINERATE")
    if image.find("TLCLISTList") is not None and image.find("TLCTIME") is not None:
        tlc0 = seconds(parse_utc(image, "TLCTIME"))
        tlc = _table(image, "TLCLISTList", "TLCLIST", 2, 1)[:, :2]
        if np.any(np.diff(tlc[:, 0]) <= 0) or np.any(np.diff(tlc[:, 1]) == 0):
            raise image.error("lines must increase and times differ", "TLCLISTList")
        tlc_lines, tlc_times = tlc[:, 0], tlc[:, 1] + tlc0
    else:
        tlc_lines, tlc_times = np.array([0.0]), np.array([seconds(first)])
    if tlc_lines.size == 1:
        direction = -1.0 if image.find("SCANDIRECTION") is not None and image.text("SCANDIRECTION").lower() != "forward" else 1.0
        tlc_lines = np.append(tlc_lines, tlc_lines[0] + rate)
        tlc_times = np.append(tlc_times, tlc_times[0] + direction)
    last = epoch.timestamp() + max(eph_t[-1], att_t[-1])
    try:
        leaps = leap_seconds_between(epoch, datetime.fromtimestamp(last, timezone.utc))
    except UnknownLeapSeconds as exc:
        raise eph.error(f"{exc}: not supported", "STARTTIME") from None
    if leaps:
        raise eph.error(f"the samples span the leap second before {leaps[0].isoformat()}: not supported", "STARTTIME")
    t_first, t_last = tlc_times[0], tlc_times[0] + (lines - 1 - tlc_lines[0]) * (tlc_times[-1] - tlc_times[0]) / (tlc_lines[-1] - tlc_lines[0])
    for node, t in ((eph, eph_t), (att, att_t)):
        if min(t_first, t_last) < t[0] or max(t_first, t_last) > t[-1]:
            raise node.error("the samples do not cover the image's line times", "STARTTIME")

    pd = geo.child("PRINCIPAL_DISTANCE").number("PD")
    distortion = geo.find("OPTICAL_DISTORTION")
    if distortion is not None and distortion.find("POLYORDER") is not None and distortion.number("POLYORDER") > 0:
        raise distortion.error("optical distortion polynomials are not supported", "POLYORDER")
    pc = geo.find("PERSPECTIVE_CENTER")
    offset = np.array([pc.number(t) for t in ("CX", "CY", "CZ")]) if pc is not None else np.zeros(3)
    ca = geo.child("CAMERA_ATTITUDE")
    qcs = np.array([ca.number(t) for t in ("QCS4", "QCS1", "QCS2", "QCS3")])  # scalar first
    if abs(np.linalg.norm(qcs) - 1.0) > 1e-3:
        raise ca.error("QCS1..QCS4 is not a unit quaternion")
    mounting = geo.child("DETECTOR_MOUNTING")
    bands = [c for c in mounting.element if c.tag.startswith("BAND_")]
    if not bands:
        raise mounting.error("missing", "BAND_P")
    band_node = mounting.child(bands[0].tag)
    arrays = band_node.children("DETECTOR_ARRAY")
    if len(arrays) != 1:
        raise band_node.error(f"one DETECTOR_ARRAY expected, {len(arrays)} found")
    det = arrays[0]
    ox, oy = det.number("DETORIGINX"), det.number("DETORIGINY")
    rot = det.number("DETROTANGLE")
    pitch = det.number("DETPITCH")
    if not 0 < pitch < 1 or not 10 < pd < 1e6:
        raise det.error(f"pitch {pitch} mm and principal distance {pd} mm are not a camera's")
    cam_to_body = quaternion_matrices(qcs[None, :])[0]

    def look_body(column: np.ndarray) -> np.ndarray:
        c = np.asarray(column, float)
        v = np.column_stack([ox + c * pitch * np.sin(rot), oy - c * pitch * np.cos(rot), np.full(c.shape, pd)])
        return v @ cam_to_body.T

    model = LinescanModel(
        lines=lines, columns=columns, epoch_utc=epoch.isoformat().replace("+00:00", "Z"),
        tlc_lines=tlc_lines, tlc_times_s=tlc_times,
        ephemeris_times_s=eph_t, positions_ecef_m=et[:, 1:4], velocities_ecef_m_s=et[:, 4:7],
        attitude_times_s=att_t, attitude_wxyz=np.column_stack([at[:, 4], at[:, 1:4]]),
        look_body=look_body, camera_offset_body_m=offset,
    )
    model, screening = screen_model(model, eph.child("EPHEMLISTList"), att.child("ATTLISTList"))
    rpb = root.find("RPB")
    return MaxarProduct(
        file=shown, satellite=image.text("SATID") if image.find("SATID") is not None else "",
        band=bands[0].tag[5:], model=model, rpc=read_rpb(rpb) if rpb is not None else None,
        pixel_mm=pitch, principal_distance_mm=pd, detector_origin_mm=(ox, oy), detector_rotation_rad=rot,
        camera_to_body_wxyz=qcs, avg_line_rate_hz=rate, first_line_time_s=seconds(first),
        position_covariance_m2=et[:, 7:13] if et.shape[1] >= 13 else np.zeros((et.shape[0], 0)),
        attitude_sigma_rad=_attitude_sigma(at),
        image_descriptor=imd.text("IMAGEDESCRIPTOR") if imd.find("IMAGEDESCRIPTOR") is not None else "",
        screening=screening, corners=_band_corners(imd, lines, columns),
    )


CORNER_TAGS = (("UL", 0.0, 0.0), ("UR", 0.0, 1.0), ("LR", 1.0, 1.0), ("LL", 1.0, 0.0))


def _band_corners(imd: Node, lines: int, columns: int) -> np.ndarray:
    """(k, 5) the corners of the first ``IMD/BAND_x`` block: ``ULLON``, ``ULLAT``, ``ULHAE`` ...
    ``LLHAE`` (degrees, metres above the ellipsoid) at the image's first and last lines and
    columns (pixel centres), as line, column, lon, lat, h; none when the block lacks them."""
    bands = [c for c in imd.element if c.tag.startswith("BAND_")]
    if not bands:
        return np.zeros((0, 5))
    band = imd.child(bands[0].tag)
    rows = []
    for tag, fl, fc in CORNER_TAGS:
        if all(band.find(f"{tag}{k}") is not None for k in ("LON", "LAT", "HAE")):
            rows.append([fl * (lines - 1), fc * (columns - 1), band.number(f"{tag}LON"), band.number(f"{tag}LAT"),
                         band.number(f"{tag}HAE")])
    return np.array(rows).reshape(-1, 5)


def _attitude_sigma(at: np.ndarray) -> float | None:
    """2 sqrt(mean variance of q1, q2, q3) (small-angle sigma, rad) from the 10 upper-triangle
    covariance terms of each ATT row (q1q1 q1q2 q1q3 q1q4 q2q2 q2q3 q2q4 q3q3 q3q4 q4q4)."""
    if at.shape[1] < 15:
        return None
    var = at[:, [5, 9, 12]]
    if np.any(var < 0):
        return None
    return float(2.0 * np.sqrt(np.mean(var)))


def summary(p: MaxarProduct) -> dict[str, Any]:
    """A few facts of the product, for messages."""
    return {"satellite": p.satellite, "band": p.band, "lines": p.model.lines, "columns": p.model.columns,
            "first_line_utc": p.model.epoch_utc, "line_rate_hz": p.avg_line_rate_hz}
