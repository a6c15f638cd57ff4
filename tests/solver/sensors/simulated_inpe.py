"""A simulated INPE product record (root ``prdf``, one camera, as the CBERS-4 MUX records of
tests/data/vendor) from a known line-time law, for the tests of the reader's time stamps:

- orbit: the circular orbit of :class:`simulated_spot14.Spot14Scene` (closed form), its
  Earth-fixed states written 1 s apart, as the records' GPS states;
- line times: line L (0-based, raw) is imaged at ``T0 + L * period``; the record's ``timeStamp``
  ``begin`` and ``end`` lag the corners' first and last lines by 8 lines inwards (16 lines closer
  together, as every real record with an ``integrationTime`` shows: docs/sensor-metadata.md);
- camera: the orbital frame of the inertial velocity (x along it without its radial part, z up)
  turned by a known roll, pitch and yaw, column C looking along ``(0, (C - c0) ifov, -1)``;
- corners UL, UR, LR, LL: the truth's rays met with the ellipsoid by pyproj (not our geodesy).

No code of :mod:`solver.sensors` is used here.
"""

from __future__ import annotations

from dataclasses import dataclass
from datetime import timedelta

import numpy as np
from scipy.spatial.transform import Rotation
from simulated_spot14 import OMEGA_E, START, TO_GEODETIC, Spot14Scene

NAMESPACE = "http://www.gisplan.com.br/xmlsat"


@dataclass
class InpeScene:
    orbit: Spot14Scene
    lines: int = 7000  # raw lines of the corners: first line 8, last line lines - 1
    columns: int = 6000
    period_s: float = 2.98e-3
    ifov_rad: float = 2.56e-5
    rpy_rad: tuple[float, float, float] = (np.radians(0.4), np.radians(-0.2), np.radians(0.3))
    first_line: int = 8  # the corners' first line (the records start at 8)

    def t(self, line: np.ndarray) -> np.ndarray:
        """Seconds after START of raw lines: the law the record is written from."""
        return 2.0 + np.asarray(line, float) * self.period_s

    def ray(self, line: np.ndarray, col: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        t = self.t(line)
        p, v = self.orbit.state(t)
        vi = v + np.cross([0.0, 0.0, OMEGA_E], p)
        z = p / np.linalg.norm(p, axis=1, keepdims=True)
        x = vi - np.sum(vi * z, axis=1, keepdims=True) * z
        x /= np.linalg.norm(x, axis=1, keepdims=True)
        frame = np.stack([x, np.cross(z, x), z], axis=2)  # columns: orbital axes in ECEF
        turn = Rotation.from_euler("XYZ", self.rpy_rad).as_matrix()  # Rx(roll) Ry(pitch) Rz(yaw)
        c0 = (self.columns - 1) / 2.0
        look = np.column_stack([0 * col, (np.asarray(col, float) - c0) * self.ifov_rad, -np.ones(np.size(col))])
        d = np.einsum("nij,jk,nk->ni", frame, turn, look)
        return p, d / np.linalg.norm(d, axis=1, keepdims=True)

    def ground(self, line: np.ndarray, col: np.ndarray) -> np.ndarray:
        """(lon, lat) of image positions on the ellipsoid."""
        s, d = self.ray(line, col)
        lo, hi = np.full(s.shape[0], 500e3), np.full(s.shape[0], 1500e3)
        for _ in range(60):
            mid = 0.5 * (lo + hi)
            q = s + mid[:, None] * d
            above = np.array(TO_GEODETIC.transform(q[:, 0], q[:, 1], q[:, 2]))[2] > 0
            lo, hi = np.where(above, mid, lo), np.where(above, hi, mid)
        q = s + (0.5 * (lo + hi))[:, None] * d
        return np.column_stack(TO_GEODETIC.transform(q[:, 0], q[:, 1], q[:, 2]))[:, :2]


def _utc(t: float) -> str:
    return (START + timedelta(seconds=float(t))).strftime("%Y-%m-%dT%H:%M:%S.%f")


def record_xml(scene: InpeScene, lag_lines: int = 8) -> str:
    """The ``*_BANDn.xml`` text of the scene (module docstring)."""
    l0, l1 = scene.first_line, scene.lines - 1
    c1 = scene.columns - 1
    corners = {"UL": (l0, 0), "UR": (l0, c1), "LR": (l1, c1), "LL": (l1, 0), "CT": ((l0 + l1) // 2, c1 // 2)}
    lonlat = scene.ground(np.array([v[0] for v in corners.values()], float), np.array([v[1] for v in corners.values()], float))
    data = "".join(f"<{k}><line>{v[0]:.6f}</line><column>{v[1]:.6f}</column><latitude>{g[1]!r}</latitude>"
                   f"<longitude>{g[0]!r}</longitude></{k}>" for (k, v), g in zip(corners.items(), lonlat.tolist()))
    t_eph = np.arange(-3.0, float(scene.t(l1)) + 5.0, 1.0)
    p, v = scene.orbit.state(t_eph)
    eph = "".join(f'<ephemeris description="PACDB_GPS"><time>{_utc(t)}</time><x>{a[0]!r}</x><y>{a[1]!r}</y><z>{a[2]!r}</z>'
                  f"<vx>{b[0]!r}</vx><vy>{b[1]!r}</vy><vz>{b[2]!r}</vz></ephemeris>" for t, a, b in zip(t_eph, p.tolist(), v.tolist()))
    begin, end = float(scene.t(l0 + lag_lines)), float(scene.t(l1 - lag_lines))
    return f"""<?xml version="1.0" encoding="UTF-8" standalone="no" ?>
<prdf xmlns="{NAMESPACE}">
  <satellite><name>CBERS</name><number>4</number><instrument channel="1">MUX</instrument></satellite>
  <image>
    <level>2</level>
    <timeStamp><begin>{_utc(begin)}</begin><center>{_utc(0.5 * (begin + end))}</center><end>{_utc(end)}</end></timeStamp>
    <imageData>{data}</imageData>
    <ephemerides>{eph}</ephemerides>
    <integrationTime><band name="6">148600</band></integrationTime>
  </image>
</prdf>
"""
