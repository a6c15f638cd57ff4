"""Simulated DIMAP v2 sensor products with known truth, for the reader's tests. No public DIMAP v2
product under a licence we may commit carries the full geometric model (docs/sensor-metadata.md
says where we searched), so the reader is tested on products written here in the format of a
real SPOT 6 product, from an independent physical scene:

- orbit: a circle of radius ``a + 694 km`` at 98.2 degrees inclination in the inertial frame,
  turned into ECEF by the Earth's rotation (positions and velocities in closed form);
- attitude: the orbital frame (x along the velocity, z to the Earth's centre) turned by a roll
  that grows linearly in time and constant pitch and yaw (scipy's Rotation for the quaternions);
- look angles: polynomials ``XLOS``, ``YLOS`` in the column (with a swath's first column);
- truth: the ray ``M(t) (YLOS, -XLOS, 1)`` from the orbit position at the line's time,
  intersected with the geodetic height by pyproj (not our geodesy), without corrections (the
  vendor's refined model has none).

Only the format's conventions are shared with the reader (they are checked on the real SPOT 6
product); no code of :mod:`solver.sensors` is used here.
"""

from __future__ import annotations

from dataclasses import dataclass
from datetime import datetime, timedelta, timezone

import numpy as np
from pyproj import Transformer
from scipy.spatial.transform import Rotation

A = 6378137.0
MU = 3.986004418e14
OMEGA_E = 7.2921151467e-5
START = datetime(2021, 5, 3, 10, 21, 7, 123456, tzinfo=timezone.utc)
TO_GEODETIC = Transformer.from_crs("EPSG:4978", "EPSG:4979", always_xy=True)
TO_ECEF = Transformer.from_crs("EPSG:4979", "EPSG:4978", always_xy=True)


