"""The nominal attitude of an image without control (solver/blocks/platform_values.py): the camera
pitched by its mounting angle from the platform's own vertical, its x axis along the flight.

The LGS has one vertical, at its origin. An image hundreds of kilometres away sees the ground
under a vertical tilted by 2.7 deg per 300 km (13.5 deg at 1,500 km along a strip, 68 deg at
7,500 km): a nominal attitude taken from the LGS vertical starts such an image's rays kilometres
to thousands of kilometres off, and a five-million-observation strip diverged from it.

The independent evidence:
- the boresight and the along-track axis against the satellite convention written out in ECEF
  (``-z_c = -cos(theta) up + sin(theta) x_track``, the convention of ``solver/simulate/attitude.py``),
  with the platform's geodetic vertical from PROJ (not from the solver's geodesy), and the
  angles turned into a matrix by the kernels' own rotation (the model's convention);
- the independent simulator's true camera rotation of every image of a strip with too little
  control for a resection.
"""

from __future__ import annotations

import math
from types import SimpleNamespace

import numpy as np
import pytest
from pyproj import Transformer

from solver.blocks.platform_values import nominal_attitude
from solver.geometry.geodesy import LocalFrame, geodetic_to_ecef
from solver.kernels import rotation_and_derivatives
from solver.platforms import ANGLES, coef_index
from solver.procedures.single import prepare

ORIGIN = (-51.39, -22.12, 450.0)  # lon, lat, h of the LGS origin (deg, deg, m)
_TO_GEODETIC = Transformer.from_crs("EPSG:4978", "EPSG:4979", always_xy=True)


def _geodetic_up(r_ecef: np.ndarray) -> np.ndarray:
    lon, lat, _h = _TO_GEODETIC.transform(*r_ecef)
    lon, lat = math.radians(lon), math.radians(lat)
    return np.array([math.cos(lat) * math.cos(lon), math.cos(lat) * math.sin(lon), math.sin(lat)])


def _platform(lon: float, lat: float, heading_deg: float) -> tuple[np.ndarray, np.ndarray]:
    """ECEF position 692 km above (lon, lat) and a horizontal velocity of 7.5 km/s on the heading."""
    r = geodetic_to_ecef(np.array([[lon, lat, 692e3]]))[0]
    up = _geodetic_up(r)
    east = np.cross([0.0, 0.0, 1.0], up)
    east /= np.linalg.norm(east)
    north = np.cross(up, east)
    h = math.radians(heading_deg)
    return r, 7500.0 * (math.sin(h) * east + math.cos(h) * north)


def _camera_axes_ecef(frame: LocalFrame, angles: tuple[float, float, float]) -> tuple[np.ndarray, np.ndarray]:
    """The camera's x axis and boresight (-z) in ECEF for LGS angles (the kernels' rotation)."""
    m = rotation_and_derivatives(*angles)[0]  # LGS -> camera
    return frame.vector_to_ecef(m[0]), frame.vector_to_ecef(-m[2])


VERTICAL_DEG = 1e-6


def _angle_deg(a: np.ndarray, b: np.ndarray) -> float:
    """The angle between two vectors, from atan2 of the cross and dot products: exact to rounding
    for small angles too (acos of a dot product rounds to 0 or to at least 8.5e-7 deg near 1)."""
    return math.degrees(math.atan2(float(np.linalg.norm(np.cross(a, b))), float(a @ b)))


@pytest.mark.parametrize("offset_deg", [(0.0, 0.0), (2.7, 0.0), (-1.0, 13.5), (40.0, -30.0), (68.0, 20.0)])
@pytest.mark.parametrize("pitch_deg", [0.0, 23.8, -23.8])
@pytest.mark.parametrize("heading_deg", [190.0, 12.0])
def test_the_camera_looks_from_the_platform_vertical(offset_deg, pitch_deg: float, heading_deg: float) -> None:
    frame = LocalFrame.at(geodetic_to_ecef(np.array([ORIGIN]))[0])
    r, v = _platform(ORIGIN[0] + offset_deg[0], ORIGIN[1] + offset_deg[1], heading_deg)
    img = SimpleNamespace(camera=SimpleNamespace(mounting_pitch_deg=pitch_deg))
    x_cam, boresight = _camera_axes_ecef(frame, nominal_attitude(img, frame, v, r))
    up, track = _geodetic_up(r), v / np.linalg.norm(v)
    theta = math.radians(pitch_deg)
    # VERTICAL_DEG: the solver's geodetic vertical and PROJ's differ by 1e-8 to 2.6e-8 deg here
    # (0.3 mm at 692 km); a vertical of the wrong place is off by degrees
    assert _angle_deg(boresight, -math.cos(theta) * up + math.sin(theta) * track) < VERTICAL_DEG
    assert _angle_deg(x_cam, math.cos(theta) * track + math.sin(theta) * up) < VERTICAL_DEG


def test_on_the_origin_vertical_it_is_the_lgs_nominal() -> None:
    """Above the LGS origin both verticals agree: small blocks start where they did."""
    frame = LocalFrame.at(geodetic_to_ecef(np.array([ORIGIN]))[0])
    r, v = _platform(ORIGIN[0], ORIGIN[1], 190.0)
    img = SimpleNamespace(camera=SimpleNamespace(mounting_pitch_deg=23.8))
    levelled = np.array(nominal_attitude(img, frame, v, r))
    assert np.allclose(levelled, nominal_attitude(img, frame, v), atol=1e-12)  # radians: rounding only


def test_a_strip_without_control_starts_at_the_simulated_attitude() -> None:
    """Every image of the independent simulator's strip (about 650 km of PRISM triplets, two
    control points per triplet: too few for a resection) starts within 0.3 deg of its true
    boresight; from the LGS vertical its end images would start degrees off."""
    from solver.api import _as_job
    from solver.simulate import presets
    from solver.simulate.scene import SceneSettings

    scene = presets.strip(SceneSettings(preset="strip", seed=3), triplets=18, tie_points=900, gcps=36, checks=18)
    job = scene.job()
    for image in job["images"]:
        image["model"] = {"name": "P2"}
    job.setdefault("options", {})["ephemeris"] = {"sigma_position_m": 10.0, "sigma_velocity_m_s": 0.05}
    problem = prepare(_as_job(job))
    truth = {im["id"]: im for im in scene.truth()["images"]}
    frame = problem.frame
    levelled, lgs_vertical = [], []
    for img, doc in zip(problem.images, problem.job.images):
        true_m = np.array(truth[img.id]["samples"]["camera_from_ecef"][0])  # line 0: ECEF -> camera
        true_boresight = -true_m[2]
        ours = tuple(img.base[coef_index(e, 0)] for e in ANGLES)
        levelled.append(_angle_deg(_camera_axes_ecef(frame, ours)[1], true_boresight))
        state = doc.approx_state
        flat = nominal_attitude(img, frame, np.array(state.velocity_ecef_m_s))
        lgs_vertical.append(_angle_deg(_camera_axes_ecef(frame, flat)[1], true_boresight))
    # 0.3 deg: the simulator points along the geocentric radius (our geodetic vertical differs by
    # up to 0.19 deg) and adds its attitude drift; the LGS vertical is off by the arc to the origin
    assert max(levelled) < 0.3, max(levelled)
    assert max(lgs_vertical) > 2.0, max(lgs_vertical)
