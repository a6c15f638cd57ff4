"""DEM heights of tie points (solver.observations.dem_heights): the residual v = h_dem - h of a
point in the LGS and its derivatives along the LGS axes (the local east, north, up at the
point, the DEM's slope) against central differences, far from the LGS origin where the axes
differ from the local ones; the linearised term against its own evaluation."""

from __future__ import annotations

import numpy as np
import pytest
from pyproj import CRS
from utils.differences import central_jacobian

from solver.geometry.dem import Dem
from solver.geometry.geodesy import LocalFrame, geodetic_to_ecef
from solver.geometry.vertical import resolve
from solver.observations.dem_heights import DemTerm, sample

STEP_M = 0.5  # inside one 1-arc-second cell (30 m): the bilinear surface is smooth there
# m/m: the DEM's slope is per metre on the ellipsoid, the point moves h above it (h / R = 1.5e-4
# of a slope of 0.4 at 950 m); the differences' truncation over 0.5 m is far below
JAC_TOL = 1e-4


def _rough_dem(lon0: float, lat0: float) -> Dem:
    d = 1.0 / 3600
    n = 600
    rng = np.random.default_rng(7)
    cols, rows = np.meshgrid(np.arange(n), np.arange(n))
    values = 400.0 + 0.15 * cols * 30 - 0.08 * rows * 30 + rng.normal(0, 4.0, (n, n))
    return Dem(values, (d, 0.0, lon0 - n * d / 2, 0.0, -d, lat0 + n * d / 2), CRS.from_epsg(4326), resolve(None, "ellipsoid"))


def test_residual_gradient_agrees_with_central_differences() -> None:
    lon0, lat0 = 5.2, 44.2
    frame = LocalFrame.at(geodetic_to_ecef(np.array([[lon0, lat0, 0.0]]))[0])
    dem = _rough_dem(lon0, lat0)
    # points 2-4 km from the origin: their local up is 0.3-0.6 mrad from the LGS's
    for lon, lat, h in ((5.225, 44.21, 600.0), (5.17, 44.185, 300.0), (5.21, 44.19, 950.0)):
        p = frame.to_lgs(geodetic_to_ecef(np.array([[lon, lat, h]]))[0])
        p[:2] += 7.3  # away from a cell edge in neither axis
        smp = sample(frame, dem, p[None, :])
        numeric = central_jacobian(lambda x: sample(frame, dem, x[None, :]).residual[0], p, STEP_M)
        np.testing.assert_allclose(smp.gradient[0], numeric, atol=JAC_TOL)
        assert smp.gradient[0][2] == pytest.approx(-1.0, abs=1e-3)  # mostly the point's own height


def test_term_is_its_linearisation() -> None:
    term = DemTerm(3, np.array([10.0, -20.0, 500.0]), 2.5, np.array([0.1, -0.05, -1.0]), 0.5)
    p = np.array([12.0, -19.0, 498.0])
    r, j = term.evaluate(p)
    a, b = term.linear_form()
    np.testing.assert_allclose(r, a @ p - b, atol=1e-12)
    np.testing.assert_allclose(j, a)
    assert r[0] == pytest.approx(0.5 * (2.5 + 0.2 - 0.05 + 2.0))