@dataclass
class Scene:
    """The simulated product's truth (module docstring)."""

    lines: int = 3000
    columns: int = 2500
    period_s: float = 1.5e-4
    first_col: int = 5  # the swath's first column (1-based): the polynomials' column is col + 4
    xlos: tuple[float, ...] = (-1.26e-3, 1.0e-6, 3.0e-13)  # across track, tangents
    ylos: tuple[float, ...] = (2.5e-3, 2.0e-9)  # along track
    roll0_rad: float = np.radians(6.0)
    roll_rate_rad_s: float = np.radians(0.15)
    pitch_rad: float = np.radians(-4.0)
    yaw_rad: float = np.radians(1.5)
    node_rad: float = np.radians(20.0)  # right ascension of the ascending node at START
    anomaly_rad: float = np.radians(50.0)  # argument of latitude at START

    def radius(self) -> float:
        return A + 694e3

    def state(self, t: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """ECEF position (m) and velocity (m/s) (n, 3) at seconds ``t`` after START."""
        t = np.atleast_1d(np.asarray(t, float))
        r = self.radius()
        n = np.sqrt(MU / r**3)
        u = self.anomaly_rad + n * t
        inc = np.radians(98.2)
        orbit = Rotation.from_euler("ZX", [self.node_rad, inc]).as_matrix()
        p_in = (orbit @ np.stack([r * np.cos(u), r * np.sin(u), 0 * u]).T[..., None])[..., 0]
        v_in = (orbit @ np.stack([-r * n * np.sin(u), r * n * np.cos(u), 0 * u]).T[..., None])[..., 0]
        earth = Rotation.from_euler("z", -OMEGA_E * t[:, None]).as_matrix()
        p = np.einsum("nij,nj->ni", earth, p_in)
        v = np.einsum("nij,nj->ni", earth, v_in) - np.cross([0.0, 0.0, OMEGA_E], p)
        return p, v

    def attitude(self, t: np.ndarray) -> np.ndarray:
        """(n, 3, 3) satellite frame to ECEF."""
        p, v = self.state(t)
        z = -p / np.linalg.norm(p, axis=1, keepdims=True)
        x = v - np.sum(v * z, axis=1, keepdims=True) * z
        x /= np.linalg.norm(x, axis=1, keepdims=True)
        y = np.cross(z, x)
        orbital = np.stack([x, y, z], axis=2)
        t = np.atleast_1d(np.asarray(t, float))
        turn = Rotation.from_euler("xyz", np.column_stack([self.roll0_rad + self.roll_rate_rad_s * t,
                                                           np.full(t.shape, self.pitch_rad), np.full(t.shape, self.yaw_rad)]))
        return orbital @ turn.as_matrix()

    def quaternions(self, t: np.ndarray) -> np.ndarray:
        """(n, 4) scalar-first quaternions of :meth:`attitude`, continuous in sign."""
        q = Rotation.from_matrix(self.attitude(t)).as_quat()[:, [3, 0, 1, 2]]
        for k in range(1, q.shape[0]):
            if np.dot(q[k], q[k - 1]) < 0:
                q[k] = -q[k]
        return q

    def look(self, col: np.ndarray) -> np.ndarray:
        c = np.asarray(col, float) + self.first_col - 1
        x = np.polynomial.polynomial.polyval(c, self.xlos)
        y = np.polynomial.polynomial.polyval(c, self.ylos)
        return np.column_stack([y, -x, np.ones_like(x)])

    def ground(self, line: np.ndarray, col: np.ndarray, h: np.ndarray, attitude=None) -> np.ndarray:
        """ECEF (n, 3) of image positions (0-based) at geodetic heights ``h``: the truth."""
        line, col, h = np.broadcast_arrays(np.atleast_1d(np.asarray(line, float)), np.atleast_1d(np.asarray(col, float)),
                                           np.atleast_1d(np.asarray(h, float)))
        t = line * self.period_s
        s, _ = self.state(t)
        m = self.attitude(t) if attitude is None else attitude(t)
        d = np.einsum("nij,nj->ni", m, self.look(col))
        d /= np.linalg.norm(d, axis=1, keepdims=True)

        def height(dist: np.ndarray) -> np.ndarray:
            q = s + dist[:, None] * d
            return np.array(TO_GEODETIC.transform(q[:, 0], q[:, 1], q[:, 2]))[2] - h

        lo = np.full(h.shape, 600e3)
        hi = np.full(h.shape, 900e3)
        for _ in range(60):  # bisection to well below a millimetre
            mid = 0.5 * (lo + hi)
            above = height(mid) > 0
            lo = np.where(above, mid, lo)
            hi = np.where(above, hi, mid)
        return s + (0.5 * (lo + hi))[:, None] * d

    def geodetic(self, ecef: np.ndarray) -> np.ndarray:
        return np.column_stack(TO_GEODETIC.transform(ecef[:, 0], ecef[:, 1], ecef[:, 2]))


def _utc(t: float) -> str:
    return (START + timedelta(seconds=float(t))).strftime("%Y-%m-%dT%H:%M:%S.%fZ")


def polynomial_attitude(scene: Scene, offset_s: float, scale_s: float) -> tuple[np.ndarray, object]:
    """Pleiades 1A/1B: cubic polynomials fitted to the scene's quaternions over its lines (and
    the attitude they define, the truth of a polynomial product)."""
    t_end = scene.lines * scene.period_s
    t = np.linspace(-1.0, t_end + 1.0, 200)
    midnight = START.replace(hour=0, minute=0, second=0, microsecond=0)
    since = (START - midnight).total_seconds()
    u = (t + since - offset_s) / scale_s
    coeffs = np.array([np.polynomial.polynomial.polyfit(u, scene.quaternions(t)[:, k], 3) for k in range(4)])

    def attitude(tt: np.ndarray) -> np.ndarray:
        uu = (np.atleast_1d(tt) + since - offset_s) / scale_s
        q = np.column_stack([np.polynomial.polynomial.polyval(uu, c) for c in coeffs])
        q /= np.linalg.norm(q, axis=1, keepdims=True)
        return Rotation.from_quat(q[:, [1, 2, 3, 0]]).as_matrix()

    return coeffs, attitude


def dimap_v2_xml(scene: Scene, profile: str = "S6_SENSOR", attitude: str = "list", rpc_name: str | None = None,
                 corners_h: float | None = None, quaternion_step_s: float = 0.03125) -> tuple[str, object]:
    """The DIM_*.XML text of a simulated product and the truth attitude it carries (None: the
    scene's own). ``attitude`` "list" (SPOT 6/7, Neo: Quaternion_List, every
    ``quaternion_step_s``) or "polynomial" (Pleiades 1A/1B); LINE_PERIOD in microseconds, or in
    ms for ``PHR_SENSOR``."""
    t_end = (scene.lines - 1) * scene.period_s
    eph_t = np.arange(-4.0, t_end + 4.0, 0.5)
    p, v = scene.state(eph_t)
    points = "".join(
        f"<Point><LOCATION_XYZ unit=\"m\">{float(a[0])!r} {float(a[1])!r} {float(a[2])!r}</LOCATION_XYZ>"
        f"<VELOCITY_XYZ unit=\"m/s\">{float(b[0])!r} {float(b[1])!r} {float(b[2])!r}</VELOCITY_XYZ><TIME>{_utc(t)}</TIME></Point>"
        for t, a, b in zip(eph_t, p, v))
    truth = None
    if attitude == "list":
        qt = np.arange(-0.2, t_end + 0.2 + quaternion_step_s, quaternion_step_s)
        q = scene.quaternions(qt)
        att = "<Quaternion_List>" + "".join(
            f"<Quaternion><Q_STATUS>NOMINAL</Q_STATUS><Q0>{float(a[0])!r}</Q0><Q1>{float(a[1])!r}</Q1><Q2>{float(a[2])!r}</Q2><Q3>{float(a[3])!r}</Q3>"
            f"<TIME>{_utc(t)}</TIME></Quaternion>" for t, a in zip(qt, q)) + "</Quaternion_List>"
    else:
        midnight = START.replace(hour=0, minute=0, second=0, microsecond=0)
        offset = (START - midnight).total_seconds() + 0.37
        coeffs, truth = polynomial_attitude(scene, offset, 4.0)
        att = (f"<Polynomial_Quaternions><OFFSET>{offset!r}</OFFSET><SCALE>4.0</SCALE>"
               + "".join(f"<Q{k}><DEGREE>3</DEGREE><COEFFICIENTS>{' '.join(repr(float(c)) for c in coeffs[k])}</COEFFICIENTS></Q{k}>"
                         for k in range(4)) + "</Polynomial_Quaternions>")
    looks = "".join(f"<XLOS_{k}>{c!r}</XLOS_{k}>" for k, c in enumerate(scene.xlos)) + \
        "".join(f"<YLOS_{k}>{c!r}</YLOS_{k}>" for k, c in enumerate(scene.ylos))
    swath = f"<Swath_Range><FIRST_COL>{scene.first_col}</FIRST_COL><LAST_COL>{scene.first_col + scene.columns - 1}</LAST_COL></Swath_Range>"
    if profile == "PHR_SENSOR":
        period = f"<LINE_PERIOD unit=\"ms\">{scene.period_s * 1e3!r}</LINE_PERIOD>"
        calib = f"{swath}<Polynomial_Look_Angles>{looks}</Polynomial_Look_Angles>"
    else:
        period = f"<LINE_PERIOD unit=\"microsecond\">{scene.period_s * 1e6!r}</LINE_PERIOD>"
        calib = (f"<Band_Calibration_List><Band_Calibration><BAND_ID>P</BAND_ID>{swath}"
                 f"<Polynomial_Look_Angles>{looks}</Polynomial_Look_Angles></Band_Calibration></Band_Calibration_List>")
    corners = ""
    if corners_h is not None:
        rows, cols = [0, 0, scene.lines - 1, scene.lines - 1], [0, scene.columns - 1, scene.columns - 1, 0]
        g = scene.geodetic(scene.ground(np.array(rows, float), np.array(cols, float), np.full(4, corners_h), truth))
        corners = "<Dataset_Extent>" + "".join(
            f"<Vertex><LON>{float(x[0])!r}</LON><LAT>{float(x[1])!r}</LAT><COL>{c + 1}</COL><ROW>{r + 1}</ROW></Vertex>"
            for x, r, c in zip(g, rows, cols)) + "</Dataset_Extent>"
    rpc = (f"<Dataset_Components><Component><COMPONENT_TITLE>RPC Model</COMPONENT_TITLE><COMPONENT_PATH href=\"{rpc_name}\"/>"
           "</Component></Dataset_Components>") if rpc_name else ""
    text = f"""<?xml version="1.0" encoding="UTF-8"?>
<Dimap_Document>
  <Metadata_Identification><METADATA_FORMAT version="2.12">DIMAP</METADATA_FORMAT><METADATA_PROFILE>{profile}</METADATA_PROFILE></Metadata_Identification>
  <Dataset_Content>{rpc}{corners}</Dataset_Content>
  <Raster_Data><Raster_Dimensions><NROWS>{scene.lines}</NROWS><NCOLS>{scene.columns}</NCOLS><NBANDS>1</NBANDS></Raster_Dimensions></Raster_Data>
  <Geometric_Data><Refined_Model>
    <Time><Time_Range><START>{_utc(0.0)}</START><END>{_utc(t_end)}</END></Time_Range><Time_Stamp>{period}</Time_Stamp></Time>
    <Ephemeris><EPHEMERIS_USED>CORRECTED</EPHEMERIS_USED><Point_List>{points}</Point_List></Ephemeris>
    <Attitudes><ATTITUDES_USED>CORRECTED</ATTITUDES_USED>{att}</Attitudes>
    <Instrument_Configuration><FOCAL_LENGTH>3.76</FOCAL_LENGTH><DETECTOR_SIZE_COL>6.5</DETECTOR_SIZE_COL></Instrument_Configuration>
    <Geometric_Calibration><Instrument_Calibration>{calib}<Instrument_Biases><YAW>0.0</YAW><PITCH>0.0</PITCH><ROLL>0.0</ROLL></Instrument_Biases></Instrument_Calibration></Geometric_Calibration>
  </Refined_Model></Geometric_Data>
</Dimap_Document>
"""
    return text, truth
