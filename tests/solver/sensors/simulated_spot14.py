"""Simulated SPOT 1-4 DIMAP v1 scenes (``METADATA.DIM``) with known truth, for the reader's tests.
The public SPOT 1-4 files we found carry a non-commercial licence (docs/sensor-metadata.md gives
the numbers measured on them), so the tests use scenes written here in their format, from an
independent physical scene that has what those files showed:

- orbit: a circle of radius ``a + 822 km`` at 98.7 degrees inclination in the inertial frame,
  turned into ECEF by the Earth's rotation (closed form); the file's ``Velocity`` is the
  *inertial* velocity in Earth-fixed axes (``v_ecef + omega x P``), 60 s apart, as the real
  files (their positions and velocities agree only that way);
- attitude: the local orbital frame of the SPOT geometry handbook (``Z2 = P / |P|``,
  ``X2 = V x Z2`` normalised with the file's velocity, ``Y2 = Z2 x X2``) turned by yaw, pitch
  and roll (handbook eq. 11) that oscillate slowly; the file gives their gyro speeds at 8 Hz
  and the first absolute angles (``Aocs_Attitude``), as the real files;
- look angles: the first and last detector's ``PSI_X``, ``PSI_Y``; the truth's angles are
  linear in the detector between them (a mirror turned by ``mirror_rad`` across track);
- truth: the detector's direction ``(-tan PSI_Y, tan PSI_X, -1)`` in the navigation frame,
  from the orbit position at the line's time, intersected with the geodetic height by pyproj
  (not our geodesy), without corrections (the vendor's location model has none); the four
  corner tie points and the ``Scene_Center`` are located at height 0 *without the attitude*
  (the orbital frame alone), as the real files' are (their corners and centres meet the exact
  model with zero angles to 0.4-2.7 m, with the measured angles 1.5-24 m away).

Only the format's conventions are shared with the reader; no code of :mod:`solver.sensors` is
used here.
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
START = datetime(1998, 7, 12, 9, 15, 3, 250000, tzinfo=timezone.utc)  # the first line's time
TO_GEODETIC = Transformer.from_crs("EPSG:4978", "EPSG:4979", always_xy=True)


@dataclass
class Spot14Scene:
    """The simulated scene's truth (module docstring); times in seconds after START."""

    lines: int = 6000
    columns: int = 6000
    period_s: float = 1.504e-3
    mirror_rad: float = np.radians(28.0)  # the middle detector's across-track angle
    half_field_rad: float = np.radians(2.07)  # first and last detector about the middle
    psi_x: tuple[float, float] = (1.0142e-2, 1.0527e-2)  # along track, first and last detector
    node_rad: float = np.radians(200.0)
    anomaly_rad: float = np.radians(140.0)  # descending over the northern hemisphere
    pitch_amplitude_rad: float = 6e-6  # the pitch's oscillation (the SPOT 3 scene of 1994-08-09: 1e-5 over 4.5 s)
    pitch_period_s: float = 7.0

    def state(self, t: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """ECEF position (m) and Earth-fixed velocity (m/s) (n, 3)."""
        t = np.atleast_1d(np.asarray(t, float))
        r = A + 822e3
        n = np.sqrt(MU / r**3)
        u = self.anomaly_rad + n * t
        orbit = Rotation.from_euler("ZX", [self.node_rad, np.radians(98.7)]).as_matrix()
        p_in = (orbit @ np.stack([r * np.cos(u), r * np.sin(u), 0 * u]).T[..., None])[..., 0]
        v_in = (orbit @ np.stack([-r * n * np.sin(u), r * n * np.cos(u), 0 * u]).T[..., None])[..., 0]
        earth = Rotation.from_euler("z", -OMEGA_E * t[:, None]).as_matrix()
        p = np.einsum("nij,nj->ni", earth, p_in)
        return p, np.einsum("nij,nj->ni", earth, v_in) - np.cross([0.0, 0.0, OMEGA_E], p)

    def inertial_velocity(self, t: np.ndarray) -> np.ndarray:
        """What the file's ``Velocity`` holds: ``v_ecef + omega x P``."""
        p, v = self.state(t)
        return v + np.cross([0.0, 0.0, OMEGA_E], p)

    def angles(self, t: np.ndarray) -> np.ndarray:
        """(n, 3) yaw, pitch, roll (rad): slow oscillations, as gyros see."""
        t = np.atleast_1d(np.asarray(t, float))
        a, w1 = self.pitch_amplitude_rad, 2 * np.pi / self.pitch_period_s
        return np.column_stack([2e-5 + 1e-6 * t, a * np.cos(w1 * t), -1e-5 + 4e-6 * np.sin(2 * np.pi * t / 11.0)])

    def rates(self, t: np.ndarray) -> np.ndarray:
        t = np.atleast_1d(np.asarray(t, float))
        a, w1, w2 = self.pitch_amplitude_rad, 2 * np.pi / self.pitch_period_s, 2 * np.pi / 11.0
        return np.column_stack([np.full(t.shape, 1e-6), -a * w1 * np.sin(w1 * t), 4e-6 * w2 * np.cos(w2 * t)])

    def psi_y(self) -> tuple[float, float]:
        return float(self.mirror_rad - self.half_field_rad), float(self.mirror_rad + self.half_field_rad)

    def look(self, col: np.ndarray) -> np.ndarray:
        """(n, 3) directions in the navigation frame: angles linear in the detector."""
        u = np.asarray(col, float) / (self.columns - 1)
        y0, y1 = self.psi_y()
        x0, x1 = self.psi_x
        py, px = y0 + u * (y1 - y0), x0 + u * (x1 - x0)
        return np.column_stack([-np.tan(py), np.tan(px), -np.ones_like(py)])

    def navigation_to_ecef(self, t: np.ndarray, attitude: bool = True) -> np.ndarray:
        """(n, 3, 3): the handbook's orbital frame (columns X2, Y2, Z2, from the file's velocity)
        times its eq. 11 matrix of yaw, pitch, roll (the identity without ``attitude``)."""
        p, _ = self.state(t)
        v = self.inertial_velocity(t)
        z = p / np.linalg.norm(p, axis=1, keepdims=True)
        x = np.cross(v, z)
        x /= np.linalg.norm(x, axis=1, keepdims=True)
        orbital = np.stack([x, np.cross(z, x), z], axis=2)
        y, pch, r = (self.angles(t) if attitude else 0.0 * self.angles(t)).T
        cp, sp, cr, sr, cy, sy = np.cos(pch), np.sin(pch), np.cos(r), np.sin(r), np.cos(y), np.sin(y)
        m = np.stack([np.stack([cr * cy, -cr * sy, -sr], -1),
                      np.stack([cp * sy + sp * sr * cy, cp * cy - sp * sr * sy, sp * cr], -1),
                      np.stack([-sp * sy + cp * sr * cy, -sp * cy - cp * sr * sy, cp * cr], -1)], -2)
        return orbital @ m

    def ground(self, line: np.ndarray, col: np.ndarray, h: np.ndarray, attitude: bool = True) -> np.ndarray:
        """ECEF (n, 3) of image positions (0-based) at geodetic heights ``h``: the truth (without
        ``attitude``: the vendor's systematic location of its tie points)."""
        line, col, h = np.broadcast_arrays(*(np.atleast_1d(np.asarray(a, float)) for a in (line, col, h)))
        t = line * self.period_s
        s, _ = self.state(t)
        d = np.einsum("nij,nj->ni", self.navigation_to_ecef(t, attitude), self.look(col))
        d /= np.linalg.norm(d, axis=1, keepdims=True)

        def height(dist: np.ndarray) -> np.ndarray:
            q = s + dist[:, None] * d
            return np.array(TO_GEODETIC.transform(q[:, 0], q[:, 1], q[:, 2]))[2] - h

        lo, hi = np.full(h.shape, 700e3), np.full(h.shape, 1200e3)
        for _ in range(60):  # bisection to well below a millimetre
            mid = 0.5 * (lo + hi)
            above = height(mid) > 0
            lo, hi = np.where(above, mid, lo), np.where(above, hi, mid)
        return s + (0.5 * (lo + hi))[:, None] * d

    def geodetic(self, ecef: np.ndarray) -> np.ndarray:
        return np.column_stack(TO_GEODETIC.transform(ecef[:, 0], ecef[:, 1], ecef[:, 2]))


def _utc(t: float) -> str:
    return (START + timedelta(seconds=float(t))).strftime("%Y-%m-%dT%H:%M:%S.%f")


def _angles_rows(tag: str, t: np.ndarray, v: np.ndarray) -> str:
    return "".join(f"<{tag}><TIME>{_utc(x)}</TIME><YAW>{a[0]!r}</YAW><PITCH>{a[1]!r}</PITCH><ROLL>{a[2]!r}</ROLL>"
                   f"<OUT_OF_RANGE>N</OUT_OF_RANGE></{tag}>" for x, a in zip(t, v.tolist()))


def metadata_dim(scene: Spot14Scene, mission: int = 2) -> str:
    """The METADATA.DIM text of the scene (module docstring)."""
    centre_line = scene.lines // 2  # 1-based SCENE_CENTER_LINE: line centre_line - 1 (0-based)
    t_centre = (centre_line - 1) * scene.period_s
    eph_t = np.arange(-180.0, 241.0, 60.0) - 3.25  # on whole minutes of UTC, as the real files
    p = scene.state(eph_t)[0]
    v = scene.inertial_velocity(eph_t)
    points = "".join(
        f"<Point><TIME>{_utc(t)}</TIME><Location><X>{a[0]!r}</X><Y>{a[1]!r}</Y><Z>{a[2]!r}</Z></Location>"
        f"<Velocity><X>{b[0]!r}</X><Y>{b[1]!r}</Y><Z>{b[2]!r}</Z></Velocity></Point>"
        for t, a, b in zip(eph_t, p.tolist(), v.tolist()))
    t_speed = np.arange(0.0, scene.lines * scene.period_s + 0.2, 0.126) - 0.09
    first = np.array([t_speed[0] - 0.124])
    attitude = (f"<Aocs_Attitude><Angles_List>{_angles_rows('Angles', first, scene.angles(first))}</Angles_List>"
                f"<Angular_Speeds_List>{_angles_rows('Angular_Speeds', t_speed, scene.rates(t_speed))}</Angular_Speeds_List></Aocs_Attitude>")
    y0, y1 = scene.psi_y()
    looks = (f"<Look_Angles><DETECTOR_ID>1</DETECTOR_ID><PSI_X>{scene.psi_x[0]!r}</PSI_X><PSI_Y>{y0!r}</PSI_Y></Look_Angles>"
             f"<Look_Angles><DETECTOR_ID>{scene.columns}</DETECTOR_ID><PSI_X>{scene.psi_x[1]!r}</PSI_X><PSI_Y>{y1!r}</PSI_Y></Look_Angles>")
    rows = np.array([0, 0, scene.lines - 1, scene.lines - 1], float)
    cols = np.array([0, scene.columns - 1, scene.columns - 1, 0], float)
    g = scene.geodetic(scene.ground(rows, cols, np.zeros(4), attitude=False))
    c = scene.geodetic(scene.ground(np.array([centre_line - 1.0]), np.array([scene.columns / 2 - 1.0]), np.zeros(1),
                                    attitude=False))[0].tolist()
    vertices = "".join(f"<Vertex><FRAME_LON>{x[0]!r}</FRAME_LON><FRAME_LAT>{x[1]!r}</FRAME_LAT><FRAME_ROW>{int(r) + 1}</FRAME_ROW>"
                       f"<FRAME_COL>{int(k) + 1}</FRAME_COL></Vertex>" for x, r, k in zip(g.tolist(), rows, cols))
    ties = "".join(f"<Tie_Point><TIE_POINT_CRS_X>{x[0]!r}</TIE_POINT_CRS_X><TIE_POINT_CRS_Y>{x[1]!r}</TIE_POINT_CRS_Y>"
                   f"<TIE_POINT_CRS_Z>0.0</TIE_POINT_CRS_Z><TIE_POINT_DATA_X>{k + 1}</TIE_POINT_DATA_X>"
                   f"<TIE_POINT_DATA_Y>{r + 1}</TIE_POINT_DATA_Y></Tie_Point>" for x, r, k in zip(g.tolist(), rows, cols))
    return f"""<?xml version="1.0"?>
<Dimap_Document name="METADATA.DIM">
  <Metadata_Id><METADATA_FORMAT version="1.1">DIMAP</METADATA_FORMAT><METADATA_PROFILE>SPOTSCENE_1A</METADATA_PROFILE></Metadata_Id>
  <Dataset_Frame>{vertices}<Scene_Center><FRAME_LON>{c[0]!r}</FRAME_LON><FRAME_LAT>{c[1]!r}</FRAME_LAT>
    <FRAME_ROW>{centre_line}</FRAME_ROW><FRAME_COL>{scene.columns // 2}</FRAME_COL></Scene_Center></Dataset_Frame>
  <Geoposition><Geoposition_Points>{ties}</Geoposition_Points></Geoposition>
  <Dataset_Sources><Source_Information><Scene_Source><MISSION>SPOT</MISSION><MISSION_INDEX>{mission}</MISSION_INDEX>
    <INSTRUMENT>HRV</INSTRUMENT><INCIDENCE_ANGLE>{float(np.degrees(scene.mirror_rad))!r}</INCIDENCE_ANGLE></Scene_Source></Source_Information></Dataset_Sources>
  <Raster_Dimensions><NCOLS>{scene.columns}</NCOLS><NROWS>{scene.lines}</NROWS><NBANDS>1</NBANDS></Raster_Dimensions>
  <Data_Strip>
    <Ephemeris><Points>{points}</Points><DORIS_USED>N</DORIS_USED></Ephemeris>
    <Satellite_Attitudes><Raw_Attitudes>{attitude}</Raw_Attitudes></Satellite_Attitudes>
    <Sensor_Configuration>
      <Time_Stamp><LINE_PERIOD>{scene.period_s!r}</LINE_PERIOD><SCENE_CENTER_TIME>{_utc(t_centre)}</SCENE_CENTER_TIME>
        <SCENE_CENTER_LINE>{centre_line}</SCENE_CENTER_LINE><SCENE_CENTER_COL>{scene.columns // 2}</SCENE_CENTER_COL></Time_Stamp>
      <Instrument_Look_Angles_List><Instrument_Look_Angles><BAND_INDEX>1</BAND_INDEX>
        <Look_Angles_List>{looks}</Look_Angles_List></Instrument_Look_Angles></Instrument_Look_Angles_List>
    </Sensor_Configuration>
  </Data_Strip>
</Dimap_Document>
"""
